"""``relcal measure`` and ``relcal calibrate``: from a dataset folder to a calibrated model."""

from __future__ import annotations

import argparse
from contextlib import nullcontext
from pathlib import Path

from relcal.cli.common import (
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

EPILOG = """\
examples:
  relcal measure my_dataset --json measured.json   # camera poses and rejected frames
  relcal calibrate my_dataset --out results/       # model.yaml, robot.urdf, results.json, ...
  relcal calibrate my_dataset --holdout 0.3 --loss huber --report report.html --quiet --json r.json
  relcal calibrate my_dataset --handeye my_dataset/handeye  # start from relcal handeye's X
"""


def _not_coincidence(dataset) -> None:
    """Coincidence samples (joints and groups) need no measuring."""
    from relcal.errors import RelcalError

    if dataset.measured == "coincidence":
        raise RelcalError(
            f"{dataset.spec_path}: coincidence samples (a group per sample) have nothing to "
            "measure: their joints and groups are the data"
        )


def run_measure(args: argparse.Namespace) -> int:
    from relcal.data.dataset import load_dataset
    from relcal.data.imaging import measure
    from relcal.outputset import check
    from relcal.reporting.outputs import write_measurements

    dataset = load_dataset(args.dataset)
    _not_coincidence(dataset)
    out = Path(args.out or Path(args.dataset) / "measured")
    check(_destinations(out, args.json))  # refuse before the work, not after it
    m = measure(dataset, workers=args.workers, progress=not args.quiet, max_rms=args.max_rms)
    write_measurements(dataset, m, out, args.json)
    if not args.quiet:
        ok = m.ok
        print(f"{int(ok.sum())} of {len(ok)} samples posed; written to {out}/poses.csv")
        for i in range(len(ok)):
            if not ok[i]:
                print(f"  rejected {dataset.ids[i]}: {m.reasons[i]}")
    return 0


def _destinations(out: Path, json_path, report_path=None):
    from relcal.outputset import File, Folder

    items = [Folder(out, what="--out")]
    if json_path:
        items.append(File(json_path, b"", "--json"))
    if report_path:
        items.append(File(report_path, b"", "--report"))
    return items


# --weighting: the row weightings tried per candidate (relcal.calibrate's ``weightings``)
WEIGHTING_CHOICES = {"plain": ("plain",), "both": ("plain", "noise model")}


def check_kfold(dataset, k: int | None, usable: int | None = None) -> None:
    """More folds than pairs of samples cannot each hold out a validation pair."""
    from relcal.errors import RelcalError

    n = len(dataset.ids) if usable is None else usable
    what = "samples" if usable is None else "usable samples"
    if k is not None and k > n // 2:
        raise RelcalError(
            f"--kfold {k}: {dataset.spec_path.parent} has {n} {what}; each fold needs at least "
            f"2 held-out samples, so K can be at most {n // 2}"
        )


def check_holdout(dataset, holdout: float, usable: int | None = None) -> None:
    """Enough training samples left after holding out ``holdout`` of them."""
    from relcal.errors import RelcalError

    n = len(dataset.ids) if usable is None else usable
    if holdout <= 0 or n < 4:  # fewer than 4 in all: the calibration says so itself
        return
    n_test = max(2, int(round(holdout * n)))
    if n - n_test < 4:
        raise RelcalError(
            f"--holdout {holdout:g}: of {n} samples {n_test} would be held out, leaving "
            f"{n - n_test} to calibrate (at least 4 are needed); lower --holdout"
        )


def id_origin(dataset) -> str:
    """How a dataset's samples got their ids, for messages."""
    ids = dataset.ids
    where = dataset.spec_path.parent.resolve() if dataset.spec_path else dataset.root
    if ids == tuple(str(k + 1) for k in range(len(ids))):
        return (
            f"{where} has {len(ids)} samples, numbered 1 to {len(ids)} in the order of their rows "
            "(the samples table has no id column)"
        )
    shown = ", ".join(ids[:3]) + (f", ... {ids[-1]}" if len(ids) > 3 else "")
    return f"{where} has {len(ids)} samples, ids {shown}"


def check_holdout_ids(dataset, ids: list[str]) -> None:
    """Every id of ``--holdout-ids`` names a sample, and enough are left to calibrate."""
    from relcal.errors import RelcalError, excerpt

    if not ids:
        raise RelcalError("--holdout-ids: no ids given ('a,b,c' or '@file', one id per line)")
    known = set(dataset.ids)
    unknown = [i for i in ids if i not in known]
    if unknown:
        names = ", ".join(excerpt(i, 30) for i in unknown[:5])
        more = f" and {len(unknown) - 5} more" if len(unknown) > 5 else ""
        raise RelcalError(f"--holdout-ids: no sample {names}{more}: {id_origin(dataset)}")
    left = len(known - set(ids))
    if left < 4:
        raise RelcalError(
            f"--holdout-ids: {len(set(ids))} of {len(known)} samples held out, leaving {left} to "
            "calibrate (at least 4 are needed); hold out fewer"
        )


def run_calibrate(args: argparse.Namespace) -> int:
    from relcal.data.dataset import load_dataset
    from relcal.fleet.registry import open_for_writing
    from relcal.outputset import check

    dataset = load_dataset(args.dataset)
    if args.handeye:  # a finished hand-eye as the starting guess of X
        from dataclasses import replace

        from relcal.calibration.handeye_file import handeye_guess

        dataset = replace(dataset, handeye=handeye_guess(args.handeye, dataset))
    out = Path(args.out or Path(args.dataset) / "calibration")
    holdout_ids = _ids(args.holdout_ids) if args.holdout_ids else None
    destinations = _destinations(out, args.json, args.report)
    check(destinations)  # refuse before the work, not after it
    if dataset.measured in ("pose", "image", "position"):  # sizes: refused before measuring
        from relcal.calibration.selection import candidate_model
        from relcal.limits import check_calibration_memory
        from relcal.robot.kinematics import make_layout

        n_params = make_layout(candidate_model(dataset.model, args.nongeometric)).size + 6
        n = len(dataset.ids)
        held = len(set(holdout_ids)) if holdout_ids else round(args.holdout * n)
        # all pairs of poses are quadratic; points are one fit per sample, linear like a board
        pairing = "board" if dataset.measured == "position" else args.pairs
        check_calibration_memory(n, pairing, n_params, str(dataset.root), n - held)
    # the registry opened, migrated and checked before any computation (the inputs are known
    # by now: an input is never turned into a database, nor is an output)
    registry = open_for_writing(args.registry, outputs=destinations)
    with registry if registry is not None else nullcontext():
        return _calibrate(args, dataset, out, holdout_ids, registry)


def _calibrate(args, dataset, out, holdout_ids, registry) -> int:
    import sys

    from relcal.calibration.pipeline import calibrate
    from relcal.data.imaging import measure
    from relcal.fleet.records import calibration_record
    from relcal.reporting.documents import cross_validation_document, results_document
    from relcal.reporting.outputs import write_calibration
    from relcal.reporting.text import calibration_summary

    by_placement = dataset.measured == "coincidence"  # held out by placement, not by sample
    if not by_placement:
        check_kfold(dataset, args.kfold)
        if holdout_ids is None:
            check_holdout(dataset, args.holdout)
        else:
            check_holdout_ids(dataset, holdout_ids)
    m = measure(dataset, workers=args.workers, progress=not args.quiet, max_rms=args.max_rms)
    if by_placement and args.kfold:
        from relcal.calibration.kinds.dispatch import kind_of

        kind_of(dataset, m).folds(args.kfold, args.seed)  # K within the placements
    elif not by_placement:
        check_kfold(dataset, args.kfold, int(m.ok.sum()))
        if holdout_ids is None:
            check_holdout(dataset, args.holdout, int(m.ok.sum()))
    options = {
        "pairing": args.pairs,
        "method": args.method,
        "loss": args.loss,
        "keep_outliers": args.keep_outliers,
        "selection": args.select,
        "nongeometric": args.nongeometric,
        "weightings": WEIGHTING_CHOICES[args.weighting],
        "priors": args.priors,
    }
    cal = calibrate(
        dataset, m, holdout=args.holdout, seed=args.seed, holdout_ids=holdout_ids, **options
    )
    doc = results_document(cal)
    if cal.hurts:
        val = cal.validation
        what = "spread" if by_placement else "position"
        print(calibration_summary(doc), file=sys.stderr)
        print(
            f"relcal: error: the chosen model ({doc['model_selection']['chosen']}) is worse than "
            f"the baseline on the held-out samples ({what} RMS {val.rms('calibrated'):.3f} mm "
            f"against {val.rms('before'):.3f} mm, the whole 95% interval of the ratio above 1): "
            "the calibration would hurt, so nothing was written. Collect more varied poses, or "
            "check with --kfold.",
            file=sys.stderr,
        )
        return 1
    if args.kfold:
        from relcal.calibration.pipeline import cross_validate

        folds = cross_validate(
            dataset, m, k=args.kfold, seed=args.seed, progress=not args.quiet, **options
        )
        doc["cross_validation"] = cross_validation_document(folds)
    if not cal.result.converged:
        if not args.quiet:
            print(calibration_summary(doc))
        print(
            f"relcal: the identification did not converge; nothing written ({out} left as it was)",
            file=sys.stderr,
        )
        return 1
    journal = None if registry is None else registry.pending(calibration_record(cal, doc, out))
    written = write_calibration(cal, out, doc, args.json, args.report, journal=journal)
    run_id = None if journal is None else journal.run_id
    if not args.quiet:
        print(calibration_summary(doc))
        if cal.worse:
            print(
                "note: on this held-out split the calibrated model is worse than the baseline, "
                "within the sampling interval: the baseline was written (nominal kinematics "
                "with the measurement frames fitted); --kfold K measures the calibration on "
                "every sample"
            )
        print(f"written: {out}/" + ", ".join(p.name for p in written if p.parent == out))
        if args.report:
            print(f"report: {args.report}")
        if run_id is not None:
            print(f"recorded in the registry as run {run_id}")
    return 0


def _ids(text: str) -> list[str]:
    """Sample ids from ``a,b,c`` or ``@file`` (one id per line)."""
    if text.startswith("@"):
        from relcal.errors import RelcalError
        from relcal.io import note_input
        from relcal.limits import read_input

        note_input(text[1:])
        try:
            lines = read_input(text[1:], "text").decode("utf-8-sig").splitlines()
        except UnicodeDecodeError:
            raise RelcalError(f"--holdout-ids {text}: not a text file (one id per line)") from None
        except OSError as exc:
            raise RelcalError(f"--holdout-ids {text}: cannot read: {exc.strerror or exc}") from None
        return [line.strip() for line in lines if line.strip()]
    return [t.strip() for t in text.split(",") if t.strip()]


def nongeometric_terms(text: str) -> str | list[str]:
    """``--nongeometric``: ``auto``, ``none`` or terms like ``scale,harmonic``."""
    from relcal.robot.model import NONGEOMETRIC

    if text in ("auto", "none"):
        return text
    terms = [s.strip() for s in text.split(",") if s.strip()]
    unknown = [s for s in terms if s not in NONGEOMETRIC]
    if unknown or not terms:
        raise argparse.ArgumentTypeError(
            f"'{text}': expected auto, none or a comma-separated list of {', '.join(NONGEOMETRIC)}"
        )
    return terms


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", help="dataset folder (with dataset.yaml)")
    p.add_argument(
        "--out",
        type=output_folder,
        help="output folder, written as one set; an earlier relcal set there is kept as OUT.prev/",
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
        "and the marker position estimated, and validated against that refitted baseline. "
        "Coincidence samples (a group per sample: a ball seated in the sockets of a plate) are "
        "fitted with the tool point and the group points estimated, and validated on whole "
        "placements held out (--holdout picks placements, --holdout-ids names them, --kfold "
        "folds over them), their group points refitted.",
        epilog=EPILOG,
        formatter_class=fmt,
    )
    _common(cp)
    cp.add_argument(
        "--holdout",
        type=holdout_fraction,
        default=0.25,
        help="held-out share, 0 <= H < 1 (default 0.25; 0: no validation); of the placements "
        "for coincidence samples",
    )
    cp.add_argument("--seed", type=seed, default=0, help="seed of the held-out split")
    cp.add_argument(
        "--holdout-ids",
        help="validation samples by id (placements by name for coincidence samples): 'a,b,c' "
        "or '@file' (one id per line)",
    )
    cp.add_argument(
        "--kfold",
        type=int_at_least(2),
        metavar="K",
        help="also run K-fold cross-validation (results.json); 2 <= K <= samples / 2 (for "
        "coincidence samples, K <= placements: K = placements leaves each one out in turn)",
    )
    pairing_arg(cp)
    cp.add_argument("--method", choices=("lm", "published"), default="lm")
    cp.add_argument(
        "--loss",
        choices=("linear", "huber", "cauchy", "soft_l1"),
        default="linear",
        help="loss of the weighted residuals once outlier samples are out, with either --method "
        "(default linear; the outlier search's own fit uses huber for points, linear for poses)",
    )
    cp.add_argument(
        "--keep-outliers", action="store_true", help="do not leave detected outliers out of the fit"
    )
    cp.add_argument(
        "--selection",
        "--select",
        dest="select",
        choices=("cv", "conservative", "all"),
        default="cv",
        help="model selection: cv (default) the simplest candidate within two standard errors "
        "of the best cross-validated one; conservative: then only parameters above 3 std; all: "
        "every identifiable parameter (--select is its former name)",
    )
    cp.add_argument(
        "--nongeometric",
        default="auto",
        type=nongeometric_terms,
        metavar="auto|none|TERMS",
        help="non-geometric candidates for model selection: auto (default: joint scale, first "
        "harmonic, and compliance where the model has masses), none, or a list such as "
        "scale,harmonic",
    )
    cp.add_argument(
        "--priors",
        choices=("model", "none"),
        default="model",
        help="model (default): weakly determined parameters are held by the manufacturing "
        "tolerances of the model file's priors: (1 mm, 0.5 deg, joint offsets 1 deg unless it "
        "says otherwise), a maximum a posteriori fit; none: the plain least squares",
    )
    cp.add_argument(
        "--weighting",
        choices=tuple(WEIGHTING_CHOICES),
        default="plain",
        help="row weightings tried per candidate: plain (default; translation in m, rotation x "
        "0.1 m/rad) or both (also each pair whitened by the learned 6x6 noise)",
    )
    cp.add_argument(
        "--report",
        metavar="FILE",
        type=output_file,
        help="write the HTML calibration report to FILE",
    )
    cp.add_argument(
        "--handeye",
        metavar="FOLDER|FILE",
        help="start from a finished hand-eye: the handeye.yaml relcal handeye wrote (or its "
        "folder) gives the starting guess of the hand-eye transform instead of handeye: of "
        "dataset.yaml or the closed form (refused when its mode or frames are not the "
        "dataset's)",
    )
    registry_arg(cp)
    json_arg(cp, "a copy of results.json (parameters, hand-eye, validation, calibrated model)")
    cp.set_defaults(func=run_calibrate)
