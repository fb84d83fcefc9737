"""Imports go one way: no cycle among relcal's modules, counting every ``import`` statement
(module level and inside functions; only ``if TYPE_CHECKING:`` blocks, which never run, are left
out), and :mod:`relcal.checks` imports nothing of relcal but :mod:`relcal.errors`.

Run as a script (``python tests/test_layers.py [src]``) it prints the cycles it finds."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

import relcal

PACKAGE = Path(relcal.__file__).parent


def module_files(package: Path) -> dict[str, Path]:
    """Dotted module name of every ``.py`` file under ``package`` (a package is its
    ``__init__.py``)."""
    out = {}
    for path in sorted(package.rglob("*.py")):
        parts = list(path.relative_to(package.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _type_checking_only(tree: ast.AST) -> set[int]:
    """Ids of the nodes inside ``if TYPE_CHECKING:`` blocks."""
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for inner in node.body:
                skip.update(id(n) for n in ast.walk(inner))
    return skip


def imported(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The modules of ``modules`` that ``path`` (module ``name``) imports anywhere in it:
    ``import a.b``, ``from a.b import c`` (``a.b``, and ``a.b.c`` when that is a module),
    relative imports resolved."""
    tree = ast.parse(path.read_text(), str(path))
    skip = _type_checking_only(tree)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                head = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(head + ([base] if base else []))
            targets = [base] + [f"{base}.{alias.name}" for alias in node.names]
        else:
            continue
        found.update(t for t in targets if t in modules and t != name)
    return found


def import_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    """Module -> the package's modules it imports."""
    modules = module_files(package)
    return {name: imported(name, path, modules) for name, path in modules.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * len(graph) + 100))
    try:
        for v in sorted(graph):
            if v not in index:
                visit(v)
    finally:
        sys.setrecursionlimit(limit)
    return found


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return import_graph()


def test_no_import_cycle(graph):
    assert len(graph) > 100 and "relcal.calibration.measurement" in graph
    assert cycles(graph) == []


def test_checks_is_low_level(graph):
    """relcal.checks holds the generic primitives: it imports relcal.errors only."""
    assert graph["relcal.checks"] == {"relcal.errors"}
    assert graph["relcal.errors"] == set()


# DESIGN.md's order of the packages (vision and data side by side): a package imports only
# packages before it (or its own level); the top-level helpers (io, limits, outputset, ...) are
# outside the order
ORDER = {
    "errors": 0,
    "checks": 1,
    "geometry": 2,
    "robot": 3,
    "vision": 4,
    "data": 4,
    "calibration": 5,
    "design": 6,
    "sim": 7,
    "capture": 8,
    "reporting": 9,
    "fleet": 10,
    "cli": 11,
}
# known exceptions, each to be removed rather than added to: write_calibration(registry=)
# builds the registry record of the set it writes
UPWARD = {("relcal.reporting.outputs", "relcal.fleet.records")}


def upward_imports(graph: dict[str, set[str]]) -> set[tuple[str, str]]:
    """``(module, imported)`` pairs where a package imports one later in :data:`ORDER`."""

    def level(name: str) -> int | None:
        parts = name.split(".")
        return ORDER.get(parts[1]) if len(parts) > 1 else None

    return {
        (m, t)
        for m, targets in graph.items()
        for t in targets
        if level(m) is not None and level(t) is not None and level(t) > level(m)
    }


def test_packages_import_down_the_flow_only(graph):
    found = upward_imports(graph)
    assert found - UPWARD == set(), "new upward imports"
    assert UPWARD - found == set(), "a known exception is gone: remove it from UPWARD"
    planted = {"relcal.robot.model": {"relcal.calibration.measurement"}, "relcal.x": set()}
    assert upward_imports(planted) == {("relcal.robot.model", "relcal.calibration.measurement")}


def test_the_walker_finds_cycles(tmp_path):
    """A cycle through a function-local import, a relative import and a package's
    ``__init__`` is found; a ``TYPE_CHECKING`` import is not one."""
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from pkg import b\n")
    (pkg / "b.py").write_text("def f():\n    from . import c\n")
    (pkg / "c.py").write_text("import pkg.a\n")
    (pkg / "sub" / "__init__.py").write_text("def g():\n    from pkg.sub.d import x\n")
    (pkg / "sub" / "d.py").write_text("from pkg.sub import g\nx = 1\n")
    (pkg / "e.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg.f import y\n"
    )
    (pkg / "f.py").write_text("from pkg.e import TYPE_CHECKING\ny = 1\n")
    found = cycles(import_graph(pkg))
    assert sorted(found) == [["pkg.a", "pkg.b", "pkg.c"], ["pkg.sub", "pkg.sub.d"]]


def test_problem_dispatches_to_the_registered_formulation():
    """The coincidence math registers itself into measurement (which never imports it)."""
    from relcal.calibration import coincidence, measurement

    hooks = measurement.formulation_hooks("coincidence")
    assert hooks.residuals is coincidence.residuals
    assert hooks.sample_errors is coincidence.sample_errors


if __name__ == "__main__":
    root = Path(sys.argv[1]) / "relcal" if len(sys.argv) > 1 else PACKAGE
    found = cycles(import_graph(root))
    for component in found:
        print(f"{len(component)} modules: {', '.join(component)}")
    print(f"{len(found)} cycle(s)")
    sys.exit(1 if found else 0)
