"""``relcal import``: convert other tools' measurement files into relcal dataset folders."""

from __future__ import annotations

import argparse
from pathlib import Path

from relcal.cli.common import json_arg, length_m, nonnegative_float, output_folder, positive_float

EPILOG = """\
examples:
  relcal import rct-positioner positioner_kinematic_measurements.yaml --out positioner/
  relcal import rct-positioner measurements.yaml --out positioner/ --quiet --json import.json
  relcal calibrate positioner/                    # then calibrate the dataset folder
  relcal import rosbag run.mcap --joints /joint_states --image /camera/image_raw --robot ur5e \
      --out run/                                  # one sample per stop of the robot
  relcal import rosbag run_bag/ --joints /joint_states --pose /mocap/tool_pose --out run/
  relcal import rct-images rct_charuco_eye_to_hand/ --out charuco/ --intrinsics calibrate
  relcal measure charuco/ --max-rms 1.5           # camera poses, intrinsics, rejected frames
  relcal import mukca mukca/data/panda_1 --urdf mukca/urdf/panda.urdf --tip ball_link \
      --distance 0.050 --out panda_1/               # ball-in-socket joints, 50 mm sockets
  relcal import easy-handeye2 ~/.ros2/easy_handeye2/samples/cell.samples --mode eye_in_hand \
      --out cell-handeye/ && relcal handeye cell-handeye/

rct-images: a robot_cal_tools image set (cal_data.yaml, target.yaml, camera_intr*.yaml); the
images are copied into the dataset; the recorded tool poses become the joints of a pose chain.
mukca: a robot's folder of PLACEMENT/hole_*.csv joint files (MUKCa layout): a coincidence
dataset, one group per socket file, the URDF copied in as robot.urdf.
easy-handeye2: a session's saved samples (~/.ros2/easy_handeye2/samples/NAME.samples) with
--mode: a dataset of flange and camera poses for relcal handeye (no robot model needed).
Every dataset written holds no path outside its folder (robot files and images are copied): it
still calibrates when moved.
"""


def run(args: argparse.Namespace) -> int:
    from relcal.errors import RelcalError
    from relcal.io import File, Folder, write_json
    from relcal.outputset import check, check_outside, note_input

    source = Path(args.file)
    if not source.exists():
        raise RelcalError(f"{source}: file not found")
    folder = args.format in ("rct-images", "mukca")
    if args.format != "rosbag" and source.is_dir() != folder:
        want = "a folder (the image set)" if folder else "a file"
        raise RelcalError(f"{source}: expected {want} for {args.format}")
    note_input(source)
    check_outside(args.out, "--out", source, f"the {args.format} input folder")
    items = [Folder(args.out, what="--out", replace="refuse")]
    check(items + ([File(args.json, b"", "--json")] if args.json else []))
    extra: dict = {}
    if args.format == "rosbag":
        done = _rosbag(args)
        extra = {
            "joint_names": list(done.joint_names),
            "velocity_source": "recorded" if done.measured_velocity else "finite differences",
            "camera_info": done.camera_info,
            "stops": [
                {"start_s": s.start, "end_s": s.end, "q": [float(v) for v in s.q]}
                for s in done.stops
            ],
            "skipped": list(done.skipped),
        }
    elif args.format == "easy-handeye2":
        from relcal.data.easy_handeye import import_easy_handeye2

        if not args.mode:
            raise RelcalError(
                "relcal import easy-handeye2: --mode eye_in_hand or eye_to_hand (easy_handeye2's "
                "eye_on_base) is required: the samples file does not say, and the other reading "
                "fits the data as well, giving a wrong transform"
            )
        done = import_easy_handeye2(source, args.out, args.mode)
    elif args.format == "mukca":
        from relcal.data.importers import import_mukca

        if not args.urdf:
            raise RelcalError("relcal import mukca: --urdf FILE is required")
        note_input(Path(args.urdf))
        done = import_mukca(
            source,
            args.out,
            args.urdf,
            tip=args.tip,
            root=args.root,
            distance=args.distance,
            distance_std=args.distance_std,
            placements=args.placements,
        )
    elif folder:
        from relcal.data.importers import import_rct_images

        done = import_rct_images(source, args.out, mode=args.mode, intrinsics=args.intrinsics)
    else:
        from relcal.data.importers import import_rct_positioner

        done = import_rct_positioner(source, args.out)
    if args.json:
        from relcal.reporting.documents import import_document

        write_json(args.json, {**import_document(done, args.format, args.file), **extra})
    if not args.quiet:
        shown = [f.name for f in done.files if f.parent == done.folder]
        n_images = len(done.files) - len(shown)
        names = ", ".join(shown + ([f"{n_images} images"] if n_images else []))
        print(f"dataset written to {done.folder} ({names}): {done.n_samples} samples")
        if args.format == "rosbag":
            print(
                f"{len(done.stops)} stops of the robot found ({extra['velocity_source']} joint "
                f"velocities below {args.velocity:g} for {args.settle:g} s)"
            )
            for reason in done.skipped:
                print(f"  skipped {reason}")
            if not args.robot:
                print("set robot: in dataset.yaml (or import with --robot)")
    return 0


def _rosbag(args: argparse.Namespace):
    from relcal.data.rosbag import StopOptions, import_rosbag
    from relcal.errors import RelcalError

    if not args.joints:
        raise RelcalError("relcal import rosbag: --joints TOPIC is required")
    return import_rosbag(
        args.file,
        args.out,
        joints=args.joints,
        image=args.image,
        pose=args.pose,
        camera_info=args.camera_info,
        robot=args.robot,
        options=StopOptions(velocity=args.velocity, settle=args.settle),
    )


def name_list(text: str) -> list[str]:
    """``A,B,...``: names, none empty."""
    names = [n.strip() for n in text.split(",")]
    if not all(names):
        raise argparse.ArgumentTypeError(f"'{text}': expected names separated by commas")
    return names


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "import",
        help="convert robot_cal_tools measurements, a ROS bag, MUKCa joint files or "
        "easy_handeye2 samples into a dataset folder",
        description="Convert ROS-Industrial robot_cal_tools' positioner kinematic measurements "
        "(joint angles + camera-to-target poses), or a ROS 1 / ROS 2 bag or MCAP file of a "
        "calibration run (one sample per stop of the robot), MUKCa ball-in-socket joint files, "
        "or easy_handeye2's saved samples, into a relcal dataset folder.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "format",
        choices=("rct-positioner", "rct-images", "rosbag", "mukca", "easy-handeye2"),
        help="input format",
    )
    p.add_argument(
        "file",
        help="input file (rct-positioner), image set folder (rct-images), bag (rosbag: a "
        ".bag, a ROS 2 bag folder, .mcap or .db3), or a robot's folder (mukca)",
    )
    p.add_argument(
        "--out",
        required=True,
        type=output_folder,
        help="dataset folder to write (new or empty: an existing dataset is never replaced)",
    )
    rct = p.add_argument_group("rct-images, easy-handeye2")
    rct.add_argument(
        "--mode",
        choices=("eye_in_hand", "eye_to_hand"),
        help="camera on the wrist or fixed (rct-images default: from the folder name; "
        "easy-handeye2: required, eye_to_hand for its eye_on_base)",
    )
    rct.add_argument(
        "--intrinsics",
        choices=("calibrated", "guess", "calibrate"),
        default="calibrated",
        help="camera_intr_calibrated.yaml, camera_intr.yaml, or calibrate them from the images "
        "(default calibrated)",
    )
    ros = p.add_argument_group("rosbag")
    ros.add_argument("--joints", metavar="TOPIC", help="sensor_msgs/JointState topic")
    what = ros.add_mutually_exclusive_group()
    what.add_argument("--image", metavar="TOPIC", help="sensor_msgs/Image or CompressedImage")
    what.add_argument(
        "--pose", metavar="TOPIC", help="geometry_msgs/PoseStamped or TransformStamped"
    )
    ros.add_argument(
        "--camera-info",
        metavar="TOPIC",
        help="sensor_msgs/CameraInfo (default: camera_info beside the image topic, if recorded)",
    )
    ros.add_argument("--robot", help="robot: written into dataset.yaml (name or model file)")
    ros.add_argument(
        "--velocity",
        type=positive_float,
        default=0.01,
        help="a stop: every joint slower than this (rad/s, m/s; default 0.01)",
    )
    ros.add_argument(
        "--settle",
        type=nonnegative_float,
        default=0.5,
        help="... for at least this long (s; default 0.5)",
    )
    mukca = p.add_argument_group("mukca")
    mukca.add_argument(
        "--urdf", metavar="FILE", help="the robot's URDF (copied into the dataset as robot.urdf)"
    )
    mukca.add_argument(
        "--tip",
        metavar="LINK",
        default="ball_link",
        help="the link at the ball centre (default ball_link): its origin is the tool point guess",
    )
    mukca.add_argument("--root", metavar="LINK", help="first link of the chain (default the root)")
    mukca.add_argument(
        "--distance",
        type=length_m(0.0, 10.0),
        metavar="M",
        help="distance between the two sockets of every placement, m (e.g. 0.050); without it "
        "the scale is not determined",
    )
    mukca.add_argument(
        "--distance-std",
        type=length_m(0.0, 0.1),
        default=1e-4,
        metavar="M",
        help="its standard deviation, m (default 0.0001)",
    )
    mukca.add_argument(
        "--placements",
        type=name_list,
        metavar="A,B,...",
        help="the placement folders to import (default all): e.g. some to calibrate with, the "
        "others as a later session to verify on",
    )
    json_arg(p, "the list of files written and the number of samples")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=run)
