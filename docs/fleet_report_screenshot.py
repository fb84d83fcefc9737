"""Regenerate ``docs/fleet-report.png``: a sample fleet report as headless Chromium renders it.

    .venv/bin/python docs/fleet_report_screenshot.py [--html fleet.html]

The sample is the synthetic fleet of the tests (10 robots of 2 models, two sessions each, one
corrupt dataset, a[2] of one robot 0.3 mm longer in its second session), calibrated by `relcal
fleet calibrate` on 2 local worker processes; the page is captured at 1280 px, then downscaled
and reduced to a 256-colour palette to stay small.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from helpers_browser import save_page_png  # noqa: E402
from helpers_fleet import make_robot, write_session  # noqa: E402

from relcal.cli import main as relcal  # noqa: E402

SCALE = 0.6


def sample_fleet(root: Path) -> None:
    for i in range(10):
        robot = make_robot(("a465", "ur5e")[i % 2], f"r{i:02d}", 40 + i)
        write_session(root / f"r{i:02d}" / "2026-01", robot, 100 + i)
        change = {"a[2]": 3e-4} if i == 4 else None
        write_session(root / f"r{i:02d}" / "2026-06", robot, 200 + i, change=change)
    samples = root / "r09" / "2026-06" / "samples.csv"
    lines = samples.read_text().splitlines()
    lines[5] = lines[5].replace(",", ",x", 1)
    samples.write_text("\n".join(lines) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--html", type=Path, help="also keep the sample report here")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "fleet-report.png")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "fleet.html"
        sample_fleet(Path(tmp) / "plant")
        with contextlib.redirect_stdout(io.StringIO()):
            relcal(
                [
                    "fleet",
                    "calibrate",
                    f"{tmp}/plant",
                    "--out",
                    f"{tmp}/cal",
                    "--quiet",
                    "--report",
                    str(report),
                ]
            )
        html = report.read_text().replace(tmp + "/", "")
    print(save_page_png(html, args.out, args.html, SCALE))


if __name__ == "__main__":
    main()
