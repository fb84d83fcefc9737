"""Regenerate ``docs/report.png``: a sample calibration report as headless Chromium renders it.

    .venv/bin/python docs/report_screenshot.py [--html report.html]

The sample is the synthetic A465 dataset of the tests (poses given directly, one planted outlier)
with two samples marked as rejected images; the page is captured at 1280 px, then downscaled and
reduced to a 256-colour palette to stay small.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from helpers_browser import save_page_png  # noqa: E402
from helpers_dataset import synthetic_dataset  # noqa: E402
from helpers_sim import HANDEYE  # noqa: E402

from relcal import geometry as tf  # noqa: E402
from relcal.calibration.pipeline import calibrate  # noqa: E402
from relcal.data.dataset import load_dataset  # noqa: E402
from relcal.data.imaging import measure  # noqa: E402
from relcal.reporting.calibration_report import calibration_report  # noqa: E402
from relcal.reporting.documents import results_document  # noqa: E402

SCALE = 0.6


def sample_report(folder: Path) -> str:
    """The report of a 60-sample synthetic calibration with two rejected images."""
    root = folder / "sample_dataset"
    synthetic_dataset(root, n=60, outliers=1, seed=3)
    xyz, rpy = tf.to_xyz_rpy(HANDEYE)  # a hand-eye guess from the mount drawing
    xyz, rpy = np.round(xyz, 3).tolist(), np.round(np.degrees(rpy), 1).tolist()
    (root / "dataset.yaml").write_text(
        f"robot: a465\nhayati: auto\njoint_unit: deg\nhandeye: {{xyz: {xyz}, rpy: {rpy}}}\n"
    )
    dataset = load_dataset(root)
    m = measure(dataset, progress=False)
    ok, reasons, poses = m.ok.copy(), list(m.reasons), m.poses.copy()
    for k, reason in ((5, "board not found"), (17, "reprojection RMS 3.2 px > 1.0 px")):
        ok[k], reasons[k], poses[k] = False, reason, np.nan
    cal = calibrate(dataset, replace(m, ok=ok, reasons=tuple(reasons), poses=poses))
    return calibration_report(cal, results_document(cal))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--html", type=Path, help="also keep the sample report here")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "report.png")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        html = sample_report(Path(tmp)).replace(tmp + "/", "")
    print(save_page_png(html, args.out, args.html, SCALE))


if __name__ == "__main__":
    main()
