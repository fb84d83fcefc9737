"""The public API's docstrings: numpydoc sections checked by numpydoc's own validator, the
Examples of the main entry points executed, and the Raises sections checked against what bad
input really raises.

What is checked (``CHECKS``, also ``numpydoc_validation_checks`` in docs/conf.py, so the site's
build warns too) and what is not:

- checked: a docstring at all (GL08), a summary (SS01), every parameter documented (PR01) and
  none that does not exist (PR02), in signature order (PR03), with a type (PR04) and a
  description (PR07), types spelled ``int``/``bool``/``str`` (PR06), descriptions that start
  with a capital and end with a period (PR08, PR09), ``name : type`` spacing (PR10), a Returns
  section on functions that return (RT01) with descriptions (RT03, RT04, RT05) and one entry
  per returned item (RT02), a Yields section on generators (YD01);
- not checked: See Also (SA01) and an extended summary (ES01), optional in this project; a
  summary on one line ending in a period (SS03, SS06) and the closing quotes' line (GL02):
  relcal's summaries may be two lines or a question (``verify_session``); an infinitive verb
  (SS05): relcal describes what a function returns ("The model with ..."), and numpydoc's test
  is whether the first word ends in "s"; Examples (EX01) on every object: only the main entry
  points (``EXAMPLES``) must have them.
"""

from __future__ import annotations

import ast
import doctest
import inspect
from pathlib import Path

import numpy as np
import pytest
from numpydoc.docscrape import NumpyDocString
from numpydoc.validate import validate

import relcal
from relcal.errors import ArgumentError, RelcalError

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"

CHECKS = {
    "GL08", "SS01", "PR01", "PR02", "PR03", "PR04", "PR06", "PR07", "PR08", "PR09", "PR10",
    "RT01", "RT02", "RT03", "RT04", "RT05", "YD01",
}  # fmt: skip

# The main entry points: each has an Examples section, executed below.
EXAMPLES = (
    "load_dataset", "calibrate", "Dataset.from_arrays", "fk", "identify", "plan",
    "verify_session", "write_calibration", "simulate", "analyse_problem", "make_pairs",
    "make_layout", "apply_errors", "get_robot",
)  # fmt: skip


def public_objects() -> list[str]:
    """Dotted names (``Result.covariance``) of every name of ``relcal.__all__`` and of the
    public methods and properties of its classes (exceptions: the class only)."""
    out = []
    for name in relcal.__all__:
        obj = getattr(relcal, name)
        out.append(name)
        if not inspect.isclass(obj) or issubclass(obj, BaseException):
            continue
        for attr, value in vars(obj).items():
            if attr.startswith("_"):
                continue
            if isinstance(value, staticmethod | classmethod):
                value = value.__func__
            if inspect.isfunction(value) or isinstance(value, property) or hasattr(value, "func"):
                out.append(f"{name}.{attr}")  # functions, properties, cached properties
    return out


def resolve(dotted: str):
    """The object of ``relcal`` named ``dotted`` (``Result.covariance``)."""
    obj = relcal
    for part in dotted.split("."):
        obj = inspect.getattr_static(obj, part) if inspect.isclass(obj) else getattr(obj, part)
    if isinstance(obj, staticmethod | classmethod):
        obj = obj.__func__
    return obj


def qualified(dotted: str) -> str:
    """``relcal.MODULE.NAME[.MEMBER]``: the import path numpydoc's validator takes."""
    head, _, rest = dotted.partition(".")
    module = getattr(relcal, head).__module__
    return f"{module}.{dotted}"


OBJECTS = public_objects()


def test_the_api_is_enumerated():
    """The enumeration sees the classes' members (a broken one would check nothing)."""
    assert len(OBJECTS) > 60
    for member in ("Result.covariance", "Dataset.from_arrays", "RobotModel.with_values"):
        assert member in OBJECTS
    assert "Dataset.__repr__" not in OBJECTS


@pytest.mark.parametrize("name", OBJECTS)
def test_numpydoc_sections(name):
    errors = [(c, m) for c, m in validate(qualified(name))["errors"] if c in CHECKS]
    assert not errors, f"relcal.{name}: " + "; ".join(f"{c} {m}" for c, m in errors)


def test_the_validator_catches_what_the_checks_name():
    """A docstring missing a parameter, documenting a parameter that does not exist and
    without Returns fails the same checks (so the test above can fail)."""

    def sample(a: int, b: float) -> float:
        """Add.

        Parameters
        ----------
        a : int
            First.
        c : float
            Not a parameter.
        """
        return a + b

    import sys

    module = sys.modules[__name__]
    module._sample = sample  # validate() imports the object by name
    sample.__module__, sample.__qualname__ = __name__, "_sample"
    try:
        codes = {c for c, _ in validate(f"{__name__}._sample")["errors"]} & CHECKS
    finally:
        del module._sample
    assert {"PR01", "PR02", "RT01"} <= codes


def test_docs_build_validates_the_same_checks():
    """docs/conf.py's ``numpydoc_validation_checks`` is this set: the site's build and this
    test agree on what a complete docstring is."""
    tree = ast.parse((ROOT / "docs" / "conf.py").read_text())
    for node in ast.walk(tree):
        target = getattr(node, "target", None) or (getattr(node, "targets", None) or [None])[0]
        if getattr(target, "id", None) == "numpydoc_validation_checks":
            assert ast.literal_eval(node.value) == CHECKS
            return
    raise AssertionError("docs/conf.py sets no numpydoc_validation_checks")


@pytest.mark.parametrize("name", EXAMPLES)
def test_examples_run(name, monkeypatch):
    """The Examples section of each main entry point runs as printed, from the repository's
    root (examples/tiago-pro-poses reads ../shared/data)."""
    obj = resolve(name)
    assert NumpyDocString(inspect.getdoc(obj))["Examples"], f"relcal.{name}: no Examples"
    if "examples/" in inspect.getdoc(obj) and not SHARED.is_dir():
        pytest.skip(f"{SHARED} not found")
    monkeypatch.chdir(ROOT)
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    tests = doctest.DocTestFinder(recurse=False).find(obj, f"relcal.{name}", globs={})
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    out: list[str] = []
    for test in tests:
        runner.run(test, out=out.append)
    assert runner.failures == 0 and runner.tries > 0, "".join(out)


def bad_calls():
    """``(name, call)``: a call of a public function or class with bad input, which must raise
    an error its Raises section names."""
    model = relcal.get_robot("a465")
    layout = relcal.make_layout(model)
    return [
        ("fk", lambda: relcal.fk(model, np.zeros(5))),
        ("fk", lambda: relcal.fk(model, np.full(6, np.nan))),
        ("make_layout", lambda: relcal.make_layout("a465")),
        ("apply_errors", lambda: relcal.apply_errors(model, layout, np.zeros(3))),
        ("get_robot", lambda: relcal.get_robot("no-such-robot")),
        ("get_robot", lambda: relcal.get_robot(3)),
        ("load_model", lambda: relcal.load_model(ROOT / "pyproject.toml")),
        ("load_urdf", lambda: relcal.load_urdf("x.urdf", parametrisation="dh")),
        ("load_dataset", lambda: relcal.load_dataset(ROOT / "src")),
        ("load_dataset", lambda: relcal.load_dataset(3)),
        ("measure", lambda: relcal.measure("examples/tiago-pro-poses")),
        ("calibrate", lambda: relcal.calibrate("examples/tiago-pro-poses")),
        ("make_pairs", lambda: relcal.make_pairs(-1)),
        ("make_pairs", lambda: relcal.make_pairs(4, "ring")),
        ("identify", lambda: relcal.identify(None)),
        ("analyse_problem", lambda: relcal.analyse_problem(None)),
        ("simulate", lambda: relcal.simulate(model, n_poses=2)),
        ("simulate", lambda: relcal.simulate(model, formulation="tracker")),
        ("SolverOptions", lambda: relcal.SolverOptions(method="gauss")),
        ("SolverOptions", lambda: relcal.SolverOptions(rcond=2.0)),
        ("Noise.parse", lambda: relcal.Noise.parse("0.05")),
        ("calibrated_urdf", lambda: relcal.calibrated_urdf(model)),
        ("verify_session", lambda: relcal.verify_session(ROOT / "src", None)),
        ("Problem", lambda: relcal.Problem(model, layout, np.zeros((4, 6)), np.zeros((4, 3)))),
    ]


@pytest.mark.parametrize("index", range(len(bad_calls())))
def test_raises_sections_name_what_bad_input_raises(index):
    name, call = bad_calls()[index]
    with pytest.raises(RelcalError) as caught:
        call()
    documented = {
        (p.type or p.name).strip().rsplit(".", 1)[-1]  # "ArgumentError" or "relcal.errors.X"
        for p in NumpyDocString(inspect.getdoc(resolve(name)))["Raises"]
    }
    raised = {cls.__name__ for cls in type(caught.value).__mro__}
    assert documented & raised, (
        f"relcal.{name} raised {type(caught.value).__name__} ({caught.value}); its Raises "
        f"section names {sorted(documented) or 'nothing'}"
    )
    if isinstance(caught.value, ArgumentError):  # argument errors say which argument
        assert str(caught.value).strip()
