"""The HTML reports in a real browser: headless Chromium loads them, a probe copy reports where each
plot landed and whether it decoded, and the screenshot must show each plot at that place.

Chromium is Debian's ``chromium`` package, installed by ``make test`` (target ``chromium``); a
missing browser fails these tests, it never skips them. The browser itself (launch, layout probe,
screenshots) is in helpers_browser.py, shared with the docs' screenshot scripts.
"""

from __future__ import annotations

import base64
from dataclasses import replace
from html.parser import HTMLParser
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers_browser import WIDTH, layout, screenshot
from helpers_dataset import synthetic_dataset
from helpers_sim import HANDEYE

from relcal import geometry as tf
from relcal.calibration.pipeline import calibrate
from relcal.cli import main
from relcal.data.dataset import load_dataset
from relcal.data.imaging import measure
from relcal.reporting.calibration_report import calibration_report
from relcal.reporting.documents import results_document
from relcal.reporting.htmlkit import compact_names, flatten

CAL_SECTIONS = {
    "summary",
    "parameters",
    "singular-values",
    "residuals",
    "per-pair",
    "rejected",
    "settings",
}
CAL_PLOTS = {"plot-parameters", "plot-singular-values", "plot-residuals", "plot-per-pair"}
PLOT_SECTIONS = {  # the section each plot of the calibration report belongs in
    "plot-parameters": "parameters",
    "plot-singular-values": "singular-values",
    "plot-residuals": "residuals",
    "plot-per-pair": "per-pair",
}
REJECTED = {3: "board not found", 8: "reprojection RMS 3.2 px > 1.0 px <script>alert(1)</script>"}


# --- the HTML ------------------------------------------------------------------------------------


class Page(HTMLParser):
    """Sections, images, external references, scripts and table text of a page."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.sections: list[str] = []
        self.images: dict[str, dict] = {}
        self.references: list[str] = []
        self.tags: set[str] = set()
        self.cells: list[str] = []
        self._cell: list[str] | None = None
        self.feed(text)

    def handle_starttag(self, tag: str, attrs: list) -> None:
        attrs = dict(attrs)
        self.tags.add(tag)
        if tag == "section":
            self.sections.append(attrs.get("id"))
        if tag == "img":
            self.images[attrs.get("id")] = attrs
        self.references += [attrs[k] for k in ("src", "href") if k in attrs]
        if tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag: str) -> None:
        if tag in ("td", "th") and self._cell is not None:
            self.cells.append("".join(self._cell).strip())
            self._cell = None

    def handle_data(self, data: str) -> None:
        if self._cell is not None:
            self._cell.append(data)


def decode_png(src: str) -> np.ndarray:
    """The image of a ``data:image/png;base64,`` URI (BGR); fails on anything else."""
    prefix = "data:image/png;base64,"
    assert src.startswith(prefix), src[:40]
    raw = base64.b64decode(src[len(prefix) :], validate=True)
    assert raw[:8] == b"\x89PNG\r\n\x1a\n"
    image = cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_COLOR)
    assert image is not None and image.shape[0] > 100 and image.shape[1] > 300
    return image


def check_page(text: str, sections: set[str], plots: set[str]) -> Page:
    """Every section and plot present, plots decodable PNG data, nothing fetched, no script."""
    page = Page(text)
    assert sections <= set(page.sections), sections - set(page.sections)
    assert len(page.sections) == len(set(page.sections)), "duplicate section ids"
    assert plots <= set(page.images), plots - set(page.images)
    for ident in plots:
        assert page.images[ident]["alt"].strip(), f"{ident} has no alt text"
        decode_png(page.images[ident]["src"])
    external = [r for r in page.references if not r.startswith(("data:", "#"))]
    assert external == [], f"the report refers to outside resources: {external}"
    assert not {"script", "link", "iframe"} & page.tags
    return page


# --- the rendering -------------------------------------------------------------------------------


def white_fraction(region: np.ndarray) -> float:
    return float(np.mean(np.all(region > 245, axis=2)))


def check_rendering(html_path: Path, tmp: Path, plots: set[str]) -> tuple[dict, np.ndarray]:
    """Load the page in Chromium: each plot decoded at its natural size, inside the page width,
    and the screenshot shows that very plot where the layout put it."""
    text = html_path.read_text()
    found = layout(html_path, tmp)
    assert found["width"] <= WIDTH, "the page is wider than the window"
    images = {i["id"]: i for i in found["images"]}
    assert plots <= set(images)
    shot = screenshot(html_path, tmp, found["height"])
    assert shot.shape[:2] == (found["height"], WIDTH)
    gray = cv2.cvtColor(shot, cv2.COLOR_BGR2GRAY)
    assert gray.std() > 20, "the screenshot is (nearly) uniform"
    assert gray[:60].mean() < 80, "the dark page header is missing (inline CSS not applied?)"
    page = Page(text)
    for ident in plots:
        info = images[ident]
        png = decode_png(page.images[ident]["src"])
        assert info["complete"] and (info["naturalHeight"], info["naturalWidth"]) == png.shape[:2]
        assert info["w"] >= 600, f"{ident} is drawn only {info['w']:.0f} px wide"
        assert info["x"] >= 0 and info["x"] + info["w"] <= WIDTH, f"{ident} leaves the page"
        x, y, w, h = (int(round(info[k])) for k in ("x", "y", "w", "h"))
        region = shot[y : y + h, x : x + w].astype(float)
        assert region.shape[:2] == (h, w), f"{ident} lies outside the screenshot"
        assert white_fraction(region) < 0.97, f"{ident}: blank where the plot should be"
        assert (w, h) == (png.shape[1], png.shape[0]), f"{ident} is shown scaled (blurred)"
        plot = cv2.cvtColor(png, cv2.COLOR_BGR2GRAY).astype(np.float32)
        # a layout position on half a pixel (y 1688.5) is painted at either neighbour: the best
        # of the placements one pixel around the rounded one
        best = (-1.0, np.inf)
        for dy, dx in ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)):
            part = shot[max(y + dy, 0) : y + dy + h, max(x + dx, 0) : x + dx + w]
            if part.shape[:2] != (h, w):
                continue
            drawn = cv2.cvtColor(part, cv2.COLOR_BGR2GRAY).astype(np.float32)
            score = float(cv2.matchTemplate(drawn, plot, cv2.TM_CCOEFF_NORMED)[0, 0])
            best = max(best, (score, float(np.abs(drawn - plot).mean())))
        similarity, difference = best
        assert similarity > 0.97 and difference < 8, (
            f"{ident}: the screenshot differs from the plot (correlation {similarity:.3f}, "
            f"mean difference {difference:.1f})"
        )
    return found, shot


def check_section_drawn(found: dict, shot: np.ndarray, ident: str) -> None:
    box = next(s for s in found["sections"] if s["id"] == ident)
    x, y, w, h = (int(round(box[k])) for k in ("x", "y", "w", "h"))
    assert h > 80 and white_fraction(shot[y : y + h, x : x + w]) < 0.99, f"{ident} looks empty"


def check_plot_in_section(found: dict, plot: str, section: str) -> None:
    """The plot's image lies inside the box of its section, as the browser laid them out."""
    img = next(i for i in found["images"] if i["id"] == plot)
    box = next(s for s in found["sections"] if s["id"] == section)
    inside = (
        box["x"] <= img["x"]
        and img["x"] + img["w"] <= box["x"] + box["w"]
        and box["y"] <= img["y"]
        and img["y"] + img["h"] <= box["y"] + box["h"]
    )
    assert inside, f"{plot} is drawn at {img}, outside its section {section} at {box}"


# --- the tests -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    """A calibration of a synthetic A465 dataset (poses given directly, one planted outlier), with
    two samples marked rejected as the image pipeline would, one reason carrying markup."""
    root = tmp_path_factory.mktemp("report") / "dataset"
    synthetic_dataset(root, n=40, outliers=1, seed=5)
    xyz, rpy = tf.to_xyz_rpy(HANDEYE)
    (root / "dataset.yaml").write_text(
        "robot: a465\nhayati: auto\njoint_unit: deg\n"
        f"handeye: {{xyz: {xyz.tolist()}, rpy: {np.degrees(rpy).tolist()}}}\n"
    )
    dataset = load_dataset(root)
    m = measure(dataset, progress=False)
    ok, reasons, poses = m.ok.copy(), list(m.reasons), m.poses.copy()
    for k, reason in REJECTED.items():
        ok[k], reasons[k], poses[k] = False, reason, np.nan
    m = replace(m, ok=ok, reasons=tuple(reasons), poses=poses)
    cal = calibrate(dataset, m, holdout=0.3)
    return cal, results_document(cal)


def test_calibration_report_renders_in_chromium(calibration, tmp_path):
    cal, doc = calibration
    path = tmp_path / "report.html"
    path.write_text(calibration_report(cal, doc))
    text = path.read_text()
    page = check_page(text, CAL_SECTIONS, CAL_PLOTS)

    # the summary: held-out accuracy of the baseline -> calibrated, and convergence
    val = doc["validation"]
    for key, unit in (("position_mm", "mm"), ("orientation_deg", "deg")):
        b, a = val["baseline"][key]["rms"], val["calibrated"][key]["rms"]
        assert f"{b:.3g} → {a:.3g} {unit}" in text
        assert b > 5 * a
        assert f"{b / a:.2f}× smaller" in text  # never "1.0x smaller" when nothing changed
    assert "converged" in text
    # the parameter table: every parameter, identifiable ones with a number and a std
    cells = page.cells
    for row in doc["parameters"]:
        k = cells.index(row["name"])
        assert cells[k + 1] == row["unit"]
        assert cells[k + 7] == row["status"]
        if row["status"] in ("estimated", "combination"):
            assert float(cells[k + 3]) == pytest.approx(row["error"], abs=1e-4)
            assert float(cells[k + 4]) > 0 and float(cells[k + 5]) > 0  # predicted, bootstrap
        else:
            assert cells[k + 3] == "–"
    for candidate in doc["model_selection"]["candidates"]:
        assert candidate["name"] in text
    for combination in doc["identification"]["unidentifiable"]:
        assert combination.replace("'", "&#x27;") in text
    # rejected images with their reasons (escaped), the outlier, every setting
    for k, reason in REJECTED.items():  # the synthetic set's ids are s000, s001, ... by row
        assert f"s{k:03d}" in cells and reason in cells
        assert {"id": f"s{k:03d}", "reason": reason} in doc["rejected"]
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in text
    for name in doc["outliers"]:
        assert name in cells
    for key, value in flatten(doc["settings"]):
        assert cells[cells.index(key) + 1] == value

    # the parameter plot: beside the table, with what was held at nominal listed under it
    held = [r["name"] for r in doc["parameters"] if r["status"] == "unidentifiable"]
    assert held and f"nominal kept: {compact_names(held)}." in text
    assert text.index('id="plot-parameters"') < text.index("<table", text.index('id="parameters"'))

    found, shot = check_rendering(path, tmp_path, CAL_PLOTS)
    for ident in CAL_SECTIONS:
        check_section_drawn(found, shot, ident)
    for plot, section in PLOT_SECTIONS.items():
        check_plot_in_section(found, plot, section)
    top = [s["y"] for s in found["sections"] if s["id"] == "summary"][0]
    assert top < 400, "the summary should open the page"


def test_calibrate_command_writes_the_report(tmp_path):
    syn = synthetic_dataset(tmp_path / "d", n=24, seed=2)
    report = tmp_path / "calibration.html"
    args = ["calibrate", str(syn.root), "--out", str(tmp_path / "out"), "--quiet"]
    assert main([*args, "--report", str(report)]) == 0
    page = check_page(report.read_text(), CAL_SECTIONS, CAL_PLOTS)
    assert page.sections[0] == "summary"
    assert "none: every sample gave a camera pose" in report.read_text()


def test_simulation_report_holds_both_runs_and_renders(tmp_path):
    path = tmp_path / "simulation.html"
    args = ["simulate", "--robot", "a465", "--poses", "20", "--noise", "0.02,0.005"]
    assert main([*args, "--quiet", "--report", str(path)]) == 0
    runs = ("run1", "run2")
    sections = {"summary", "settings"} | {
        f"{r}-{part}" for r in runs for part in ("parameters", "singular-values", "residuals")
    }
    plots = {f"plot-{r}-{part}" for r in runs for part in ("parameters", "singular-values")}
    plots |= {f"plot-{r}-residuals" for r in runs}
    page = check_page(path.read_text(), sections, plots)
    assert "run 1: position" in page.cells and "run 2: pose" in page.cells
    found, shot = check_rendering(path, tmp_path, plots)
    check_section_drawn(found, shot, "summary")
