"""A dataset folder written sample by sample, so that a run stopped at any moment leaves a dataset
``relcal calibrate`` reads, and ``--resume`` continues it.

Layout (relcal's dataset format, :mod:`relcal.data.dataset`)::

    DATASET/
      dataset.yaml      robot, board, camera intrinsics, joint unit, mode (written first)
      board.yaml        the board
      camera.yaml       the intrinsics (absent with ``camera: calibrate``)
      robot.yaml        the robot model, when it is not a built-in name (robot.urdf: a URDF)
      samples.csv       id, one column per joint (named as the robot names them), with a
                        driver that reads the controller's flange pose fx, fy, fz (m), fqx,
                        fqy, fqz, fqw (quaternion x first; relcal handeye reads them), image
      images/ID.png     one image per recorded pose, named by the pose id
      capture.json      the capture log: plan, devices, per pose the attempts, reasons, frame
                        stamp, still window, gate values; what --resume checks

Every file is written to a temporary sibling, flushed to disk and renamed into place. A sample is
committed image first, then ``samples.csv`` (the whole table, rewritten), then ``capture.json``,
with SIGINT and SIGTERM held back during the renames: a row never names a missing image, and an
image without a row (a run stopped between the two) is taken again on resume. Nothing the user
gave is overwritten: an existing non-empty folder is refused unless ``resume`` is asked, and then
it must be a capture of the same robot and plan. One run writes a dataset at a time: the writer
holds ``.capture.lock`` in the folder for as long as it lives (removed when it is closed), and a
second run on the same folder (two ``--resume`` at once) is refused, not merged. What a run has
stored is listed in :func:`relcal.outputset.written` as it goes, so the message after an
interrupt names the samples kept.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from relcal import geometry as tf
from relcal.capture.loop import Sample
from relcal.data.dataset import joints_in_unit
from relcal.errors import RelcalError
from relcal.io import yaml_text
from relcal.limits import read_input
from relcal.outputset import _signals_held, check_parent, exclusive, inputs, note_written
from relcal.robot.model import RobotModel, dump_model, library_names
from relcal.vision.boards import Board, board_to_spec
from relcal.vision.camera import Camera as Intrinsics

LOG = "capture.json"
SAMPLES = "samples.csv"
IMAGES = "images"
LOCK = ".capture.lock"  # held by the one run writing the folder (removed when it ends)


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fill(tmp: Path, data: bytes) -> None:
    """``data`` written and flushed to the temporary ``tmp``, with the permissions of a new file."""
    with open(tmp, "wb") as handle:
        handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())
    mask = os.umask(0)
    os.umask(mask)
    os.chmod(tmp, 0o666 & ~mask)


def _commit(pairs: Sequence[tuple[Path, bytes]], done: list | None = None) -> None:
    """Write several files, each atomically, renamed in order with signals held back; ``done``
    gets ``True`` appended once every rename is made (a signal held back meanwhile is raised
    after that, so the caller can tell a write that happened from one that did not). A
    temporary is created and listed, and the temporaries removed, with signals held back too:
    an interrupt never leaves one behind."""
    staged: list[tuple[Path, Path]] = []
    try:
        for path, data in pairs:
            path.parent.mkdir(parents=True, exist_ok=True)
            with _signals_held():
                fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
                os.close(fd)
                staged.append((Path(tmp), path))
            _fill(Path(tmp), data)
        with _signals_held():
            for tmp, path in staged:
                os.replace(tmp, path)
            staged = []
            if done is not None:
                done.append(True)
            for folder in {path.parent for path, _ in pairs}:
                _fsync_dir(folder)
    finally:
        with _signals_held():
            for tmp, _ in staged:
                tmp.unlink(missing_ok=True)


def file_digest(path: Path) -> str:
    """SHA-256 of a file's bytes (hex)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def encode_image(image: np.ndarray) -> bytes:
    """PNG bytes of an 8-bit grey or BGR image."""
    import cv2

    ok, data = cv2.imencode(".png", np.ascontiguousarray(image))
    if not ok:
        raise RelcalError("could not encode a captured image as PNG")
    return data.tobytes()


def _csv_cell(text: str) -> str:
    return f'"{text}"' if any(c in text for c in ',"\n') else text


def check_destination(root: str | Path, resume: bool) -> None:
    """Refuse ``--out`` before any device is touched: a file, a folder holding an input, a
    non-empty folder without ``resume``, or with ``resume`` a folder that is not a capture."""
    root = Path(root)
    if root.exists() and not root.is_dir():
        raise RelcalError(f"--out {root}: exists and is a file, not a folder")
    check_parent(root / "x", "--out")
    real = Path(os.path.realpath(root))
    for p in inputs():
        if p == real or real in p.parents:
            raise RelcalError(f"--out {root}: holds {p}, which this run reads; choose another")
    if root.is_dir() and any(p.name != LOCK for p in root.iterdir()):
        if not resume:
            raise RelcalError(
                f"--out {root}: already exists and is not empty; add --resume to continue the "
                "capture recorded there, or choose a new folder"
            )
        if not (root / LOG).is_file():
            raise RelcalError(
                f"--out {root}: --resume: not a capture folder (no {LOG}); relcal never "
                "writes into a folder it did not make"
            )


def flange_cells(flange: np.ndarray | None, pose_id: str) -> list[str]:
    """The cells ``fx, fy, fz, fqx, fqy, fqz, fqw`` (m, unit quaternion x first) of a flange pose
    ``(4, 4)``."""
    from scipy.spatial.transform import Rotation

    if flange is None:
        raise RelcalError(f"pose {pose_id}: no flange pose to record (the driver reported none)")
    quat = Rotation.from_matrix(np.asarray(flange, float)[:3, :3]).as_quat()
    return [f"{v:.12g}" for v in (*flange[:3, 3], *quat)]


@contextmanager
def claim(root: str | Path, resume: bool) -> Iterator[None]:
    """The dataset folder ``root`` for this run alone, for the block: checked
    (:func:`check_destination`), created, locked (``.capture.lock``; another run writing it is
    refused, naming it) and checked again under the lock. Re-entrant: the command line claims
    the folder before any device is opened, the writer claims it again. A folder this claim
    created and nothing was written into is removed again at the end."""
    root = Path(root)
    check_destination(root, resume)
    created = not root.exists()
    root.mkdir(parents=True, exist_ok=True)
    try:
        with exclusive(root / LOCK, f"--out {root}", wait=False):
            check_destination(root, resume)  # again: another run may have started it
            yield
    finally:
        if created:
            try:
                root.rmdir()  # only if nothing was written
            except OSError:
                pass


class DatasetWriter:
    """The dataset folder of one capture (see the module docstring).

    Parameters
    ----------
    root : str or Path
        The folder (``--out``).
    model : RobotModel
    robot : str
        How ``dataset.yaml`` names the robot: a built-in name is written as is; a robot from a
        URDF as a copy of the file, ``robot.urdf``, with its root and tip links; any other as
        ``robot.yaml`` (the model) in the folder.
    board : Board
    intrinsics : Camera or None
        Written as ``camera.yaml``; None writes ``camera: calibrate`` (intrinsics from the same
        images).
    plan_ids, plan_targets : sequence of str, ndarray (K, n)
        The plan (rad, m), kept in the log so that a resume with another plan is refused.
    plan_path : str or Path or None
    joint_unit : {"deg", "rad"}
        Of ``samples.csv`` (prismatic joints in m).
    handeye : ndarray (4, 4) or None
        Flange-from-camera guess for ``dataset.yaml`` (``eye_to_hand``: flange-from-board).
    limits : dict or None
        The cell's joint limits by joint name (rad, m), for ``dataset.yaml``'s ``joint_limits``.
    resume : bool
        Continue the capture in an existing folder (its robot, board, intrinsics and the targets
        of its recorded poses must match); without it an existing non-empty folder is refused.
    devices : dict
        Driver names and options, for the log.
    flange : bool
        Write the controller's flange pose of each sample (columns ``fx`` .. ``fqw``); on
        resume the existing table decides (a capture started without them continues without).
    mode : {"eye_in_hand", "eye_to_hand"}
        Where the camera is, for ``dataset.yaml``'s ``mode``: on the flange, or fixed with the
        board on the flange (the plan file's ``# relcal mode:`` line).
    """

    def __init__(
        self,
        root: str | Path,
        model: RobotModel,
        robot: str,
        board: Board,
        intrinsics: Intrinsics | None,
        plan_ids: Sequence[str],
        plan_targets: np.ndarray,
        plan_path: str | Path | None = None,
        joint_unit: str = "deg",
        handeye: np.ndarray | None = None,
        limits: dict[str, tuple[float, float]] | None = None,
        resume: bool = False,
        devices: dict | None = None,
        flange: bool = False,
        mode: str = "eye_in_hand",
    ) -> None:
        if mode not in ("eye_in_hand", "eye_to_hand"):
            raise ValueError(f"mode '{mode}': use eye_in_hand or eye_to_hand")
        self.mode = mode
        self.root = Path(root)
        self.flange = bool(flange)
        self.model = model
        self.board = board
        self.intrinsics = intrinsics
        self.joint_unit = joint_unit
        self.plan_ids = list(plan_ids)
        self.plan_targets = np.asarray(plan_targets, float)
        self._order = {pid: k for k, pid in enumerate(self.plan_ids)}
        named = len(set(model.joint_names)) == model.n_joints and all(model.joint_names)
        self.columns = (
            list(model.joint_names)
            if named
            else [f"q{i + 1}" for i in range(len(model.joint_names))]
        )
        self.rows: dict[str, str] = {}
        self.log: dict[str, Any] = {}
        self.recorded: list[str] = []  # ids this run stored
        check_destination(self.root, resume)
        spec = self._spec(robot, handeye, limits)
        self._claim = claim(self.root, resume)
        self._claim.__enter__()
        try:
            if resume and (self.root / LOG).is_file():
                self._resume(spec)
            else:
                self._start(spec, plan_path, devices or {})
        except BaseException as exc:
            self._claim.__exit__(type(exc), exc, exc.__traceback__)
            self._claim = None
            raise

    def close(self) -> None:
        """Release the folder (its lock file is removed); the writer takes no more samples."""
        held, self._claim = self._claim, None
        if held is not None:
            held.__exit__(None, None, None)

    def __enter__(self) -> DatasetWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _note(self) -> None:
        """What this run has stored, for the message after an interrupt."""
        ids = self.recorded
        if ids:
            shown = ", ".join(ids[:10]) + (f" and {len(ids) - 10} more" if len(ids) > 10 else "")
            text = (
                f"--out {self.root}: {len(ids)} sample{'s' if len(ids) != 1 else ''} recorded by "
                f"this run ({shown}), {len(self.rows)} in the dataset"
            )
        else:
            text = f"--out {self.root}: the dataset's set-up files, no sample recorded yet"
        note_written(text, key=("capture", str(self.root)))

    # ------------------------------------------------------------------ set-up

    def _spec(self, robot: str, handeye: np.ndarray | None, limits=None) -> dict[str, Any]:
        if robot in library_names():
            named: Any = robot
        elif self.model.urdf is not None:  # the URDF itself, copied: exports go back into it
            u = self.model.urdf
            named = {"urdf": "robot.urdf", "root": u.root, "tip": u.tip}
            named["parametrisation"] = u.parametrisation
        else:
            named = "robot.yaml"
        spec: dict[str, Any] = {
            "robot": named,
            "hayati": "auto",
            "mode": self.mode,
            "board": "board.yaml",
            "camera": "camera.yaml" if self.intrinsics is not None else "calibrate",
            "joint_unit": self.joint_unit,
            "samples": SAMPLES,
        }
        if handeye is not None:
            xyz, rpy = tf.to_xyz_rpy(np.asarray(handeye, float))
            spec["handeye"] = {
                "xyz": [round(float(v), 9) for v in xyz],
                "rpy": [round(float(np.degrees(v)), 9) + 0.0 for v in rpy],
            }
        if limits:
            index = {name: i for i, name in enumerate(self.model.joint_names)}
            index.update({f"q{i + 1}": i for i in range(self.model.n_joints)})
            spec["joint_limits"] = {}
            for name, (lo, hi) in limits.items():
                pair = np.array([[lo, hi]])
                if not self.model.prismatic[index[name]] and self.joint_unit == "deg":
                    pair = np.degrees(pair)
                spec["joint_limits"][name] = [round(float(v), 9) for v in pair[0]]
        return spec

    def _start(self, spec: dict, plan_path, devices: dict) -> None:
        self.log = {
            "format": "relcal capture log 1",
            "started_utc": datetime.now(UTC).isoformat(timespec="seconds"),
            "plan": None if plan_path is None else str(plan_path),
            "plan_sha256": None if plan_path is None else file_digest(Path(plan_path)),
            "robot": self.model.name,
            "joint_names": list(self.model.joint_names),
            "joint_unit_of_log": "rad (m for prismatic joints)",
            "board": board_to_spec(self.board),
            "camera": None if self.intrinsics is None else self.intrinsics.to_dict(),
            "devices": devices,
            "runs": 1,
            "samples": {},
            "skipped": {},
        }
        files: list[tuple[Path, bytes]] = [
            (self.root / "board.yaml", yaml_text(board_to_spec(self.board)).encode()),
        ]
        if self.intrinsics is not None:
            files.append((self.root / "camera.yaml", yaml_text(self.intrinsics.to_dict()).encode()))
        if spec["robot"] == "robot.yaml":
            files.append((self.root / "robot.yaml", dump_model(self.model).encode()))
        elif isinstance(spec["robot"], dict):
            files.append((self.root / "robot.urdf", self.model.urdf.data))
        files.append((self.root / LOG, self._log_bytes()))
        files.append((self.root / "dataset.yaml", yaml_text(spec).encode()))
        (self.root / IMAGES).mkdir(parents=True, exist_ok=True)
        done: list = []
        try:
            _commit(files, done)
        finally:
            if done:
                self._note()

    def _resume(self, spec: dict) -> None:
        path = self.root / LOG
        try:
            self.log = json.loads(read_input(path, "text"))
        except (OSError, ValueError) as exc:
            raise RelcalError(f"{path}: --resume: cannot read the capture log: {exc}") from None
        what = f"--resume {self.root}"
        if self.log.get("joint_names") != list(self.model.joint_names):
            raise RelcalError(
                f"{what}: captured with the robot {self.log.get('robot')} (joints "
                f"{self.log.get('joint_names')}), not {self.model.name}; give the same --robot"
            )
        if self.log.get("board") != board_to_spec(self.board):
            raise RelcalError(
                f"{what}: captured with the board {self.log.get('board')}, not "
                f"{board_to_spec(self.board)}; give the same --board"
            )
        camera = None if self.intrinsics is None else self.intrinsics.to_dict()
        if self.log.get("camera") != camera:
            raise RelcalError(
                f"{what}: captured with other camera intrinsics ({self.log.get('camera')}); give "
                "the same --intrinsics (or none, as before)"
            )
        for pid, entry in self.log.get("samples", {}).items():
            if pid not in self._order:
                raise RelcalError(f"{what}: pose {pid} was recorded but is not in this plan")
            target = np.asarray(entry["target"], float)
            if not np.allclose(target, self.plan_targets[self._order[pid]], atol=1e-9, rtol=0):
                raise RelcalError(
                    f"{what}: pose {pid} was recorded at other joint targets than this plan "
                    "gives; resume with the plan the capture started with"
                )
        self._read_rows()
        self.log["runs"] = int(self.log.get("runs", 1)) + 1
        (self.root / IMAGES).mkdir(parents=True, exist_ok=True)
        _commit([(self.root / LOG, self._log_bytes())])

    def _read_rows(self) -> None:
        """The rows of an existing samples.csv, checked against the log."""
        path = self.root / SAMPLES
        logged = set(self.log.get("samples", {}))
        if not path.is_file():
            if logged:
                raise RelcalError(f"{path}: missing, but {LOG} records {len(logged)} samples")
            return
        try:
            lines = read_input(path, "csv").decode("utf-8").splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            raise RelcalError(f"{path}: --resume: cannot read the samples: {exc}") from None
        header = lines[0].split(",") if lines else []
        self.flange = header == self._header(True)  # the table as started decides
        if header != self._header(self.flange):
            raise RelcalError(f"{path} line 1: header {header} is not the one this capture writes")
        for line in lines[1:]:
            if line.strip():
                pid = line.split(",", 1)[0]
                self.rows[pid] = line
        if set(self.rows) != logged:
            raise RelcalError(f"{path}: its ids and those of {LOG} differ; the folder was edited")

    # ------------------------------------------------------------------ samples

    @property
    def done(self) -> set[str]:
        """Ids of the recorded poses."""
        return set(self.rows)

    def skipped_before(self) -> set[str]:
        """Ids skipped by earlier runs."""
        return set(self.log.get("skipped", {}))

    def image_name(self, pose_id: str) -> str:
        return f"{IMAGES}/{pose_id}.png"

    def _header(self, flange: bool) -> list[str]:
        from relcal.data.flange import FLANGE_COLUMNS

        return ["id", *self.columns, *(FLANGE_COLUMNS if flange else ()), "image"]

    def _table(self) -> bytes:
        ordered = sorted(self.rows, key=lambda pid: self._order.get(pid, len(self._order)))
        lines = [",".join(self._header(self.flange))]
        lines += [self.rows[pid] for pid in ordered]
        return ("\n".join(lines) + "\n").encode()

    def _log_bytes(self) -> bytes:
        return (json.dumps(self.log, indent=1, allow_nan=False) + "\n").encode()

    def record(self, sample: Sample) -> None:
        """Store one sample whole: image, then its row, then the log entry."""
        pid = sample.pose_id
        if pid in self.rows:
            raise RelcalError(f"pose {pid} is already recorded in {self.root}")
        q = joints_in_unit(self.model, sample.q[None, :], self.joint_unit)[0]
        name = self.image_name(pid)
        cells = [_csv_cell(pid), *(f"{v:.12g}" for v in q)]
        if self.flange:
            cells += flange_cells(sample.flange, pid)
        self.rows[pid] = ",".join([*cells, name])
        entry = sample.record()
        entry["image"] = name
        entry["run"] = int(self.log.get("runs", 1))
        entry["recorded_utc"] = datetime.now(UTC).isoformat(timespec="seconds")
        self.log.setdefault("samples", {})[pid] = entry
        self.log.setdefault("skipped", {}).pop(pid, None)
        done: list = []
        try:
            _commit(
                [
                    (self.root / name, encode_image(sample.frame.image)),
                    (self.root / SAMPLES, self._table()),
                    (self.root / LOG, self._log_bytes()),
                ],
                done,
            )
        except BaseException:
            if not done:  # not written: forget it (an interrupt after the renames keeps it)
                self.rows.pop(pid, None)
                self.log["samples"].pop(pid, None)
            raise
        finally:
            if done:
                self.recorded.append(pid)
                self._note()

    def skip(self, pose_id: str, index: int, reasons: Sequence[str]) -> None:
        """Note a skipped pose and why in the log."""
        self.log.setdefault("skipped", {})[pose_id] = list(reasons)
        _commit([(self.root / LOG, self._log_bytes())])

    def finish(self, summary: dict) -> None:
        """Store the run's summary in the log."""
        self.log.setdefault("summaries", []).append(summary)
        _commit([(self.root / LOG, self._log_bytes())])
