"""``relcal plan``: joint configurations that see the board and identify the parameters well."""

from __future__ import annotations

import argparse
from dataclasses import replace
from typing import TYPE_CHECKING

from relcal.cli.common import (
    fraction,
    int_at_least,
    interval,
    json_arg,
    load_robot,
    nonnegative_float,
    nonnegative_int,
    numbers,
    output_file,
    positive_float,
    positive_int,
    robot_args,
    seed,
)
from relcal.cli.observability import add_noise_arg

if TYPE_CHECKING:
    import numpy as np

EPILOG = """\
examples:
  relcal plan --robot a465 --hayati auto --out plan.csv
  relcal plan --robot a465 --hayati auto --board 7x10@20mm --camera camera.yaml --poses 40
  relcal plan --robot a465 --hayati auto --index O1 --algorithm greedy --random-out random.csv
  relcal plan --robot a465 --hayati auto --candidates 20000 --workers 2
  relcal plan --robot a465 --hayati auto --candidates 100000 --scheduler tcp://head:8786

output: a CSV  id,q1..qn  (angles in --joint-unit, prismatic joints in m) in an order that keeps
joint moves short; run it on the robot, record an image at each pose, and add an image column to
make it a dataset's samples.csv. Collisions with anything but the board plane are not checked.
With --workers or --scheduler the plan is the same as in one process (each batch of candidates
has its own random stream from --seed).
"""


def build_cell(args: argparse.Namespace):
    """The cell from the command line (board, its centre, camera, hand-eye guess)."""
    import numpy as np

    from relcal import geometry as tf
    from relcal.design.cell import Cell
    from relcal.design.plan import parse_board, parse_camera

    cell = Cell(board=parse_board(args.board))
    if args.camera:
        cell = replace(cell, camera=parse_camera(args.camera))
    if args.board_center:
        cell = replace(cell, center=np.array(args.board_center))
    if args.handeye:
        he = list(args.handeye) + [0.0, 0.0, 0.0]
        cell = replace(cell, handeye=tf.from_xyz_rpy(np.array(he[:3]), np.radians(he[3:6])))
    return cell


def run(args: argparse.Namespace) -> int:
    from relcal.calibration.noise import Noise
    from relcal.data.dataset import joints_in_unit, write_samples
    from relcal.design.plan import Constraints, plan
    from relcal.io import File, json_text, write_set
    from relcal.outputset import check
    from relcal.reporting.documents import plan_document
    from relcal.reporting.text import format_plan

    named = ((args.out, "--out"), (args.random_out, "--random-out"), (args.json, "--json"))
    model = load_robot(args)
    check([File(p, b"", what) for p, what in named if p])  # before the work
    cell = build_cell(args)
    lo, hi = args.distance
    constraints = Constraints(
        margin_px=args.margin,
        distance=(lo, hi),
        max_view_angle_deg=args.max_angle,
        min_inverse_condition=args.min_inverse_condition,
        clearance=args.clearance,
        length_scale=args.length_scale,
    )
    noise = Noise.parse(args.noise)
    client, cluster = None, None
    if args.scheduler or args.workers:
        from relcal.cluster import connect

        client, cluster = connect(args.scheduler, args.workers or 2)
    try:
        res = plan(
            model,
            cell,
            k=args.poses,
            constraints=constraints,
            criterion=args.index,
            algorithm=args.algorithm,
            n_candidates=args.candidates,
            noise=noise,
            random_sets=args.random_sets,
            seed=args.seed,
            client=client,
        )
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()

    def joints_table(q: np.ndarray) -> str:
        ids = [f"p{k + 1:03d}" for k in range(len(q))]
        return write_samples(args.out, ids, joints_in_unit(model, q, args.joint_unit))

    items = []
    if args.out:
        items.append(File(args.out, joints_table(res.q), "--out"))
    if args.random_out and res.random_q is not None:
        items.append(File(args.random_out, joints_table(res.random_q), "--random-out"))
    if args.json:
        items.append(File(args.json, json_text(plan_document(res, model)), "--json"))
    write_set(*items)
    if not args.quiet:
        center = ",".join(f"{v:g}" for v in cell.center)
        print(f"{model.name}: {cell.board.describe()}, centre {center} m")
        print(format_plan(res, args.length_scale))
        if args.out:
            print(f"wrote {len(res.q)} joint configurations to {args.out}")
        if args.random_out:
            print(f"wrote the median random set to {args.random_out}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "plan",
        help="plan joint configurations that keep the board in view and identify the "
        "parameters well",
        description="Generate feasible configurations (whole board in view with a margin, "
        "distance and viewing angle limits, joint limits, away from singularities), select K "
        "of them that maximise an observability criterion, write them as CSV and compare the "
        "predicted parameter standard deviations and accuracy with random feasible sets.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    robot_args(p)
    p.add_argument(
        "--board",
        default="7x10@0.02",
        help="ROWSxCOLS@SQUARE chessboard squares (m, or with mm) or a board YAML file "
        "(default 7x10@0.02)",
    )
    p.add_argument(
        "--camera",
        help="FX,FY,CX,CY,WIDTH,HEIGHT (px) or a camera YAML file (default 2448x2048 px, "
        "3.45 um pixels, 8 mm lens)",
    )
    p.add_argument(
        "--board-center",
        type=numbers((3,), "X,Y,Z of the board centre, m", 100.0),
        help="X,Y,Z of the pattern centre in the base frame, m; the board lies flat, face up "
        "(default 0.45,0,0, the simulation's cell)",
    )
    p.add_argument(
        "--handeye",
        type=numbers((3, 6), "X,Y,Z[,ROLL,PITCH,YAW] in m and deg", 360.0),
        help="flange-from-camera guess X,Y,Z[,ROLL,PITCH,YAW] (m, deg; default 0,0.04,0.06, the "
        "simulation's mount)",
    )
    p.add_argument("--poses", type=int_at_least(3), default=30, help="poses to select (default 30)")
    p.add_argument(
        "--candidates",
        type=positive_int,
        default=2000,
        help="feasible candidates (default 2000)",
    )
    p.add_argument(
        "--index",
        choices=("worst", "O1", "O2", "O3", "O4", "O5", "A"),
        default="worst",
        help="criterion: worst-parameter std (default), observability index O1..O5, or A "
        "(trace of the scaled covariance)",
    )
    p.add_argument("--algorithm", choices=("exchange", "greedy"), default="exchange")
    p.add_argument(
        "--distance",
        type=interval(0.01, 10.0, "m"),
        default=(0.25, 0.45),
        metavar="LOW,HIGH",
        help="camera to board centre, m (default 0.25,0.45)",
    )
    p.add_argument(
        "--max-angle", type=positive_float, default=40.0, help="viewing angle limit, deg"
    )
    p.add_argument("--margin", type=nonnegative_float, default=40.0, help="image margin, px")
    p.add_argument(
        "--min-inverse-condition",
        type=fraction,
        default=0.05,
        help="singularity limit on the joint Jacobian's inverse condition number",
    )
    p.add_argument(
        "--clearance", type=nonnegative_float, default=0.05, help="above the board plane, m"
    )
    p.add_argument(
        "--length-scale",
        type=positive_float,
        default=0.5,
        help="angles count as the displacement this far away (m) in the worst-parameter std",
    )
    add_noise_arg(p)
    p.add_argument(
        "--random-sets",
        type=nonnegative_int,
        default=20,
        help="random sets to compare with",
    )
    p.add_argument("--seed", type=seed, default=0)
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=positive_int,
        help="generate and score the candidates on a local Dask cluster of this many worker "
        "processes (default: in this process)",
    )
    where.add_argument(
        "--scheduler",
        metavar="tcp://HOST:8786",
        help="generate and score the candidates on this running Dask cluster",
    )
    p.add_argument(
        "--out", type=output_file, help="write the planned joint configurations to this CSV"
    )
    p.add_argument("--random-out", type=output_file, help="write the median random set to this CSV")
    p.add_argument("--joint-unit", choices=("deg", "rad"), default="deg")
    json_arg(p, "the plan and the comparison")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=run)
