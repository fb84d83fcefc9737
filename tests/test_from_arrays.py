"""Calibrating from NumPy arrays: ``Dataset.from_arrays`` gives what ``load_dataset`` reads from a
folder, the same calibration as ``relcal calibrate`` on the same data, and checks its arguments
at the boundary (a RelcalError naming the argument, its shape and the likely cause)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import DATA

import relcal
from relcal import geometry as tf
from relcal.cli import main
from relcal.data.dataset import load_dataset, write_samples
from relcal.data.importers import import_rct_positioner
from relcal.io import write_text
from relcal.reporting.documents import parameter_rows


@pytest.fixture(scope="module")
def positioner(tmp_path_factory):
    folder = tmp_path_factory.mktemp("arrays") / "positioner"
    import_rct_positioner(
        DATA / "rct_positioner" / "positioner_kinematic_measurements.yaml", folder
    )
    return folder


def test_from_arrays_gives_the_command_lines_calibration(positioner, tmp_path):
    """One documented call on arrays in memory; the same numbers as the command line."""
    folder = load_dataset(positioner)
    model = relcal.get_robot(positioner / "positioner.yaml")
    q, poses = folder.q, folder.poses  # the arrays a user has (rad, (N, 4, 4))

    cal = relcal.calibrate(relcal.Dataset.from_arrays(model, q, poses, mode="eye_to_hand"))

    out = tmp_path / "cal"
    assert main(["calibrate", str(positioner), "--out", str(out), "--quiet"]) == 0
    cli = json.loads((out / "results.json").read_text())
    ours = parameter_rows(cal)
    assert [r["name"] for r in ours] == [r["name"] for r in cli["parameters"]]
    for mine, theirs in zip(ours, cli["parameters"], strict=True):
        assert mine["status"] == theirs["status"], mine["name"]
        if mine["error"] is not None:
            assert mine["error"] == pytest.approx(theirs["error"], rel=1e-9, abs=1e-12)
            assert mine["std"] == pytest.approx(theirs["std"], rel=1e-6)
    assert cal.exported == cli["model_selection"]["exported"]
    base = cli["validation"]["baseline"]["position_mm"]["rms"]
    calibrated = cli["validation"]["calibrated"]["position_mm"]["rms"]
    assert f"{base:.4g} -> {calibrated:.4g} mm" in repr(cal)


def test_positions_and_quaternion_rows_match_a_dataset_folder(a465, rng, tmp_path):
    """(N, 3) positions and (N, 7) x..qw rows read as the folder's position and pose tables."""
    q_deg = rng.uniform(-40, 40, (12, 6))
    poses = relcal.fk(a465, np.radians(q_deg)) @ tf.from_vector(np.array([0, 0, 0.1, 0, 0, 0]))
    for kind, positions_only in (("position", True), ("pose", False)):
        folder = tmp_path / kind
        folder.mkdir()
        ids = [f"s{k}" for k in range(12)]
        text = write_samples(
            folder / "samples.csv", ids, q_deg, poses=poses, positions_only=positions_only
        )
        write_text(folder / "samples.csv", text)
        write_text(folder / "dataset.yaml", "robot: a465\n")
        ref = load_dataset(folder)
        if positions_only:
            given = poses[:, :3, 3]
        else:
            from scipy.spatial.transform import Rotation

            given = np.c_[poses[:, :3, 3], Rotation.from_matrix(poses[:, :3, :3]).as_quat()]
        ds = relcal.Dataset.from_arrays(a465, q_deg, given, joint_unit="deg", ids=ids)
        assert ds.measured == ref.measured == kind
        assert ds.ids == ref.ids and ds.mode == ref.mode
        np.testing.assert_allclose(ds.q, ref.q, atol=1e-12)
        np.testing.assert_allclose(ds.poses, ref.poses, atol=1e-9)
        assert ds.model.joint_names == ref.model.joint_names
        np.testing.assert_array_equal(ds.model.hayati, ref.model.hayati)  # hayati: auto


@pytest.mark.parametrize(
    ("change", "parts"),
    [
        ({"q": np.zeros((10, 5))}, ["q: shape (10, 5)", "(N, 6)", "6-joint"]),
        ({"q": np.zeros(6)}, ["q: shape (6,)", "q[None]"]),
        ({"q": np.full((10, 6), 90.0)}, ["q:", "looks like degrees", "joint_unit='deg'"]),
        ({"q": np.zeros((2, 6)), "poses": np.tile(np.eye(4), (2, 1, 1))}, ["q: 2 samples"]),
        ({"poses": np.zeros((10, 7))}, ["poses", "unit quaternion"]),
        ({"poses": np.zeros((10, 4, 3))}, ["poses: shape (10, 4, 3)", "(N, 4, 4)"]),
        ({"poses": np.zeros((9, 4, 4))}, ["poses: 9 measurements for 10 samples"]),
        ({"poses": 2 * np.tile(np.eye(4), (10, 1, 1))}, ["poses[0]: not a rigid transform"]),
        ({"poses": np.full((10, 3), np.nan)}, ["poses", "not finite"]),
        ({"handeye": np.eye(3)}, ["handeye: shape (3, 3)"]),
        ({"mode": "eye_on_hand"}, ["mode: unknown str 'eye_on_hand'"]),
        ({"ids": ["a"] * 10}, ["ids:", "unique"]),
        ({"poses": None}, ["either poses", "or images"]),
    ],
)
def test_bad_arrays_are_refused_by_name(a465, change, parts):
    args = {"q": np.full((10, 6), 0.3), "poses": np.tile(np.eye(4), (10, 1, 1))}
    args.update(change)
    with pytest.raises(relcal.RelcalError) as err:
        relcal.Dataset.from_arrays(a465, **args)
    for part in parts:
        assert part in str(err.value), str(err.value)


def test_reprs_are_short(positioner):
    """No whole arrays: one line each, what a person looks for."""
    dataset = load_dataset(positioner)
    cal = relcal.calibrate(dataset, select_folds=2)
    for obj, words in (
        (dataset, ["205 samples", "poses given", "eye_to_hand"]),
        (dataset.model, ["2 joints", "standard DH"]),
        (cal, ["205 samples", "1 outliers", "held out", "exported", "mm"]),
        (cal.result, ["converged", "rank"]),
        (cal.problem, ["samples", "board formulation"]),
        (relcal.get_robot("a465"), ["6 joints"]),
    ):
        text = repr(obj)
        assert "\n" not in text and len(text) < 300 and "array(" not in text, text
        for word in words:
            assert word in text, (text, word)
