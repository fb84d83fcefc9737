"""Numbers that depend on the data alone: every real set calibrated with its rows in another
order and its ids renamed gives the same model, held-out numbers and verdict (to round-off)."""

from pathlib import Path

import numpy as np
import pytest
from conftest import DATA

import relcal
from relcal.data.importers import import_mukca, import_rct_images, import_rct_positioner
from relcal.data.order import canonical_order, take, take_measurements
from relcal.reporting.documents import validation_document

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

UR10 = """robot:
  name: UR10 (CB3)
  convention: dh
  angle_unit: deg
  joints:
    - {name: shoulder_pan_joint, theta_off: 0, d: 0.1273, a: 0, alpha: 90}
    - {name: shoulder_lift_joint, theta_off: 0, d: 0, a: -0.612, alpha: 0}
    - {name: elbow_joint, theta_off: 0, d: 0, a: -0.5723, alpha: 0}
    - {name: wrist_1_joint, theta_off: 0, d: 0.163941, a: 0, alpha: 90}
    - {name: wrist_2_joint, theta_off: 0, d: 0.1157, a: 0, alpha: -90}
    - {name: wrist_3_joint, theta_off: 0, d: 0.0922, a: 0, alpha: 0}
joint_unit: rad
decimal: ","
position_unit: mm
euler: XYZ
pose_angle_unit: deg
columns: {x: measurement_x, y: measurement_y, z: measurement_z, roll: measurement_rx,
          pitch: measurement_ry, yaw: measurement_rz}
"""


def _real(name, tmp_path):
    """The real set ``name`` as a dataset folder (imported where it needs importing)."""
    if name == "positioner":
        source = DATA / "rct_positioner" / "positioner_kinematic_measurements.yaml"
        return import_rct_positioner(source, tmp_path / name).folder
    if name in ("charuco", "circles"):
        source = {"charuco": "rct_charuco_eye_to_hand", "circles": "rct_circle_grid_eye_in_hand"}
        return import_rct_images(DATA / source[name], tmp_path / name).folder
    if name == "panda_1":
        mukca = DATA / "mukca"
        return import_mukca(
            mukca / "data" / "panda_1", tmp_path / name, mukca / "urdf" / "panda.urdf",
            distance=0.05,
        ).folder  # fmt: skip
    if name == "ipa_ur10":
        folder = tmp_path / name
        folder.mkdir()
        csv = DATA / "ipa_ur10" / "measurements_joint_configurations.csv"
        (folder / "dataset.yaml").write_text(UR10 + f"samples: {csv}\n")
        return folder
    return EXAMPLES / name


def _summary(cal):
    """What a user reads, with the ids as given: parameters, held-out numbers, verdict."""
    val, verdict = cal.validation, cal.verdict()
    ids = cal.dataset.ids
    return {
        "params": cal.result.params,
        "names": cal.result.names,
        "numbers": validation_document(val)["calibrated"],
        "before": val.rms("before"),
        "verdict": (verdict.code, verdict.factor, verdict.interval),
        "held_out": sorted(ids[i] for i in cal.test),
        "outliers": sorted(cal.outliers),
    }


def _close(a, b, rtol=1e-7, atol=1e-12):
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for k in a:
            _close(a[k], b[k], rtol, atol)
    elif isinstance(a, list | tuple) and a and not isinstance(a[0], str):
        for x, y in zip(a, b, strict=True):
            _close(x, y, rtol, atol)
    elif isinstance(a, float | np.ndarray | int) and not isinstance(a, bool):
        np.testing.assert_allclose(a, b, rtol=rtol, atol=atol)
    else:
        assert a == b


@pytest.mark.skipif(not DATA.is_dir(), reason="real data not available")
@pytest.mark.parametrize(
    "name",
    [
        "positioner",
        "tiago-pro-poses",
        "tiago-pro-positions",
        "charuco",
        "circles",
        "panda_1",
        "ipa_ur10",
    ],
)
def test_rows_reordered_and_ids_renamed_change_nothing(name, tmp_path):
    dataset = relcal.load_dataset(_real(name, tmp_path))
    measurements = relcal.measure(dataset)
    n = len(dataset.ids)
    perm = np.random.default_rng(7).permutation(n)
    rename = {sid: f"renamed-{k}" for k, sid in enumerate(reversed(dataset.ids))}
    other = take(dataset, perm)
    other = other.__class__(**{**other.__dict__, "ids": tuple(rename[i] for i in other.ids)})
    back = {v: k for k, v in rename.items()}
    first = _summary(relcal.calibrate(dataset, measurements))
    second = _summary(relcal.calibrate(other, take_measurements(measurements, perm)))
    second["held_out"] = sorted(back[i] for i in second["held_out"])
    second["outliers"] = sorted(back[i] for i in second["outliers"])
    _close(first, second)


def test_canonical_order_depends_on_content_alone():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(30, 6))
    q[5] = q[9]  # a repeated configuration, told apart by its pose
    poses = np.broadcast_to(np.eye(4), (30, 4, 4)).copy()
    poses[:, :3, 3] = rng.normal(size=(30, 3))
    ds = relcal.Dataset.from_arrays("a465", q, poses)
    order = canonical_order(ds)
    perm = rng.permutation(30)
    shuffled = take(ds, perm)
    again = take(shuffled, canonical_order(shuffled))
    np.testing.assert_array_equal(again.q, ds.q[order])
    np.testing.assert_array_equal(again.poses, ds.poses[order])
