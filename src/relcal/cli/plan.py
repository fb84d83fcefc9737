"""``relcal plan``: joint configurations that see the board and identify the parameters well."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from relcal.cli.common import (
    CELL_REACH_M,
    HANDEYE_REACH_M,
    fraction,
    int_at_least,
    interval,
    json_arg,
    load_robot,
    nonnegative_float,
    nonnegative_int,
    numbers,
    output_file,
    pose_numbers,
    positive_float,
    positive_int,
    robot_args,
    seed,
    worker_processes,
)
from relcal.cli.observability import add_noise_arg

if TYPE_CHECKING:
    import numpy as np

    from relcal.vision.boards import Board
    from relcal.vision.camera import Camera

EPILOG = """\
examples:
  relcal plan --robot a465 --hayati auto --out plan.csv
  relcal plan --robot a465 --hayati auto --board 7x10@20mm --camera camera.yaml --poses 40
  relcal plan --robot a465 --hayati auto --index O1 --algorithm greedy --random-out random.csv
  relcal plan --robot a465 --hayati auto --candidates 20000 --workers 2
  relcal plan --robot a465 --hayati auto --candidates 100000 --scheduler tcp://head:8786

  relcal plan --robot ur5e --limits elbow=-160:160,wrist3=-180:180 --out plan.csv
  relcal plan --robot ur5e --obstacle 0.2,-0.6,0,0.6,-0.3,0.5 --link-radius 0.05 --out plan.csv
  relcal plan --robot ur5e --for handeye --poses 15 --out handeye-plan.csv
  relcal plan --robot ur5e --mode eye_to_hand --camera-pose 1.0,0.4,0.5,-106.6,-21,129.8 \\
      --for handeye --poses 12 --out fixed-camera-plan.csv

output: a CSV, first line  # relcal plan: robot NAME, joint unit UNIT, second  # relcal robot:
SPEC (how relcal capture loads the robot), then  id,<joint names>  (angles in --joint-unit,
prismatic joints in m), in a travel order that keeps joint moves short (nearest neighbour + 2-opt
on the largest joint move, each angle the equivalent within the limits nearest the previous pose)
and every revolute joint's move within --max-move (a pose of a longer move is exchanged for the
best candidate within it); the longest single move and the total travel are printed. Run it with
`relcal capture PLAN` (the robot comes from the plan), or on the robot by other means. Checked for
every pose: joint limits (the robot's own, narrowed by --limits), the board in view with --margin,
distance, viewing angle, singularity, clearance above the board plane, self-collision and
collision with --obstacle boxes (a URDF's <collision> geometry with python-fcl where it has some,
else capsules of --link-radius about the kinematic skeleton; a sphere of --camera-radius about the
camera). With --workers or --scheduler the plan is the same as in one process (each batch of
candidates has its own random stream from --seed).
"""


def parse_board(text: str) -> Board:
    """A chessboard from ``ROWSxCOLS@SQUARE`` (squares; ``SQUARE`` in m, or with ``mm``), e.g.
    ``7x10@0.02`` or ``7x10@20mm``, or a board YAML file (:func:`boards.load_board`)."""
    import re

    from relcal.errors import RelcalError
    from relcal.numbers import parse_number
    from relcal.vision.boards import Board

    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*@\s*([0-9.eE+-]+)\s*(mm|m)?\s*", text)
    if match:
        rows, cols, size, unit = match.groups()
        try:
            spacing = parse_number(size) * (1e-3 if unit == "mm" else 1.0)
            return Board(type="chessboard", rows=int(rows), columns=int(cols), spacing=spacing)
        except ValueError as exc:
            raise RelcalError(f"--board '{text}': {exc}") from None
    from pathlib import Path

    if Path(text).suffix in (".yaml", ".yml") or Path(text).exists():
        from relcal.vision.boards import load_board

        return load_board(text)
    raise RelcalError(
        f"--board '{text}': expected ROWSxCOLS@SQUARE (squares, metres or mm, e.g. 7x10@0.02) "
        "or a board YAML file"
    )


def parse_camera(text: str) -> Camera:
    """A camera from ``FX,FY,CX,CY,WIDTH,HEIGHT`` (px) or a camera YAML file."""
    from relcal.errors import RelcalError
    from relcal.numbers import parse_number
    from relcal.vision.camera import Camera

    parts = text.split(",")
    if len(parts) == 6:
        try:
            fx, fy, cx, cy = (parse_number(v) for v in parts[:4])
            return Camera(fx=fx, fy=fy, cx=cx, cy=cy, width=int(parts[4]), height=int(parts[5]))
        except ValueError as exc:
            raise RelcalError(f"--camera '{text}': {exc}") from None
    from relcal.vision.camera import load_camera

    camera = load_camera(text)
    if camera.width is None or camera.height is None:
        raise RelcalError(f"{text}: the camera's image size (width, height) is needed to plan")
    return camera


def _floats(text: str, count: tuple[int, ...], what: str) -> list[float]:
    import numpy as np

    from relcal.errors import RelcalError
    from relcal.numbers import parse_number

    try:
        values = [parse_number(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) not in count or not all(np.isfinite(values)):
        raise RelcalError(f"{what} '{text}': expected {' or '.join(map(str, count))} numbers")
    return values


def parse_limits(text: str, model, unit: str) -> dict[str, tuple[float, float]]:
    """User joint limits (rad, m) from ``NAME=LOWER:UPPER,...`` (angles in ``unit``, prismatic
    joints in m; NAME a joint name or qK) or a YAML file with ``joint_limits:`` (a dataset.yaml,
    whose ``joint_unit`` applies, default deg)."""
    from pathlib import Path

    from relcal.data.dataset import limits_from_unit
    from relcal.errors import RelcalError
    from relcal.numbers import parse_number

    if Path(text).suffix in (".yaml", ".yml") or Path(text).is_file():
        from relcal.io import load_yaml

        data, _ = load_yaml(text)
        if not isinstance(data, dict) or not isinstance(data.get("joint_limits"), dict):
            raise RelcalError(f"--limits {text}: expected a YAML mapping with joint_limits:")
        raw, unit = data["joint_limits"], data.get("joint_unit", "deg")
        limits = {}
        for name, pair in raw.items():
            ok = isinstance(pair, list) and len(pair) == 2
            if not ok or not all(isinstance(v, int | float) for v in pair):
                raise RelcalError(f"--limits {text}: joint_limits.{name}: expected [lower, upper]")
            limits[str(name)] = (float(pair[0]), float(pair[1]))
        return limits_from_unit(model, limits, unit)
    limits = {}
    for part in text.split(","):
        name, sep, rest = part.partition("=")
        lo, sep2, hi = rest.partition(":")
        try:
            if not (sep and sep2):
                raise ValueError
            limits[name.strip()] = (parse_number(lo), parse_number(hi))
        except ValueError:
            raise RelcalError(
                f"--limits '{part}': expected NAME=LOWER:UPPER (e.g. elbow=-160:160, in "
                f"--joint-unit {unit}) or a YAML file with joint_limits:"
            ) from None
    return limits_from_unit(model, limits, unit)


def _pose(values: list[float]) -> np.ndarray:
    """``(4, 4)`` from X,Y,Z[,ROLL,PITCH,YAW] (m, deg)."""
    import numpy as np

    from relcal import geometry as tf

    v = list(values) + [0.0, 0.0, 0.0]
    return tf.from_xyz_rpy(np.array(v[:3]), np.radians(v[3:6]))


def build_cell(args: argparse.Namespace):
    """The cell from the command line (board, its centre, camera, hand-eye guess); with
    ``--mode eye_to_hand`` the fixed camera's cell (camera pose, board on the flange)."""
    import numpy as np

    from relcal.design.cell import Cell
    from relcal.errors import RelcalError

    mode = getattr(args, "mode", "eye_in_hand")
    if mode == "eye_to_hand":
        return build_fixed_cell(args)
    if getattr(args, "camera_pose", None) is not None:
        raise RelcalError(
            "--camera-pose: a fixed camera's pose; it needs --mode eye_to_hand (the default, "
            "eye_in_hand, has the camera on the flange: give --handeye and --board-center)"
        )
    cell = Cell(board=parse_board(args.board))
    if args.camera:
        cell = replace(cell, camera=parse_camera(args.camera))
    if args.board_center:
        cell = replace(cell, center=np.array(args.board_center))
    if args.handeye:
        cell = replace(cell, handeye=_pose(args.handeye))
    return cell


def build_fixed_cell(args: argparse.Namespace):
    """The eye-to-hand cell from the command line: the board (on the flange, at ``--handeye``,
    flange-from-board, default 80 mm in front of it facing out), the camera's intrinsics and
    its pose ``--camera-pose`` in the base frame."""
    from relcal.design.cell import FixedCameraCell
    from relcal.errors import RelcalError

    if args.board_center:
        raise RelcalError(
            "--board-center: with --mode eye_to_hand the board is on the flange, not fixed in "
            "the cell: give its mount as --handeye (flange-from-board) and the camera's place "
            "as --camera-pose"
        )
    cell = FixedCameraCell(board=parse_board(args.board))
    if args.camera:
        cell = replace(cell, camera=parse_camera(args.camera))
    if args.camera_pose:
        cell = replace(cell, camera_pose=_pose(args.camera_pose))
    if args.handeye:
        cell = replace(cell, handeye=_pose(args.handeye))
    return cell


def cell_line(model_name: str, cell) -> str:
    """The line the plan prints first: the robot, the board and where the board (eye-in-hand)
    or the camera (eye-to-hand) is."""
    import numpy as np

    from relcal import geometry as tf

    if cell.mode == "eye_to_hand":
        xyz, rpy = tf.to_xyz_rpy(cell.camera_pose)
        where = ",".join(f"{v:.4g}" for v in np.r_[xyz, np.degrees(rpy)])
        return (
            f"{model_name}: eye-to-hand, {cell.board.describe()} on the flange, fixed camera at "
            f"{where} (m, deg)"
        )
    center = ",".join(f"{v:g}" for v in cell.center)
    return f"{model_name}: {cell.board.describe()}, centre {center} m"


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from relcal.calibration.noise import Noise
    from relcal.design.plan import Constraints, plan
    from relcal.design.planfile import plan_robot, plan_text
    from relcal.io import File, json_text, write_set
    from relcal.outputset import check, is_stream
    from relcal.reporting.documents import plan_document
    from relcal.reporting.text import format_plan

    named = ((args.out, "--out"), (args.random_out, "--random-out"), (args.json, "--json"))
    model = load_robot(args)
    if args.limits:
        from relcal.robot.model import restrict_limits

        limits = parse_limits(args.limits, model, args.joint_unit)
        model = restrict_limits(model, limits, f"--limits {args.limits}")
    obstacles = tuple(tuple(_floats(o, (6,), "--obstacle")) for o in args.obstacle or ())
    for box in obstacles:
        if not all(lo < hi for lo, hi in zip(box[:3], box[3:], strict=True)):
            from relcal.errors import RelcalError

            raise RelcalError(
                f"--obstacle {','.join(f'{v:g}' for v in box)}: expected XMIN,YMIN,ZMIN,XMAX,"
                "YMAX,ZMAX with each minimum below its maximum (m, base frame)"
            )
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
        link_radius=args.link_radius,
        camera_radius=args.camera_radius,
        obstacles=obstacles,
        sight_grid=args.sight_lines,
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
            n_poses=args.poses,
            constraints=constraints,
            criterion=args.index,
            algorithm=args.algorithm,
            n_candidates=args.candidates,
            noise=noise,
            random_sets=args.random_sets,
            seed=args.seed,
            client=client,
            max_move=np.radians(args.max_move),
            purpose=args.purpose,
        )
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()

    def joints_table(q: np.ndarray, out: str | None) -> str:
        where = None if out is None or is_stream(out) else Path(out).parent
        source = plan_robot(model, args.robot, where)
        return plan_text(model, q, unit=args.joint_unit, source=source, mode=cell.mode)

    items = []
    if args.out:
        items.append(File(args.out, joints_table(res.q, args.out), "--out"))
    if args.random_out and res.random_q is not None:
        items.append(
            File(args.random_out, joints_table(res.random_q, args.random_out), "--random-out")
        )
    if args.json:
        items.append(File(args.json, json_text(plan_document(res, model)), "--json"))
    write_set(*items)
    if not args.quiet:
        print(cell_line(model.name, cell))
        print(format_plan(res, args.length_scale, model))
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
        type=pose_numbers((3, 6), "X,Y,Z[,ROLL,PITCH,YAW] in m and deg", HANDEYE_REACH_M),
        help="flange-from-camera guess X,Y,Z[,ROLL,PITCH,YAW] (m, deg; default 0,0.04,0.06, the "
        "simulation's mount); --mode eye_to_hand: flange-from-board (default: the pattern "
        "centred 80 mm in front of the flange, printed face out along its z axis)",
    )
    p.add_argument(
        "--mode",
        choices=("eye_in_hand", "eye_to_hand"),
        default="eye_in_hand",
        help="eye_in_hand: the camera on the flange, the board fixed (default); eye_to_hand: the "
        "camera fixed at --camera-pose, the board on the flange at --handeye (the plan file "
        "says so, and relcal capture writes it into the dataset)",
    )
    p.add_argument(
        "--camera-pose",
        type=pose_numbers((6,), "X,Y,Z,ROLL,PITCH,YAW in m and deg", CELL_REACH_M),
        metavar="X,Y,Z,ROLL,PITCH,YAW",
        help="--mode eye_to_hand: the fixed camera's optical frame (z along the view) in the base "
        "frame, m and deg, rotations as --handeye's (default 1.1,0,0.6,180,-66.8,180: 1.1 m out "
        "and 0.6 m up, looking back at 0.4,0,0.3)",
    )
    p.add_argument(
        "--n-poses",
        "--poses",
        dest="poses",
        type=int_at_least(3),
        default=30,
        help="poses to select (default 30; --poses is its former name)",
    )
    p.add_argument(
        "--n-candidates",
        "--candidates",
        dest="candidates",
        type=positive_int,
        default=2000,
        help="feasible candidates (default 2000; --candidates is its former name)",
    )
    p.add_argument(
        "--for",
        dest="purpose",
        choices=("calibrate", "handeye"),
        default="calibrate",
        help="what the poses are for: calibrate (the kinematics and the hand-eye, default) or "
        "handeye (the hand-eye transform alone, for relcal handeye: the criterion over its six "
        "components with the kinematics known, rotation axes spread, no two poses turning near "
        "180 deg from each other or barely moving)",
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
        "--limits",
        metavar="NAME=LO:HI,...|FILE",
        help="narrower joint limits than the robot's: joint name (or qK) = lower:upper in "
        "--joint-unit (prismatic joints in m), or a YAML file with joint_limits: (a dataset.yaml)",
    )
    p.add_argument(
        "--obstacle",
        action="append",
        metavar="XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX",
        help="a box in the cell the arm and camera must not touch (m, base frame); repeatable",
    )
    p.add_argument(
        "--link-radius",
        type=nonnegative_float,
        default=0.04,
        help="radius of the capsules about the links for the collision checks, m (default 0.04; "
        "0 with --camera-radius 0: no self-collision check)",
    )
    p.add_argument(
        "--camera-radius",
        type=nonnegative_float,
        default=0.04,
        help="radius of the sphere about the camera for the collision checks, m (default 0.04)",
    )
    p.add_argument(
        "--sight-lines",
        type=nonnegative_int,
        default=5,
        metavar="N",
        help="line of sight: N x N lines from the camera to the pattern must pass the robot's "
        "own links (the URDF's collision geometry, else capsules of --link-radius); 0: no check "
        "(default 5)",
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
        type=worker_processes,
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
    p.add_argument(
        "--max-move",
        type=positive_float,
        metavar="DEG",
        default=120.0,
        help="largest travel of any revolute joint between consecutive poses, deg (default 120): "
        "the order keeps within it, and a pose of a longer move is exchanged for the best "
        "candidate within it (or, failing that, one is added between)",
    )
    json_arg(p, "the plan and the comparison")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=run)
