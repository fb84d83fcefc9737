"""The summary of a capture run, for a person."""

from __future__ import annotations

from relcal.capture.loop import CaptureSummary


def format_capture(summary: CaptureSummary, out: str, planned_file: str = "") -> str:
    """A few lines: counts, the time taken, each skipped pose with its reason."""
    doc = summary.document()
    lines = []
    before = (
        f", {doc['recorded_before']} recorded by an earlier run" if doc["recorded_before"] else ""
    )
    if doc["skipped_before"]:
        before += f", {doc['skipped_before']} skipped by an earlier run (--retry-skipped: again)"
    rate = doc["poses_per_minute"]
    pace = f" ({rate:.1f} poses/min)" if rate else ""
    lines.append(
        f"{doc['recorded']} of {doc['planned']} poses recorded{before}, {doc['skipped']} skipped "
        f"in {summary.seconds:.1f} s{pace}{' from ' + planned_file if planned_file else ''}"
    )
    for o in summary.outcomes:
        if o.status == "skipped":
            tries = (
                f" after {o.attempts} attempt{'s' if o.attempts != 1 else ''}" if o.attempts else ""
            )
            lines.append(f"  skipped {o.pose_id}{tries}: {o.reason}")
    if summary.interrupted:
        lines.append(
            f"interrupted: the samples in {out} are whole; run the same command with --resume "
            "to continue"
        )
    elif doc["recorded"] + doc["recorded_before"] > 0:
        lines.append(f"dataset: {out}   next: relcal calibrate {out}")
    return "\n".join(lines)
