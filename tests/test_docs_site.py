"""The documentation site: it builds with no warning (as ``make docs``: warnings are errors, the
gallery runs), the API reference lists every public name and the CLI reference every command,
and in headless Chromium a tutorial page is laid out by its theme, the API index links every
name, and the search page finds pages (its index loads and a query returns results).

Chromium is Debian's ``chromium`` package (``make chromium``); a missing browser fails these
tests, it never skips them (tests/helpers_browser.py).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest
from helpers_browser import chromium
from helpers_docs import DOCS

import relcal

PROBE = """<script>
addEventListener("load", () => setTimeout(() => {
  const q = (s) => document.querySelector(s);
  const visible = (e) => !!e && e.getBoundingClientRect().width > 0;
  const out = {
    title: document.title,
    h1: q("h1") ? q("h1").textContent.replace("#", "").trim() : null,
    stylesheets: [...document.styleSheets].filter((s) => { try { return s.cssRules.length > 0; }
                  catch (e) { return true; } }).length,
    header: visible(q(".bd-header")),
    sidebar: visible(q(".bd-sidebar-primary")),
    code: [...document.querySelectorAll("div.highlight pre")].map((e) => e.textContent),
    links: [...document.querySelectorAll("a[href]")].map((a) => a.getAttribute("href")),
    results: [...document.querySelectorAll("#search-results li a")].map((a) => a.textContent),
    index_loaded: typeof Search !== "undefined" && !!Search._index,
  };
  const pre = document.createElement("pre");
  pre.id = "probe"; pre.style.display = "none"; pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
}, 1500));
</script>"""


@pytest.fixture(scope="session")
def site(tmp_path_factory):
    """The site built once, as ``make docs`` builds it; (output folder, seconds, stderr)."""
    out = tmp_path_factory.mktemp("site")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", MPLBACKEND="Agg")
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html"]
        + ["-d", str(out / ".doctrees"), str(DOCS), str(out / "html")],
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )
    seconds = time.perf_counter() - start
    assert done.returncode == 0, f"make docs would fail:\n{done.stdout[-4000:]}\n{done.stderr}"
    print(f"\ndocs site built in {seconds:.1f} s")
    return out / "html", done.stderr


def probe(page, tmp, query: str = "") -> dict:
    """What Chromium shows of ``page``: a copy with a probe script beside it (so its relative
    links, styles and scripts resolve), dumped after the scripts ran."""
    copy = page.with_name(f"_probe_{page.name}")
    copy.write_text(page.read_text().replace("</body>", PROBE + "</body>"))
    try:
        dom = chromium(
            tmp,
            "--window-size=1280,1000",
            "--virtual-time-budget=15000",
            "--allow-file-access-from-files",
            "--dump-dom",
            copy.as_uri() + query,
        )
    finally:
        copy.unlink()
    start = dom.index('<pre id="probe"')
    text = dom[dom.index(">", start) + 1 : dom.index("</pre>", start)]
    return json.loads(text.replace("&quot;", '"').replace("&amp;", "&").replace("&lt;", "<"))


def test_site_builds_with_no_warning(site):
    html, stderr = site
    assert not stderr.strip(), stderr
    for page in ("index", "tutorials/positioner", "reference/api", "reference/cli", "search"):
        assert (html / f"{page}.html").is_file(), page
    gallery = sorted((html / "gallery").glob("plot_*.html"))
    assert len(gallery) >= 4
    assert list((html / "_images").glob("sphx_glr_plot_*.png"))  # the examples ran and plotted


def test_reference_lists_every_public_name_and_command(site):
    html, _ = site
    api = (html / "reference" / "api.html").read_text()
    for name in relcal.__all__:
        assert f"generated/relcal.{name}.html" in api, name
        assert (html / "reference" / "generated" / f"relcal.{name}.html").is_file(), name
    cli = (html / "reference" / "cli.html").read_text()
    for command in ("relcal calibrate", "relcal import", "relcal fleet calibrate"):
        assert f'id="{command.replace(" ", "-")}"' in cli, command
    assert "--kfold" in cli and "exit codes" in cli


def test_tutorial_page_in_a_browser(site, tmp_path):
    html, _ = site
    shown = probe(html / "tutorials" / "positioner.html", tmp_path)
    assert shown["h1"] == "A real calibration: the two-axis positioner"
    assert shown["stylesheets"] >= 2 and shown["header"] and shown["sidebar"]  # the theme's
    assert any(c.startswith("relcal import rct-positioner") for c in shown["code"])
    assert any("relcal.calibrate(dataset)" in c for c in shown["code"])


def test_api_index_in_a_browser(site, tmp_path):
    html, _ = site
    shown = probe(html / "reference" / "api.html", tmp_path)
    assert shown["h1"] == "Python API"
    linked = {h.split("#")[0] for h in shown["links"] if h.startswith("generated/relcal.")}
    assert linked == {f"generated/relcal.{name}.html" for name in relcal.__all__}


def test_search_finds_pages_in_a_browser(site, tmp_path):
    html, _ = site
    shown = probe(html / "search.html", tmp_path, "?q=positioner")
    assert shown["index_loaded"], shown
    assert len(shown["results"]) >= 2, shown["results"]
    assert any("positioner" in r.lower() for r in shown["results"]), shown["results"]
