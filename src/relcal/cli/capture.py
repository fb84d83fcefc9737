"""``relcal capture``: move the robot through a plan and record a dataset."""

from __future__ import annotations

import argparse

from relcal.cli.common import (
    HANDEYE_REACH_M,
    json_arg,
    load_robot,
    nonnegative_int,
    output_folder,
    pose_numbers,
    positive_float,
    positive_int,
    robot_args,
)

EPILOG = """\
examples:
  relcal capture plan.csv --robot ur5e --robot-driver sim --camera sim --out ds
  relcal calibrate ds
  relcal capture plan.csv --robot ur5e --robot-driver sim --camera sim --out ds --resume
  relcal capture plan.csv --robot ur5e --robot-driver sim --camera sim --out ds2 \\
      --robot-option seed=3,truth=truth.json --robot-option 'faults=hide:p004;stale:6'
  relcal capture plan.csv --robot ur5e --robot-driver ur --robot-option host=192.168.1.10 \\
      --camera realsense --out ds --handeye 0,0.04,0.06
  relcal capture plan.csv --robot franka_fr3 --robot-driver franka \\
      --robot-option host=127.0.0.1 --camera sim --camera-option seed=2 --out ds

For every pose of PLAN (the CSV of relcal plan): check the joint limits, move, wait until the
joints are still over --settle-window, take a frame stamped after that (older buffered frames are
discarded), detect the board and check corners, sharpness and reprojection error, then write the
image and the mean joints of the still window as one sample of the dataset. A pose that fails is
tried again (--retries), then skipped with its reason. Samples are written whole as they are
taken: an interrupted run (Ctrl-C) leaves a dataset relcal calibrate reads, and --resume
continues it. Drivers that read the controller's flange pose (ur, franka, ros with the tf
frames found, sim; manual through its source driver) record it beside the joints as columns fx,
fy, fz, fqx, fqy, fqz, fqw, the mean over the still window, for relcal handeye. --robot-driver
and --camera name a device of relcal.capture.devices (below);
their settings are --robot-option / --camera-option KEY=VALUE (several per option, comma-
separated). A plan for a fixed camera (relcal plan --mode eye_to_hand: its line
# relcal mode: eye_to_hand) records mode: eye_to_hand in dataset.yaml (--handeye is then the
flange-from-board guess); the virtual cell (--camera sim) has the camera on the flange and
refuses such a plan.
"""


def _settings(args: argparse.Namespace):
    from relcal.capture.loop import DEG, CaptureSettings

    return CaptureSettings(
        retries=args.retries,
        move_timeout=args.timeout,
        settle_window=args.settle_window,
        settle_threshold=args.settle_threshold * DEG,
        settle_timeout=args.settle_timeout,
        settle_velocity=None if args.settle_velocity is None else args.settle_velocity * DEG,
        joint_tolerance=args.joint_tolerance * DEG,
        max_rms=args.max_rms,
        min_sharpness=args.min_sharpness,
        min_points=args.min_points,
    )


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from relcal import geometry as tf
    from relcal.capture.record import check_destination, claim
    from relcal.cli.plan import parse_board
    from relcal.design.planfile import plan_mode, read_plan
    from relcal.errors import RelcalError
    from relcal.io import File, note_input
    from relcal.outputset import check

    plan_robot(args)
    model = load_robot(args)
    limits = None
    if args.limits:  # the cell's limits, as relcal plan takes them; kept in dataset.yaml
        from relcal.cli.plan import parse_limits
        from relcal.robot.model import restrict_limits

        limits = parse_limits(args.limits, model, args.joint_unit or "deg")
        model = restrict_limits(model, limits, f"--limits {args.limits}")
    note_input(args.plan)
    plan = read_plan(args.plan, model, args.joint_unit)
    mode = plan_mode(args.plan)
    if mode == "eye_to_hand":
        from relcal.capture import devices

        entry = devices.CAMERAS.get(args.camera)
        if entry is not None and getattr(entry.load(), "simulated", False):
            raise RelcalError(
                f"--camera {args.camera}: the plan {args.plan} is for a fixed camera and the "
                "board on the flange (eye_to_hand); the virtual cell has the camera on the flange "
                "and the board fixed: capture this plan with a real camera"
            )
    board = parse_board(args.board)
    settings = _settings(args)
    intrinsics = None
    if args.intrinsics:
        from relcal.vision.camera import load_camera

        intrinsics = load_camera(args.intrinsics)
    handeye = None
    if args.handeye:  # (read strictly, in range, by pose_numbers)
        he = np.r_[args.handeye, 0.0, 0.0, 0.0][:6]
        handeye = tf.from_xyz_rpy(he[:3], np.radians(he[3:]))
    if args.json:
        check([File(args.json, b"", "--json")])
    check_destination(args.out, args.resume)  # before any device is touched
    check_ids(args.plan, plan.ids)
    with claim(args.out, args.resume):  # this run's alone (another one writing it: refused)
        return _capture(args, model, plan, board, settings, intrinsics, handeye, limits, mode)


def _capture(args, model, plan, board, settings, intrinsics, handeye, limits, mode) -> int:
    import sys

    from relcal.capture import devices
    from relcal.capture.interfaces import RealClock
    from relcal.capture.loop import capture
    from relcal.capture.record import DatasetWriter
    from relcal.errors import RelcalError
    from relcal.io import File, json_text, write_set
    from relcal.reporting.capture_text import format_capture

    clock = RealClock()
    robot = devices.open_robot(
        args.robot_driver,
        devices.parse_options(args.robot_option or [], "--robot-option"),
        joint_names=model.joint_names,
        clock=clock,
        model=model,
        board=board,
        plan_ids=plan.ids,
        plan_targets=plan.q,
    )
    camera = writer = None
    try:
        if tuple(robot.joint_names) != tuple(model.joint_names):
            raise RelcalError(
                f"--robot-driver {args.robot_driver}: the robot reports joints "
                f"{', '.join(robot.joint_names)}, the model {model.name} has "
                f"{', '.join(model.joint_names)}; is --robot the robot connected?"
            )
        clock = getattr(robot, "clock", None) or clock  # a simulated robot keeps its own time
        entry = devices.CAMERAS.get(args.camera)
        simulated = entry is not None and getattr(entry.load(), "simulated", False)
        if getattr(robot, "simulated", False) and not simulated:
            raise RelcalError(
                "the virtual cell's robot runs on simulated time and a real camera cannot "
                "see it: use --robot-driver sim with --camera sim (--camera sim also follows "
                "any other robot driver)"
            )
        camera = devices.open_camera(
            args.camera,
            devices.parse_options(args.camera_option or [], "--camera-option"),
            clock=clock,
            robot=robot,
            model=model,
            board=board,
        )
        if intrinsics is None:
            intrinsics = camera.intrinsics()
        writer = DatasetWriter(
            args.out,
            model,
            args.robot,
            board,
            intrinsics,
            plan.ids,
            plan.q,
            plan_path=args.plan,
            joint_unit=args.dataset_joint_unit,
            handeye=handeye,
            limits=limits,
            resume=args.resume,
            flange=bool(getattr(robot, "reports_flange", False)),
            mode=mode,
            devices={
                "robot_driver": args.robot_driver,
                "robot_options": context_options(args.robot_option),
                "camera": args.camera,
                "camera_options": context_options(args.camera_option),
            },
        )
        skipped_before = set() if args.retry_skipped else writer.skipped_before()
        try:
            summary = capture(
                plan.ids,
                plan.q,
                model,
                robot,
                camera,
                clock,
                board,
                writer,
                intrinsics=intrinsics,
                settings=settings,
                done=writer.done,
                skipped_before=skipped_before,
                progress=not args.quiet,
                flange=writer.flange,
            )
        except KeyboardInterrupt as exc:
            summary = getattr(exc, "capture_summary", None)
            if summary is not None:
                writer.finish(summary.document())
                print(format_capture(summary, args.out), file=sys.stderr)
            raise
        doc = summary.document()
        writer.finish(doc)
        if args.json:
            write_set(File(args.json, json_text({"dataset": str(args.out), **doc}), "--json"))
    finally:
        try:
            if writer is not None:
                writer.close()  # the dataset's lock: released, its file removed
            if camera is not None:
                camera.close()
        finally:
            robot.close()
    if not args.quiet:
        print(format_capture(summary, args.out, str(args.plan)))
        if writer.flange:
            print(
                "the controller's flange poses are recorded beside the joints (fx .. fqw): "
                f"relcal handeye {args.out} uses them"
            )
    return 0 if doc["recorded"] + doc["recorded_before"] > 0 else 1


def plan_robot(args: argparse.Namespace) -> None:
    """The robot of ``args.plan``'s header into ``args.robot`` (``--root``, ``--tip``) when
    ``--robot`` is not given; a built-in robot named only by its full name (older plans) is
    found by that name. A ``--robot`` that names another robot than the plan is refused."""
    from relcal.design.planfile import plan_header
    from relcal.errors import RelcalError
    from relcal.robot.loading import library_by_title

    name, _, source = plan_header(args.plan)
    if args.robot is not None:
        if name is not None:
            given = load_robot(args)
            if given.name != name:
                raise RelcalError(
                    f"--robot {args.robot} is '{given.name}', the plan {args.plan} was made for "
                    f"'{name}': leave --robot out to capture with the plan's robot, or plan "
                    "again for this one"
                )
        return
    if source is not None:
        args.robot = source.robot
        if args.root is None and args.tip is None:
            args.root, args.tip = source.root, source.tip
        return
    builtin = library_by_title(name) if name is not None else None
    if builtin is None:
        raise RelcalError(
            f"{args.plan}: the plan does not say how to load its robot"
            + (f" ('{name}')" if name else "")
            + ": give --robot (a built-in name, a model YAML or a URDF file)"
        )
    args.robot = builtin


def context_options(pairs: list[str] | None) -> list[str]:
    """The options as given, for the capture log."""
    return list(pairs or [])


def check_ids(path: str, ids) -> None:
    """Pose ids name image files: unique (also ignoring case: a file system may), and letters,
    digits, ``_``, ``-`` and ``.`` only."""
    import re

    from relcal.errors import RelcalError

    seen: set[str] = set()
    folded: dict[str, str] = {}
    for pid in ids:
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", pid) or pid in (".", ".."):
            raise RelcalError(
                f"{path}: pose id '{pid}': use letters, digits, '_', '-' and '.' only (it names "
                "the image file)"
            )
        if pid in seen:
            raise RelcalError(f"{path}: pose id '{pid}' appears twice; ids must be unique")
        seen.add(pid)
        other = folded.setdefault(pid.casefold(), pid)
        if other != pid:
            raise RelcalError(
                f"{path}: pose ids '{other}' and '{pid}' differ only in case: their image files "
                "would be one file on Windows and macOS (one image written over the other); "
                "rename one"
            )


def _describe() -> str:
    from relcal.capture.devices import describe  # light: imports no driver library

    return describe()


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "capture",
        help="move the robot through a plan and record a dataset (or rehearse in the virtual cell)",
        description="Capture a dataset: for every planned pose move, wait until still, take a "
        "fresh frame, check it and record joints and image as one sample.",
        epilog=EPILOG + "\n" + _describe(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("plan", metavar="PLAN", help="the plan CSV (relcal plan --out)")
    robot_args(
        p,
        default=None,
        help="the robot, only to override the plan's (its header names the robot it was made "
        "for; refused when it contradicts the plan): built-in name, model YAML or URDF file",
    )
    p.add_argument(
        "--robot-driver", required=True, metavar="NAME", help="robot driver (listed below)"
    )
    p.add_argument("--camera", required=True, metavar="NAME", help="camera (listed below)")
    p.add_argument(
        "--robot-option",
        action="append",
        metavar="KEY=VALUE",
        help="settings of the robot driver (repeat, or comma-separate; sim: seed, truth, faults, "
        "board_center, handeye, nongeometric, errors, joint_noise, board_pixels)",
    )
    p.add_argument(
        "--camera-option", action="append", metavar="KEY=VALUE", help="a setting of the camera"
    )
    p.add_argument(
        "--board",
        default="7x10@0.02",
        help="ROWSxCOLS@SQUARE chessboard (m, or with mm) or a board YAML file (default "
        "7x10@0.02, as relcal plan)",
    )
    p.add_argument(
        "--intrinsics",
        metavar="FILE",
        help="camera YAML (default: the camera driver's own; without either, the dataset "
        "says camera: calibrate)",
    )
    p.add_argument(
        "--handeye",
        type=pose_numbers((3, 6), "X,Y,Z[,ROLL,PITCH,YAW] in m and deg", HANDEYE_REACH_M),
        metavar="X,Y,Z[,ROLL,PITCH,YAW]",
        help="flange-from-camera guess X,Y,Z[,ROLL,PITCH,YAW] (m, deg) written to dataset.yaml "
        "(default: none; calibrate then solves hand-eye from the data)",
    )
    p.add_argument("--out", required=True, type=output_folder, help="the dataset folder")
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue the capture in --out: poses recorded (or skipped) there are not visited",
    )
    p.add_argument(
        "--retry-skipped", action="store_true", help="with --resume, try skipped poses again"
    )
    p.add_argument(
        "--retries",
        type=nonnegative_int,
        default=2,
        help="further attempts at a pose before it is skipped (default 2)",
    )
    p.add_argument(
        "--timeout", type=positive_float, default=60.0, help="s allowed for one move (default 60)"
    )
    p.add_argument(
        "--settle-window",
        type=positive_float,
        default=0.5,
        help="s the joints must stay still before a frame is taken (default 0.5)",
    )
    p.add_argument(
        "--settle-threshold",
        type=positive_float,
        default=0.01,
        help="deg (mm for prismatic joints): largest peak-to-peak spread of a joint over the "
        "window (default 0.01)",
    )
    p.add_argument(
        "--settle-velocity",
        type=positive_float,
        metavar="DEG_PER_S",
        help="deg/s (mm/s): also require every joint velocity the driver reports (franka, ur) "
        "to stay below this over the window (default: positions only)",
    )
    p.add_argument(
        "--settle-timeout",
        type=positive_float,
        default=15.0,
        help="s after the move within which the arm must be still (default 15)",
    )
    p.add_argument(
        "--joint-tolerance",
        type=positive_float,
        default=0.1,
        help="deg: largest difference of the still joints from the target (default 0.1)",
    )
    p.add_argument(
        "--limits",
        metavar="NAME=LO:HI,...|FILE",
        help="the cell's joint limits, narrower than the robot's (as relcal plan takes them; "
        "angles in --joint-unit, default deg): no target outside them is sent; written to "
        "dataset.yaml",
    )
    p.add_argument(
        "--max-rms",
        type=positive_float,
        default=0.5,
        help="px: largest reprojection RMS of a frame (default 0.5)",
    )
    p.add_argument(
        "--min-sharpness",
        type=positive_float,
        default=150.0,
        help="smallest variance of the Laplacian over the board, after a 1 px Gaussian "
        "(default 150: rejects a blur of about 4 px)",
    )
    p.add_argument(
        "--min-points",
        type=positive_int,
        help="fewest board points in a frame (default: the whole board; half of a ChArUco's)",
    )
    p.add_argument(
        "--joint-unit",
        choices=("deg", "rad"),
        help="angle unit of PLAN when it states none (default deg, as relcal plan writes)",
    )
    p.add_argument(
        "--dataset-joint-unit",
        choices=("deg", "rad"),
        default="deg",
        help="angle unit of the dataset's samples.csv (default deg)",
    )
    json_arg(p, "the capture summary (per pose: status, attempts, reasons)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=run)
