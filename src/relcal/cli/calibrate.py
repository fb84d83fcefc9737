"""``relcal measure`` and ``relcal calibrate``: from a dataset folder to a calibrated model."""

from __future__ import annotations

import argparse
from pathlib import Path

from relcal.cli.common import json_arg

EPILOG = """\
examples:
  relcal measure my_dataset --json measured.json   # camera poses and rejected frames
  relcal calibrate my_dataset --out results/       # model.yaml, robot.urdf, results.json, ...
  relcal calibrate my_dataset --holdout 0.3 --loss huber --report report.html --quiet --json r.json
"""


def run_measure(args: argparse.Namespace) -> int:
    from relcal.data.dataset import load_dataset, write_samples
    from relcal.data.imaging import measure
    from relcal.io import write_json, write_text

    dataset = load_dataset(args.dataset)
    m = measure(dataset, workers=args.workers, progress=not args.quiet)
    out = Path(args.out or Path(args.dataset) / "measured")
    ok = m.ok
    ids = [dataset.ids[i] for i in range(len(ok)) if ok[i]]
    write_text(
        out / "poses.csv",
        write_samples(out / "poses.csv", ids, _degrees(dataset)[ok], poses=m.poses[ok]),
    )
    rejected = [{"id": dataset.ids[i], "reason": m.reasons[i]} for i in range(len(ok)) if not ok[i]]
    rms = {
        dataset.ids[i]: float(m.rms_px[i])
        for i in range(len(ok))
        if ok[i] and m.rms_px[i] == m.rms_px[i]
    }
    doc = {
        "n_samples": len(ok),
        "n_posed": int(ok.sum()),
        "rejected": rejected,
        "reprojection_rms_px": rms,
        "intrinsics": m.intrinsics_report,
    }
    write_json(out / "measurements.json", doc)
    if args.json:
        write_json(args.json, doc)
    if not args.quiet:
        print(f"{int(ok.sum())} of {len(ok)} samples posed; written to {out}/poses.csv")
        for r in rejected:
            print(f"  rejected {r['id']}: {r['reason']}")
    return 0


def _degrees(dataset):
    import numpy as np

    return np.where(dataset.model.prismatic, dataset.q, np.degrees(dataset.q))


def run_calibrate(args: argparse.Namespace) -> int:
    from relcal.calibration.pipeline import calibrate
    from relcal.data.dataset import load_dataset
    from relcal.data.imaging import measure
    from relcal.io import write_json, write_text
    from relcal.reporting.documents import results_document
    from relcal.robot.export import calibrated_model, parameter_csv, urdf
    from relcal.robot.model import dump_model

    dataset = load_dataset(args.dataset)
    m = measure(dataset, workers=args.workers, progress=not args.quiet)
    options = {
        "pairing": args.pairs,
        "method": args.method,
        "loss": args.loss,
        "reject_outliers": not args.keep_outliers,
    }
    holdout_ids = _ids(args.holdout_ids) if args.holdout_ids else None
    cal = calibrate(
        dataset, m, holdout=args.holdout, seed=args.seed, holdout_ids=holdout_ids, **options
    )
    out = Path(args.out or Path(args.dataset) / "calibration")
    model = calibrated_model(cal.problem.model, cal.problem.layout, cal.result.params)
    doc = results_document(cal)
    if args.kfold:
        from relcal.calibration.pipeline import cross_validate

        folds = cross_validate(dataset, m, k=args.kfold, seed=args.seed, **options)
        doc["cross_validation"] = cross_validation_summary(folds)
    write_text(out / "model.yaml", dump_model(model))
    write_text(out / "robot.urdf", urdf(model))
    write_text(out / "parameters.csv", parameter_csv(doc["parameters"]))
    write_json(out / "results.json", doc)
    if args.json:
        write_json(args.json, doc)
    if args.report:
        from relcal.reporting.html import calibration_report

        write_text(args.report, calibration_report(cal, doc))
    if not args.quiet:
        print(summary_text(doc))
        print(f"written: {out}/model.yaml, robot.urdf, parameters.csv, results.json")
        if args.report:
            print(f"report: {args.report}")
    return 0 if cal.result.converged else 1


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


def cross_validation_summary(folds) -> dict:
    """Held-out errors per fold and pooled over all folds (each sample held out once)."""
    import numpy as np

    from relcal.calibration.validate import Validation

    done = [f.validation for f in folds if f.validation]
    pooled = Validation(
        pairs=np.concatenate([v.pairs for v in done]),
        before=np.concatenate([v.before for v in done]),
        after=np.concatenate([v.after for v in done]),
    )
    return {
        "k": len(folds),
        "folds": [f.validation.summary() if f.validation else None for f in folds],
        "pooled": pooled.summary(),
    }


def summary_text(doc: dict) -> str:
    """A few lines for the terminal: convergence, held-out accuracy, unidentifiable parameters."""
    ident = doc["identification"]
    lines = [
        f"{doc['robot']}: {doc['n_used']} of {doc['n_samples']} samples used, "
        f"{len(doc['held_out_ids'])} held out",
        f"identification: rank {ident['rank']} of {ident['n_params']}, "
        f"{'converged' if ident['converged'] else 'NOT converged'}, residual RMS "
        f"{ident['initial_residual_rms']:.3g} -> {ident['residual_rms']:.3g} noise std",
    ]
    val = doc["validation"]
    if val:
        for key, unit in (("position_mm", "mm"), ("orientation_deg", "deg")):
            if key in val["before"]:
                b, a = val["before"][key], val["after"][key]
                ratio = val["rms_ratio"][key]
                lo, hi = ratio["ci95"]
                lines.append(
                    f"held-out relative {key.split('_')[0]} error over {val['n_pairs']} pairs: "
                    f"RMS {b['rms']:.3f} -> {a['rms']:.3f} {unit} "
                    f"(x{ratio['after_over_before']:.3g}, 95% interval {lo:.3g}..{hi:.3g} over "
                    f"the {val['n_samples']} samples), "
                    f"median {b['median']:.3f} -> {a['median']:.3f} {unit}"
                )
    if doc["outliers"]:
        lines.append(
            "outliers (their pairs fit badly; left out unless --keep-outliers): "
            + ", ".join(doc["outliers"])
        )
    cv = doc.get("cross_validation")
    if cv:
        pooled = cv["pooled"]
        b, a = pooled["before"]["position_mm"], pooled["after"]["position_mm"]
        lo, hi = pooled["rms_ratio"]["position_mm"]["ci95"]
        lines.append(
            f"{cv['k']}-fold cross-validation over {pooled['n_pairs']} held-out pairs: position "
            f"RMS {b['rms']:.3f} -> {a['rms']:.3f} mm "
            f"(95% interval of the ratio {lo:.3g}..{hi:.3g})"
        )
    for text in ident["unidentifiable"]:
        lines.append(f"  not identifiable: {text}")
    return "\n".join(lines)


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
        "identifiable subset only) and validate on held-out samples.",
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
        default="huber",
        help="loss of the weighted residuals (lm only; default huber, robust to outliers)",
    )
    cp.add_argument(
        "--keep-outliers", action="store_true", help="do not leave detected outliers out of the fit"
    )
    cp.add_argument("--report", metavar="FILE", help="write the HTML calibration report to FILE")
    json_arg(cp, "a copy of results.json (parameters, hand-eye, validation, calibrated model)")
    cp.set_defaults(func=run_calibrate)
