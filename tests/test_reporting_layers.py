"""The HTML reports by concern: a public kit (markup, page), plots, the reports; presentation
reads results and never computes them (no residuals or pair errors), and nothing reaches into
another module's private names."""

from __future__ import annotations

import ast
from pathlib import Path

import relcal

PACKAGE = Path(relcal.__file__).parent
PRESENTATION = [
    "reporting/htmlkit.py",
    "reporting/plots.py",
    "reporting/calibration_report.py",
    "reporting/simulation_report.py",
    "reporting/html.py",
    "fleet/report.py",
]
COMPUTING = {"relcal.calibration.measurement", "relcal.calibration.identify"}


def imports(path: Path) -> list[tuple[str, str]]:
    """``(module, name)`` of every ``from module import name`` of ``path``."""
    tree = ast.parse(path.read_text())
    return [
        (node.module or "", alias.name)
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom)
        for alias in node.names
    ]


def test_presentation_imports_no_computation_and_no_private_names():
    for name in PRESENTATION:
        for module, imported in imports(PACKAGE / name):
            assert module not in COMPUTING, (name, module, imported)
            if module.startswith("relcal."):
                assert not imported.startswith("_"), (name, module, imported)


def test_the_kit_is_public_and_the_old_path_still_works():
    from relcal.reporting import htmlkit
    from relcal.reporting.html import calibration_report, simulation_report

    for name in htmlkit.__all__:
        assert not name.startswith("_") and getattr(htmlkit, name) is not None
    assert htmlkit.escape("<a>") == "&lt;a&gt;" and htmlkit.escape(htmlkit.Html("<b>")) == "<b>"
    assert callable(calibration_report) and callable(simulation_report)
