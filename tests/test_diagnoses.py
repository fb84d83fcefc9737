"""Diagnoses that point the right way, tested by following them.

A right synthetic dataset is corrupted the way real ones are (columns swapped, signs and units
mixed up, poses inverted, one mistyped row, rows copied); ``relcal calibrate`` must refuse with
a fix, and the fix, applied as the message words it (:func:`follow`), must lead to a correct
calibration (or to another refusal whose fix does). Corruptions that only touch a row or two
must not refuse the whole set: the row is named as an outlier, the model is right. Nothing may
end in exit 0 with a wrong model.
"""

from __future__ import annotations

import csv
import io
import json
import re
from pathlib import Path

import numpy as np
import pytest
from helpers_dataset import synthetic_dataset
from scipy.spatial.transform import Rotation

from relcal import geometry as tf
from relcal.cli import main

QUAT = ("qx", "qy", "qz", "qw")


@pytest.fixture(scope="module")
def right(tmp_path_factory):
    """60 samples of a perturbed A465, poses given (quaternions); its calibrated held-out
    error is about 0.06 mm."""
    return synthetic_dataset(tmp_path_factory.mktemp("right") / "d", n=60)


class Table:
    """A dataset folder's samples table and dataset.yaml, edited as text and cells."""

    def __init__(self, root: Path) -> None:
        rows = list(csv.reader(io.StringIO((root / "samples.csv").read_text())))
        self.header, self.rows = rows[0], rows[1:]
        self.spec = (root / "dataset.yaml").read_text()
        self.delimiter = ","

    def write(self, root: Path) -> Path:
        root.mkdir(parents=True, exist_ok=True)
        out = io.StringIO()
        csv.writer(out, delimiter=self.delimiter, lineterminator="\n").writerows(
            [self.header, *self.rows]
        )
        (root / "samples.csv").write_text(out.getvalue())
        (root / "dataset.yaml").write_text(self.spec)
        return root

    def col(self, name: str) -> int:
        return self.header.index(name)

    def values(self, names) -> np.ndarray:
        idx = [self.col(n) for n in names]
        return np.array([[float(r[i]) for i in idx] for r in self.rows])

    def set_values(self, names, values: np.ndarray) -> None:
        idx = [self.col(n) for n in names]
        for r, row_values in zip(self.rows, values, strict=True):
            for i, v in zip(idx, row_values, strict=True):
                r[i] = repr(float(v))

    def poses(self) -> np.ndarray:
        v = self.values(("x", "y", "z", *QUAT))
        return tf.homogeneous(Rotation.from_quat(v[:, 3:]).as_matrix(), v[:, :3])

    def set_poses(self, poses: np.ndarray) -> None:
        quat = Rotation.from_matrix(poses[:, :3, :3]).as_quat()
        self.set_values(("x", "y", "z", *QUAT), np.concatenate([poses[:, :3, 3], quat], axis=1))

    def rename(self, mapping: dict[str, str]) -> None:
        self.header = [mapping.get(h, h) for h in self.header]

    def set_spec(self, key: str, value: str) -> None:
        lines = [line for line in self.spec.splitlines() if not line.startswith(f"{key}:")]
        self.spec = "\n".join([*lines, f"{key}: {value}"]) + "\n"

    def to_rpy(self, unit: str) -> None:
        poses = self.poses()
        rpy = Rotation.from_matrix(poses[:, :3, :3]).as_euler("xyz")
        rpy = np.degrees(rpy) if unit == "deg" else rpy
        keep = [i for i, h in enumerate(self.header) if h not in QUAT]
        self.header = [self.header[i] for i in keep] + ["roll", "pitch", "yaw"]
        self.rows = [
            [r[i] for i in keep] + [repr(float(v)) for v in a]
            for r, a in zip(self.rows, rpy, strict=True)
        ]


# ---------------------------------------------------------------- corruptions users make


def swap_columns(a: str, b: str):
    def edit(t: Table) -> None:
        t.rename({a: b, b: a})  # the values stay, the names are exchanged

    return edit


def negate(name: str):
    def edit(t: Table) -> None:
        t.set_values([name], -t.values([name]))

    return edit


def reverse_joints(t: Table) -> None:
    names = [f"q{i}" for i in range(1, 7)]
    t.rename(dict(zip(names, names[::-1], strict=True)))


def joints_in_radians(t: Table) -> None:  # dataset.yaml still says deg
    names = [f"q{i}" for i in range(1, 7)]
    t.set_values(names, np.radians(t.values(names)))


def joints_declared_radians(t: Table) -> None:  # the numbers are degrees
    t.set_spec("joint_unit", "rad")


def inverted(t: Table) -> None:
    t.set_poses(tf.invert(t.poses()))


def w_first(t: Table) -> None:
    t.set_values(QUAT, np.roll(t.values(QUAT), 1, axis=1))  # w, x, y, z under qx, qy, qz, qw


def millimetres(t: Table) -> None:
    t.set_values(("x", "y", "z"), 1000 * t.values(("x", "y", "z")))


def rpy(values_unit: str, declared: str):
    def edit(t: Table) -> None:
        t.to_rpy(values_unit)
        t.set_spec("pose_angle_unit", declared)

    return edit


def copied_rows(count: int):
    def edit(t: Table) -> None:
        t.rows += [[f"copy{k}", *r[1:]] for k, r in enumerate(t.rows[:count])]

    return edit


def both(*edits):
    def edit(t: Table) -> None:
        for e in edits:
            e(t)

    return edit


REFUSED = {
    # parallel axes (q2, q3 of the A465) turn the flange alike: only translations tell
    "joints-q2-q3-swapped": swap_columns("q2", "q3"),
    "joints-q1-q2-swapped": swap_columns("q1", "q2"),
    "joints-q4-q6-swapped": swap_columns("q4", "q6"),
    "joints-q5-q6-swapped": swap_columns("q5", "q6"),
    "joints-in-reverse-order": reverse_joints,
    "joint-q2-negated": negate("q2"),
    "joint-q5-negated": negate("q5"),
    "joints-radians-declared-degrees": joints_in_radians,
    "joints-degrees-declared-radians": joints_declared_radians,
    "poses-inverted": inverted,
    "quaternions-w-first": w_first,
    "inverted-and-written-w-first": both(inverted, w_first),
    "positions-x-y-swapped": swap_columns("x", "y"),
    "positions-y-z-swapped": swap_columns("y", "z"),
    "positions-in-millimetres": millimetres,
    "rpy-radians-declared-degrees": rpy("rad", "deg"),
    "rpy-degrees-declared-radians": rpy("deg", "rad"),
    "every-sample-copied-under-new-ids": copied_rows(60),
    "one-sample-copied": copied_rows(1),
    # two mistakes at once (e.g. after following a wrong advice)
    "q2-q3-swapped-and-inverted": both(swap_columns("q2", "q3"), inverted),
    "q3-negated-and-w-first": both(negate("q3"), w_first),
}


# ------------------------------------------------------------- following a suggestion


def follow(message: str, t: Table) -> str:
    """Apply the first fix the message suggests, as worded; returns what was done."""
    fixes = re.findall(r"fix: ([^)]*)\)", message)
    assert fixes, f"no fix suggested: {message}"
    fix = fixes[0]
    if m := re.match(r"swap the names (\w+) and (\w+) in the samples file's header", fix):
        t.rename({m[1]: m[2], m[2]: m[1]})
    elif m := re.match(r"negate the (q\d) column", fix):
        t.set_values([m[1]], -t.values([m[1]]))
    elif fix.startswith("reverse the joint names"):
        reverse_joints(t)
    elif m := re.match(r"(joint_unit|pose_angle_unit): (\w+)", fix):
        t.set_spec(m[1], m[2])
    elif fix.startswith("name the columns qw, qx, qy, qz"):
        t.rename({"qx": "qw", "qy": "qx", "qz": "qy", "qw": "qz"})
    elif fix.startswith("give camera in board"):
        t.set_poses(tf.invert(t.poses()))
    elif fix == "x, y, z divided by 1000":
        t.set_values(("x", "y", "z"), t.values(("x", "y", "z")) / 1000)
    elif fix == "remove the repeated rows":
        seen, kept = set(), []
        for r in t.rows:
            if tuple(r[1:]) not in seen:
                seen.add(tuple(r[1:]))
                kept.append(r)
        t.rows = kept
    else:
        raise AssertionError(f"a fix this test cannot follow: {fix!r} in {message}")
    return fix


def calibrate(root: Path, capsys) -> tuple[int, str, dict | None]:
    out = root / "calibration"
    code = main(["calibrate", str(root), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err, err
    doc = json.loads((out / "results.json").read_text()) if code == 0 else None
    return code, err, doc


def assert_right(doc: dict, outliers: set[str] = frozenset()) -> None:
    """A right model: the held-out error of the right data (0.06 mm; the baseline 14 mm)."""
    calibrated = doc["validation"]["calibrated"]["position_mm"]["rms"]
    assert calibrated < 0.2, calibrated
    assert set(doc["outliers"]) | set(doc["held_out_outliers"]) == set(outliers)


@pytest.mark.parametrize("name", list(REFUSED))
def test_the_suggested_fix_leads_to_a_right_calibration(name, right, tmp_path, capsys):
    t = Table(right.root)
    REFUSED[name](t)
    steps = []
    for step in range(4):
        root = t.write(tmp_path / f"step{step}")
        code, err, doc = calibrate(root, capsys)
        if code == 0:
            break
        assert code == 2, err
        steps.append(follow(err, t))
    else:
        raise AssertionError(f"still refused after following {steps}: {err}")
    assert steps, "the corrupted data were not refused"
    assert len(steps) <= 2, steps
    assert_right(doc)


def test_right_data_in_every_supported_layout_pass(right, tmp_path, capsys):
    """Tabs, semicolons (with decimal commas), roll-pitch-yaw in either unit, no id column."""
    for name, edit in {
        "tabs": lambda t: setattr(t, "delimiter", "\t"),
        "semicolons": lambda t: setattr(t, "delimiter", ";"),
        "rpy-deg": rpy("deg", "deg"),
        "rpy-rad": rpy("rad", "rad"),
        "no-id": lambda t: (
            setattr(t, "rows", [r[1:] for r in t.rows]),
            setattr(t, "header", t.header[1:]),
        ),
    }.items():
        t = Table(right.root)
        edit(t)
        code, err, doc = calibrate(t.write(tmp_path / name), capsys)
        assert code == 0, (name, err)
        assert_right(doc)


@pytest.mark.parametrize(
    ("row", "column", "change"),
    [
        (10, "q3", lambda v: v / 10),  # a digit lost
        (10, "q3", lambda v: -v),  # a sign lost
        (10, "q2", lambda v: v + 10),  # a digit mistyped
        (10, "x", lambda v: v + 0.3),  # a measurement off
        (40, "q4", lambda v: -v),  # another row (held out or not, by the split)
        (3, "qw", lambda v: -v),  # a quaternion sign within the unit sphere: a different pose
    ],
)
def test_one_wrong_row_is_named_not_the_whole_set(right, tmp_path, capsys, row, column, change):
    """One mistyped row does not pass for a wrong unit or order of all: the calibration is right
    and that row is named as an outlier (left out of the fit, or of the held-out errors)."""
    t = Table(right.root)
    r = t.rows[row]
    r[t.col(column)] = repr(float(change(float(r[t.col(column)]))))
    if column == "qw":  # keep it a unit quaternion: flip the vector part instead
        for c in ("qx", "qy", "qz"):
            r[t.col(c)] = repr(-float(r[t.col(c)]) * 0.5)
        q = np.array([float(r[t.col(c)]) for c in QUAT])
        for c, v in zip(QUAT, q / np.linalg.norm(q), strict=True):
            r[t.col(c)] = repr(float(v))
    code, err, doc = calibrate(t.write(tmp_path / "d"), capsys)
    assert code == 0, err
    assert_right(doc, {r[0]})


def test_inverted_rows_among_held_out_samples_are_named(right, tmp_path, capsys):
    """8 of 60 poses inverted (some land among the held-out samples): all 8 are named, the
    held-out errors are those of the right samples, the model is right."""
    t = Table(right.root)
    poses = t.poses()
    bad = [3, 9, 15, 21, 27, 33, 39, 45]
    poses[bad] = tf.invert(poses[bad])
    t.set_poses(poses)
    code, err, doc = calibrate(t.write(tmp_path / "d"), capsys)
    assert code == 0, err
    assert doc["held_out_outliers"], "no inverted row among the held-out samples: pick others"
    assert_right(doc, {t.rows[k][0] for k in bad})


@pytest.mark.parametrize(
    ("spec", "table", "expect"),
    [
        ("", None, ("dataset.yaml: empty", "robot:")),
        ("# only a comment\n", None, ("dataset.yaml: empty",)),
        ("robot: ur5e\njoint_unit: deg\n", None, ("no other reading", "robot model")),
        ("robot: a465\n", "id q1 q2 q3 q4 q5 q6 x y z qx qy qz qw\n", ("separated by spaces",)),
    ],
)
def test_refusals_without_a_fix_name_the_cause(right, tmp_path, capsys, spec, table, expect):
    t = Table(right.root)
    t.spec = spec
    root = t.write(tmp_path / "d")
    if table is not None:
        (root / "samples.csv").write_text(table + "s0 1 2 3 4 5 6 0 0 0 0 0 0 1\n")
    code, err, _ = calibrate(root, capsys)
    assert code == 2, err
    for part in expect:
        assert part in err, err
    assert "NoneType" not in err


def test_ids_without_an_id_column_are_row_numbers(right, tmp_path, capsys):
    """Without an id column the samples are numbered 1..N by row: --holdout-ids 1,2,3,4 works,
    and an id that is not there is answered with the dataset's path and how ids were given."""
    t = Table(right.root)
    t.rows = [r[1:] for r in t.rows]
    t.header = t.header[1:]
    root = t.write(tmp_path / "d")
    argv = ["calibrate", str(root), "--out", str(root / "calibration"), "--quiet"]
    assert main([*argv, "--holdout-ids", "1,2,3,4,5,6"]) == 0
    doc = json.loads((root / "calibration" / "results.json").read_text())
    assert doc["held_out_ids"] == ["1", "2", "3", "4", "5", "6"]
    capsys.readouterr()
    assert main([*argv, "--holdout-ids", "61"]) == 2
    err = capsys.readouterr().err
    assert str(root.resolve()) in err and "numbered 1 to 60" in err and "no id column" in err


RCT_OBSERVATION = """\
'{k}':
  camera_joints: []
  pose: {{qw: {qw}, qx: 0.0, qy: 0.0, qz: 0.0, x: 0.1, y: 0.{k}, z: 0.9}}
  target_joints: {joints}
"""


@pytest.mark.parametrize(
    ("qw", "joints", "expect"),
    [
        (0.0, "[0.1, 0.2]", ("observation '3'", "unit quaternion", "norm is 0")),
        (2.0, "[0.1, 0.2]", ("observation '3'", "unit quaternion", "norm is 2")),
        (1.0, "[0.1, 0.2, 0.3]", ("observation '3'", "target_joints: 3 values", "has 2")),
    ],
)
def test_importers_name_the_observation_at_fault(tmp_path, capsys, qw, joints, expect):
    """A wrong observation in robot_cal_tools' file is named there, not later in the written
    samples.csv (or as an internal error of a zero quaternion)."""
    text = "".join(
        RCT_OBSERVATION.format(k=k, qw=qw if k == 3 else 1.0, joints=joints if k == 3 else "[0, 0]")
        for k in range(1, 6)
    )
    (tmp_path / "m.yaml").write_text(text)
    assert (
        main(["import", "rct-positioner", str(tmp_path / "m.yaml"), "--out", str(tmp_path / "o")])
        == 2
    )
    err = capsys.readouterr().err
    for part in expect:
        assert part in err, err
    assert not (tmp_path / "o").exists()


def test_a_diagnosis_names_the_samples_file_dataset_yaml_names(right, tmp_path, capsys):
    """The file named in a refusal is the samples table of ``samples:`` (it named a
    'samples.csv' that did not exist for every dataset whose table is called otherwise, the
    shipped examples included)."""
    t = Table(right.root)
    millimetres(t)
    root = t.write(tmp_path / "d")
    (root / "samples.csv").rename(root / "tracker export.csv")
    (root / "dataset.yaml").write_text(t.spec + "\nsamples: tracker export.csv\n")
    code, err, _ = calibrate(root, capsys)
    assert code == 2 and "divided by 1000" in err
    assert f"{root / 'tracker export.csv'}:" in err and "samples.csv" not in err
