"""Headless Chromium for the report tests and the docs screenshots: one way to launch it (offline,
a throw-away profile, 1:1 pixels), the page's layout as the browser measures it, and screenshots.

Chromium is Debian's ``chromium`` package (``make chromium``); without it every function here
raises, so a test that needs the browser fails, never skips. Used by tests/test_report_browser.py,
tests/test_fleet.py and docs/*_screenshot.py (which put tests/ on ``sys.path``).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
from pathlib import Path

WIDTH = 1280  # px, the window width of every rendering
PROBE = """<script>
addEventListener("load", () => {
  const box = (e) => { const r = e.getBoundingClientRect();  // content box, page coordinates
    return {x: r.left + e.clientLeft + scrollX, y: r.top + e.clientTop + scrollY,
            w: e.clientWidth, h: e.clientHeight}; };
  const out = {
    height: document.documentElement.scrollHeight,
    width: document.documentElement.scrollWidth,
    images: [...document.images].map((i) => ({id: i.id, complete: i.complete,
      naturalWidth: i.naturalWidth, naturalHeight: i.naturalHeight, ...box(i)})),
    sections: [...document.querySelectorAll("section")].map((s) => ({id: s.id, ...box(s)})),
  };
  const pre = document.createElement("pre");
  pre.id = "probe"; pre.style.display = "none"; pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});
</script>"""


def chromium(tmp: Path, *args: str) -> str:
    """Run headless Chromium offline with a throw-away profile under ``tmp``; its standard
    output. Raises RuntimeError if Chromium is missing or fails."""
    exe = shutil.which("chromium")
    if exe is None:
        raise RuntimeError(
            "chromium is not installed: the report tests and docs screenshots need Debian's "
            "chromium package (`make chromium`, or `apt-get install chromium`)"
        )
    cmd = [
        exe,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--hide-scrollbars",
        "--force-device-scale-factor=1",
        f"--user-data-dir={tmp / 'chromium-profile'}",
        *args,
    ]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    if done.returncode != 0:
        raise RuntimeError(f"chromium failed ({done.returncode}): {done.stderr[-2000:]}")
    return done.stdout


def layout(html_path: Path, tmp: Path) -> dict:
    """Where the page puts its sections and images (px, page coordinates), its scroll height and
    width, and whether the images decoded, as measured by a probe script in a copy of the page
    (the report itself has no script)."""
    probe = tmp / f"{html_path.stem}-probe.html"
    probe.write_text(html_path.read_text().replace("</body>", PROBE + "</body>"))
    dom = chromium(tmp, f"--window-size={WIDTH},1000", "--dump-dom", probe.as_uri())
    start = dom.index('<pre id="probe"')
    text = dom[dom.index(">", start) + 1 : dom.index("</pre>", start)]
    return json.loads(text.replace("&quot;", '"').replace("&amp;", "&"))


def screenshot_png(html_path: Path, tmp: Path, height: int) -> Path:
    """Render the page in a ``WIDTH x height`` px window; the PNG Chromium wrote (under ``tmp``)."""
    png = tmp / f"{html_path.stem}.png"
    chromium(tmp, f"--window-size={WIDTH},{height}", f"--screenshot={png}", html_path.as_uri())
    if not png.is_file():
        raise RuntimeError(f"chromium wrote no screenshot at {png}")
    return png


def screenshot(html_path: Path, tmp: Path, height: int):
    """The page as rendered by Chromium, ``(height, WIDTH, 3)`` uint8 BGR (OpenCV's order)."""
    import cv2

    png = screenshot_png(html_path, tmp, height)
    image = cv2.imread(str(png))
    if image is None:
        raise RuntimeError(f"chromium wrote no readable screenshot at {png}")
    return image


def save_page_png(html: str, out: Path, keep_html: Path | None = None, scale: float = 0.6) -> str:
    """The docs' screenshots: render the page ``html`` (text) whole at ``WIDTH`` px, downscale
    by ``scale``, reduce it to a 256-colour palette (to stay small) and save it as ``out``;
    ``keep_html`` also gets the page. Returns a line saying what was written."""
    from PIL import Image

    if keep_html:
        keep_html.write_text(html)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        page = tmp / f"{out.stem}.html"
        page.write_text(html)
        with Image.open(screenshot_png(page, tmp, layout(page, tmp)["height"])) as shot:
            image = shot.convert("RGB")
    size = (round(image.width * scale), round(image.height * scale))
    image = image.resize(size, Image.Resampling.LANCZOS).quantize(256, dither=Image.Dither.NONE)
    image.save(out, optimize=True)
    return f"{out}: {size[0]} x {size[1]} px, {out.stat().st_size // 1024} KB"
