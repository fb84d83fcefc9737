"""``--json FILE`` of measure, calibrate, compensate, board and import: the documents hold what
the command produced (the same as its other outputs), every number finite and with its unit."""

import json
import math

import numpy as np
import pytest
from conftest import DATA, random_q
from helpers_dataset import synthetic_dataset

from relcal.cli import main
from relcal.data.dataset import load_dataset
from relcal.robot.kinematics import apply_errors, make_layout
from relcal.robot.model import dump_model
from relcal.vision.boards import board_extent, load_board


def numbers(doc) -> list[float]:
    """Every number in a JSON document (booleans excluded)."""
    if isinstance(doc, dict):
        return [v for value in doc.values() for v in numbers(value)]
    if isinstance(doc, list):
        return [v for value in doc for v in numbers(value)]
    return [doc] if isinstance(doc, int | float) and not isinstance(doc, bool) else []


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return synthetic_dataset(tmp_path_factory.mktemp("json") / "d", n=16)


def test_measure_json_is_measurements_json(dataset, tmp_path, capsys):
    out, doc_path = tmp_path / "m", tmp_path / "measure.json"
    argv = ["measure", str(dataset.root), "--out", str(out), "--quiet"]
    assert main([*argv, "--json", str(doc_path)]) == 0
    doc = json.loads(doc_path.read_text())
    assert doc == json.loads((out / "measurements.json").read_text())
    assert doc["n_samples"] == doc["n_posed"] == 16 and doc["rejected"] == []
    assert capsys.readouterr().out == ""


def test_calibrate_json_is_results_json(dataset, tmp_path):
    out, doc_path = tmp_path / "c", tmp_path / "calibrate.json"
    argv = ["calibrate", str(dataset.root), "--out", str(out), "--quiet", "--holdout", "0.25"]
    assert main([*argv, "--json", str(doc_path)]) == 0
    doc = json.loads(doc_path.read_text())
    assert doc == json.loads((out / "results.json").read_text())
    ids = load_dataset(dataset.root).ids
    assert sorted(doc["train_ids"] + doc["held_out_ids"]) == sorted(ids)
    assert doc["identification"]["converged"]
    assert all(math.isfinite(v) for v in numbers(doc))
    units = {row["unit"] for row in doc["parameters"]}
    assert {"mm", "deg"} <= units <= {"mm", "deg", "ppm"}  # non-geometric candidates: scale


@pytest.fixture
def models(a465, tmp_path):
    """A 'calibrated' A465 (small known errors) and its nominal model, as YAML files."""
    layout = make_layout(a465)
    errors = np.where(layout.is_angle(), np.radians(0.05), 0.3e-3)
    cal_path, nominal_path = tmp_path / "cal.yaml", tmp_path / "nominal.yaml"
    cal_path.write_text(dump_model(apply_errors(a465, layout, errors)))
    nominal_path.write_text(dump_model(a465))
    return cal_path, nominal_path


def test_compensate_json_matches_the_csv(a465, rng, models, tmp_path):
    cal_path, nominal_path = models
    program = tmp_path / "program.csv"
    q = np.degrees(random_q(a465, 4, rng, scale=0.5))
    rows = ["id," + ",".join(f"q{i + 1}" for i in range(6))]
    rows += [f"t{k}," + ",".join(f"{v:.12g}" for v in q[k]) for k in range(4)]
    program.write_text("\n".join(rows) + "\n")
    out, doc_path = tmp_path / "joints.csv", tmp_path / "joints.json"
    argv = ["compensate", "--model", str(cal_path), "--targets", str(program)]
    argv += ["--nominal", str(nominal_path), "--out", str(out), "--json", str(doc_path)]
    assert main(argv) == 0
    doc = json.loads(doc_path.read_text())
    lines = out.read_text().splitlines()
    header, csv_rows = lines[0].split(","), [line.split(",") for line in lines[1:]]
    assert [t["id"] for t in doc["targets"]] == [r[0] for r in csv_rows] == ["t0", "t1", "t2", "t3"]
    assert doc["joint_units"] == ["deg"] * 6
    assert doc["summary"] == {"n_targets": 4, "n_not_converged": 0, "n_refused": 0}
    for target, row in zip(doc["targets"], csv_rows, strict=True):
        cell = dict(zip(header, row, strict=True))
        np.testing.assert_allclose(
            target["q"], [float(cell[f"q{i + 1}"]) for i in range(6)], atol=1e-7
        )
        np.testing.assert_allclose(
            target["dq"], [float(cell[f"dq{i + 1}"]) for i in range(6)], rtol=1e-5, atol=1e-9
        )
        assert target["converged"] and cell["converged"] == "True"
        # Errors of 0.3 mm and 0.05 deg per parameter move the tool by a fraction of a mm to mm.
        assert 0.01 < target["predicted_position_mm"] < 20
        assert target["predicted_position_mm"] == pytest.approx(
            float(cell["predicted_position_mm"]), rel=1e-5
        )
        assert 0 < target["predicted_rotation_deg"] < 2
    assert all(math.isfinite(v) for v in numbers(doc))


def test_compensate_json_counts_unreached_targets_and_quiet_says_nothing(models, tmp_path, capsys):
    cal_path, _ = models
    targets = tmp_path / "poses.csv"
    targets.write_text("id,x,y,z,qx,qy,qz,qw\nnear,0.4,0.1,0.3,1,0,0,0\nfar,5,0,0,0,0,0,1\n")
    doc_path = tmp_path / "j.json"
    argv = ["compensate", "--model", str(cal_path), "--targets", str(targets)]
    assert main([*argv, "--joint-unit", "rad", "--json", str(doc_path), "--quiet"]) == 1
    captured = capsys.readouterr()
    assert captured.err == "" and captured.out.startswith("id,q1,")  # the CSV is still the output
    doc = json.loads(doc_path.read_text())
    assert doc["summary"] == {"n_targets": 2, "n_not_converged": 1, "n_refused": 0}
    assert [(t["id"], t["converged"]) for t in doc["targets"]] == [("near", True), ("far", False)]
    assert doc["joint_units"] == ["rad"] * 6 and "dq" not in doc["targets"][0]
    assert main([*argv, "--joint-unit", "rad"]) == 1
    assert "1 target(s) not reached" in capsys.readouterr().err


@pytest.mark.parametrize("suffix", ["pdf", "png"])
def test_board_json_geometry_and_page(tmp_path, suffix):
    doc_path, yaml_path = tmp_path / "board.json", tmp_path / "board.yaml"
    argv = ["board", "--type", "charuco", "--rows", "5", "--columns", "4", "--square", "0.03"]
    argv += ["--marker", "0.02", "--dictionary", "DICT_4X4_50", "--dpi", "50", "--quiet"]
    argv += ["--out", str(tmp_path / f"b.{suffix}"), "--yaml", str(yaml_path)]
    assert main([*argv, "--json", str(doc_path)]) == 0
    doc = json.loads(doc_path.read_text())
    assert (doc["type"], doc["rows"], doc["columns"]) == ("charuco", 5, 4)
    assert (doc["square_m"], doc["marker_m"], doc["dictionary"]) == (0.03, 0.02, "DICT_4X4_50")
    assert doc["margin_m"] == 0.03 and doc["file"] == str(tmp_path / f"b.{suffix}")
    board = load_board(yaml_path)
    x0, y0, x1, y1 = board_extent(board)
    tolerance = 0.6 if suffix == "png" else 0.2  # one pixel at 50 dpi is 0.5 mm
    assert doc["page_width_mm"] == pytest.approx((x1 - x0) * 1e3, abs=tolerance)
    assert doc["page_height_mm"] > (y1 - y0) * 1e3  # the caption and the scale bar below
    assert doc["description"] == board.describe()


def test_import_json_lists_the_dataset(tmp_path):
    out, doc_path = tmp_path / "p", tmp_path / "import.json"
    source = DATA / "rct_positioner" / "positioner_kinematic_measurements.yaml"
    argv = ["import", "rct-positioner", str(source), "--out", str(out), "--quiet"]
    assert main([*argv, "--json", str(doc_path)]) == 0
    doc = json.loads(doc_path.read_text())
    assert doc["n_samples"] == len(load_dataset(out).ids) == 205
    assert sorted(doc["files"]) == sorted(
        str(p) for p in out.iterdir() if p.name != ".relcal-set.json"
    )
    assert doc["dataset"] == str(out) and doc["format"] == "rct-positioner"
