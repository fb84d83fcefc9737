"""``relcal simulate``: the published simulation with known errors."""

from __future__ import annotations

import argparse

from relcal.cli.common import (
    int_at_least,
    json_arg,
    load_robot,
    noise_levels,
    output_file,
    output_folder,
    robot_args,
    seed,
)

EPILOG_SIMULATE = """\
examples:
  relcal simulate --robot a465                       # both published runs, random errors
  relcal simulate --robot a465 --measure pose --formulation invariant --noise 0.05,0.01
  relcal simulate --robot puma560 --errors errors.yaml --json out.json
  relcal simulate --robot a465 --images synthetic/ --poses 40   # rendered images, full pipeline
  relcal simulate --robot a465 --measure pose --nongeometric scale,harmonic  # + joint scale, runout
  relcal simulate --robot arm_with_masses.yaml --nongeometric compliance     # needs link masses
"""


def nongeometric_model(args: argparse.Namespace, model):
    """``model`` with the non-geometric terms of ``--nongeometric`` on every joint that can have
    them, and those the ``--errors`` file names on their joints."""
    from relcal.robot.model import with_nongeometric
    from relcal.sim.scenario import nongeometric_in_errors

    if args.nongeometric:
        terms = [t.strip() for t in args.nongeometric.split(",") if t.strip()]
        model = with_nongeometric(model, terms)
    if args.errors:
        for term, joints in nongeometric_in_errors(args.errors).items():
            model = with_nongeometric(model, [term], joints)
    return model


def run(args: argparse.Namespace) -> int:
    from relcal.calibration.noise import Noise
    from relcal.io import File, json_text, write_set
    from relcal.outputset import check
    from relcal.reporting.documents import simulation_document
    from relcal.reporting.text import format_simulation
    from relcal.robot.kinematics import make_layout
    from relcal.sim.scenario import load_errors
    from relcal.sim.simulate import simulate

    model = nongeometric_model(args, load_robot(args))
    if args.images:
        return run_images(args, model)
    noise = Noise.parse(args.noise) if args.noise else Noise()
    errors = load_errors(args.errors, make_layout(model)) if args.errors else None
    check(
        [File(p, b"", what) for p, what in ((args.json, "--json"), (args.report, "--report")) if p]
    )
    measures = [args.measure] if args.measure else ["position", "pose"]
    runs = []
    for measure in measures:
        sim = simulate(
            model,
            formulation=args.formulation,
            measure=measure,
            n_poses=args.poses,
            noise=noise,
            seed=args.seed,
            errors=errors,
            method=args.method,
            pairing=args.pairs,
        )
        runs.append(sim)
        if not args.quiet:
            what = "position only" if measure == "position" else "position and orientation"
            print(
                f"\n{model.name}: relative {what}, {args.formulation} formulation, "
                f"{len(sim.problem.q)} poses, {args.pairs} pairs, {sim.result.method} solver"
            )
            print(format_simulation(sim))
    items = []
    if args.json:
        reports = [simulation_document(s) for s in runs]
        doc = reports[0] if len(reports) == 1 else {"runs": reports}
        items.append(File(args.json, json_text(doc), "--json"))
    if args.report:
        from relcal.reporting.html import simulation_report

        items.append(File(args.report, simulation_report(runs), "--report"))
    write_set(*items)
    return 0 if all(s.result.converged for s in runs) else 1


def run_images(args: argparse.Namespace, model) -> int:
    """Render a synthetic image dataset, run the real image pipeline and calibration on it, and
    compare with the truth."""
    from relcal.calibration.pipeline import calibrate
    from relcal.data.dataset import load_dataset
    from relcal.data.imaging import measure
    from relcal.io import Folder, write_set
    from relcal.reporting.documents import results_document
    from relcal.reporting.text import calibration_summary, format_truth
    from relcal.robot.model import auto_hayati
    from relcal.sim.synth import write_image_dataset

    found = {}

    def render(folder):
        found["truth"] = write_image_dataset(
            folder, auto_hayati(model), n_images=args.poses, seed=args.seed, progress=not args.quiet
        )

    write_set(Folder(args.images, what="--images", replace="refuse", fill=render))
    truth = found["truth"]
    dataset = load_dataset(args.images)
    cal = calibrate(dataset, measure(dataset, progress=not args.quiet), seed=args.seed)
    if not args.quiet:
        print(calibration_summary(results_document(cal)))
        print(format_truth(cal.problem.layout, truth.errors, cal.result))
        print(f"dataset written to {args.images}")
    return 0 if cal.result.converged else 1


def register(sub: argparse._SubParsersAction) -> None:
    sim = sub.add_parser(
        "simulate",
        help="reproduce the published simulation on a robot with known errors",
        description="Synthesise geometric errors, measure relative poses in simulation, identify "
        "them and print specified versus identified errors per joint.",
        epilog=EPILOG_SIMULATE,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    robot_args(sim)
    sim.add_argument("--measure", choices=("position", "pose"), help="one run only (default both)")
    sim.add_argument("--formulation", choices=("published", "invariant"), default="published")
    sim.add_argument("--method", choices=("published", "lm"), default="published")
    sim.add_argument("--pairs", choices=("consecutive", "star", "all"), default="consecutive")
    sim.add_argument(
        "--poses", type=int_at_least(3), default=60, help="number of poses (default 60)"
    )
    sim.add_argument(
        "--noise", type=noise_levels, help="POS_MM,ORI_DEG[,JOINT_DEG] standard deviations"
    )
    sim.add_argument("--seed", type=seed, default=0)
    sim.add_argument("--errors", help="YAML file of specified errors (default: random)")
    sim.add_argument(
        "--nongeometric",
        metavar="TERMS",
        help="plant and identify non-geometric terms on every joint: a comma list of scale "
        "(gear ratio), compliance (under gravity; the model needs link masses or a payload), "
        "harmonic (first harmonic, revolute joints); terms an --errors file names are added",
    )
    json_arg(sim, "the results")
    sim.add_argument(
        "--report",
        metavar="FILE",
        type=output_file,
        help="write an HTML report of the run(s) to FILE",
    )
    sim.add_argument(
        "--images",
        metavar="DIR",
        type=output_folder,
        help="render a synthetic image dataset (2448x2048 px, 8 mm lens, chessboard; --poses "
        "images) into DIR and calibrate it with the real image pipeline",
    )
    sim.add_argument("--quiet", action="store_true", help="print nothing but errors")
    sim.set_defaults(func=run)
