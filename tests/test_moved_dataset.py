"""Datasets written by importers hold no path outside their folder: moved elsewhere, they still
calibrate; and the commands write nothing but what they are asked to (``--out``)."""

import shutil
from pathlib import Path

import pytest
from conftest import DATA

from relcal.cli import main
from relcal.io import load_yaml

MUKCA = DATA / "mukca"
CIRCLES = DATA / "rct_circle_grid_eye_in_hand"


def files_under(root: Path) -> set[Path]:
    return {p.relative_to(root) for p in root.rglob("*")}


def no_outside_paths(folder: Path) -> None:
    """dataset.yaml and samples.csv name no absolute path and nothing above the folder."""
    data, _ = load_yaml(folder / "dataset.yaml")

    def strings(node):
        if isinstance(node, dict):
            for v in node.values():
                yield from strings(v)
        elif isinstance(node, list):
            for v in node:
                yield from strings(v)
        elif isinstance(node, str):
            yield node

    text = [*strings(data), *(folder / "samples.csv").read_text().replace(",", "\n").split()]
    assert not [s for s in text if s.startswith("/") or s.startswith("..")], folder


@pytest.mark.parametrize(
    "argv",
    [
        ["mukca", str(MUKCA / "data" / "panda_1"), "--urdf", str(MUKCA / "urdf" / "panda.urdf"),
         "--tip", "ball_link", "--distance", "0.050"],
        ["rct-images", str(CIRCLES)],
    ],
    ids=["mukca", "rct-images"],
)  # fmt: skip
def test_an_imported_dataset_moved_elsewhere_still_calibrates(argv, tmp_path, monkeypatch):
    if not Path(argv[1]).exists():
        pytest.skip(f"{argv[1]} is not available")
    monkeypatch.chdir(tmp_path)
    before = files_under(DATA)
    assert main(["import", *argv, "--out", "imported", "--quiet"]) == 0
    assert {p.parts[0] for p in files_under(tmp_path)} == {"imported"}  # nothing else written
    no_outside_paths(tmp_path / "imported")
    moved = tmp_path / "elsewhere" / "deeper" / "dataset"
    moved.parent.mkdir(parents=True)
    shutil.move(tmp_path / "imported", moved)
    inputs = files_under(moved)
    assert main(["calibrate", str(moved), "--out", "cal", "--quiet"]) in (0, 1)
    assert (tmp_path / "cal" / "model.yaml").is_file()
    assert {p.parts[0] for p in files_under(tmp_path)} == {"elsewhere", "cal"}
    assert files_under(moved) == inputs  # the dataset folder got nothing new
    assert files_under(DATA) == before  # nothing written into the source data
