"""``relcal handeye DATASET``: the hand-eye transform alone, every closed form beside the refined
estimate, scored on the same held-out samples."""

from __future__ import annotations

import argparse
from pathlib import Path

from relcal.cli.common import (
    int_at_least,
    json_arg,
    output_file,
    output_folder,
    positive_float,
    registry_arg,
    seed,
    worker_processes,
)

DEFAULT_FOLDS = 5  # relcal.calibration.handeye_job.DEFAULT_FOLDS (the parser stays light)
METHODS = ("tsai", "park", "horaud", "andreff", "daniilidis", "shah", "li")

EPILOG = """\
examples:
  relcal handeye my_dataset                       # DATASET/handeye/: handeye.yaml, launch, URDF
  relcal handeye cell --mode robot_world --out he --json he.json
  relcal handeye cell --methods tsai,park --folds 10 --report he.html

modes (mode: in dataset.yaml, or --mode):
  eye_in_hand  a camera on the flange, a fixed board: delivers flange -> camera
  eye_to_hand  a fixed camera, the board on the flange: delivers base -> camera
  robot_world  a camera or marker on the flange measured in a fixed world frame (a board, a
               tracker): delivers flange -> camera and world -> base

robot poses: joint angles with the dataset's robot model, or the controller's flange poses
(columns fx, fy, fz, fqx, fqy, fqz, fqw: m, quaternion x first) with no robot at all.

exit status: 0 written; 1 written but not good enough to deploy (directions only weakly
determined: collect more samples), or refused (directions the motions leave undetermined: only
results.json is written); 2 bad input (nothing written).
"""


def _methods(text: str) -> tuple[str, ...]:
    names = tuple(t.strip().lower() for t in text.split(",") if t.strip())
    unknown = [n for n in names if n not in METHODS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(
            f"'{text}': expected a comma-separated list of {', '.join(METHODS)}"
        )
    return names


def run(args: argparse.Namespace) -> int:
    from contextlib import nullcontext

    from relcal.data.dataset import load_dataset
    from relcal.fleet.registry import open_for_writing
    from relcal.outputset import File, Folder, check

    dataset = load_dataset(args.dataset)
    out = Path(args.out or Path(args.dataset) / "handeye")
    destinations = [Folder(out, what="--out")]
    if args.json:
        destinations.append(File(args.json, b"", "--json"))
    if args.report:
        destinations.append(File(args.report, b"", "--report"))
    check(destinations)  # refused before the work, not after it
    registry = open_for_writing(args.registry, outputs=destinations)
    with registry if registry is not None else nullcontext():
        return _run(args, dataset, out, registry)


def _run(args, dataset, out: Path, registry) -> int:
    from relcal.calibration.handeye_job import handeye
    from relcal.data.imaging import measure
    from relcal.io import json_text
    from relcal.outputset import File, Folder, write_set
    from relcal.reporting.handeye_report import (
        handeye_document,
        handeye_files,
        handeye_html,
        handeye_text,
    )

    m = measure(dataset, workers=args.workers, progress=not args.quiet, max_rms=args.max_rms)
    result = handeye(
        dataset,
        m,
        mode=args.mode,
        methods=args.methods,
        folds=args.folds,
        seed=args.seed,
        refine_intrinsics=True if args.refine_intrinsics else None,
        reject=not args.keep_outliers,
        progress=not args.quiet,
    )
    doc = handeye_document(result, dataset)
    files = handeye_files(result, doc)
    items = [Folder(out, files, what="--out")]
    if args.json:
        items.append(File(args.json, json_text(doc), "--json"))
    if args.report:
        items.append(File(args.report, handeye_html(doc), "--report"))
    journal = None
    if registry is not None:
        from relcal.fleet.records import handeye_record

        journal = registry.pending(handeye_record(result, doc, dataset, outputs=out))
    write_set(*items, journal=journal)
    if not args.quiet:
        print(handeye_text(doc, per_sample=args.per_sample))
        print(f"written: {out}/" + ", ".join(sorted(files)))
        if args.report:
            print(f"report: {args.report}")
        if journal is not None:
            print(f"recorded in the registry as run {journal.run_id}")
    return 0 if result.verdict.code == "deploy" else 1


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "handeye",
        help="the hand-eye transform alone, every closed form beside the refined estimate",
        description="Hand-eye calibration (eye-in-hand, eye-to-hand, robot-world) from joint "
        "angles and a robot model, or from logged flange poses with no model: OpenCV's closed "
        "forms (Tsai, Park, Horaud, Andreff, Daniilidis; Shah and Li for robot-world) on motion "
        "pairs that carry information, the refined maximum-likelihood estimate (reprojection "
        "error with images, the learned pose noise otherwise; bad frames left out), each "
        "refitted and scored on the same held-out samples (K-fold by sample), what the motions "
        "leave undetermined named, and the files a cell loads: handeye.yaml, a ROS 2 launch "
        "file (tf2 static_transform_publisher), a URDF joint, an easy_handeye2 calibration.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("dataset", help="dataset folder (with dataset.yaml)")
    p.add_argument(
        "--out",
        type=output_folder,
        help="output folder (default DATASET/handeye), written as one set; an earlier relcal set "
        "there is kept as OUT.prev/",
    )
    p.add_argument(
        "--mode",
        choices=("eye_in_hand", "eye_to_hand", "robot_world"),
        help="overrides mode: of dataset.yaml",
    )
    p.add_argument(
        "--methods",
        type=_methods,
        default=METHODS,
        metavar="M,M",
        help="closed forms to run and score (default all: " + ",".join(METHODS) + ")",
    )
    p.add_argument(
        "--folds",
        type=int_at_least(2),
        default=DEFAULT_FOLDS,
        metavar="K",
        help=f"folds of the cross-validation (default {DEFAULT_FOLDS})",
    )
    p.add_argument("--seed", type=seed, default=0, help="seed of the folds and the bootstrap")
    p.add_argument(
        "--refine-intrinsics",
        action="store_true",
        help="with images: refine the camera intrinsics with the frames (default: only when "
        "the dataset's camera is 'calibrate')",
    )
    p.add_argument(
        "--keep-outliers", action="store_true", help="keep bad frames in the refined fit"
    )
    p.add_argument(
        "--workers", type=worker_processes, default=2, help="processes for image measurement"
    )
    p.add_argument(
        "--max-rms",
        type=positive_float,
        metavar="PX",
        default=1.0,
        help="reject frames whose board reprojection RMS exceeds PX pixels (default 1)",
    )
    p.add_argument(
        "--report", type=output_file, metavar="FILE", help="write an HTML report to FILE"
    )
    p.add_argument("--per-sample", action="store_true", help="print the per-sample errors too")
    p.add_argument("--quiet", action="store_true", help="no progress bars or summary")
    registry_arg(p)
    json_arg(p, "the results (every method's held-out errors, the verdict)")
    p.set_defaults(func=run)
