"""The fleet report: one self-contained HTML page (filled in below)."""


def fleet_report(doc: dict, entries: list[dict]) -> str:
    return "<html><body>fleet</body></html>"
