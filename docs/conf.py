"""Sphinx configuration of relcal's documentation site (``make docs``).

Pages are MyST Markdown (``*.md``); each section (tutorials, how-to, explanation, reference)
lists its folder with a glob toctree, so a page added there joins the site without an edit. The
API reference is generated from ``relcal.__all__`` (numpydoc docstrings, autosummary), the CLI
reference from the argparse parsers (``relcal.cli.build_parser``), and the gallery
(``examples/gallery/plot_*.py``) runs during the build, so its numbers and plots are fresh.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT / "src"))  # the checkout's relcal, installed or not
sys.path.insert(0, str(DOCS / "_ext"))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: one BLAS thread is faster
os.environ.setdefault("MPLBACKEND", "Agg")

from relcal_docs import write_api_page  # noqa: E402

import relcal  # noqa: E402

project = "relcal"
author = "the relcal authors"
copyright = "the relcal authors, Apache License 2.0"  # noqa: A001
version = release = relcal.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "numpydoc",
    "sphinx_gallery.gen_gallery",
    "relcal_docs",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
templates_path = ["_templates"]
exclude_patterns = [
    "_build",
    "**.ipynb",
    "**.py",
    "**.zip",
    "**.md5",
    "gallery/*.json",
    "sg_execution_times.rst",
]
suppress_warnings = ["config.cache"]  # sphinx-gallery's callables in the config

# MyST: ::: fences, definition lists, anchors for headings down to ###. No math markup: MathJax
# would come from a CDN, and the site must read offline.
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3

# API: one page per public name of relcal.__all__ (written into reference/api.rst at start-up).
write_api_page(DOCS / "reference" / "api.rst")
autosummary_generate = True
autosummary_imported_members = True
autodoc_typehints = "none"  # numpydoc sections carry the types; signatures stay readable
autodoc_member_order = "bysource"
numpydoc_show_class_members = False
numpydoc_xref_param_type = False
# Checked on every object the reference documents (warnings, so errors under -W); the same set
# as tests/test_docstrings.py, which says what is left out and why. The build validates the
# docstring text as autodoc hands it over, which misses some checks on methods (numpydoc 1.11:
# a method without Returns, an undocumented parameter); the test validates the imported objects
# themselves and catches those.
numpydoc_validation_checks = {
    "GL08", "SS01", "PR01", "PR02", "PR03", "PR04", "PR06", "PR07", "PR08", "PR09", "PR10",
    "RT01", "RT02", "RT03", "RT04", "RT05", "YD01",
}  # fmt: skip

# The gallery: every examples/gallery/plot_*.py runs at build time (seconds each).
sphinx_gallery_conf = {
    "examples_dirs": str(ROOT / "examples" / "gallery"),
    "gallery_dirs": "gallery",
    "filename_pattern": r"plot_",
    "within_subsection_order": "FileNameSortKey",
    "download_all_examples": False,
    "remove_config_comments": True,
    "show_signature": False,
    "reset_modules": ("matplotlib",),
    "abort_on_example_error": True,
    "run_stale_examples": True,  # every build runs them: the numbers are of this tree
    "write_computation_times": False,
}

html_theme = "pydata_sphinx_theme"
html_title = f"relcal {release}"
html_static_path = ["_static"]
html_css_files = ["relcal.css"]
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "header_links_before_dropdown": 6,
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
html_show_sourcelink = False
html_last_updated_fmt = None
