"""``relcal observability``: what a set of poses can identify, and how well."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from relcal.cli.common import json_arg, load_robot, robot_args

EPILOG = """\
examples:
  relcal observability --robot a465                        # 40 simulated poses, hand-eye estimated
  relcal observability --robot a465 --hayati auto          # Hayati's beta resolves axes 2 and 3
  relcal observability --robot a465 --poses plan.csv --json report.json
  relcal observability --robot a465 --formulation published --measure position --handeye known

poses: a CSV with a header  id,q1..qn  (other columns are ignored, so a dataset's samples.csv
works too); angles in --joint-unit (prismatic joints in m)
"""


def read_joints(path: Path, model, joint_unit: str) -> np.ndarray:
    """Joint values ``(N, n)`` (rad, m) from a CSV with ``q1..qn`` columns."""
    from relcal.data.dataset import parse_number
    from relcal.errors import RelcalError
    from relcal.io import read_table

    header, data = read_table(path, "pose")
    joints = [f"q{i + 1}" for i in range(model.n_joints)]
    missing = [c for c in joints if c not in header]
    if missing:
        raise RelcalError(
            f"{path} line 1: header: expected columns {', '.join(joints)} for the "
            f"{model.n_joints}-joint robot '{model.name}'; missing {', '.join(missing)}"
        )
    idx = [header.index(c) for c in joints]
    values = []
    for row in data:
        line = row.line
        if len(row) != len(header):
            raise RelcalError(f"{path} line {line}: {len(row)} fields, expected {len(header)}")
        values.append(
            [parse_number(path, line, c, row[i]) for c, i in zip(joints, idx, strict=True)]
        )
    q = np.array(values, dtype=float)
    if joint_unit == "deg":
        q = np.where(model.prismatic, q, np.radians(q))
    return q


def simulated_joints(model, n_poses: int, seed: int) -> np.ndarray:
    """Joint values reaching the simulation's spiral of camera poses over the board."""
    from relcal.design.cell import Setup, joint_path
    from relcal.errors import RelcalError

    q = joint_path(model, Setup(), n_poses, np.random.default_rng(seed))
    if len(q) < 3:
        raise RelcalError(f"only {len(q)} of {n_poses} simulated poses are reachable")
    return q


def build_problem(model, q: np.ndarray, formulation: str, measure: str, pairs: str):
    """The identification problem at configurations ``q`` with the simulation's hand-eye."""
    from relcal.design.cell import Setup
    from relcal.design.observability import nominal_problem

    return nominal_problem(model, q, Setup().handeye, formulation, measure, pairs)


def joint_source(args: argparse.Namespace, model) -> tuple[np.ndarray, str]:
    """Joint values from ``--poses`` or simulated, and a phrase saying which."""
    if args.poses:
        return read_joints(Path(args.poses), model, args.joint_unit), f"poses from {args.poses}"
    q = simulated_joints(model, args.n_poses, args.seed)
    return q, f"{len(q)} simulated poses over the board (seed {args.seed})"


def run(args: argparse.Namespace) -> int:
    from relcal.calibration.noise import Noise
    from relcal.design.observability import report
    from relcal.io import write_json
    from relcal.reporting.documents import observability_document
    from relcal.reporting.text import format_observability

    model = load_robot(args)
    q, source = joint_source(args, model)
    problem = build_problem(model, q, args.formulation, args.measure, args.pairs)
    noise = None if args.noise.lower() == "none" else Noise.parse(args.noise)
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
    if not args.quiet:
        print(f"{source}, {args.pairs} pairs")
        print(format_observability(rep))
    if args.json:
        doc = observability_document(rep)
        doc["poses_source"] = source
        write_json(args.json, doc)
    return 0


def add_noise_arg(parser: argparse.ArgumentParser, default: str = "0.05,0.01,0.001") -> None:
    parser.add_argument(
        "--noise",
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
    p.add_argument("--poses", help="CSV of joint configurations (default: simulated poses)")
    p.add_argument("--joint-unit", choices=("deg", "rad"), default="deg")
    p.add_argument("--n-poses", type=int, default=40, help="simulated poses (default 40)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--formulation", choices=("invariant", "published"), default="invariant")
    p.add_argument("--measure", choices=("pose", "position"), default="pose")
    p.add_argument(
        "--handeye",
        choices=("estimated", "known"),
        default="estimated",
        help="frame-invariant formulation: estimate the hand-eye transform or take it as known",
    )
    p.add_argument("--pairs", choices=("consecutive", "star", "all"), default="consecutive")
    add_noise_arg(p)
    p.add_argument(
        "--estimator",
        choices=("weighted", "least_squares"),
        default="weighted",
        help="whose covariance the correlations are of (both standard deviations are shown)",
    )
    p.add_argument(
        "--validation",
        type=int,
        default=30,
        help="simulated validation poses for the predicted accuracy (0: skip; default 30)",
    )
    p.add_argument("--rcond", type=float, default=1e-6, help="relative rank tolerance")
    json_arg(p, "the report")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=run)
