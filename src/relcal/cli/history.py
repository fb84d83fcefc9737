"""``relcal history ROBOT_ID`` and ``relcal compare RUN_A RUN_B``: the calibration registry."""

from __future__ import annotations

import argparse

from relcal.cli.common import fraction, json_arg, positive_int, registry_arg
from relcal.fleet import ALPHA as DRIFT_ALPHA

EPILOG = """\
examples:
  relcal history arm07 --registry history.sqlite           # every calibration of arm07
  relcal compare 12 31 --registry history.sqlite --json c.json   # did arm07 change?
  RELCAL_REGISTRY=postgresql+psycopg://cal@db/relcal relcal history arm07

Drift: the difference of two calibrations over the parameters both identify, with its
covariance the sum of both runs' covariances; flagged when the chi-square test or a parameter's
z (Bonferroni) rejects at --alpha (default 0.01). Without a change, at most 2 alpha of
comparisons are flagged. When the two runs chose different models (a joint scale or a
compliance in one of them), they are compared on one model, the geometric model with the terms
both chose (the other run refitted from its dataset with its recorded settings): a difference
of model terms is not a change of the robot (--as-recorded compares the recorded values).

Verifications (relcal verify --registry) are listed under the robot: the calibration's
prediction error on a new session, the drift signal in millimetres.
"""


def run_history(args: argparse.Namespace) -> int:
    from relcal.fleet.drift import consecutive
    from relcal.fleet.registry import require_registry
    from relcal.fleet.text import (
        drift_summary,
        history_text,
        mixed_models,
        run_document,
        verification_run_document,
    )
    from relcal.io import write_json

    with require_registry(args.registry) as registry:
        runs = registry.runs(args.robot_id)
        checks = registry.verifications(args.robot_id)
        where = registry.engine.url.render_as_string(hide_password=True)
        if not runs and not checks:
            from relcal.errors import RelcalError

            known = registry.robots()
            hint = f" (robots: {', '.join(known[:10])})" if known else " (the registry is empty)"
            raise RelcalError(f"registry {where}: no calibration of robot {args.robot_id!r}{hint}")
    if args.last:
        runs = runs[-args.last :]
        checks = checks[-args.last :]
    by_model: dict[int, object] = {}  # each robot model's runs compared among themselves only
    previous: dict[int, str] = {}  # the run each is compared with
    for model in dict.fromkeys(r.model_name for r in runs):
        same = [r for r in runs if r.model_name == model]
        found = consecutive(same, args.alpha, common=not args.as_recorded)
        by_model.update({r.id: c for r, c in zip(same, found, strict=True)})
        previous.update({b.id: str(a.id) for a, b in zip(same, same[1:], strict=False)})
    comparisons = [by_model[r.id] for r in runs]
    mixed = mixed_models(args.robot_id, runs)
    if args.json:
        write_json(
            args.json,
            {
                "robot_id": args.robot_id,
                "alpha": args.alpha,
                "runs": [
                    {
                        **run_document(r),
                        "drift": drift_summary(c, previous.get(r.id)),
                    }
                    for r, c in zip(runs, comparisons, strict=True)
                ],
                "verifications": [verification_run_document(v) for v in checks],
                "robot_models": list(dict.fromkeys(r.model_name for r in runs)),
                "warnings": [mixed] if mixed else [],
            },
        )
    if not args.quiet:
        print(history_text(args.robot_id, runs, comparisons, where, checks))
    return 0


def run_compare(args: argparse.Namespace) -> int:
    from relcal.fleet.drift import compare
    from relcal.fleet.registry import require_registry
    from relcal.fleet.text import comparison_document, comparison_text
    from relcal.io import write_json

    with require_registry(args.registry) as registry:
        a, b = registry.get(args.run_a), registry.get(args.run_b)
    c = compare(a, b, args.alpha, include_handeye=args.with_handeye, common=not args.as_recorded)
    if args.json:
        write_json(args.json, comparison_document(c))
    if not args.quiet:
        print(comparison_text(c))
    return 0


def _common(p: argparse.ArgumentParser) -> None:
    registry_arg(p)
    p.add_argument(
        "--alpha",
        type=fraction,
        default=DRIFT_ALPHA,
        help=f"drift test level (default {DRIFT_ALPHA})",
    )
    p.add_argument(
        "--as-recorded",
        action="store_true",
        help="compare the recorded values even when the runs chose different models (default: "
        "the run with more non-geometric terms refitted from its dataset on the geometric model "
        "with the terms both chose)",
    )
    p.add_argument("--quiet", action="store_true", help="no text (use with --json)")


def register(sub: argparse._SubParsersAction) -> None:
    fmt = argparse.RawDescriptionHelpFormatter
    hp = sub.add_parser(
        "history",
        help="calibrations of one robot over time",
        description="Every recorded calibration of ROBOT_ID, oldest first: held-out errors, "
        "drift against the previous run, the parameters with their standard deviations, and "
        "the verifications of its calibrations on new sessions (relcal verify --registry): "
        "their prediction error on new data against the nominal baseline and against the "
        "calibration's own held-out error.",
        epilog=EPILOG,
        formatter_class=fmt,
    )
    hp.add_argument("robot_id")
    hp.add_argument("--last", type=positive_int, metavar="N", help="only the N latest runs")
    _common(hp)
    json_arg(
        hp, "the runs (parameters in SI units) with their drift verdicts, and the verifications"
    )
    hp.set_defaults(func=run_history)
    cp = sub.add_parser(
        "compare",
        help="did the robot change between two calibrations?",
        description="The difference of two recorded calibrations with its uncertainty: "
        "chi-square test over the common identifiable subset and z per parameter.",
        epilog=EPILOG,
        formatter_class=fmt,
    )
    cp.add_argument("run_a", help="run id (from `relcal history`) or uid prefix")
    cp.add_argument("run_b", help="the later run")
    cp.add_argument(
        "--with-handeye", action="store_true", help="compare the hand-eye parameters too"
    )
    _common(cp)
    json_arg(cp, "the comparison (SI units)")
    cp.set_defaults(func=run_compare)
