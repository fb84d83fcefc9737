"""``relcal observability``: what a set of poses can identify, and how well."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from relcal.cli.common import (
    existing_file,
    fraction,
    json_arg,
    load_robot,
    noise_levels,
    nonnegative_int,
    pairing_arg,
    robot_args,
    seed,
    simulated_poses,
)

if TYPE_CHECKING:
    import numpy as np

EPILOG = """\
examples:
  relcal observability --robot a465                        # 40 simulated poses, hand-eye estimated
  relcal observability --robot a465 --hayati auto          # Hayati's beta resolves axes 2 and 3
  relcal observability --robot a465 --poses plan.csv --json report.json
  relcal observability --robot a465 --formulation published --measure position --handeye known
  relcal observability --robot a465 --pairing board        # the board formulation (W estimated)

poses: a CSV with a header  id,q1..qn  (other columns are ignored, so a dataset's samples.csv
works too); angles in --joint-unit (prismatic joints in m)
"""


def build_problem(model, q: np.ndarray, formulation: str, measure: str, pairs: str):
    """The identification problem at configurations ``q`` with the simulation's hand-eye
    (``pairs`` ``board``: the board formulation)."""
    from relcal.calibration.measurement import camera_problem
    from relcal.design.cell import Cell

    return camera_problem(model, q, Cell().handeye, formulation, measure, pairs)


def joint_source(args: argparse.Namespace, model) -> tuple[np.ndarray, str]:
    """Joint values from ``--poses`` or simulated, and a phrase saying which."""
    from relcal.data.dataset import read_joints
    from relcal.sim.scenario import simulated_joints

    if args.poses:
        return read_joints(
            Path(args.poses), model, args.joint_unit, "--joint-unit"
        ), f"poses from {args.poses}"
    q = simulated_joints(model, args.n_poses, args.seed)
    return q, f"{len(q)} simulated poses over the board (seed {args.seed})"


def run(args: argparse.Namespace) -> int:
    from relcal.calibration.noise import Noise
    from relcal.design.observability import report
    from relcal.io import write_json
    from relcal.limits import resolve_pairing
    from relcal.reporting.documents import observability_document
    from relcal.reporting.text import comparison_text, format_observability

    model = load_robot(args)
    q, source = joint_source(args, model)
    if args.json:
        from relcal.outputset import File, check

        check([File(args.json, b"", "--json")])  # before the work
    problem = build_problem(model, q, args.formulation, args.measure, args.pairs)
    noise = None if args.noise.lower() == "none" else Noise.parse(args.noise)
    from relcal.sim.scenario import simulated_joints

    q_val = None
    if noise is not None and args.validation > 0:
        q_val = simulated_joints(model, args.validation, args.seed + 1)
    rep = report(
        problem,
        handeye=args.handeye,
        rcond=args.rcond,
        noise=noise,
        q_validation=q_val,
        estimator=args.estimator,
    )
    pairing = resolve_pairing(args.pairs, len(q), problem.formulation)
    if not args.quiet:
        print(f"{source}, {comparison_text(problem.formulation, pairing)}")
        print(format_observability(rep))
    if args.json:
        doc = observability_document(rep)
        doc["poses_source"] = source
        doc["pairing"] = pairing
        write_json(args.json, doc)
    return 0


def add_noise_arg(parser: argparse.ArgumentParser, default: str = "0.05,0.01,0.001") -> None:
    parser.add_argument(
        "--noise",
        type=noise_levels,
        default=default,
        help="POS_MM,ORI_DEG[,JOINT_DEG] standard deviations of each measured pose and joint "
        f"reading (default {default}; 'none' skips the uncertainty)",
    )


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "observability",
        help="identifiability report: singular values, observability indices, named "
        "unidentifiable combinations, parameter uncertainty",
        description="Analyse the identification Jacobian of a robot, formulation and set of "
        "poses: singular values, observability indices O1..O5, the identifiable subset (QR with "
        "column pivoting), unidentifiable combinations named with the reason, parallel axes, "
        "and the standard deviations and correlations of the identified parameters.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    robot_args(p)
    p.add_argument(
        "--poses",
        type=existing_file,
        help="CSV of joint configurations (default: simulated poses)",
    )
    p.add_argument(
        "--joint-unit",
        choices=("deg", "rad"),
        help="the unit of a --poses file's angles (default: the unit a relcal plan states, else "
        "deg)",
    )
    p.add_argument(
        "--n-poses", type=simulated_poses, default=40, help="simulated poses (default 40)"
    )
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--formulation", choices=("invariant", "published"), default="invariant")
    p.add_argument("--measure", choices=("pose", "position"), default="pose")
    p.add_argument(
        "--handeye",
        choices=("estimated", "known"),
        default="estimated",
        help="frame-invariant formulation: estimate the hand-eye transform or take it as known "
        "(the board formulation, --pairing board, estimates it)",
    )
    pairing_arg(p, calibration=False)
    add_noise_arg(p)
    p.add_argument(
        "--estimator",
        choices=("weighted", "least_squares"),
        default="weighted",
        help="whose covariance the correlations are of (both standard deviations are shown)",
    )
    p.add_argument(
        "--validation",
        type=nonnegative_int,
        default=30,
        help="simulated validation poses for the predicted accuracy (0: skip; default 30)",
    )
    p.add_argument(
        "--rcond",
        type=fraction,
        default=1e-6,
        help="relative rank tolerance, 0 < RCOND < 1 (default 1e-6)",
    )
    json_arg(p, "the report")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=run)
