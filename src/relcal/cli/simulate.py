"""``relcal simulate``: the published simulation with known errors."""

from __future__ import annotations

import argparse

from relcal.cli.common import (
    fraction_at_most_one,
    int_at_least,
    json_arg,
    load_robot,
    noise_levels,
    nonnegative_float,
    output_file,
    output_folder,
    pairing_arg,
    positive_float,
    robot_args,
    seed,
    simulated_poses,
)

EPILOG_SIMULATE = """\
examples:
  relcal simulate --robot a465                       # both published runs, random errors
  relcal simulate --robot a465 --measure pose --formulation invariant --noise 0.05,0.01
  relcal simulate --robot a465 --measure pose --pairing board --method lm   # board formulation
  relcal simulate --robot puma560 --errors errors.yaml --json out.json
  relcal simulate --robot a465 --images synthetic/ --poses 40   # rendered images, full pipeline
  relcal simulate --robot a465 --images synthetic/ --poses 40 --image-scale 0.5  # 1224x1024 px
  relcal simulate --robot a465 --measure pose --nongeometric scale,harmonic  # + joint scale, runout
  relcal simulate --robot arm_with_masses.yaml --nongeometric compliance     # needs link masses
  relcal simulate --robot panda.urdf --tip ball_link --coincidence balls/   # ball-in-socket data
  relcal simulate --robot panda.urdf --tip ball_link --coincidence balls/ --placements 6 \
      --seating 0.05 --no-distance                   # no known distance: the scale is not seen
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
    from relcal.reporting.text import format_simulation, simulated_text
    from relcal.robot.kinematics import make_layout
    from relcal.sim.scenario import load_errors
    from relcal.sim.simulate import simulate

    model = nongeometric_model(args, load_robot(args))
    if args.images:
        return run_images(args, model)
    if args.coincidence:
        return run_coincidence(args, model)
    noise = Noise.parse(args.noise) if args.noise else Noise()
    errors = load_errors(args.errors, make_layout(model)) if args.errors else None
    check(
        [File(p, b"", what) for p, what in ((args.json, "--json"), (args.report, "--report")) if p]
    )
    measures = [args.measure] if args.measure else ["position", "pose"]
    from relcal.limits import resolve_pairing

    # the board formulation (asked for, or auto's for the frame-invariant data, or above 300
    # poses) compares camera poses in the board frame; the default is the paper's simulation
    formulation = args.formulation or "published"
    board = resolve_pairing(args.pairs, args.poses, formulation) == "board"
    formulation = args.formulation or ("invariant" if board else "published")
    runs = []
    for measure in measures:
        sim = simulate(
            model,
            formulation=formulation,
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
            print(
                f"\n{model.name}: {simulated_text(sim)}, {len(sim.problem.q)} poses, "
                f"{sim.result.method} solver"
            )
            print(format_simulation(sim))
    items = []
    if args.json:
        reports = [simulation_document(s) for s in runs]
        doc = reports[0] if len(reports) == 1 else {"runs": reports}
        items.append(File(args.json, json_text(doc), "--json"))
    if args.report:
        from relcal.reporting.simulation_report import simulation_report

        items.append(File(args.report, simulation_report(runs), "--report"))
    write_set(*items)
    return 0 if all(s.result.converged for s in runs) else 1


def run_images(args: argparse.Namespace, model) -> int:
    """Render a synthetic image dataset, run the real image pipeline and calibration on it, and
    compare with the truth."""
    import numpy as np

    from relcal.calibration.pipeline import calibrate
    from relcal.data.dataset import load_dataset
    from relcal.data.imaging import measure
    from relcal.io import Folder, write_set
    from relcal.reporting.documents import parameter_status, results_document
    from relcal.reporting.text import calibration_summary, format_truth
    from relcal.robot.model import auto_hayati
    from relcal.sim.synth import DEFAULT_CAMERA, write_image_dataset

    found = {}
    camera = DEFAULT_CAMERA.scaled(args.image_scale)

    def render(folder):
        found["truth"] = write_image_dataset(
            folder,
            auto_hayati(model),
            n_images=args.poses,
            seed=args.seed,
            camera=camera,
            progress=not args.quiet,
        )

    write_set(Folder(args.images, what="--images", replace="refuse", fill=render))
    truth = found["truth"]
    dataset = load_dataset(args.images)
    cal = calibrate(dataset, measure(dataset, progress=not args.quiet), seed=args.seed)
    if not args.quiet:
        print(calibration_summary(results_document(cal)))
        # The calibration's layout adds model selection's non-geometric candidates to the
        # truth's: compare by name, the chosen model's estimated parameters.
        layout = cal.problem.layout
        estimated = np.array([s == "estimated" for s in parameter_status(cal)[: layout.size]])
        print(format_truth(layout, truth.errors_on(layout), cal.result, estimated))
        print(f"dataset written to {args.images}")
    return 0 if cal.result.converged else 1


def run_coincidence(args: argparse.Namespace, model) -> int:
    """Write a simulated ball-in-socket dataset (planted errors, seating scatter, several
    placements of a plate with two sockets), then hold out each placement in turn and print the
    spread of the predicted points and the distance error, nominal against calibrated."""
    from relcal.calibration.pipeline import cross_validate
    from relcal.calibration.validate import pooled
    from relcal.data.dataset import load_dataset
    from relcal.io import Folder, write_set
    from relcal.robot.model import auto_hayati
    from relcal.sim.coincidence import dataset_files, robot_entry, simulate_coincidence
    from relcal.sim.scenario import load_errors

    if args.hayati == "auto":
        model = auto_hayati(model)
    from relcal.robot.kinematics import make_layout

    errors = load_errors(args.errors, make_layout(model)) if args.errors else None
    truth = simulate_coincidence(
        model,
        placements=args.placements,
        per_socket=args.per_socket,
        spacing=args.spacing * 1e-3,
        seating=args.seating * 1e-3,
        errors=errors,
        seed=args.seed,
    )
    files = dataset_files(
        truth,
        robot_entry(args.robot, args.root, args.tip),
        None if args.no_distance else args.distance_std * 1e-3,
    )
    write_set(Folder(args.coincidence, files, what="--coincidence", replace="refuse"))
    if args.quiet:
        return 0
    print(
        f"dataset written to {args.coincidence}: {len(truth.q)} samples, {args.placements} "
        f"placements of two sockets {args.spacing:g} mm apart, seating scatter {args.seating:g} "
        "mm (truth.yaml holds the planted errors)"
    )
    if args.placements < 2:
        return 0
    dataset = load_dataset(args.coincidence)
    # the planted errors are geometric: no non-geometric candidate (a few samples per placement)
    folds = cross_validate(dataset, k=args.placements, seed=args.seed, nongeometric="none")
    check = pooled([f.validation for f in folds])
    print("each placement held out in turn (its points refitted, the rest frozen):")
    for which in ("baseline", "calibrated"):
        summary = getattr(check, which).summary()
        spread, dist = summary["spread_mm"], summary["distance_error_mm"]
        line = f"  {which:10s} spread RMS {spread['rms']:.3f} mm, max {spread['max']:.3f} mm"
        if dist is not None:
            line += f"; distance error RMS {dist['rms']:.3f} mm, max {dist['max']:.3f} mm"
        print(line)
    return 0


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
    sim.add_argument(
        "--formulation",
        choices=("published", "invariant"),
        help="published (default; Lu & Hayes, base-aligned differences) or invariant (camera "
        "poses in the board frame, the hand-eye estimated); invariant is the default with "
        "--pairing board, and with auto's board above 300 poses",
    )
    sim.add_argument("--method", choices=("published", "lm"), default="published")
    pairing_arg(sim, calibration=False)
    sim.add_argument(
        "--n-poses",
        "--poses",
        dest="poses",
        type=simulated_poses,
        default=60,
        help="number of poses (default 60; --poses is its former name)",
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
    ball = sim.add_argument_group("coincidence (a ball seated in the sockets of a plate)")
    ball.add_argument(
        "--coincidence",
        metavar="DIR",
        type=output_folder,
        help="write a coincidence dataset into DIR (new or empty): planted errors (--errors or "
        "random), joints that seat the tool point in two sockets per placement",
    )
    ball.add_argument("--placements", type=int_at_least(1), default=4, help="default 4")
    ball.add_argument(
        "--per-socket", type=int_at_least(3), default=30, help="samples per socket (default 30)"
    )
    ball.add_argument(
        "--spacing", type=positive_float, default=50.0, help="socket spacing, mm (default 50)"
    )
    ball.add_argument(
        "--seating",
        type=nonnegative_float,
        default=0.08,
        help="standard deviation of the ball centre within a socket, mm per axis (default 0.08)",
    )
    ball.add_argument(
        "--distance-std",
        type=positive_float,
        default=0.05,
        help="standard deviation of the spacing written in distances:, mm (default 0.05)",
    )
    ball.add_argument(
        "--no-distance", action="store_true", help="write no distances: (the scale is unseen)"
    )
    sim.add_argument(
        "--image-scale",
        metavar="F",
        type=fraction_at_most_one,
        default=1.0,
        help="with --images: render at F times the 2448x2048 px resolution, same lens and field "
        "of view (0.5: 1224x1024 px, about 4x faster to render; default 1)",
    )
    sim.add_argument("--quiet", action="store_true", help="print nothing but errors")
    sim.set_defaults(func=run)
