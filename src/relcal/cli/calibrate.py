"""``relcal measure`` and ``relcal calibrate``: from a dataset folder to a calibrated model."""

from __future__ import annotations

import argparse
from pathlib import Path

from relcal.cli.common import json_arg, registry_arg

EPILOG = """\
examples:
  relcal measure my_dataset --json measured.json   # camera poses and rejected frames
  relcal calibrate my_dataset --out results/       # model.yaml, robot.urdf, results.json, ...
  relcal calibrate my_dataset --holdout 0.3 --loss huber --report report.html --quiet --json r.json
"""


def run_measure(args: argparse.Namespace) -> int:
    from relcal.data.dataset import joints_in_unit, load_dataset, write_samples
    from relcal.data.imaging import measure
    from relcal.io import write_json, write_text
    from relcal.reporting.documents import measurements_document

    dataset = load_dataset(args.dataset)
    m = measure(dataset, workers=args.workers, progress=not args.quiet)
    out = Path(args.out or Path(args.dataset) / "measured")
    ok = m.ok
    ids = [dataset.ids[i] for i in range(len(ok)) if ok[i]]
    write_text(
        out / "poses.csv",
        write_samples(
            out / "poses.csv",
            ids,
            joints_in_unit(dataset.model, dataset.q, "deg")[ok],
            poses=m.poses[ok],
            positions_only=dataset.measured == "position",
        ),
    )
    doc = measurements_document(dataset, m)
    write_json(out / "measurements.json", doc)
    if args.json:
        write_json(args.json, doc)
    if not args.quiet:
        print(f"{int(ok.sum())} of {len(ok)} samples posed; written to {out}/poses.csv")
        for r in doc["rejected"]:
            print(f"  rejected {r['id']}: {r['reason']}")
    return 0


def run_calibrate(args: argparse.Namespace) -> int:
    from relcal.calibration.pipeline import calibrate
    from relcal.data.dataset import load_dataset
    from relcal.data.imaging import measure
    from relcal.fleet.records import record_calibration
    from relcal.io import write_json, write_text, write_with
    from relcal.reporting.documents import cross_validation_document, results_document
    from relcal.reporting.text import calibration_summary
    from relcal.robot.export import parameter_csv, robot_files
    from relcal.robot.model import dump_model

    dataset = load_dataset(args.dataset)
    m = measure(dataset, workers=args.workers, progress=not args.quiet)
    options = {
        "pairing": args.pairs,
        "method": args.method,
        "loss": args.loss,
        "reject_outliers": not args.keep_outliers,
        "selection": args.select,
        "nongeometric": args.nongeometric
        if args.nongeometric in ("auto", "none")
        else [s.strip() for s in args.nongeometric.split(",") if s.strip()],
        "weightings": ("plain",) if args.weighting == "plain" else ("plain", "noise model"),
    }
    holdout_ids = _ids(args.holdout_ids) if args.holdout_ids else None
    cal = calibrate(
        dataset, m, holdout=args.holdout, seed=args.seed, holdout_ids=holdout_ids, **options
    )
    out = Path(args.out or Path(args.dataset) / "calibration")
    model = cal.model
    doc = results_document(cal)
    if cal.hurts:
        val = doc["validation"]
        import sys

        print(calibration_summary(doc), file=sys.stderr)
        print(
            f"relcal: error: the chosen model ({doc['model_selection']['chosen']}) is worse than "
            "the baseline on the held-out samples (position RMS "
            f"{val['calibrated']['position_mm']['rms']:.3f} mm against "
            f"{val['baseline']['position_mm']['rms']:.3f} mm, the whole 95% interval of the "
            "ratio above 1): the calibration would hurt, so nothing was written. Collect more "
            "varied poses, or check with --kfold.",
            file=sys.stderr,
        )
        return 1
    if args.kfold:
        from relcal.calibration.pipeline import cross_validate

        folds = cross_validate(dataset, m, k=args.kfold, seed=args.seed, **options)
        doc["cross_validation"] = cross_validation_document(folds)
    write_text(out / "model.yaml", dump_model(model))
    files = robot_files(model)  # robot.urdf (+ origin corrections, UR/Franka files for URDFs)
    for name, data in files.items():
        write_with(out / name, lambda f, data=data: f.write(data), "wb")
    write_text(out / "parameters.csv", parameter_csv(doc["parameters"]))
    write_json(out / "results.json", doc)
    if args.json:
        write_json(args.json, doc)
    if args.report:
        from relcal.reporting.html import calibration_report

        write_text(args.report, calibration_report(cal, doc))
    run_id = record_calibration(args.registry, cal, doc, out)
    if not args.quiet:
        print(calibration_summary(doc))
        if cal.worse:
            print(
                "note: on this held-out split the calibrated model is slightly worse than the "
                "baseline, within the sampling interval (no evidence of harm; cross-validation "
                "on the training samples chose it); --kfold K measures it on every sample"
            )
        print(f"written: {out}/model.yaml, {', '.join(files)}, parameters.csv, results.json")
        if args.report:
            print(f"report: {args.report}")
        if run_id is not None:
            print(f"recorded in the registry as run {run_id}")
    if not cal.result.converged:
        return 1
    return 0


def _ids(text: str) -> list[str]:
    """Sample ids from ``a,b,c`` or ``@file`` (one id per line)."""
    if text.startswith("@"):
        from relcal.errors import RelcalError

        try:
            lines = Path(text[1:]).read_text().splitlines()
        except OSError as exc:
            raise RelcalError(f"--holdout-ids {text}: cannot read: {exc}") from None
        return [line.strip() for line in lines if line.strip()]
    return [t.strip() for t in text.split(",") if t.strip()]


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", help="dataset folder (with dataset.yaml)")
    p.add_argument("--out", help="output folder")
    p.add_argument("--workers", type=int, default=2, help="processes for image measurement")
    p.add_argument("--quiet", action="store_true", help="no progress bars or summary")


def register(sub: argparse._SubParsersAction) -> None:
    fmt = argparse.RawDescriptionHelpFormatter
    mp = sub.add_parser(
        "measure", help="camera poses from a dataset's images", epilog=EPILOG, formatter_class=fmt
    )
    _common(mp)
    json_arg(mp, "a copy of measurements.json (posed and rejected samples, reprojection RMS)")
    mp.set_defaults(func=run_measure)
    cp = sub.add_parser(
        "calibrate",
        help="identify the robot's geometry from a dataset",
        description="Measure, pair, identify (frame-invariant formulation, hand-eye estimated, "
        "identifiable subset only) and validate on held-out samples. Position-only samples (x, y, "
        "z of a tracker or marker) are fitted as absolute points with the instrument transform "
        "and the marker position estimated, and validated against that refitted baseline.",
        epilog=EPILOG,
        formatter_class=fmt,
    )
    _common(cp)
    cp.add_argument("--holdout", type=float, default=0.25, help="held-out share (default 0.25)")
    cp.add_argument("--seed", type=int, default=0, help="seed of the held-out split")
    cp.add_argument(
        "--holdout-ids", help="validation samples by id: 'a,b,c' or '@file' (one id per line)"
    )
    cp.add_argument(
        "--kfold", type=int, metavar="K", help="also run K-fold cross-validation (results.json)"
    )
    cp.add_argument("--pairs", choices=("consecutive", "star", "all"), default="all")
    cp.add_argument("--method", choices=("lm", "published"), default="lm")
    cp.add_argument(
        "--loss",
        choices=("linear", "huber", "cauchy", "soft_l1"),
        default="linear",
        help="loss of the weighted residuals once outlier samples are out (lm only; default "
        "linear; the outlier search itself always uses huber)",
    )
    cp.add_argument(
        "--keep-outliers", action="store_true", help="do not leave detected outliers out of the fit"
    )
    cp.add_argument(
        "--select",
        choices=("cv", "conservative", "all"),
        default="cv",
        help="model selection: cv (default) the simplest candidate within a standard error of "
        "the best cross-validated one; conservative: then only parameters above 3 std; all: "
        "every identifiable parameter",
    )
    cp.add_argument(
        "--nongeometric",
        default="auto",
        metavar="auto|none|TERMS",
        help="non-geometric candidates for model selection: auto (default: joint scale, first "
        "harmonic, and compliance where the model has masses), none, or a list such as "
        "scale,harmonic",
    )
    cp.add_argument(
        "--weighting",
        choices=("plain", "both"),
        default="plain",
        help="row weightings tried per candidate: plain (default; translation in m, rotation x "
        "0.1 m/rad) or both (also each pair whitened by the learned 6x6 noise)",
    )
    cp.add_argument("--report", metavar="FILE", help="write the HTML calibration report to FILE")
    registry_arg(cp)
    json_arg(cp, "a copy of results.json (parameters, hand-eye, validation, calibrated model)")
    cp.set_defaults(func=run_calibrate)
