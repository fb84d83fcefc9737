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
        write_samples(
            out / "poses.csv",
            ids,
            _degrees(dataset)[ok],
            poses=m.poses[ok],
            positions_only=dataset.measured == "position",
        ),
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
    from relcal.io import write_json, write_text, write_with
    from relcal.reporting.documents import results_document
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

        print(summary_text(doc), file=sys.stderr)
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
        doc["cross_validation"] = cross_validation_summary(folds)
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
    if not args.quiet:
        print(summary_text(doc))
        if cal.worse:
            print(
                "note: on this held-out split the calibrated model is slightly worse than the "
                "baseline, within the sampling interval (no evidence of harm; cross-validation "
                "on the training samples chose it); --kfold K measures it on every sample"
            )
        print(f"written: {out}/model.yaml, {', '.join(files)}, parameters.csv, results.json")
        if args.report:
            print(f"report: {args.report}")
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


def cross_validation_summary(folds) -> dict:
    """Held-out errors per fold and pooled over all folds (each sample held out once)."""
    from relcal.calibration.validate import pooled

    done = [f.validation for f in folds if f.validation]
    return {
        "k": len(folds),
        "folds": [f.validation.summary() if f.validation else None for f in folds],
        "chosen": [f.selection[f.chosen].candidate.name for f in folds],
        "pooled": pooled(done).summary(),
    }


def _ratio_text(ratio: dict) -> str:
    lo, hi = ratio["ci95"]
    return f"x{ratio['after_over_before']:.3g}, 95% interval {lo:.3g}..{hi:.3g}"


def summary_text(doc: dict) -> str:
    """The terminal summary: the chosen model and why, held-out errors against the baselines,
    the parameters with their standard deviations, and what the data cannot determine."""
    ident = doc["identification"]
    lines = [
        f"{doc['robot']}: {doc['n_used']} of {doc['n_samples']} samples used, "
        f"{len(doc['held_out_ids'])} held out",
    ]
    points = doc["settings"].get("formulation") == "tracker"
    frames = "the instrument transform and marker" if points else "the hand-eye transform"
    sel = doc.get("model_selection")
    if sel and sel.get("candidates"):
        lines.append(
            f"model selection ({sel['folds']}-fold cross-validation on the training samples):"
        )
        for c in sel["candidates"]:
            mark = "*" if c["chosen"] else " "
            lines.append(
                f"  {mark} {c['name']:<32} {c['weighting']:<12} {c['n_params']:>3} parameters  "
                f"held-out position RMS {c['cv_position_rms_mm']:.4f} mm"
                + (
                    f", orientation {c['cv_orientation_rms_deg']:.4f} deg"
                    if c["cv_orientation_rms_deg"] is not None
                    else ""
                )
            )
        lines.append(f"  chosen: {sel['chosen']} ({sel['weighting']}): {sel['reason']}")
        if sel["exported"] == "baseline":
            lines.append(
                "  the data support no kinematic correction: the exported model is the nominal "
                f"kinematics with {frames} fitted"
            )
    lines.append(
        f"identification: rank {ident['rank']} of {ident['n_params']}, "
        f"{'converged' if ident['converged'] else 'NOT converged'}, residual RMS "
        f"{ident['initial_residual_rms']:.3g} -> {ident['residual_rms']:.3g} (weighted rows)"
    )
    val = doc["validation"]
    if val:
        base = "baseline" if "baseline" in val else "baseline_handeye_guess"
        for key, unit in (("position_mm", "mm"), ("orientation_deg", "deg")):
            if key not in val["calibrated"]:
                continue
            g, b, a = val["baseline_handeye_guess"][key], val[base][key], val["calibrated"][key]
            if points:
                what = f"absolute {key.split('_')[0]} error over {val['n_samples']} points"
                guesses, fitted = "instrument and marker guesses", "instrument and marker fitted"
            else:
                what = (
                    f"relative {key.split('_')[0]} error over {val['n_pairs']} pairs of "
                    f"{val['n_samples']} samples"
                )
                guesses, fitted = "hand-eye guess", "hand-eye fitted"
            lines.append(
                f"held-out {what}, RMS: nominal with the {guesses} {g['rms']:.3f}, "
                f"baseline (nominal, {fitted}) {b['rms']:.3f}, calibrated {a['rms']:.3f} "
                f"{unit} ({_ratio_text(val['ratio_to_baseline'][key])} of the baseline)"
            )
    shown = [r for r in doc["parameters"] if r["status"] in ("estimated", "combination")]
    if shown:
        lines.append("parameters (error from nominal +- std; bootstrap std; |error| / std):")
        for r in shown:
            boot = f"{r['bootstrap_std']:.3g}" if r["bootstrap_std"] is not None else "-"
            std = f"{r['std']:.3g}" if r["std"] is not None else "-"
            sig = f"{r['significance']:.1f}" if r["significance"] is not None else "-"
            note = "  (carries a combination)" if r["status"] == "combination" else ""
            lines.append(
                f"  {r['name']:<14} {r['error']:+.4g} +- {std} {r['unit']}  bootstrap {boot}  "
                f"z {sig}{note}"
            )
    for c in doc.get("identifiable_combinations", []):
        std = f" +- {c['std']:.3g}" if c["std"] is not None else ""
        lines.append(f"  {c['text']} = {c['value']:+.4g}{std} {c['unit']} (identifiable sum)")
    noise = doc.get("noise_model")
    if noise:
        lines.append(
            "learned pose noise (camera frame): std "
            + ", ".join(f"{v:.3g}" for v in noise["std_mm"])
            + " mm, "
            + ", ".join(f"{v:.3g}" for v in noise["std_deg"])
            + f" deg; largest translation-rotation correlation "
            f"{noise['max_translation_rotation_correlation']:.2f}"
        )
    if doc["rejected"]:
        lines.append(f"rejected frames ({len(doc['rejected'])}):")
        lines.extend(f"  {r['id']}: {r['reason']}" for r in doc["rejected"])
    if doc["outliers"]:
        lines.append(
            "outliers (their pairs fit badly; left out unless --keep-outliers): "
            + ", ".join(doc["outliers"])
        )
    cv = doc.get("cross_validation")
    if cv:
        pooled = cv["pooled"]
        base = "baseline" if "baseline" in pooled else "baseline_handeye_guess"
        b, a = pooled[base]["position_mm"], pooled["calibrated"]["position_mm"]
        lines.append(
            f"{cv['k']}-fold cross-validation over {pooled['n_pairs']} held-out "
            f"{'points' if points else 'pairs'}: position "
            f"RMS baseline {b['rms']:.3f} -> calibrated {a['rms']:.3f} mm "
            f"({_ratio_text(pooled['ratio_to_baseline']['position_mm'])}); chosen per fold: "
            + ", ".join(cv["chosen"])
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
    cp.add_argument("--report", metavar="FILE", help="write the HTML calibration report to FILE")
    json_arg(cp, "a copy of results.json (parameters, hand-eye, validation, calibrated model)")
    cp.set_defaults(func=run_calibrate)
