"""``relcal simulate``: the published simulation with known errors."""

from __future__ import annotations

import argparse

from relcal.commands import load_robot, robot_args

EPILOG_SIMULATE = """\
examples:
  relcal simulate --robot a465                       # both published runs, random errors
  relcal simulate --robot a465 --measure pose --formulation invariant --noise 0.05,0.01
  relcal simulate --robot puma560 --errors errors.yaml --json out.json
"""


def run(args: argparse.Namespace) -> int:
    from relcal.io import write_json
    from relcal.kinematics import make_layout
    from relcal.simulate import Noise, format_table, load_errors, simulate

    model = load_robot(args)
    noise = Noise.parse(args.noise) if args.noise else Noise()
    errors = load_errors(args.errors, make_layout(model)) if args.errors else None
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
            print(format_table(sim))
    if args.json:
        reports = [s.report() for s in runs]
        write_json(args.json, reports[0] if len(reports) == 1 else {"runs": reports})
    return 0 if all(s.result.converged for s in runs) else 1


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
    sim.add_argument("--poses", type=int, default=60, help="number of poses (default 60)")
    sim.add_argument("--noise", help="POS_MM,ORI_DEG[,JOINT_DEG] standard deviations")
    sim.add_argument("--seed", type=int, default=0)
    sim.add_argument("--errors", help="YAML file of specified errors (default: random)")
    sim.add_argument("--json", help="write the results as JSON to this file")
    sim.add_argument("--quiet", action="store_true", help="print nothing but errors")
    sim.set_defaults(func=run)
