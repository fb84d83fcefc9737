"""``relcal verify CALIBRATION DATASET``: does a finished calibration hold on a new session?"""

from __future__ import annotations

import argparse

from relcal.cli.common import (
    int_at_least,
    json_arg,
    positive_float,
    positive_int,
    registry_arg,
    seed,
)

DEFAULT_FOLDS = 5  # relcal.calibration.verify.DEFAULT_FOLDS (here: the parser stays light)

EPILOG = """\
examples:
  relcal verify cell4/calibration cell4/session-2026-08-05          # exit 0: it holds
  relcal verify 12 new_session --registry history.sqlite --json verify.json
  relcal verify out/ session2 --folds 10 --quiet --json v.json && echo holds

what is refitted (for the calibrated model and the nominal baseline alike; kinematics frozen):
  relative poses  the hand-eye (camera or marker mounting) transform; the board placement cancels
  points          the instrument-to-base transform and the marker position
  coincidence     the points of the groups (the tool point is the calibration's own: frozen)
The refit is cross-fitted: each fold of the session's samples is evaluated with the nuisance
fitted on the other folds (--folds, default 5), so no error is judged on the data it was fitted to.

verdict and exit status:
  holds         0  the 95% interval of calibrated / baseline RMS lies below 1, and the error is not
                   beyond doubt larger than the calibration's own held-out error
  degraded      1  better than the baseline, but worse than the calibration's own held-out error
                   with the whole 99% interval of that ratio above 1
  inconclusive  1  the interval spans 1: no evidence of improvement on this session
  worse         1  the whole interval lies above 1 (position, or orientation for poses)
  (2: bad input; nothing recorded)
"""


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    import numpy as np

    from relcal.calibration.verify import (
        NUISANCE,
        assess,
        session_gate,
        session_kind,
        verify,
    )
    from relcal.data.dataset import load_dataset
    from relcal.data.imaging import measure
    from relcal.errors import RelcalError
    from relcal.fleet.records import input_hashes
    from relcal.fleet.registry import open_for_writing
    from relcal.fleet.verification import resolve, verification_record
    from relcal.io import json_text
    from relcal.outputset import File, write_set
    from relcal.reporting.documents import verification_document
    from relcal.reporting.text import verification_text

    registry = open_for_writing(args.registry)  # checked (and refused) before any work
    where = None if registry is None else registry.engine.url.render_as_string(hide_password=True)
    try:
        dataset = load_dataset(args.dataset)
        source = resolve(args.calibration, registry, dataset.model, where)
        kind = session_kind(dataset.measured)
        if kind == "coincidence" and source.tool_points is None:
            raise RelcalError(
                f"{dataset.spec_path}: coincidence samples: the calibration does not record both "
                "tool points, its own and its baseline's (results.json: tool_point_xyz_m and "
                "baseline_tool_point_xyz_m); verify from Python with "
                "relcal.calibration.verify.verify(..., tool_points=(calibrated, baseline))"
            )
        m = measure(dataset, workers=args.workers, progress=not args.quiet, max_rms=args.max_rms)
        # the gate of calibrate on the session, and the calibration's own samples refused
        usable, repeated = session_gate(source.results, dataset, m)
        ids = [dataset.ids[i] for i in usable]
        groups = None if dataset.groups is None else [dataset.groups[i] for i in usable]
        with np.errstate(all="ignore"):
            ver = verify(
                source.model,
                dataset.model,
                kind,
                ids,
                dataset.q[usable],
                None if m.poses is None or kind == "coincidence" else m.poses[usable],
                groups,
                source.tool_points,
                folds=args.folds,
                seed=args.seed,
                progress=not args.quiet,
            )
            reference, why = source.reference_for(kind)
            a = assess(ver, reference, source.ranges, seed=args.seed)
        if source.changed is not None:  # said first: the edit, not the robot, is the news
            a = replace(a, warnings=(source.changed, *a.warnings))
            why = why or (
                "model.yaml was changed since the calibration: the held-out error results.json "
                "records is of the file relcal wrote, not of this one"
            )
        if repeated:
            a = replace(a, warnings=(*a.warnings, repeated))
        robot_id = args.robot_id or (source.run.robot_id if source.run else dataset.robot_id)
        session = dataset.root.resolve().name
        calibration = {
            "source": source.label,
            "registry_run": None if source.run is None else source.run.id,
            "model": source.model.name,
            "chosen_model": source.chosen_model,
            "exported": source.exported,
            "notes": list(source.notes) + ([why] if why else []),
        }
        session_doc = {
            "dataset": str(dataset.root),
            "robot_id": robot_id,
            "session": session,
            "n_samples": len(dataset.ids),
            "n_used": len(usable),
            "rejected": [
                {"id": dataset.ids[i], "reason": m.reasons[i]} for i in np.flatnonzero(~m.ok)
            ],
        }
        doc = verification_document(
            ver, a, calibration, session_doc, NUISANCE[kind], source.ranges_note
        )
        journal = None
        if registry is not None:
            record = verification_record(
                source,
                ver,
                a,
                dataset.root,
                robot_id,
                session,
                input_hashes(dataset.root, dataset.images),
            )
            journal = registry.pending_verification(record)

        def document() -> dict:
            if journal is not None:  # its id is known once the record is prepared
                doc["verification_id"] = journal.run_id
                doc["registry"] = where
            return doc

        # the JSON and the record in one transaction: both written, or neither
        items = [File(args.json, lambda: json_text(document()), "--json")] if args.json else []
        if items or journal is not None:
            write_set(*items, journal=journal)
        document()
    finally:
        if registry is not None:
            registry.close()
    if not args.quiet:
        print(verification_text(doc, per_sample=not args.brief))
        if doc.get("verification_id") is not None:
            print(f"recorded in {where} as verification {doc['verification_id']}")
    return a.exit_status


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "verify",
        help="does a finished calibration hold on a new session?",
        description="Apply a finished calibration to an independent session (days later, the "
        "board moved, the marker remounted): refit only what belongs to the session, the "
        "kinematics frozen, for the calibration and for the nominal baseline alike; print both "
        "models' errors per sample and overall with intervals, and the verdict. Exit 0 only "
        "when the calibration beats the baseline beyond the interval and predicts as well as "
        "at calibration.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "calibration",
        help="output folder of relcal calibrate (model.yaml, results.json), or a registry run "
        "id (with --registry)",
    )
    p.add_argument("dataset", help="the new session's dataset folder (with dataset.yaml)")
    p.add_argument(
        "--folds",
        type=int_at_least(2),
        default=DEFAULT_FOLDS,
        metavar="K",
        help=f"folds of the cross-fitted nuisance refit (default {DEFAULT_FOLDS}; at most half "
        "the samples for poses)",
    )
    p.add_argument("--seed", type=seed, default=0, help="seed of the folds and the bootstrap")
    p.add_argument(
        "--robot-id",
        metavar="ID",
        help="robot the verification is recorded under (default: the calibration's registry "
        "run's robot, else robot_id of dataset.yaml, else the dataset folder's name)",
    )
    p.add_argument(
        "--workers", type=positive_int, default=2, help="processes for image measurement"
    )
    p.add_argument(
        "--max-rms",
        type=positive_float,
        metavar="PX",
        default=1.0,
        help="reject frames whose board reprojection RMS exceeds PX pixels (default 1)",
    )
    p.add_argument("--brief", action="store_true", help="no per-sample table")
    p.add_argument("--quiet", action="store_true", help="no progress bar or text")
    registry_arg(p)
    json_arg(p, "the verification (errors per sample and overall, intervals, verdict)")
    p.set_defaults(func=run)
