"""Calibration of dataset folders end to end: outputs, held-out improvement, planted outliers,
and the real 2-axis positioner of robot_cal_tools."""

import json
from dataclasses import replace

import numpy as np
import pytest
from conftest import DATA
from helpers_dataset import synthetic_dataset

from relcal.calibration.pipeline import calibrate
from relcal.cli import main
from relcal.data.dataset import load_dataset
from relcal.data.imaging import measure
from relcal.data.importers import import_rct_positioner
from relcal.reporting.documents import validation_document
from relcal.robot.kinematics import apply_errors, make_layout


def parameter_error(cal, truth):
    """RMS of identified-minus-true geometric errors over identifiable parameters, scaled."""
    n = cal.problem.layout.size
    ok = cal.result.identifiable[:n]
    scale = cal.result.identifiability.column_norms[:n][ok]
    return np.sqrt(np.mean(((cal.result.params[:n][ok] - truth[ok]) * scale) ** 2))


def test_calibrate_command_writes_every_output(tmp_path, capsys):
    syn = synthetic_dataset(tmp_path / "d", n=50)
    out = tmp_path / "out"
    assert main(["calibrate", str(syn.root), "--out", str(out), "--quiet"]) == 0
    doc = json.loads((out / "results.json").read_text())
    before, after = doc["validation"]["baseline"], doc["validation"]["calibrated"]
    assert before["position_mm"]["rms"] > 5 * after["position_mm"]["rms"]
    assert doc["identification"]["converged"] and doc["outliers"] == []
    for name in ("model.yaml", "robot.urdf", "parameters.csv"):
        assert (out / name).stat().st_size > 100
    assert "not identifiable" not in capsys.readouterr().out  # --quiet


def test_planted_outliers_are_reported_and_do_not_spoil_the_result(tmp_path):
    clean = synthetic_dataset(tmp_path / "clean", n=40, seed=4)
    dirty = synthetic_dataset(tmp_path / "dirty", n=40, outliers=4, seed=4)
    ds_clean, ds_dirty = load_dataset(clean.root), load_dataset(dirty.root)
    geometric = {"holdout": 0.0, "nongeometric": "none"}  # the truth is geometric
    ref = calibrate(ds_clean, measure(ds_clean), **geometric)
    robust = calibrate(ds_dirty, measure(ds_dirty), loss="huber", **geometric)
    plain = calibrate(ds_dirty, measure(ds_dirty), loss="linear", keep_outliers=True, **geometric)
    assert sorted(robust.outliers) == dirty.ids
    e_ref, e_robust = parameter_error(ref, clean.truth), parameter_error(robust, dirty.truth)
    assert e_robust < 2 * e_ref, (e_ref, e_robust)
    assert parameter_error(plain, dirty.truth) > 3 * e_robust  # the loss is what saves it


def test_real_positioner_calibration(tmp_path):
    root = import_rct_positioner(
        DATA / "rct_positioner/positioner_kinematic_measurements.yaml", tmp_path / "p"
    ).folder
    dataset = load_dataset(root)
    assert len(dataset.ids) == 205 and dataset.mode == "eye_to_hand"
    # The plain least squares (priors: none): its estimate moves with the nominal model exactly;
    # priors are centred on the nominal model, so a planted nominal error shifts them too.
    cal = calibrate(dataset, measure(dataset), holdout=0.25, seed=0, priors="none")
    assert cal.result.converged
    # Planted errors on real data: tell the calibration that the positioner's first link is off
    # by 2 mm and 0.3 deg. It must find exactly that much more error, and the held-out pairs,
    # much worse with the planted nominal model, must come back to the unplanted result.
    layout = make_layout(dataset.model)
    planted = np.zeros(layout.size)
    planted[layout.names.index("a[1]")] = 2e-3
    planted[layout.names.index("alpha[1]")] = np.radians(0.3)
    wrong = replace(dataset, model=apply_errors(dataset.model, layout, planted))
    off = calibrate(wrong, measure(wrong), holdout=0.25, seed=0, priors="none")
    for name in ("a[1]", "alpha[1]"):
        k = layout.names.index(name)
        recovered = cal.result.params[k] - off.result.params[k]
        assert abs(recovered - planted[k]) < 0.01 * cal.std[k], name
    right, planted_doc = validation_document(cal.validation), validation_document(off.validation)
    for key in ("position_mm", "orientation_deg"):
        assert planted_doc["baseline"][key]["rms"] > 1.5 * right["baseline"][key]["rms"]
        calibrated = right["calibrated"][key]["rms"]
        assert planted_doc["calibrated"][key]["rms"] == pytest.approx(calibrated, 1e-6)
    names = [c for c in cal.result.unidentifiable]
    assert any("theta_off[1]" in c and "rigid motion" in c for c in names)
    # The second joint's link is absorbed by X: one combination per link parameter, each led
    # by that parameter alone, not a mixture of link parameters.
    absorbed = [c for c in cal.result.identifiability.combinations if "hand-eye" in c.reason]
    leads = sorted(n for c in absorbed for n in c.names if not n.startswith("handeye."))
    assert leads == ["a[2]", "alpha[2]", "d[2]", "theta_off[2]"]
    assert all(c.describe().split(" with ")[0].endswith(("+1 deg", "+1 mm")) for c in absorbed)
    # X is estimated whole and absorbs them: the link stays nominal in the exported model.
    kinds = cal.problem.full_layout.kinds
    estimated = {
        cal.result.names[i]
        for i in cal.result.identifiability.subset
        if kinds[i] in ("theta_off", "a", "d", "alpha", "handeye")
    }
    assert estimated == {"a[1]", "alpha[1]"} | {
        f"handeye.{c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz")
    }
    # The second joint's repeatable error (runout) is a first harmonic the selection keeps.
    chosen = cal.selection[cal.chosen].candidate
    assert "harmonic" in chosen.name, chosen.name
    assert "harmonic" in cal.model.nongeometric[1]
    k = cal.result.names.index("harmonic_s[2]")
    assert abs(cal.result.params[k]) > 5 * cal.std[k]


def test_named_validation_set_and_k_fold_cross_validation(tmp_path):
    syn = synthetic_dataset(tmp_path / "d", n=24)
    out = tmp_path / "out"
    argv = ["calibrate", str(syn.root), "--out", str(out), "--quiet", "--kfold", "3"]
    assert main([*argv, "--holdout-ids", "s001,s005,s009,s013"]) == 0
    doc = json.loads((out / "results.json").read_text())
    assert doc["held_out_ids"] == ["s001", "s005", "s009", "s013"]
    pairs = doc["validation"]["pairs"]  # each held-out pose in the world frame
    assert len(pairs) == 4 and pairs[0]["ids"] == ["s001", "s001"]
    assert all(p["calibrated_mm"] < p["baseline_mm"] for p in pairs)
    cv = doc["cross_validation"]
    assert cv["k"] == 3 and cv["pooled"]["n_samples"] == 24  # every sample held out once
    pooled = cv["pooled"]
    assert pooled["baseline"]["position_mm"]["rms"] > 5 * pooled["calibrated"]["position_mm"]["rms"]
