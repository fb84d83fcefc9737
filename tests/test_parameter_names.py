"""One name per parameter in every command, file and report: a robot loaded from a URDF has its
joint parameters named after its joints (``theta_off[elbow_joint]``, not ``theta_off[3]``) by
one function (:func:`relcal.robot.kinematics.parameter_label`), in ``calibrate``, results.json,
``history``, ``compare`` and ``fleet calibrate`` alike (``fleet`` and ``compare`` showed the
numbers while ``calibrate`` and ``history`` showed the joints).

Two sessions of a simulated UR5e (its URDF as ur_description builds it), the second with the
elbow's zero offset 0.3 deg off, so that every command has parameters to name and a drift to
flag."""

from __future__ import annotations

import contextlib
import io
import json
import re

import numpy as np
import pytest
from conftest import random_q
from helpers_sim import BOARD, HANDEYE
from urdf_helpers import UR5E_KINEMATICS, ur_description_urdf

from relcal import geometry as tf
from relcal.cli import main
from relcal.data.dataset import write_samples
from relcal.robot.kinematics import apply_errors, fk, make_layout, parameter_label
from relcal.robot.urdf import load_urdf

NUMBERED = re.compile(r"\b(?:theta_off|a|d|alpha|beta|scale|compliance|harmonic_[cs])\[\d+\]")
ELBOW = "theta_off[elbow_joint]"


def _session(root, urdf, truth, seed: int):
    nominal = load_urdf(urdf, "base_link", "tool0")
    model = apply_errors(nominal, make_layout(nominal), truth)
    rng = np.random.default_rng(seed)
    q = random_q(nominal, 30, rng, scale=0.8)
    noise = np.c_[rng.normal(0, 3e-5, (30, 3)), rng.normal(0, 5e-5, (30, 3))]
    poses = BOARD @ fk(model, q) @ HANDEYE @ tf.from_vector(noise)
    root.mkdir(parents=True)
    xyz, rpy = tf.to_xyz_rpy(HANDEYE)
    (root / "dataset.yaml").write_text(
        f"robot: {{urdf: {urdf}, root: base_link, tip: tool0}}\njoint_unit: deg\n"
        f"robot_id: ur5e-7\nhandeye: {{xyz: {xyz.tolist()}, rpy: {np.degrees(rpy).tolist()}}}\n"
    )
    ids = [f"s{k:02d}" for k in range(30)]
    text = write_samples(root / "samples.csv", ids, np.degrees(q), poses=poses)
    (root / "samples.csv").write_text(text)


def _run(argv) -> str:
    with contextlib.redirect_stdout(io.StringIO()) as out:
        main(argv)
    return out.getvalue()


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("names")
    urdf = tmp / "ur5e.urdf"
    urdf.write_text(ur_description_urdf(UR5E_KINEMATICS))
    nominal = load_urdf(urdf, "base_link", "tool0")
    layout = make_layout(nominal)
    rng = np.random.default_rng(11)
    truth = np.where(layout.is_angle(), np.radians(0.1), 3e-4) * rng.choice([-1, 1], layout.size)
    later = truth.copy()
    later[layout.names.index("theta_off[3]")] += np.radians(0.3)
    plant = tmp / "plant"
    _session(plant / "ur5e-7" / "1-monday", urdf, truth, 1)
    _session(plant / "ur5e-7" / "2-friday", urdf, later, 2)
    return tmp, plant, nominal


def _in_process(sessions, out_root=None, options=None, workers=2, scheduler=None, client=None):
    """The fleet's sessions calibrated one after the other in this process, as the workers of
    :func:`relcal.fleet.runner.iterate_fleet` do (a Dask cluster names nothing differently;
    starting one costs more than the calibrations)."""
    from relcal.fleet.runner import calibrate_session, outputs_folder

    for s in sessions:
        out = str(outputs_folder(s, out_root))
        entry = calibrate_session(str(s.path), s.name, out, options, s.robot_id)
        entry.setdefault("robot_id", s.robot_id)
        yield entry


def test_every_command_names_the_parameters_by_their_joints(cell, monkeypatch):
    monkeypatch.setattr("relcal.fleet.runner.iterate_fleet", _in_process)
    tmp, plant, nominal = cell
    db = tmp / "history.sqlite"
    texts, docs = {}, {}
    for k, day in enumerate(("1-monday", "2-friday")):
        out, js = tmp / f"cal-{day}", tmp / f"r{k}.json"
        argv = ["calibrate", str(plant / "ur5e-7" / day), "--out", str(out), "--json", str(js)]
        texts[f"calibrate {day}"] = _run([*argv, "--registry", str(db)])
        docs[f"results {day}"] = json.loads(js.read_text())
    texts["history"] = _run(["history", "ur5e-7", "--registry", str(db), "--json", str(tmp / "h")])
    texts["compare"] = _run(["compare", "1", "2", "--registry", str(db), "--json", str(tmp / "c")])
    docs["history"] = json.loads((tmp / "h").read_text())
    docs["compare"] = json.loads((tmp / "c").read_text())
    argv = ["fleet", "calibrate", str(plant), "--out", str(tmp / "fleet-out")]
    argv += ["--json", str(tmp / "f")]
    texts["fleet"] = _run([*argv, "--registry", str(tmp / "fleet.sqlite")])
    docs["fleet"] = json.loads((tmp / "f").read_text())

    # the one function, on the robot's own joints
    joints = list(nominal.joint_names)
    assert joints[2] == "elbow_joint" and parameter_label("theta_off[3]", joints) == ELBOW
    # the drift is found and named by the joint in every command that reports it
    assert docs["compare"]["flagged"] == ["theta_off[3]"]  # the key, for programs
    for name in ("history", "compare", "fleet"):
        assert ELBOW in texts[name], (name, texts[name])
    # no command prints a joint parameter by its number
    for name, text in texts.items():
        assert not NUMBERED.findall(text), (name, NUMBERED.findall(text))
    # the same parameter, the same label, in every file
    for day in ("1-monday", "2-friday"):
        doc = docs[f"results {day}"]
        shown = [r["label"] for r in doc["parameters"] if r["status"] == "estimated"]
        assert ELBOW in shown and all(label in texts[f"calibrate {day}"] for label in shown)
        assert all(r["label"] == parameter_label(r["name"], joints) for r in doc["parameters"])
        for text in (
            doc["identification"]["unidentifiable"] + doc["identification"]["weak_directions"]
        ):
            assert not NUMBERED.findall(text), text
        run = docs["history"]["runs"][0 if day == "1-monday" else 1]
        assert run["settings"]["parameter_labels"] == doc["parameter_labels"]
        estimated = {p["name"] for p in run["parameters"] if p["estimated"]}
        assert {r["label"] for r in doc["parameters"] if r["name"] in estimated} <= set(
            parameter_label(n, joints) for n in estimated
        )
    for p in docs["compare"]["parameters"]:
        assert p["label"] == parameter_label(p["name"], joints)
    drift = next(e["drift"] for e in docs["fleet"]["sessions"] if e["drift"])
    assert drift["flagged_labels"] == [ELBOW] and drift["flagged"] == ["theta_off[3]"]
