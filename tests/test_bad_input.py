"""The bad-input catalogue: every case through the command line, answered with a clear message
naming the file or option and the likely cause, the expected exit status, no traceback, and every
file in the case's folder byte-identical afterwards (nothing written, nothing changed).

One row per case in ``CASES``: ``case(id, command line, *setups, expect=(...), code=2)``. The
command line is split like a shell's and ``{tmp}`` is the case's folder; the setups build files in
it before the run: ``ds()`` a valid poses dataset in ``{tmp}/d`` (arguments as
:func:`write_dataset`), ``text(name, content)``, ``edit(name, old, new)``, ``cell(name, line,
column, value)``, ``robot_file(name)``, ``rct(name)``, ``relcal_set(name)``. To add a case, add a
row.
"""

from __future__ import annotations

import hashlib
import shlex
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from relcal import geometry as tf
from relcal.cli import main
from relcal.robot.kinematics import fk
from relcal.robot.loading import get_robot
from relcal.robot.model import dump_model

A465 = get_robot("a465")
Setup = Callable[[Path], None]


def write_dataset(
    root, n=12, unit="deg", q=None, poses=None, header=None, extra_rows=(), spec=None
):
    """A valid eye-in-hand dataset with poses given directly, then edited by the case."""
    rng = np.random.default_rng(0)
    q = rng.uniform(-1.0, 1.0, (n, 6)) if q is None else q
    poses = (
        fk(A465, q) @ tf.from_vector(np.array([0, 0.04, 0.06, 0, 0, 0])) if poses is None else poses
    )
    root.mkdir(exist_ok=True, parents=True)
    (root / "dataset.yaml").write_text(
        spec or f"robot: a465\njoint_unit: {unit}\nhandeye: {{xyz: [0, 0.04, 0.06]}}\n"
    )
    cols = header or "id,q1,q2,q3,q4,q5,q6,x,y,z,qx,qy,qz,qw"
    rows = [cols]
    shown = np.degrees(q) if unit == "deg" else q
    for k in range(n):
        quat = Rotation.from_matrix(poses[k, :3, :3]).as_quat()
        cells = [f"s{k}", *map(str, shown[k]), *map(str, poses[k, :3, 3]), *map(str, quat)]
        rows.append(",".join(cells))
    rows += list(extra_rows)
    (root / "samples.csv").write_text("\n".join(rows) + "\n")
    return root


def run_bad(capsys, argv, *patterns):
    """Run one command that must fail with exit 2, no traceback, and every pattern in the
    message; return the message (for cases kept outside the table)."""
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    for pattern in patterns:
        assert pattern in err, err
    return err


# ------------------------------------------------------------------------------------ setups


def ds(name: str = "d", **kwargs) -> Setup:
    """A valid poses dataset in ``{tmp}/name`` (``kwargs`` as :func:`write_dataset`)."""
    return lambda tmp: write_dataset(tmp / name, **kwargs)


def text(name: str, content: str | bytes) -> Setup:
    def setup(tmp: Path) -> None:
        path = tmp / name
        path.parent.mkdir(parents=True, exist_ok=True)
        (path.write_bytes if isinstance(content, bytes) else path.write_text)(content)

    return setup


def folder(name: str) -> Setup:
    return lambda tmp: (tmp / name).mkdir(parents=True, exist_ok=True)


def edit(name: str, old: str, new: str) -> Setup:
    def setup(tmp: Path) -> None:
        path = tmp / name
        path.write_text(path.read_text().replace(old, new, 1))

    return setup


def cell(name: str, line: int, column: int, value: str) -> Setup:
    """Set one CSV cell (``line`` 1-based as in an editor, ``column`` 0-based)."""

    def setup(tmp: Path) -> None:
        path = tmp / name
        lines = path.read_text().splitlines()
        cells = lines[line - 1].split(",")
        cells[column] = value
        lines[line - 1] = ",".join(cells)
        path.write_text("\n".join(lines) + "\n")

    return setup


def robot_file(name: str = "model.yaml") -> Setup:
    """The nominal A465 as a model YAML (a 'calibrated model' for compensate)."""
    return text(name, dump_model(A465))


RCT = """\
'1':
  camera_joints: []
  pose: {qw: 1.0, qx: 0.0, qy: 0.0, qz: 0.0, x: 0.1, y: 0.2, z: 0.9}
  target_joints: [0.1, 0.2]
'2':
  camera_joints: []
  pose: {qw: 1.0, qx: 0.0, qy: 0.0, qz: 0.0, x: 0.2, y: 0.2, z: 0.9}
  target_joints: [0.3, 0.1]
"""


def rct(name: str = "m.yaml") -> Setup:
    """A two-observation robot_cal_tools positioner file."""
    return text(name, RCT)


def relcal_set(name: str) -> Setup:
    """A folder that an earlier relcal run wrote (its marker and one file)."""
    return lambda tmp: (
        text(f"{name}/.relcal-set.json", '{"run_id": "old", "files": ["model.yaml"]}\n')(tmp),
        text(f"{name}/model.yaml", "old\n")(tmp),
    )


def case(cid: str, argv: str, *setups: Setup, expect: tuple[str, ...] = (), code: int = 2):
    return pytest.param(argv, setups, code, expect, id=cid)


# Poses that never move joints 4 and 6: no longer bad input (issue 18: what they cannot determine
# is held and named), see tests/test_weak_directions.py.
Q_FIXED_WRIST = np.random.default_rng(1).uniform(-1, 1, (20, 6))
Q_FIXED_WRIST[:, 3] = 0.2  # joint 4 never moves
Q_FIXED_WRIST[:, 5] = 0.1
CHESS = "board --type chessboard --rows 7 --columns 10"
COMP = "compensate --model {tmp}/model.yaml --targets {tmp}/t.csv"
SIXQ = "id,q1,q2,q3,q4,q5,q6"

CASES = [
    # ---------------------------------------------------------- malformed files (the first 32)
    case(
        "robot-file-missing",
        "simulate --robot {tmp}/arm.yaml",
        expect=("arm.yaml: file not found",),
    ),
    case(
        "robot-yaml-malformed",
        "simulate --robot {tmp}/arm.yaml",
        text("arm.yaml", "name: x\nconvention: dh\njoints: [\n"),
        expect=("arm.yaml line", "malformed YAML"),
    ),
    case(
        "robot-name-unknown",
        "simulate --robot kuka_kr16",
        expect=("unknown robot 'kuka_kr16'", "a465"),
    ),
    case(
        "robot-field-wrong-type",
        "simulate --robot {tmp}/arm.yaml",
        text("arm.yaml", "name: x\nconvention: dh\njoints:\n  - {d: 0.3, alpha: ninety}\n"),
        expect=("arm.yaml line 4: joints[0].alpha",),
    ),
    case(
        "robot-without-joints",
        "simulate --robot {tmp}/arm.yaml",
        text("arm.yaml", "name: x\nconvention: dh\njoints: []\n"),
        expect=("joints: List should have at least 1 item",),
    ),
    case("dataset-folder-missing", "calibrate {tmp}/nope", expect=("nope: not a dataset folder",)),
    case(
        "dataset-yaml-unknown-field",
        "calibrate {tmp}/d",
        ds(spec="robot: a465\njoint_units: deg\n"),
        expect=("dataset.yaml line 2: joint_units: Extra inputs",),
    ),
    case(
        "dataset-yaml-bad-mode",
        "calibrate {tmp}/d",
        ds(spec="robot: a465\nmode: eye_on_hand\n"),
        expect=("dataset.yaml line 2: mode: Input should be",),
    ),
    case(
        "samples-missing",
        "calibrate {tmp}/d",
        ds(),
        lambda tmp: (tmp / "d/samples.csv").unlink(),
        expect=("samples.csv: file not found",),
    ),
    case(
        "samples-wrong-joint-count",
        "calibrate {tmp}/d",
        ds(),
        edit("d/samples.csv", "q6,", "q6,q7,"),
        expect=("samples.csv line 1", "unexpected q7 (wrong joint count?)"),
    ),
    case(
        "samples-row-missing-fields",
        "calibrate {tmp}/d",
        ds(extra_rows=["s99,1,2,3"]),
        expect=("samples.csv line 14: 4 fields, expected 14",),
    ),
    case(
        "samples-nan-joint",
        "calibrate {tmp}/d",
        ds(),
        cell("d/samples.csv", 4, 2, "nan"),
        expect=("samples.csv line 4: q2: expected a finite number",),
    ),
    case(
        "samples-infinite-position",
        "calibrate {tmp}/d",
        ds(),
        cell("d/samples.csv", 3, 7, "inf"),
        expect=("samples.csv line 3: x: expected a finite number",),
    ),
    case(
        "samples-not-a-number",
        "calibrate {tmp}/d",
        ds(extra_rows=["s99,1,2,3,4,5,six,0,0,0,0,0,0,1"]),
        expect=("samples.csv line 14: q6: expected a number, got 'six'",),
    ),
    case(
        "degrees-declared-radians",
        "calibrate {tmp}/d",
        ds(unit="deg"),
        edit("d/dataset.yaml", "joint_unit: deg", "joint_unit: rad"),
        expect=("looks like degrees", "joint_unit: rad"),
    ),
    case(
        "radians-declared-degrees",
        "calibrate {tmp}/d",
        ds(unit="rad"),
        edit("d/dataset.yaml", "joint_unit: rad", "joint_unit: deg"),
        expect=("looks like radians", "joint_unit: deg"),
    ),
    case(
        "duplicate-sample-ids",
        "calibrate {tmp}/d",
        ds(),
        edit("d/samples.csv", "s3,", "s2,"),
        expect=("samples.csv line 5: id 's2' duplicates line 4",),
    ),
    case(
        "non-unit-quaternion",
        "calibrate {tmp}/d",
        ds(extra_rows=["s99,1,2,3,4,5,6,0,0,0,0.5,0,0,0.5"]),
        expect=("samples.csv line 14: qx, qy, qz, qw: expected a unit",),
    ),
    case(
        "image-missing",
        "calibrate {tmp}/d",
        ds(),
        text("d/samples.csv", "id,q1,q2,q3,q4,q5,q6,image\na,1,2,3,4,5,6,img/a.png\n"),
        expect=("samples.csv line 2: image: file not found",),
    ),
    case("too-few-poses", "calibrate {tmp}/d", ds(n=3), expect=("only 3 usable samples",)),
    case(
        "header-without-pose-or-image",
        "calibrate {tmp}/d",
        ds(),
        text("d/samples.csv", f"{SIXQ}\na,1,2,3,4,5,6\n"),
        expect=("expected an 'image' column, or a pose", "exactly one"),
    ),
    case(
        "samples-empty",
        "calibrate {tmp}/d",
        ds(),
        text("d/samples.csv", "\n"),
        expect=("samples.csv: empty; expected a header line",),
    ),
    case(
        "errors-unknown-parameter",
        "simulate --errors {tmp}/errors.yaml",
        text("errors.yaml", "errors:\n  theta[1]: 0.1\n"),
        expect=("errors.yaml: errors: unknown parameter",),
    ),
    case(
        "errors-bad-unit",
        "simulate --errors {tmp}/errors.yaml",
        text("errors.yaml", "length_unit: inch\nerrors: {}\n"),
        expect=("errors.yaml line 1: length_unit",),
    ),
    case("noise-negative", "simulate --noise 0.1,-2", expect=("--noise: '0.1,-2': expected",)),
    case(
        "compensate-bad-quaternion",
        COMP,
        robot_file(),
        text("t.csv", "id,x,y,z,qx,qy,qz,qw\na,0.3,0,0.3,0,0,0,2\n"),
        expect=("t.csv line 2: qx",),
    ),
    case(
        "dataset-names-missing-robot-file",
        "calibrate {tmp}/d",
        ds(spec="robot: arm.yaml\n"),
        expect=("arm.yaml: file not found",),
    ),
    case("simulate-too-few-poses", "simulate --poses 2", expect=("--poses", "3 or more")),
    case(
        "board-negative-square",
        f"{CHESS} --square -0.02 --out {{tmp}}/b.pdf",
        expect=("--square", "between 0 and 0.5"),
    ),
    case(
        "board-yaml-negative-spacing",
        "board --spec {tmp}/board.yaml --out {tmp}/b.pdf",
        text("board.yaml", "type: circles\nrows: 10\ncolumns: 10\nspacing: -0.0254\n"),
        expect=("board.yaml line 4: spacing",),
    ),
    case(
        "holdout-id-unknown",
        "calibrate {tmp}/d --holdout-ids s1,nope",
        ds(),
        expect=("--holdout-ids: no sample 'nope'", "has 12 samples, ids s0, s1"),
    ),
    # ------------------------------------------ class 2: outputs never destroy or half-write
    case(
        "out-is-the-dataset",
        "calibrate {tmp}/d --out {tmp}/d",
        ds(),
        expect=("--out", "would overwrite", "dataset.yaml", "which this run reads"),
    ),
    case(
        "json-is-the-samples",
        "calibrate {tmp}/d --json {tmp}/d/samples.csv",
        ds(),
        expect=("--json", "would overwrite", "samples.csv"),
    ),
    case(
        "report-is-the-dataset-yaml",
        "calibrate {tmp}/d --report {tmp}/d/dataset.yaml",
        ds(),
        expect=("--report", "would overwrite", "dataset.yaml"),
    ),
    case(
        "out-is-an-input-file",
        "calibrate {tmp}/d --out {tmp}/d/samples.csv",
        ds(),
        expect=("--out", "samples.csv: exists and is not a folder"),
    ),
    case(
        "out-is-a-device",
        "calibrate {tmp}/d --out /dev/stdout",
        ds(),
        expect=("--out", "/dev/stdout", "not a folder"),
    ),
    case(
        "out-holds-the-robot-file",
        "calibrate {tmp}/d --out {tmp}/m",
        ds(spec="robot: ../m/arm.yaml\njoint_unit: deg\n"),
        robot_file("m/arm.yaml"),
        expect=("--out", "would overwrite", "arm.yaml"),
    ),
    case(
        "out-is-a-foreign-folder",
        "calibrate {tmp}/d --out {tmp}/mine",
        ds(),
        text("mine/notes.txt", "my own notes\n"),
        expect=("--out", "was not written by relcal", "new or empty folder"),
    ),
    case(
        "out-prev-is-foreign",
        "calibrate {tmp}/d --out {tmp}/o",
        ds(),
        relcal_set("o"),
        text("o.prev/notes.txt", "mine\n"),
        expect=("o.prev", "was not written by relcal", "move it away"),
    ),
    case(
        "json-is-a-folder",
        "calibrate {tmp}/d --json {tmp}/d",
        ds(),
        expect=("--json", "is a folder"),
    ),
    case(
        "json-under-a-file",
        "calibrate {tmp}/d --json {tmp}/d/samples.csv/r.json",
        ds(),
        expect=("--json", "is a file, not a folder"),
    ),
    case(
        "out-under-a-file",
        "calibrate {tmp}/d --out {tmp}/d/samples.csv/o",
        ds(),
        expect=("--out", "is a file, not a folder"),
    ),
    case(
        "json-inside-the-out-folder",
        "calibrate {tmp}/d --out {tmp}/o --json {tmp}/o/r.json",
        ds(),
        expect=("--json", "inside the output folder", "replaced as a whole"),
    ),
    case(
        "json-and-report-the-same",
        "calibrate {tmp}/d --out {tmp}/o --json {tmp}/r --report {tmp}/r",
        ds(),
        expect=("--report", "also given as --json"),
    ),
    case(
        "json-is-the-holdout-id-file",
        "calibrate {tmp}/d --holdout-ids @{tmp}/ids.txt --json {tmp}/ids.txt",
        ds(),
        text("ids.txt", "s1\ns2\n"),
        expect=("--json", "would overwrite", "ids.txt"),
    ),
    case("out-empty-name", "calibrate {tmp}/d --out ''", ds(), expect=("--out", "folder name")),
    case("json-empty-name", "calibrate {tmp}/d --json ''", ds(), expect=("--json", "file name")),
    case(
        "json-unwritable-place",
        "calibrate {tmp}/d --json /sys/relcal.json",
        ds(),
        expect=("--json /sys/relcal.json: cannot write", "nothing written"),
    ),
    case(
        "json-to-a-full-device",
        "calibrate {tmp}/d --out {tmp}/o --json /dev/full",
        ds(),
        expect=("--json /dev/full: cannot write", "No space left"),
    ),
    case(
        "failed-write-leaves-no-new-folders",
        "calibrate {tmp}/d --out {tmp}/new/deep/o --json /dev/full",
        ds(),
        expect=("--json /dev/full: cannot write",),
    ),
    case(
        "json-new-file-in-dev",
        "calibrate {tmp}/d --json /dev/relcal-nope.json",
        ds(),
        expect=("--json", "no such device"),
    ),
    case(
        "measure-out-is-the-dataset",
        "measure {tmp}/d --out {tmp}/d",
        ds(),
        expect=("--out", "would overwrite", "dataset.yaml"),
    ),
    case(
        "measure-json-is-the-dataset-yaml",
        "measure {tmp}/d --json {tmp}/d/dataset.yaml",
        ds(),
        expect=("--json", "would overwrite"),
    ),
    case(
        "measure-out-is-a-file",
        "measure {tmp}/d --out {tmp}/d/dataset.yaml",
        ds(),
        expect=("--out", "not a folder"),
    ),
    case(
        "import-into-an-existing-dataset",
        "import rct-positioner {tmp}/m.yaml --out {tmp}/d",
        ds(),
        rct(),
        expect=("--out", "never replaces a dataset folder"),
    ),
    case(
        "import-into-the-source-folder",
        "import rct-positioner {tmp}/src/m.yaml --out {tmp}/src",
        rct("src/m.yaml"),
        expect=("--out", "would overwrite", "m.yaml"),
    ),
    case(
        "import-out-is-the-source",
        "import rct-positioner {tmp}/m.yaml --out {tmp}/m.yaml",
        rct(),
        expect=("--out", "not a folder"),
    ),
    case(
        "import-json-is-the-source",
        "import rct-positioner {tmp}/m.yaml --out {tmp}/new --json {tmp}/m.yaml",
        rct(),
        expect=("--json", "would overwrite", "m.yaml"),
    ),
    case(
        "import-source-missing",
        "import rct-positioner {tmp}/none.yaml --out {tmp}/new",
        expect=("none.yaml: file not found",),
    ),
    case(
        "import-source-is-a-folder",
        "import rct-positioner {tmp} --out {tmp}/new",
        expect=("expected a file for rct-positioner",),
    ),
    case(
        "import-images-from-a-file",
        "import rct-images {tmp}/m.yaml --out {tmp}/new",
        rct(),
        expect=("expected a folder (the image set) for rct-images",),
    ),
    case(
        "import-images-without-cal-data",
        "import rct-images {tmp}/set --out {tmp}/new --mode eye_in_hand",
        folder("set"),
        expect=("not a robot_cal_tools image set", "cal_data.yaml"),
    ),
    case(
        "import-images-mode-unknown",
        "import rct-images {tmp}/set --out {tmp}/new",
        text("set/cal_data.yaml", "- {image: a.png, pose: a.yaml}\n"),
        expect=("--mode eye_in_hand or eye_to_hand",),
    ),
    case(
        "board-out-is-the-spec",
        "board --spec {tmp}/board.yaml --out {tmp}/board.yaml",
        text("board.yaml", "type: chessboard\nrows: 7\ncolumns: 10\nsquare: 0.02\n"),
        expect=("--out", "would overwrite", "board.yaml"),
    ),
    case(
        "board-out-is-a-folder",
        f"{CHESS} --square 0.02 --out {{tmp}}/f",
        folder("f"),
        expect=("--out", "is a folder"),
    ),
    case(
        "board-yaml-same-as-out",
        f"{CHESS} --square 0.02 --out {{tmp}}/b.pdf --yaml {{tmp}}/b.pdf",
        expect=("--yaml", "also given as --out"),
    ),
    case(
        "plan-out-is-a-folder",
        "plan --out {tmp}/f --poses 5",
        folder("f"),
        expect=("--out", "is a folder"),
    ),
    case(
        "plan-out-is-the-robot-file",
        "plan --robot {tmp}/arm.yaml --out {tmp}/arm.yaml",
        robot_file("arm.yaml"),
        expect=("--out", "would overwrite", "arm.yaml"),
    ),
    case(
        "compensate-out-is-the-targets",
        f"{COMP} --out {{tmp}}/t.csv --joint-unit rad",
        robot_file(),
        text("t.csv", "id,x,y,z,qx,qy,qz,qw\na,0.4,0.1,0.3,1,0,0,0\n"),
        expect=("--out", "would overwrite", "t.csv"),
    ),
    case(
        "compensate-json-is-the-model",
        f"{COMP} --json {{tmp}}/model.yaml",
        robot_file(),
        text("t.csv", "id,x,y,z,qx,qy,qz,qw\na,0.4,0.1,0.3,1,0,0,0\n"),
        expect=("--json", "would overwrite", "model.yaml"),
    ),
    case(
        "simulate-json-is-a-folder",
        "simulate --poses 10 --json {tmp}/f",
        folder("f"),
        expect=("--json", "is a folder"),
    ),
    case(
        "simulate-json-is-the-robot",
        "simulate --robot {tmp}/arm.yaml --json {tmp}/arm.yaml",
        robot_file("arm.yaml"),
        expect=("--json", "would overwrite", "arm.yaml"),
    ),
    case(
        "simulate-report-is-the-errors",
        "simulate --errors {tmp}/e.yaml --report {tmp}/e.yaml",
        text("e.yaml", "errors: {}\n"),
        expect=("--report", "would overwrite", "e.yaml"),
    ),
    case(
        "simulate-images-into-a-dataset",
        "simulate --images {tmp}/d --poses 5",
        ds(),
        expect=("--images", "never replaces a dataset folder"),
    ),
    case(
        "simulate-images-is-a-file",
        "simulate --images {tmp}/f.txt --poses 5",
        text("f.txt", "x\n"),
        expect=("--images", "not a folder"),
    ),
    case(
        "observability-json-is-the-poses",
        "observability --poses {tmp}/p.csv --json {tmp}/p.csv",
        text("p.csv", f"{SIXQ}\na,1,2,3,4,5,6\nb,2,3,4,5,6,7\nc,9,8,7,6,5,4\n"),
        expect=("--json", "would overwrite", "p.csv"),
    ),
    case(
        "study-json-is-the-poses",
        "study --poses {tmp}/p.csv --json {tmp}/p.csv --trials 2",
        text("p.csv", f"{SIXQ}\na,1,2,3,4,5,6\nb,2,3,4,5,6,7\nc,9,8,7,6,5,4\n"),
        expect=("--json", "would overwrite", "p.csv"),
    ),
    # ----------------------------------------------- class 3: options checked at parse time
    case(
        "kfold-more-than-samples",
        "calibrate {tmp}/d --kfold 1000",
        ds(),
        expect=("--kfold 1000", "at most 6"),
    ),
    case("kfold-negative", "calibrate {tmp}/d --kfold -3", ds(), expect=("--kfold", "2 or more")),
    case("kfold-one", "calibrate {tmp}/d --kfold 1", ds(), expect=("--kfold", "2 or more")),
    case(
        "kfold-not-a-number",
        "calibrate {tmp}/d --kfold five",
        ds(),
        expect=("--kfold", "not a whole number"),
    ),
    case("holdout-nan", "calibrate {tmp}/d --holdout nan", ds(), expect=("--holdout", "finite")),
    case(
        "holdout-negative", "calibrate {tmp}/d --holdout -0.1", ds(), expect=("--holdout", "from 0")
    ),
    case(
        "holdout-one",
        "calibrate {tmp}/d --holdout 1",
        ds(),
        expect=("--holdout", "not including, 1"),
    ),
    case(
        "holdout-leaves-too-few",
        "calibrate {tmp}/d --holdout 0.8",
        ds(),
        expect=("--holdout 0.8", "leaving 2 to calibrate", "lower --holdout"),
    ),
    case("workers-zero", "calibrate {tmp}/d --workers 0", ds(), expect=("--workers", "1 or more")),
    case(
        "measure-workers-negative",
        "measure {tmp}/d --workers -2",
        ds(),
        expect=("--workers", "1 or more"),
    ),
    case(
        "max-rms-zero", "measure {tmp}/d --max-rms 0", ds(), expect=("--max-rms", "greater than 0")
    ),
    case("max-rms-nan", "calibrate {tmp}/d --max-rms nan", ds(), expect=("--max-rms", "finite")),
    case("seed-not-a-number", "calibrate {tmp}/d --seed x", ds(), expect=("--seed", "not a whole")),
    case("plan-zero-poses", "plan --poses 0", expect=("--poses", "3 or more")),
    case("plan-zero-candidates", "plan --candidates 0", expect=("--candidates", "1 or more")),
    case(
        "plan-inverse-condition-above-one",
        "plan --min-inverse-condition 2",
        expect=("--min-inverse-condition", "between 0 and 1"),
    ),
    case("plan-negative-margin", "plan --margin -5", expect=("--margin", "0 or more")),
    case(
        "plan-length-scale-zero",
        "plan --length-scale 0",
        expect=("--length-scale", "greater than 0"),
    ),
    case(
        "plan-random-sets-negative", "plan --random-sets -1", expect=("--random-sets", "0 or more")
    ),
    case(
        "board-square-of-5-m",
        f"{CHESS} --square 5 --out {{tmp}}/b.pdf",
        expect=("--square", "millimetres given as metres"),
    ),
    case(
        "board-square-nan",
        f"{CHESS} --square nan --out {{tmp}}/b.pdf",
        expect=("--square", "finite"),
    ),
    case(
        "board-zero-rows",
        "board --type chessboard --rows 0 --columns 10 --square 0.02 --out {tmp}/b.pdf",
        expect=("--rows", "1 or more"),
    ),
    case(
        "board-dpi-zero",
        f"{CHESS} --square 0.02 --dpi 0 --out {{tmp}}/b.png",
        expect=("--dpi", "greater than 0"),
    ),
    case(
        "board-spec-of-5-m-squares",
        "board --spec {tmp}/board.yaml --out {tmp}/b.pdf",
        text("board.yaml", "type: chessboard\nrows: 7\ncolumns: 10\nsquare: 5\n"),
        expect=("b.pdf", "more than 2.0 m", "in metres"),
    ),
    case(
        "board-png-too-many-pixels",
        f"{CHESS} --square 0.1 --dpi 2400 --out {{tmp}}/b.png",
        expect=("b.png", "pixels at 2400 dpi", "lower --dpi"),
    ),
    case(
        "board-spec-missing",
        "board --spec {tmp}/none.yaml --out {tmp}/b.pdf",
        expect=("--spec", "not found"),
    ),
    case(
        "observability-rcond-10", "observability --rcond 10", expect=("--rcond", "between 0 and 1")
    ),
    case(
        "observability-rcond-zero", "observability --rcond 0", expect=("--rcond", "between 0 and 1")
    ),
    case(
        "observability-zero-poses", "observability --n-poses 0", expect=("--n-poses", "3 or more")
    ),
    case(
        "observability-validation-negative",
        "observability --validation -1",
        expect=("--validation", "0 or more"),
    ),
    case(
        "observability-poses-missing",
        "observability --poses {tmp}/no.csv",
        expect=("--poses", "not found"),
    ),
    case("study-one-trial", "study --trials 1", expect=("--trials", "2 or more")),
    case("study-zero-trials", "study --trials 0", expect=("--trials", "2 or more")),
    case("study-zero-workers", "study --workers 0", expect=("--workers", "1 or more")),
    case("simulate-zero-poses", "simulate --poses 0", expect=("--poses", "3 or more")),
    case(
        "compensate-model-missing",
        f"{COMP}",
        text("t.csv", "id,x\n"),
        expect=("--model", "not found"),
    ),
    case(
        "compensate-targets-a-folder",
        "compensate --model {tmp}/model.yaml --targets {tmp}",
        robot_file(),
        expect=("--targets", "is a folder"),
    ),
    case(
        "compensate-joint-outside-limits",
        f"{COMP} --nominal a465",
        robot_file(),
        text("t.csv", f"{SIXQ}\na,0,10,20,0,30,0\nb,0,400,0,0,0,0\n"),
        expect=("t.csv: target b", "q2 = 400 deg", "outside the joint limits", "--joint-unit"),
    ),
    case(
        "compensate-joint-radians-as-degrees",
        f"{COMP} --nominal a465 --joint-unit rad",
        robot_file(),
        text("t.csv", f"{SIXQ}\na,0,10,20,0,30,0\n"),
        expect=("t.csv: target a", "q2 = 10 rad", "outside the joint limits"),
    ),
]


def tree(root: Path) -> dict[str, str]:
    """Every file under ``root`` and its SHA-256, and every folder (hidden ones included)."""
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        if p.is_file()
        else "folder"
        for p in sorted(root.rglob("*"))
    }


@pytest.mark.parametrize(("argv", "setups", "code", "expect"), CASES)
def test_bad_input(capsys, tmp_path, argv, setups, code, expect):
    for setup in setups:
        setup(tmp_path)
    before = tree(tmp_path)
    args = shlex.split(argv.replace("{tmp}", str(tmp_path)))
    status = main(args)
    err = capsys.readouterr().err
    assert status == code, err
    assert "Traceback" not in err and "internal error" not in err, err
    for text_ in expect:
        assert text_ in err, err
    assert tree(tmp_path) == before, "a refused run changed files"


def test_the_catalogue_is_large_enough():
    assert len(CASES) >= 100
