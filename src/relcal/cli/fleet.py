"""``relcal fleet calibrate ROOT``: every dataset folder under ROOT as a task on Dask."""

from __future__ import annotations

import argparse
from datetime import UTC, datetime

from relcal.cli.calibrate import WEIGHTING_CHOICES, nongeometric_terms
from relcal.cli.common import (
    fraction,
    holdout_fraction,
    int_at_least,
    json_arg,
    output_file,
    output_folder,
    pairing_arg,
    positive_float,
    registry_arg,
    seed,
    worker_processes,
)
from relcal.fleet import ALPHA as DRIFT_ALPHA

EPILOG = """\
examples:
  relcal fleet calibrate plant/ --out cal/ --workers 2 --registry history.sqlite --json fleet.json
  relcal fleet calibrate plant/ --out cal/ --scheduler tcp://10.0.0.5:8786 --report fleet.html
  relcal fleet calibrate units/ --out units-cal/ --nongeometric none --report units.html
  (a remote cluster: `dask scheduler` on one machine, `dask worker tcp://HOST:8786 --nthreads 1`
  on each worker machine, with relcal installed and the dataset folders at the same path; set
  DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False for the workers: their profiler slows
  calibrations about twice)

exit status: 0 every session calibrated, 1 some session failed or did not converge, 2 bad input
"""


def run_fleet_calibrate(args: argparse.Namespace) -> int:
    from relcal.errors import RelcalError
    from relcal.fleet.registry import open_for_writing
    from relcal.fleet.runner import check_out_root, discover, outputs_folder
    from relcal.outputset import File, Folder, check

    if args.out is None:
        raise RelcalError(
            "relcal fleet calibrate: --out OUT is required: each session's calibration goes to "
            "OUT/<session> (earlier versions wrote SESSION/calibration into the input tree)"
        )
    check_out_root(args.root, args.out)
    sessions = discover(args.root)
    reports = [
        File(path, b"", what)
        for path, what in ((args.json, "--json"), (args.report, "--report"))
        if path
    ]
    check(reports)  # refused before the work
    outputs = [Folder(outputs_folder(s, args.out), what="outputs") for s in sessions]
    # opened, migrated and checked before any computation; never an input or an output
    registry = open_for_writing(args.registry, outputs=[*outputs, *reports])
    try:
        return _fleet(args, sessions, registry)
    finally:
        if registry is not None:
            registry.close()


def _fleet(args: argparse.Namespace, sessions, registry) -> int:
    from relcal.fleet.runner import attach_drift, run_fleet
    from relcal.fleet.text import fleet_text
    from relcal.fleet.units import compare_units
    from relcal.io import write_json, write_text

    options = {
        "holdout": args.holdout,
        "seed": args.seed,
        "pairing": args.pairs,
        "method": args.method,
        "loss": args.loss,
        "keep_outliers": args.keep_outliers,
        "selection": args.select,
        "nongeometric": args.nongeometric,
        "weightings": WEIGHTING_CHOICES[args.weighting],
        "priors": args.priors,
        "kfold": args.kfold,
    }
    started = datetime.now(UTC)
    bar = None
    if not args.quiet:
        from tqdm import tqdm

        bar = tqdm(total=len(sessions), unit="session", desc="fleet")

    def done(entry: dict) -> None:
        if bar is not None:
            bar.update(1)
            if entry["status"] != "ok":
                bar.write(f"{entry['session']}: {entry['status']}: {entry.get('reason')}")

    try:
        entries = run_fleet(
            sessions, args.out, options, args.workers, args.scheduler, registry, on_entry=done
        )
    finally:
        if bar is not None:
            bar.close()
    attach_drift(entries, registry, started, args.alpha)
    elapsed = (datetime.now(UTC) - started).total_seconds()
    doc = fleet_document(args, sessions, entries, elapsed, registry)
    doc["units"] = compare_units(entries, args.alpha, args.units_z)
    if registry is not None:
        doc["verifications"] = latest_verifications(registry, entries)
    if args.json:
        write_json(args.json, doc)
    if args.report:
        from relcal.fleet.report import fleet_report

        write_text(args.report, fleet_report(doc, entries))
    if not args.quiet:
        print(fleet_text(entries, doc["models"], doc.get("verifications"), doc["units"]))
        n_ok = sum(e["status"] == "ok" for e in entries)
        print(f"{n_ok} of {len(entries)} sessions calibrated in {elapsed:.1f} s")
        if registry is not None:
            print(f"recorded in {registry.name}")
        if args.report:
            print(f"report: {args.report}")
    return 0 if all(e["status"] == "ok" for e in entries) else 1


def latest_verifications(registry, entries: list[dict]) -> list[dict]:
    """The latest recorded verification of each robot of the fleet, as JSON."""
    from relcal.fleet.text import verification_run_document

    robots = sorted({str(e.get("robot_id")) for e in entries if e.get("robot_id")})
    out = []
    for robot in robots:
        found = registry.verifications(robot)
        if found:
            out.append(verification_run_document(found[-1]))
    return out


def fleet_document(args, sessions, entries, elapsed: float, registry) -> dict:
    from relcal.fleet.runner import model_summaries

    keep = (
        "session",
        "robot_id",
        "model",
        "path",
        "status",
        "reason",
        "outputs",
        "run_id",
        "baseline_position_rms_mm",
        "baseline_orientation_rms_deg",
        "calibrated_position_rms_mm",
        "calibrated_orientation_rms_deg",
        "held_out_metric",
        "kfold",
        "kfold_baseline_position_rms_mm",
        "kfold_calibrated_position_rms_mm",
        "drift",
        "seconds",
    )
    return {
        "root": str(args.root),
        "n_sessions": len(sessions),
        "n_ok": sum(e["status"] == "ok" for e in entries),
        "n_failed": sum(e["status"] != "ok" for e in entries),
        "workers": None if args.scheduler else args.workers,
        "scheduler": args.scheduler,
        "registry": None if registry is None else registry.name,
        "seconds": elapsed,
        "alpha": args.alpha,
        "models": model_summaries(entries),
        "sessions": [{k: e.get(k) for k in keep} for e in entries],
    }


def register(sub: argparse._SubParsersAction) -> None:
    fmt = argparse.RawDescriptionHelpFormatter
    fp = sub.add_parser(
        "fleet",
        help="calibrate many robots on a Dask cluster",
        description="Fleet work: many dataset folders as tasks on Dask distributed.",
        epilog=EPILOG,
        formatter_class=fmt,
    )
    fsub = fp.add_subparsers(dest="fleet_command", required=True, metavar="COMMAND")
    cp = fsub.add_parser(
        "calibrate",
        help="calibrate every dataset folder under ROOT",
        description="Every folder under ROOT with a dataset.yaml is one session (robot id: "
        "`robot_id` of dataset.yaml, else the robot's folder: ROOT/ROBOT/SESSION or "
        "ROOT/ROBOT), calibrated as `relcal calibrate` "
        "does, as one Dask task each; a bad dataset fails alone with its reason. Each session "
        "is compared with the robot's previous calibration (drift or agree), and the units of "
        "one robot model with each other: per parameter each unit's correction against the "
        "median of the other units, in combined standard deviations (units off named with the "
        "joint).",
        epilog=EPILOG,
        formatter_class=fmt,
    )
    cp.add_argument("root", help="folder of dataset folders")
    cp.add_argument(
        "--out",
        type=output_folder,
        help="required: the calibrations go under OUT/<session> (outside ROOT: nothing is "
        "written into the input tree)",
    )
    cp.add_argument(
        "--workers", type=worker_processes, default=2, help="local worker processes (default 2)"
    )
    cp.add_argument(
        "--scheduler", metavar="tcp://HOST:8786", help="use a running Dask cluster instead"
    )
    registry_arg(cp)
    cp.add_argument(
        "--holdout", type=holdout_fraction, default=0.25, help="held-out share (default 0.25)"
    )
    cp.add_argument("--seed", type=seed, default=0, help="seed of the held-out split")
    pairing_arg(cp)
    cp.add_argument("--method", choices=("lm", "published"), default="lm")
    cp.add_argument("--loss", choices=("linear", "huber", "cauchy", "soft_l1"), default="linear")
    cp.add_argument(
        "--selection",
        "--select",
        dest="select",
        choices=("cv", "conservative", "all"),
        default="cv",
        help="model selection, as `relcal calibrate --selection` (default cv; --select is its "
        "former name)",
    )
    cp.add_argument("--keep-outliers", action="store_true", help="keep detected outliers")
    cp.add_argument(
        "--nongeometric",
        default="auto",
        type=nongeometric_terms,
        metavar="auto|none|TERMS",
        help="non-geometric candidates, as `relcal calibrate --nongeometric` (default auto; "
        "none: every unit on the geometry alone, so that their corrections compare)",
    )
    cp.add_argument(
        "--priors",
        choices=("model", "none"),
        default="model",
        help="as `relcal calibrate --priors` (default model: weakly determined parameters held "
        "by the model file's tolerances; none: plain least squares)",
    )
    cp.add_argument(
        "--weighting",
        choices=tuple(WEIGHTING_CHOICES),
        default="plain",
        help="row weightings tried per candidate, as `relcal calibrate --weighting` (default "
        "plain; both: also each pair whitened by the learned 6x6 noise)",
    )
    cp.add_argument(
        "--kfold",
        type=int_at_least(2),
        metavar="K",
        help="also K-fold cross-validation of each session, as `relcal calibrate --kfold` (in "
        "its results.json, pooled RMS in the fleet JSON); a session with fewer than 2K usable "
        "samples (K placements for coincidence data) fails alone with the reason",
    )
    cp.add_argument(
        "--units-z",
        type=positive_float,
        metavar="K",
        help="name a unit off in a parameter when its correction lies more than K combined "
        "standard deviations from the median of the other units of its model (default: the "
        "normal quantile of --alpha, Bonferroni over the units and parameters compared)",
    )
    cp.add_argument(
        "--alpha",
        type=fraction,
        default=DRIFT_ALPHA,
        help=f"drift test level (default {DRIFT_ALPHA})",
    )
    cp.add_argument(
        "--report", metavar="FILE", type=output_file, help="write the fleet report (HTML) to FILE"
    )
    cp.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    json_arg(cp, "one entry per session (status, held-out errors, outputs, drift)")
    cp.set_defaults(func=run_fleet_calibrate)
