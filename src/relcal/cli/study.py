"""``relcal study``: Monte Carlo check of the predicted parameter uncertainty."""

from __future__ import annotations

import argparse
from pathlib import Path

from relcal.cli.common import (
    int_at_least,
    json_arg,
    load_robot,
    pairing_arg,
    poses_or_file,
    positive_float,
    robot_args,
    seed,
    worker_processes,
)
from relcal.cli.observability import add_noise_arg

EPILOG = """\
examples:
  relcal study --robot a465 --hayati auto                    # 200 trials, 30 simulated poses
  relcal study --robot a465 --hayati auto --poses plan.csv --json study.json
  relcal study --robot a465 --hayati auto --poses 16 --sampling matched
  relcal study --robot a465 --hayati auto --estimator least_squares --pairing all
  relcal study --robot a465 --hayati auto --pairing board    # the board formulation

The empirical standard deviation of each parameter over T independent trials scatters by about
1/sqrt(2(T-1)) around the true one (5% at 200 trials); --sampling matched removes that scatter
(the trials' noise has exactly the modelled covariance) and needs more trials than 6 (or 6 + n
with joint noise) times the number of poses.
"""


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from relcal.calibration.noise import Noise
    from relcal.cluster import connect
    from relcal.data.dataset import read_joints
    from relcal.errors import RelcalError
    from relcal.io import write_json
    from relcal.reporting.documents import study_document
    from relcal.reporting.text import comparison_text, format_study
    from relcal.robot.kinematics import make_layout
    from relcal.sim.scenario import load_errors, make_scenario, simulated_joints
    from relcal.sim.study import study

    model = load_robot(args)
    if isinstance(args.poses, str):  # (poses_or_file: an existing file, else a number)
        q = read_joints(Path(args.poses), model, args.joint_unit, "--joint-unit")
        source = f"poses from {args.poses}"
    else:
        q = simulated_joints(model, args.poses, args.seed)
        source = f"{len(q)} simulated poses over the board"
    if args.json:
        from relcal.outputset import File, check

        check([File(args.json, b"", "--json")])  # before the trials
    noise = Noise.parse(args.noise)
    if noise.position <= 0 or noise.orientation <= 0:
        raise RelcalError("--noise: the study needs positive position and orientation noise")
    errors = load_errors(args.errors, make_layout(model)) if args.errors else None
    scenario = make_scenario(
        model,
        q,
        noise,
        seed=args.seed,
        formulation=args.formulation,
        measure=args.measure,
        pairing=args.pairs,
        errors=errors,
    )
    client = connect(args.scheduler)[0] if args.scheduler else None
    try:
        res = study(
            scenario,
            trials=args.trials,
            seed=args.seed,
            workers=args.workers,
            estimator=args.estimator,
            sampling=args.sampling,
            progress=not args.quiet,
            client=client,
        )
    finally:
        if client is not None:
            client.close()
    if not args.quiet:
        how = comparison_text(scenario.problem_formulation, scenario.pairing)
        print(f"\n{model.name}: {how}, {args.measure}, {source}")
        print(format_study(res, args.length_scale))
    if args.json:
        doc = study_document(res)
        doc.update(
            robot=model.name,
            poses=source,
            formulation=scenario.problem_formulation,
            pairing=scenario.pairing,
        )
        write_json(args.json, doc)
    return 0 if np.all(res.converged) else 1


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "study",
        help="Monte Carlo study: many noisy simulated calibrations against the predicted "
        "standard deviations",
        description="Run many noisy simulated calibrations of the same poses (seeded, in "
        "parallel), and compare the empirical spread and bias of every identified parameter "
        "with the prediction (the Cramer-Rao bound for the noise-weighted estimator).",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    robot_args(p)
    p.add_argument(
        "--poses",
        type=poses_or_file,
        default=30,
        help="CSV of joint configurations, or a number of simulated poses (default 30)",
    )
    p.add_argument(
        "--joint-unit",
        choices=("deg", "rad"),
        help="the unit of a --poses file's angles (default: the unit a relcal plan states, "
        "else deg)",
    )
    p.add_argument(
        "--trials",
        type=int_at_least(2),
        default=200,
        help="number of trials, at least 2 for a standard deviation (default 200)",
    )
    add_noise_arg(p)
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument(
        "--workers", type=worker_processes, default=2, help="worker processes (default 2)"
    )
    p.add_argument(
        "--scheduler",
        metavar="tcp://HOST:8786",
        help="run the trials as tasks on this Dask cluster (instead of --workers processes)",
    )
    p.add_argument(
        "--estimator",
        choices=("weighted", "least_squares"),
        default="weighted",
        help="weighted: whitened by the full noise covariance (prediction = Cramer-Rao bound); "
        "least_squares: relcal's identify (prediction = its sandwich covariance)",
    )
    p.add_argument("--sampling", choices=("random", "matched"), default="random")
    p.add_argument("--formulation", choices=("invariant", "published"), default="invariant")
    p.add_argument("--measure", choices=("pose", "position"), default="pose")
    pairing_arg(p, calibration=False)
    p.add_argument("--errors", help="YAML file of true errors (default: random, seeded)")
    p.add_argument(
        "--length-scale",
        type=positive_float,
        default=0.5,
        help="angles count as the displacement this far away (m) in the worst-parameter line",
    )
    json_arg(p, "the comparison")
    p.add_argument("--quiet", action="store_true", help="no progress bar, print nothing")
    p.set_defaults(func=run)
