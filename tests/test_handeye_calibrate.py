"""``relcal calibrate --handeye``: a finished hand-eye (the handeye.yaml of ``relcal handeye``)
as the starting guess of X; refused when its mode or frames are not the dataset's."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers_handeye import camera_poses, flange_poses, write_flange_dataset

import relcal
from relcal import geometry as tf
from relcal.calibration.handeye_file import handeye_guess, read_handeye_file
from relcal.calibration.pipeline import calibrate
from relcal.cli import main
from relcal.errors import RelcalError

TIAGO = Path(__file__).resolve().parents[1] / "examples" / "tiago-pro-poses"


@pytest.fixture(scope="module")
def tiago_handeye(tmp_path_factory):
    out = tmp_path_factory.mktemp("he") / "he"
    assert main(["handeye", str(TIAGO), "--out", str(out), "--quiet"]) == 0
    return out


def test_the_guess_is_the_files_and_the_result_the_default_runs(tiago_handeye):
    dataset = relcal.load_dataset(TIAGO)
    guess = handeye_guess(tiago_handeye, dataset)
    data = yaml.safe_load((tiago_handeye / "handeye.yaml").read_text())["handeye"]
    assert (data["parent"], data["child"]) == ("gripper_right_pal_atc_base_link", "camera")
    np.testing.assert_allclose(guess[:3, 3], data["xyz"], atol=1e-15)
    started = calibrate(replace(dataset, handeye=guess))
    assert np.abs(started.problem.handeye - guess).max() == 0.0  # the fit starts from it
    default = calibrate(dataset)
    assert np.abs(default.problem.handeye - guess).max() > 1e-3  # the closed form's start
    n = default.problem.layout.size
    moved = np.abs(started.result.params[:n] - default.result.params[:n])
    std = default.std[:n]
    estimated = np.isfinite(std)  # the chosen model's parameters
    assert estimated.sum() >= 10
    assert np.all(moved[estimated] < 0.01 * std[estimated])  # the same optimum
    assert np.all(moved[~estimated] < 1e-12)
    he = tf.to_vector(tf.invert(default.handeye) @ started.handeye)
    assert np.abs(he[:3]).max() < 1e-6 and np.abs(he[3:]).max() < 1e-5
    assert started.validation.improvement() == pytest.approx(
        default.validation.improvement(), rel=1e-4
    )


def test_command_line_starts_from_the_handeye_folder(tiago_handeye, tmp_path):
    args = ["calibrate", str(TIAGO), "--quiet", "--holdout", "0.25"]
    assert main([*args, "--out", str(tmp_path / "a"), "--json", str(tmp_path / "a.json")]) == 0
    assert main([*args, "--out", str(tmp_path / "b"), "--json", str(tmp_path / "b.json"),
                 "--handeye", str(tiago_handeye)]) == 0  # fmt: skip
    a, b = (json.loads((tmp_path / f"{k}.json").read_text()) for k in "ab")
    assert a["handeye"]["xyz_m"] == pytest.approx(b["handeye"]["xyz_m"], abs=1e-6)
    assert a["handeye"]["rpy_deg"] == pytest.approx(b["handeye"]["rpy_deg"], abs=1e-4)


def _flange_folder(tmp_path, mode: str, name: str) -> Path:
    flange = flange_poses(10, seed=3)
    return write_flange_dataset(tmp_path / name, flange, camera_poses(flange, seed=4), mode=mode)


def test_eye_to_hand_starts_from_the_board_on_the_flange(tmp_path):
    folder = _flange_folder(tmp_path, "eye_to_hand", "e2h")
    assert main(["handeye", str(folder), "--out", str(tmp_path / "he"), "--quiet"]) in (0, 1)
    found = read_handeye_file(tmp_path / "he")
    assert set(found.entries) == {"handeye", "marker"}
    dataset = relcal.load_dataset(folder)
    guess = handeye_guess(tmp_path / "he" / "handeye.yaml", dataset)
    result = relcal.handeye(dataset)
    np.testing.assert_allclose(guess, result.handeye, atol=1e-12)  # X, not the camera's pose
    assert found.entries["handeye"][2] == pytest.approx(result.transform("handeye"), abs=1e-12)


def test_refused_when_mode_or_frames_do_not_fit(tmp_path, capsys):
    inside = _flange_folder(tmp_path, "eye_in_hand", "eih")
    fixed = _flange_folder(tmp_path, "eye_to_hand", "e2h")
    for folder in (inside, fixed):
        assert main(["handeye", str(folder), "--out", str(folder / "he"), "--quiet"]) in (0, 1)
    with pytest.raises(RelcalError, match="mode eye_to_hand, the dataset is eye_in_hand: its "
                       "transform is of a fixed camera"):  # fmt: skip
        handeye_guess(fixed / "he", relcal.load_dataset(inside))
    with pytest.raises(RelcalError, match="mode eye_in_hand, the dataset is eye_to_hand"):
        handeye_guess(inside / "he", relcal.load_dataset(fixed))
    # another camera frame: the dataset names its frames
    spec = inside / "dataset.yaml"
    spec.write_text(spec.read_text() + "frames: {camera: camera_optical}\n")
    with pytest.raises(RelcalError, match="handeye is tool0 -> camera, the dataset's is tool0 "
                       "-> camera_optical"):  # fmt: skip
        handeye_guess(inside / "he", relcal.load_dataset(inside))
    # a broken file: named with its field; the command exits 2 and writes nothing
    text = (inside / "he" / "handeye.yaml").read_text()
    broken = tmp_path / "broken.yaml"
    broken.write_text(text.replace("quaternion:\n  -", "quaternion:\n  - 0.5\n  -", 1))
    with pytest.raises(RelcalError, match=r"handeye.quaternion: expected 4 finite numbers"):
        read_handeye_file(broken)
    out = tmp_path / "cal"
    code = main(["calibrate", str(TIAGO), "--handeye", str(broken), "--out", str(out)])
    assert code == 2 and not out.exists()
    assert "handeye.quaternion: expected 4 finite numbers" in capsys.readouterr().err
