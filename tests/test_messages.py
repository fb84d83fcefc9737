"""Messages that point the right way, each tested by doing what it says: a key given twice in
dataset.yaml, a number like ``4_1.67`` (Python reads 41.67), a row separated by tabs under a
comma header, a hand-edited model.yaml verified (the edit, not the robot), one robot id with
calibrations of two robot models, compensation with another robot's nominal model, and what a
capture interrupted after some samples says it kept."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers_dataset import synthetic_dataset

from relcal.cli import main

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Two sessions of one perturbed A465 and a calibration of the first."""
    root = tmp_path_factory.mktemp("messages")
    first = synthetic_dataset(root / "first", n=24).root
    second = synthetic_dataset(root / "second", n=16, seed=3).root
    assert main(["calibrate", str(first), "--out", str(root / "cal"), "--quiet"]) == 0
    return root, first, second


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    shutil.rmtree(dst / "calibration", ignore_errors=True)
    return dst


# ------------------------------------------------------------------------ dataset files


def test_a_key_given_twice_in_dataset_yaml_is_refused_and_deleting_one_works(
    data, tmp_path, capsys
):
    _, first, _ = data
    ds = copy(first, tmp_path / "d")
    spec = (ds / "dataset.yaml").read_text()
    unit = next(line for line in spec.splitlines() if line.startswith("joint_unit:"))
    other = "joint_unit: rad" if unit.endswith("deg") else "joint_unit: deg"
    (ds / "dataset.yaml").write_text(spec + other + "\n")
    code, _, err = run(capsys, "calibrate", ds, "--quiet", "--out", tmp_path / "o")
    line = len(spec.splitlines()) + 1
    assert code == 2 and f"dataset.yaml line {line}: key 'joint_unit' given twice" in err, err
    assert "delete or merge one" in err and not (tmp_path / "o").exists()
    (ds / "dataset.yaml").write_text(spec)  # the suggestion: delete one
    assert run(capsys, "calibrate", ds, "--quiet", "--out", tmp_path / "o")[0] == 0


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (
            "underscore",
            ("q1: expected a number", "an underscore inside a number", "write the digits"),
        ),
        ("tabs", ("fields separated by tabs, but the header (line 1) by commas",)),
    ],
)
def test_a_cell_that_python_would_misread_and_a_tab_row_are_refused(
    data, tmp_path, capsys, edit, words
):
    _, first, _ = data
    ds = copy(first, tmp_path / "d")
    lines = (ds / "samples.csv").read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[1].split(",")
    k = header.index("q1")
    good = lines[1]
    if edit == "underscore":
        whole, _, frac = cells[k].partition(".")
        cells[k] = f"{whole[:1]}_{whole[1:] or '0'}.{frac}"  # 41.67 -> 4_1.67
        lines[1] = ",".join(cells)
    else:
        lines[1] = "\t".join(cells)
    (ds / "samples.csv").write_text("\n".join(lines) + "\n")
    code, _, err = run(capsys, "calibrate", ds, "--quiet", "--out", tmp_path / "o")
    assert code == 2 and "samples.csv line 2" in err, err
    for word in words:
        assert word in err, err
    lines[1] = good  # the suggestion: the digits alone, one separator
    (ds / "samples.csv").write_text("\n".join(lines) + "\n")
    assert run(capsys, "calibrate", ds, "--quiet", "--out", tmp_path / "o")[0] == 0


def test_an_underscore_in_an_option_number_is_refused(capsys):
    code, _, err = run(capsys, "calibrate", EXAMPLES / "tiago-pro-poses", "--holdout", "0_5")
    assert code == 2 and "an underscore inside a number" in err, err


# ------------------------------------------------------------------------ verify


def test_verify_of_a_hand_edited_model_says_the_file_changed_not_the_robot(data, tmp_path, capsys):
    """A link length edited by hand in model.yaml: verify says first that the file changed
    since the calibration (SHA-256 against results.json), compares no held-out error of another
    file, and never blames the robot; the file relcal wrote (the suggestion) verifies without
    that warning."""
    root, _, second = data
    edited = tmp_path / "cal"
    shutil.copytree(root / "cal", edited)
    text = (edited / "model.yaml").read_text()
    marker = "  a: "
    at = text.index(marker) + len(marker)
    end = text.index("\n", at)
    value = float(text[at:end])
    (edited / "model.yaml").write_text(text[:at] + repr(value + 0.05) + text[end:])
    code, out, err = run(capsys, "verify", edited, second, "--brief", "--json", tmp_path / "v.json")
    assert code in (0, 1), err
    assert "model.yaml was changed since the calibration" in out and "SHA-256" in out, out
    assert "the robot, its mounting or the cell changed" not in out, out
    doc = json.loads((tmp_path / "v.json").read_text())
    assert any("changed since the calibration" in w for w in doc["warnings"]), doc["warnings"]
    code, out, _ = run(capsys, "verify", root / "cal", second, "--brief")
    assert "changed since the calibration" not in out, out


# ------------------------------------------------------------------------ history


def test_history_of_one_robot_id_with_two_robot_models_says_so(data, tmp_path, capsys):
    root, first, _ = data
    registry = tmp_path / "h.sqlite"
    positions = copy(EXAMPLES / "tiago-pro-poses", tmp_path / "tiago")
    spec = (positions / "dataset.yaml").read_text()
    samples = (EXAMPLES / "tiago-pro-poses").resolve()
    spec = spec.replace("robot_id: tiago-pro-right-arm", "robot_id: arm1")
    spec = spec.replace("../../../shared", str(samples.parents[2] / "shared"))
    (positions / "dataset.yaml").write_text(spec)
    a465 = copy(first, tmp_path / "a465")
    (a465 / "dataset.yaml").write_text((a465 / "dataset.yaml").read_text() + "robot_id: arm1\n")
    for ds in (a465, positions, a465):
        argv = ["calibrate", ds, "--quiet", "--out", tmp_path / f"o-{ds.name}", "--registry"]
        assert run(capsys, *argv, registry)[0] == 0
    code, out, _ = run(capsys, "history", "arm1", "--registry", registry, "--json", tmp_path / "h")
    assert code == 0
    first_line = out.splitlines()[0]
    assert first_line.startswith("warning: robot id 'arm1' has calibrations of 2 robot models")
    assert "Thermo CRS A465 (runs 1, 3)" in first_line and "(run 2)" in first_line, first_line
    assert "recorded under the wrong id" in first_line
    doc = json.loads((tmp_path / "h").read_text())
    assert len(doc["robot_models"]) == 2 and doc["warnings"]
    drift = {r["id"]: r["drift"] for r in doc["runs"]}
    assert drift[2] is None and drift[3]["against"] == "1", drift  # each model on its own


# ------------------------------------------------------------------------ compensate


def test_compensate_with_another_robots_nominal_names_the_mismatch(data, tmp_path, capsys):
    """Another robot's nominal model, with other joint names (UR5e) or the same ones (PUMA 560:
    waist, shoulder, ... as the A465): refused naming both robots, not "not reached"; doing
    what the message says (leave --nominal out) compensates."""
    root, _, _ = data
    (tmp_path / "p.csv").write_text("id,q1,q2,q3,q4,q5,q6\nt1,10,-40,30,0,20,5\n")
    argv = ["compensate", root / "cal", "--targets", tmp_path / "p.csv"]
    code, out, err = run(capsys, *argv, "--nominal", "ur5e")
    assert code == 2 and out == "" and "another robot" in err, err
    code, out, err = run(capsys, *argv, "--nominal", "puma560")
    assert code == 2 and out == "", err
    assert "--nominal puma560 (Unimation PUMA 560) is not the robot the calibration" in err, err
    assert "flanges are up to" in err and "leave --nominal out" in err, err
    code, out, err = run(capsys, *argv, "--quiet")  # the suggestion
    assert code == 0 and out.splitlines()[1].startswith("t1,"), err


# ------------------------------------------------------------------------ capture


def test_an_interrupted_capture_lists_the_samples_it_kept(tmp_path):
    """The samples a capture stored are listed by the message after an interrupt (each
    sample is whole), never "nothing written"; its lock file is gone."""
    from test_capture_loop import BOARD, MODEL, FakeCamera, FakeRobot, targets

    from relcal.capture.loop import CaptureSettings, capture
    from relcal.capture.record import LOCK, DatasetWriter
    from relcal.capture.virtual import SIM_CAMERA, SimClock
    from relcal.cli import _what_was_written
    from relcal.outputset import forget_written
    from relcal.vision.boards import board_points
    from relcal.vision.render import look_at, render_board

    centre = board_points(BOARD).mean(axis=0)
    pose = look_at(centre + np.array([0.02, -0.03, -0.32]), centre)
    image = render_board(BOARD, SIM_CAMERA, pose, 0.6, 1.5, 0.2, seed=1)

    class Interrupting(FakeCamera):
        def grab(self, timeout):
            if len(self.stamps) == 2:
                raise KeyboardInterrupt
            return super().grab(timeout)

    forget_written()
    ids, q = targets(4)
    clock = SimClock()
    root = tmp_path / "ds"
    try:
        with DatasetWriter(root, MODEL, "ur5e", BOARD, SIM_CAMERA, ids, q) as writer:
            with pytest.raises(KeyboardInterrupt):
                capture(ids, q, MODEL, FakeRobot(clock), Interrupting(clock, image), clock, BOARD,
                        writer, SIM_CAMERA, CaptureSettings(settle_window=0.3),
                        progress=False)  # fmt: skip
        said = _what_was_written()
    finally:
        forget_written()
    assert "already written, each whole" in said and "nothing written" not in said, said
    assert f"--out {root}: 2 samples recorded by this run (p1, p2)" in said, said
    assert not (root / LOCK).exists()
