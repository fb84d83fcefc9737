"""One name per concept on the command line and in the Python API (docs/reference/names.md):
the new spellings work, the old ones still work (the API's with a DeprecationWarning), mean the
same, and conflicting values are refused."""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np
import pytest

import relcal
from relcal.cli import build_parser
from relcal.errors import ArgumentError

ROOT = Path(__file__).resolve().parents[1]
POSES = ROOT / "examples" / "tiago-pro-poses"
SHARED = ROOT.parent / "shared" / "data"
needs_data = pytest.mark.skipif(not SHARED.is_dir(), reason=f"{SHARED} not found")

# (command, main spelling, former spelling, a value other than the default)
CLI_ALIASES = [
    ("calibrate", "--pairing", "--pairs", "star"),
    ("calibrate", "--selection", "--select", "conservative"),
    ("fleet calibrate", "--pairing", "--pairs", "consecutive"),
    ("fleet calibrate", "--selection", "--select", "all"),
    ("simulate", "--pairing", "--pairs", "all"),
    ("simulate", "--n-poses", "--poses", "12"),
    ("observability", "--pairing", "--pairs", "star"),
    ("study", "--pairing", "--pairs", "all"),
    ("plan", "--n-poses", "--poses", "12"),
    ("plan", "--n-candidates", "--candidates", "300"),
]
# Each command's other arguments, so that the line parses.
REQUIRED = {
    "calibrate": [str(POSES), "--out", "{tmp}/out"],
    "fleet calibrate": [str(ROOT / "examples"), "--out", "{tmp}/out"],
}


def parse(command: str, extra: list[str], tmp: Path) -> argparse.Namespace:
    args = [a.format(tmp=tmp) for a in REQUIRED.get(command, [])]
    return build_parser().parse_args([*command.split(), *args, *extra])


@pytest.mark.parametrize(("command", "new", "old", "value"), CLI_ALIASES)
def test_both_spellings_of_an_option_mean_the_same(command, new, old, value, tmp_path):
    default = parse(command, [], tmp_path)
    by_new = parse(command, [new, value], tmp_path)
    by_old = parse(command, [old, value], tmp_path)
    assert vars(by_new) == vars(by_old)
    assert vars(by_new) != vars(default)  # the value arrived (not the default)


@pytest.mark.parametrize(("command", "new", "old", "value"), CLI_ALIASES)
def test_help_shows_the_main_spelling_first(command, new, old, value):
    parser = build_parser()
    for word in command.split():
        parser = next(
            a for a in parser._actions if isinstance(a, argparse._SubParsersAction)
        ).choices[word]
    action = next(a for a in parser._actions if new in a.option_strings)
    assert action.option_strings[:2] == [new, old]
    assert "former name" in action.help


def test_the_names_page_lists_every_alignment():
    page = (ROOT / "docs" / "reference" / "names.md").read_text()
    for _, new, old, _ in CLI_ALIASES:
        assert f"`{new}`" in page and f"`{old}`" in page, (new, old)
    for keyword in ("keep_outliers", "reject_outliers", "n_poses", "make_pairs", "strategy"):
        assert keyword in page


# --- the API's renamed keywords ------------------------------------------------------------


def test_make_pairs_strategy_is_pairing():
    assert relcal.make_pairs(5, pairing="star").tolist() == [[0, 1], [0, 2], [0, 3], [0, 4]]
    with pytest.warns(DeprecationWarning, match=r"make_pairs\(strategy=.*use pairing='star'"):
        old = relcal.make_pairs(5, strategy="star")
    assert old.tolist() == relcal.make_pairs(5, "star").tolist()
    with pytest.warns(DeprecationWarning), pytest.raises(ArgumentError, match="disagree"):
        relcal.make_pairs(5, "all", strategy="star")


def test_plan_k_is_n_poses():
    model, cell = relcal.get_robot("a465"), relcal.Cell()
    options = {"n_candidates": 60, "random_sets": 0, "n_validation": 3, "seed": 1}
    new = relcal.plan(model, cell, n_poses=5, **options)
    with pytest.warns(DeprecationWarning, match=r"plan\(k=.*use n_poses=5"):
        old = relcal.plan(model, cell, k=5, **options)
    assert new.q.shape == (5, 6)
    np.testing.assert_array_equal(new.q, old.q)
    with pytest.warns(DeprecationWarning), pytest.raises(ArgumentError, match="disagree"):
        relcal.plan(model, cell, n_poses=6, k=5, **options)


@needs_data
def test_calibrate_reject_outliers_is_keep_outliers_reversed(tmp_path):
    from helpers_dataset import synthetic_dataset

    dataset = relcal.load_dataset(synthetic_dataset(tmp_path / "d", n=40, outliers=2).root)
    m = relcal.measure(dataset, progress=False)
    options = {"nongeometric": "none", "selection": "all"}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        default = relcal.calibrate(dataset, m, **options)
        kept = relcal.calibrate(dataset, m, keep_outliers=True, **options)
    assert not [w for w in caught if issubclass(w.category, DeprecationWarning)]
    with pytest.warns(DeprecationWarning, match=r"reject_outliers=.*use keep_outliers=True"):
        old = relcal.calibrate(dataset, m, reject_outliers=False, **options)
    assert default.outliers  # the set has two: keeping them changes the fit
    assert not np.allclose(kept.result.params, default.result.params)
    np.testing.assert_array_equal(old.result.params, kept.result.params)
    # results.json keeps its key (registries and pinned results read it)
    assert kept.settings["reject_outliers"] is False and default.settings["reject_outliers"]
    with pytest.warns(DeprecationWarning), pytest.raises(ArgumentError, match="disagree"):
        relcal.calibrate(dataset, m, reject_outliers=True, keep_outliers=True)
