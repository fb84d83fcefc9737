"""``relcal verify``: a finished calibration on a new session, kinematics frozen, the session's
nuisance cross-fitted for it and the nominal baseline alike; the verdict, the registry record and
``history``; the real TIAGo Pro sessions; planted changes and sessions without one."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import DATA, random_q
from helpers_fleet import make_robot, write_session

from relcal import geometry as tf
from relcal.calibration import verify as vf
from relcal.cli import main
from relcal.fleet.registry import Registry, registry_url
from relcal.fleet.verification import model_from_record
from relcal.robot.kinematics import apply_errors, fk, make_layout
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati, load_model

TIAGO = DATA / "tiago_pro"
CHAIN = "root: base_footprint, tip: gripper_right_pal_atc_base_link"


def _verify(tmp_path: Path, *argv: str) -> tuple[int, dict]:
    out = tmp_path / "verify.json"
    code = main(["verify", *map(str, argv), "--quiet", "--json", str(out)])
    return code, json.loads(out.read_text())


# --- the real TIAGo Pro --------------------------------------------------------------------------


def _tiago(folder: Path, samples: str) -> Path:
    """A dataset folder of the TIAGo Pro's marker positions (x1, y1, z1 only) of ``samples``."""
    folder.mkdir(parents=True)
    (folder / "dataset.yaml").write_text(
        f"robot: {{urdf: {TIAGO / 'tiago_pro.urdf'}, {CHAIN}}}\njoint_unit: rad\n"
        f"columns: {{x: x1, y: y1, z: z1}}\nsamples: {TIAGO / samples}\n"
    )
    return folder


@pytest.mark.skipif(not TIAGO.is_dir(), reason="real data not available")
def test_real_tiago_calibration_verified_on_the_other_session(tmp_path):
    """Kinematics calibrated on the 94 positions of 2026-07-02 (``--selection conservative``),
    verified on the positions of the 48 poses of
    2026-08-05 (another session, another marker: ``T`` and ``m`` refitted). It beats the nominal
    URDF there, but predicts it about 3.5 times worse than its own held-out points: the numbers
    of docs/howto/verify.md."""
    pytest.importorskip("relcal.robot.urdf")
    first = _tiago(tmp_path / "tiago-0702", "mocap_position_20260702.csv")
    second = _tiago(tmp_path / "tiago-0805", "mocap_pose_20260805.csv")
    cal = tmp_path / "cal"
    argv = ["calibrate", str(first), "--selection", "conservative", "--out", str(cal), "--quiet"]
    assert main(argv) == 0
    assert "joint_ranges" in json.loads((cal / "results.json").read_text())
    code, doc = _verify(tmp_path, cal, second)
    assert code == 1 and doc["verdict"]["code"] == "degraded" and doc["verdict"]["exit_status"] == 1
    assert doc["session"]["kind"] == "position" and doc["session"]["n_evaluated"] == 48
    assert doc["nuisance"]["folds"] == 5 and "cross-fitting" in doc["nuisance"]["scheme"]
    base, after = doc["baseline"]["position_mm"], doc["calibrated"]["position_mm"]
    assert base["rms"] == pytest.approx(20.93, abs=0.02)
    # 17.40 mm before the priors held the marker's weak parameters (issue 18) and before
    # model.yaml reloaded exactly (its gravity reference written: a reload was 1.2 mm off)
    assert after["rms"] == pytest.approx(15.92, abs=0.02)
    assert base["ci95"][0] < base["rms"] < base["ci95"][1]
    ratio = doc["ratio_to_baseline"]["position_mm"]
    assert ratio["ci95"][1] < 1.0  # it beats the nominal URDF on the new session
    at = doc["at_calibration"]["position_mm"]
    # 4.48 mm before the held-out split drew from the samples in their content's order (issue
    # 28: the split depends on the data alone, not on the rows' order); 24 samples either way
    assert at["rms"] == pytest.approx(4.71, abs=0.01) and at["n_samples"] == 24
    assert doc["ratio_to_calibration"]["position_mm"]["ci99"][0] > 2.0  # far worse than then
    assert len(doc["samples"]) == 48 and doc["joint_ranges"]["checked"]
    # the session's nuisance, fitted to all its points: the instrument close to the identity
    # (the data's README), the new marker near the gripper
    frames = doc["nuisance"]["fitted_to_all_samples"]["calibrated"]["values"]
    assert np.linalg.norm(frames["instrument"]["xyz_m"]) < 0.05
    assert np.abs(frames["instrument"]["rpy_deg"]).max() < 3.0  # deg, as in results.json
    assert 0.1 < np.linalg.norm(frames["marker_xyz_m"]) < 0.2


# --- synthetic sessions: planted changes, none, the registry and history --------------------------


def test_a_planted_change_is_caught_by_verify_and_history(tmp_path, capsys):
    """One robot, calibrated on Monday (recorded in a registry); Tuesday's session has no change,
    Wednesday's a[2] 1 mm longer, Thursday's theta_off[3] 0.2 deg off. verify holds on Tuesday
    (exit 0) and calls the others degraded (exit 1): the calibration still beats the nominal
    model there, but predicts many times worse than at calibration. history lists the jump."""
    robot = make_robot("a465", "arm7", 3)
    monday = write_session(tmp_path / "arm7" / "mon", robot, 11)
    tuesday = write_session(tmp_path / "arm7" / "tue", robot, 12)
    wednesday = write_session(tmp_path / "arm7" / "wed", robot, 13, change={"a[2]": 1e-3})
    change = {"theta_off[3]": np.radians(0.2)}
    thursday = write_session(tmp_path / "arm7" / "thu", robot, 14, change=change)
    db = tmp_path / "history.sqlite"
    assert main(["calibrate", str(monday), "--quiet", "--registry", str(db)]) == 0
    cal = monday / "calibration"

    code, doc = _verify(tmp_path, cal, tuesday, "--registry", db)
    assert code == 0 and doc["verdict"]["code"] == "holds", doc["verdict"]
    assert doc["calibration"]["registry_run"] == 1 and doc["verification_id"] == 1
    assert doc["ratio_to_baseline"]["position_mm"]["ci95"][1] < 0.05
    assert doc["ratio_to_calibration"]["position_mm"]["ci99"][0] < 1.0
    for session in (wednesday, thursday):
        code, doc = _verify(tmp_path, "1", session, "--registry", db)  # by its run id
        assert code == 1 and doc["verdict"]["code"] == "degraded", doc["verdict"]
        assert doc["ratio_to_baseline"]["position_mm"]["ci95"][1] < 1.0
        assert doc["ratio_to_calibration"]["position_mm"]["ratio"] > 4.0
    capsys.readouterr()
    assert main(["history", "arm7", "--registry", str(db), "--json", str(tmp_path / "h.json")]) == 0
    text = capsys.readouterr().out
    assert "verifications on new sessions" in text
    lines = [line.strip() for line in text.splitlines()]
    rows = [line.split() for line in lines if line.startswith(("1 ", "2 ", "3 "))]
    verdicts = [r[-1] for r in rows if r[-1] in ("holds", "DEGRADED")]
    assert verdicts == ["holds", "DEGRADED", "DEGRADED"], text
    history = json.loads((tmp_path / "h.json").read_text())
    found = history["verifications"]
    assert [v["session"] for v in found] == ["tue", "wed", "thu"]
    assert [v["verdict"] for v in found] == ["holds", "degraded", "degraded"]
    assert all(v["calibration_id"] == 1 for v in found)
    held = found[0]["at_calibration_position_rms_mm"]
    assert found[0]["calibrated_position_rms_mm"] < 2 * held
    assert min(v["calibrated_position_rms_mm"] for v in found[1:]) > 4 * held  # the jump


@pytest.mark.parametrize("seed", range(6))
def test_no_false_alarm_on_a_session_without_change(seed, tmp_path):
    """A second session of the same robot, nothing changed: verify holds. (Over 100 seeds each
    of an A465 and a UR5e, 30 samples per session: see docs/howto/verify.md.)"""
    robot = make_robot(("a465", "ur5e")[seed % 2], f"r{seed}", 500 + seed)
    first = write_session(tmp_path / "s1", robot, 600 + seed)
    second = write_session(tmp_path / "s2", robot, 700 + seed)
    assert main(["calibrate", str(first), "--quiet"]) == 0
    code, doc = _verify(tmp_path, first / "calibration", second)
    assert code == 0 and doc["verdict"]["code"] == "holds", doc["verdict"]


# --- the pieces -----------------------------------------------------------------------------------


def _points_session(model, truth_model, n, rng, noise=5e-5):
    """Points of a marker seen by an instrument: ``p = T F(q) m`` plus noise, for ``n`` random
    configurations."""
    q = random_q(model, n, rng, scale=0.8)
    instrument = tf.from_vector(np.array([0.4, -0.2, 0.1, 0.05, -0.02, 0.3]))
    marker = np.array([0.01, -0.02, 0.08])
    tip = fk(truth_model, q)
    points = (tip[:, :3, :3] @ marker + tip[:, :3, 3]) @ instrument[:3, :3].T + instrument[:3, 3]
    poses = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    poses[:, :3, 3] = points + rng.normal(0, noise, (n, 3))
    return q, poses


def test_cross_fitting_keeps_a_sample_out_of_its_own_fit():
    """A sample made wrong by 100 mm shows its whole error (its nuisance was fitted without it),
    and the other samples of its fold are untouched (their nuisance was fitted on other folds)."""
    rng = np.random.default_rng(3)
    model = get_robot("ur5e")
    truth = apply_errors(model, make_layout(model), rng.normal(0, 3e-4, make_layout(model).size))
    q, poses = _points_session(model, truth, 40, rng)
    ids = [f"s{k}" for k in range(40)]
    clean = vf.verify(truth, model, "position", ids, q, poses, folds=5, seed=1)
    bad = poses.copy()
    bad[7, :3, 3] += [0.1, 0.0, 0.0]
    spoilt = vf.verify(truth, model, "position", ids, q, bad, folds=5, seed=1)
    fold = next(f for f in spoilt.folds if 7 in f)
    rows = {k: r for r, (k, _) in enumerate(spoilt.pairs)}
    err = np.linalg.norm(spoilt.calibrated[rows[7], :3])
    assert err == pytest.approx(0.1, abs=0.005)
    for k in fold:
        if k != 7:
            np.testing.assert_allclose(spoilt.calibrated[rows[k]], clean.calibrated[rows[k]])
    # the calibrated model is the truth: its errors are the noise (sqrt(3) x 0.05 mm per point)
    assert vf.stats(clean.calibrated)["position_mm"]["rms"] == pytest.approx(0.087, rel=0.3)


def test_identical_models_hold_as_the_baseline_and_a_worse_model_is_called_worse():
    """The nominal model verified against itself is 'the calibration exported the nominal
    kinematics'; a model made worse than nominal is called worse (exit status 1)."""
    rng = np.random.default_rng(5)
    model = auto_hayati(get_robot("a465"))
    layout = make_layout(model)
    truth = apply_errors(model, layout, rng.normal(0, 2e-4, layout.size))
    q, poses = _points_session(model, truth, 30, rng)
    ids = [str(k) for k in range(30)]
    same = vf.assess(vf.verify(model, model, "position", ids, q, poses))
    assert same.identical and same.verdict == "holds" and "nominal kinematics" in same.reason
    spoilt = apply_errors(model, layout, rng.normal(0, 3e-3, layout.size))
    worse = vf.assess(vf.verify(spoilt, model, "position", ids, q, poses))
    assert worse.verdict == "worse" and worse.exit_status == 1


def test_verify_coincidence_samples_refits_the_group_points():
    """A new placement of the plate: the group points refitted, the tool point frozen (the same
    ball). The true geometry holds against the nominal one; its spread is the seating scatter."""
    from relcal.geometry import MM
    from relcal.sim.coincidence import simulate_coincidence

    model = get_robot("franka_fr3")
    truth = simulate_coincidence(model, placements=2, per_socket=12, seating=0.05 * MM, seed=3)
    ver = vf.verify(
        truth.true_model,
        model,
        "coincidence",
        [f"k{i}" for i in range(len(truth.q))],
        truth.q,
        groups=truth.groups,
        tool_points=(truth.tool_point, truth.tool_guess),
        folds=4,
    )
    a = vf.assess(ver)
    assert a.verdict == "holds" and a.n_samples == len(truth.q)
    assert a.calibrated["position_mm"]["rms"] < 0.05 * np.sqrt(3) * 1.4
    assert a.baseline["position_mm"]["rms"] > 10 * a.calibrated["position_mm"]["rms"]


def test_joint_ranges_are_recorded_and_a_session_beyond_them_is_warned(tmp_path):
    robot = make_robot("a465", "arm1", 8)
    first = write_session(tmp_path / "s1", robot, 21)
    second = write_session(tmp_path / "s2", robot, 22)
    assert main(["calibrate", str(first), "--quiet"]) == 0
    results = first / "calibration" / "results.json"
    doc = json.loads(results.read_text())
    ranges = doc["joint_ranges"]
    assert [j["name"] for j in ranges["joints"]] == list(get_robot("a465").joint_names)
    assert all(j["lower"] < j["upper"] and j["unit"] == "rad" for j in ranges["joints"])
    # the same calibration, as if it had covered only a narrow range of joint 2
    ranges["joints"][1].update(lower=-0.1, upper=0.1)
    results.write_text(json.dumps(doc))
    code, out = _verify(tmp_path, first / "calibration", second)
    outside = {o["joint"]: o for o in out["joint_ranges"]["outside"]}
    narrowed = outside[ranges["joints"][1]["name"]]  # (others may reach a little beyond too)
    assert narrowed["n_samples"] > 10
    assert any("outside the ranges the calibration covered" in w for w in out["warnings"])
    flagged = [s for s in out["samples"] if 1 in s["outside_range"]]
    assert len(flagged) == narrowed["n_samples"]
    # an older results.json without the ranges: they come from its training samples again
    del doc["joint_ranges"]
    results.write_text(json.dumps(doc))
    code, out = _verify(tmp_path, first / "calibration", second)
    assert out["joint_ranges"]["checked"] and "training samples" in out["joint_ranges"]["source"]


def test_a_registry_run_is_rebuilt_from_its_record(tmp_path):
    """The calibrated model rebuilt from a registry record (the session's nominal robot, the
    recorded errors, the chosen non-geometric terms) predicts as its model.yaml does."""
    robot = make_robot("a465", "arm2", 9)
    first = write_session(tmp_path / "s1", robot, 31, n=40, scale={2: 8e-4, 3: -6e-4})
    db = tmp_path / "h.sqlite"
    assert main(["calibrate", str(first), "--quiet", "--registry", str(db)]) == 0
    with Registry(registry_url(db)) as registry:
        (run,) = registry.runs("arm2")
    assert "scale" in run.settings["chosen_model"]
    from relcal.data.dataset import load_dataset

    nominal = load_dataset(first).model
    rebuilt = model_from_record(run, nominal)
    written = load_model(first / "calibration" / "model.yaml")
    q = random_q(nominal, 50, np.random.default_rng(0))
    np.testing.assert_allclose(fk(rebuilt, q), fk(written, q), atol=1e-9)
    assert rebuilt.scale[1] == pytest.approx(written.scale[1], rel=1e-9)
    with pytest.raises(vf.RelcalError, match="the session's robot is"):
        model_from_record(run, replace(nominal, name="another robot"))


@pytest.mark.parametrize(
    "argv, message",
    [
        (["verify", "{tmp}/nothing", "{tmp}/s2"], "a registry run id needs --registry"),
        (["verify", "{tmp}/s2", "{tmp}/s2"], "no model.yaml and no results.json"),
        (["verify", "{tmp}/s1/calibration", "{tmp}/ur"], "the session's robot"),
    ],
)
def test_bad_calibrations_are_one_line_errors(argv, message, tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("RELCAL_REGISTRY", raising=False)
    first = write_session(tmp_path / "s1", make_robot("a465", "a", 1), 1, n=12)
    write_session(tmp_path / "s2", make_robot("a465", "a", 1), 2, n=12)
    write_session(tmp_path / "ur", make_robot("ur5e", "u", 1), 3, n=12)
    assert main(["calibrate", str(first), "--quiet", "--holdout", "0.2"]) == 0
    capsys.readouterr()
    assert main([a.replace("{tmp}", str(tmp_path)) for a in argv]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and err.count("\n") == 1


def test_the_fleet_report_and_text_show_the_latest_verification(tmp_path):
    """A robot of the fleet with verifications in the registry: the fleet's text and report show
    its latest one (verdict, errors, the calibration's own held-out error)."""
    from relcal.cli.fleet import latest_verifications
    from relcal.fleet.report import fleet_report
    from relcal.fleet.runner import model_summaries
    from relcal.fleet.text import fleet_text

    robot = make_robot("a465", "arm9", 4)
    first = write_session(tmp_path / "arm9" / "a", robot, 41)
    second = write_session(tmp_path / "arm9" / "b", robot, 42, change={"a[2]": 1e-3})
    db = tmp_path / "h.sqlite"
    assert main(["calibrate", str(first), "--quiet", "--registry", str(db)]) == 0
    assert (
        main(["verify", str(first / "calibration"), str(second), "--quiet", "--registry", str(db)])
        == 1
    )
    entries = [{"session": "arm9/c", "robot_id": "arm9", "model": None, "status": "failed",
                "reason": "a reason"}]  # fmt: skip
    with Registry(registry_url(db)) as registry:
        found = latest_verifications(registry, entries)
    assert [v["verdict"] for v in found] == ["degraded"] and found[0]["robot_id"] == "arm9"
    text = fleet_text(entries, model_summaries(entries), found)
    assert "latest verification of arm9" in text and "degraded" in text
    doc = {"models": model_summaries(entries), "verifications": found, "seconds": 1.0}
    page = fleet_report(doc, entries)
    assert 'id="verifications"' in page and "degraded" in page
    assert f"{found[0]['calibrated_position_rms_mm']:.3f}" in page


@pytest.mark.parametrize("entry", ["command", "api"])
def test_the_calibrations_own_training_samples_are_refused(entry, tmp_path, capsys):
    """Verifying on the dataset a calibration was fitted to says nothing of a new session: the
    command refused it as verify_session does (it answered 'HOLDS', exit 0, on the TIAGo Pro's
    own training poses), naming the session and its samples; a new session still holds."""
    robot = make_robot("a465", "arm1", 8)
    first = write_session(tmp_path / "s1", robot, 21)
    second = write_session(tmp_path / "s2", robot, 22)
    assert main(["calibrate", str(first), "--quiet"]) == 0
    capsys.readouterr()
    cal = first / "calibration"
    if entry == "command":
        assert main(["verify", str(cal), str(first), "--quiet", "--brief"]) == 2
        err = capsys.readouterr().err
        assert "the calibration's own training samples" in err and "Traceback" not in err
        assert str(first / "dataset.yaml") in err and err.count("\n") == 1
        assert main(["verify", str(cal), str(second), "--quiet", "--brief"]) in (0, 1)
    else:
        from relcal.data.dataset import load_dataset

        with pytest.raises(vf.RelcalError, match="the calibration's own training samples"):
            vf.verify_session(cal, load_dataset(first))
        vf.verify_session(cal, load_dataset(second))
