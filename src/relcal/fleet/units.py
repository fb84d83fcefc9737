"""Several units of one robot model, compared parameter by parameter.

A fleet often holds several arms of one model (two Franka Panda units, ten UR10e). Each unit's
calibration identifies its own corrections; which unit is *off* (its correction far from its
siblings', beyond what their uncertainties explain) and in which joint is what a maintenance
engineer wants named. For every parameter estimated in two or more units of a model, each unit's
correction is compared with the median of the *other* units' corrections (leave-one-out, so the
unit under test never pulls its own reference):

``z = (v_i - median_j≠i v_j) / sqrt(s_i^2 + s_ref^2)``

with ``s_ref`` the standard deviation of that median (the middle unit's own, or half the root sum
of squares of the two middle units' when their number is even). A unit is named off in a parameter
when ``|z|`` exceeds the threshold: by default the two-sided normal quantile of ``alpha`` with a
Bonferroni correction over every (unit, parameter) test of the model, so that with correct
standard deviations and no unit off, at most ``alpha`` of fleets name any unit.

With two units the reference of each is the other: both are named, with opposite signs, and
which one is off cannot be told (a third unit decides). Units of different robot models are
never compared. Values are in the units people read (mm, deg, ppm).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.stats import norm

from relcal.errors import RelcalError
from relcal.fleet.drift import display
from relcal.robot.kinematics import parameter_label, relabel

# the session's (or the instrument's) frames and points: not a property of the unit
NUISANCE_PREFIXES = ("handeye.", "instrument.", "marker.", "tool_point.", "point[")
_PER_JOINT = re.compile(r"^([a-z_]+)\[(\d+)\]$")


@dataclass(frozen=True)
class UnitParameter:
    """One unit's correction of one parameter, in the unit people read (``shown_unit``)."""

    value: float
    std: float


def joint_label(name: str, joints: list[str] | None) -> tuple[str, str | None]:
    """The name a person reads (:func:`relcal.robot.kinematics.parameter_label`, the one that
    names parameters everywhere), and the joint: ``theta_off[4]`` -> ``theta_off[panda_joint4]``
    when the 4th joint is called ``panda_joint4`` (``joints``: the chain's joint names, first
    joint first); other names (URDF origins, which already name their joint) unchanged."""
    match = _PER_JOINT.match(name)
    if match is None or not joints:
        joint = name.split(".")[0] if ".origin." in name or name.endswith(".zero") else None
        return name, joint
    index = int(match.group(2)) - 1
    if not 0 <= index < len(joints):
        return name, None
    return parameter_label(name, joints), joints[index]


def record_joints(record: dict) -> list[str] | None:
    """The joint names of a registry record (its settings' ``joint_ranges``), or None."""
    ranges = (record.get("settings") or {}).get("joint_ranges") or {}
    joints = ranges.get("joints") if isinstance(ranges, dict) else None
    if not joints:
        return None
    return [str(j.get("name")) for j in joints]


def unit_parameters(record: dict) -> dict[str, tuple[UnitParameter, str]]:
    """The robot's own estimated corrections of a registry record (a value and a standard
    deviation; the session's nuisance frames and points left out), by name, each with the unit it
    is shown in.

    Those ``results.json`` calls ``estimated`` (the record's ``status``; records without it:
    the identifiable ones): a parameter that only carries the value of a combination whose other
    members are held at nominal (``combination``) is left out, its value is not its own."""
    out = {}
    for p in record.get("parameters") or []:
        name = p["name"]
        if name.startswith(NUISANCE_PREFIXES):
            continue
        if p.get("value") is None or p.get("std") is None:
            continue
        if p.get("status", "estimated" if p.get("identifiable") else None) != "estimated":
            continue
        value, unit = display(p["value"], p["unit"])
        out[name] = (UnitParameter(value, display(p["std"], p["unit"])[0]), unit)
    return out


def held_parameters(record: dict) -> frozenset[str]:
    """The robot parameters a record leaves at nominal (not identifiable, or not in the chosen
    model); nuisance frames and points left out."""
    return frozenset(
        p["name"]
        for p in record.get("parameters") or []
        if p.get("value") is None and not p["name"].startswith(NUISANCE_PREFIXES)
    )


def median_with_std(values: np.ndarray, stds: np.ndarray) -> tuple[float, float]:
    """The median of ``values`` ``(m,)`` and its standard deviation: the middle value's own, or
    for an even count (the mean of the two middle values) half their root sum of squares."""
    if len(values) == 0:
        raise RelcalError("median_with_std: no values")
    order = np.argsort(values, kind="stable")
    m = len(values)
    if m % 2:
        k = order[m // 2]
        return float(values[k]), float(stds[k])
    a, b = order[m // 2 - 1], order[m // 2]
    return float((values[a] + values[b]) / 2), float(np.hypot(stds[a], stds[b]) / 2)


def leave_one_out_z(values: np.ndarray, stds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each value's difference from the median of the others, in its unit and in combined
    standard deviations.

    Parameters
    ----------
    values : ndarray, shape (n,)
        One correction per unit (n >= 2), any one unit (mm, deg, ...).
    stds : ndarray, shape (n,)
        Their standard deviations, same unit.

    Returns
    -------
    difference, z : ndarray, shape (n,)
        ``values[i]`` minus the median of the others (:func:`median_with_std`), and that
        difference over ``sqrt(stds[i]**2 + std_of_that_median**2)`` (infinite when both
        standard deviations are zero and the values differ).
    """
    values, stds = np.asarray(values, dtype=float), np.asarray(stds, dtype=float)
    n = len(values)
    if n < 2 or stds.shape != values.shape:
        raise RelcalError("leave_one_out_z: two or more values with one std each")
    diff, z = np.empty(n), np.empty(n)
    for i in range(n):
        others = np.arange(n) != i
        ref, ref_std = median_with_std(values[others], stds[others])
        diff[i] = values[i] - ref
        combined = np.hypot(stds[i], ref_std)
        if combined > 0:
            z[i] = diff[i] / combined
        else:  # no uncertainty given: any difference is infinitely many std
            z[i] = np.copysign(np.inf, diff[i]) if diff[i] else 0.0
    return diff, z


def z_threshold(alpha: float, n_tests: int) -> float:
    """Two-sided normal quantile of ``alpha`` over ``n_tests`` tests (Bonferroni)."""
    if not 0 < alpha < 1:
        raise RelcalError(f"alpha {alpha!r}: must lie strictly between 0 and 1")
    return float(norm.isf(alpha / (2 * max(n_tests, 1))))


def _latest_units(entries: list[dict]) -> dict[str, dict]:
    """The registry record of the latest calibrated session of each unit (robot id; session
    order), by robot model."""
    by_model: dict[str, dict[str, dict]] = {}
    for e in entries:
        if e.get("status") == "ok" and e.get("record") is not None and e.get("model"):
            by_model.setdefault(e["model"], {})[str(e["robot_id"])] = e["record"]
    return by_model


def compare_model_units(
    units: dict[str, dict], alpha: float = 0.01, z: float | None = None
) -> dict[str, Any]:
    """Compare the units of one robot model parameter by parameter.

    Parameters
    ----------
    units : dict of str to dict
        Each unit's (robot id's) registry record (:func:`relcal.fleet.records.calibration_record`),
        of its latest calibration; two or more.
    alpha : float
        Level of the test over the whole model (Bonferroni over every unit and parameter
        compared, :func:`z_threshold`).
    z : float, optional
        The threshold of ``|z|`` instead (``relcal fleet calibrate --units-z``).

    Returns
    -------
    dict
        As JSON: ``robots``, ``sessions`` and ``chosen_models`` per unit; ``parameters``, one
        entry per parameter estimated in two or more units (``name``, ``label`` with the joint
        name, ``joint``, ``unit`` (mm, deg, ppm ...), and per unit ``value``, ``std``,
        ``difference`` from the median of the other units and ``z``); ``z_threshold``,
        ``n_tests``, ``alpha``; ``off``, each (unit, parameter) whose ``|z|`` exceeds the
        threshold, largest first, with a sentence naming the unit and the joint (``text``); and
        ``notes`` on what makes the corrections less comparable (two units only, different chosen
        models, different parameters held at nominal).
    """
    robots = sorted(units)
    if len(robots) < 2:
        raise RelcalError("compare_model_units: two or more units of one model")
    values = {r: unit_parameters(units[r]) for r in robots}
    joints = next((j for j in (record_joints(units[r]) for r in robots) if j), None)
    # as each unit's calibration showed its parameters (records older than the labels: the
    # joints of the chain named)
    settings = [units[r].get("settings") or {} for r in robots]
    labelled = any("parameter_labels" in s for s in settings)
    labels: dict[str, str] = {}
    for one in settings:
        labels |= one.get("parameter_labels") or {}
    names: list[str] = []
    for r in robots:
        names += [n for n in values[r] if n not in names]
    rows = []
    for name in names:
        have = [r for r in robots if name in values[r]]
        if len(have) < 2:
            continue
        v = np.array([values[r][name][0].value for r in have])
        s = np.array([values[r][name][0].std for r in have])
        diff, zs = leave_one_out_z(v, s)
        label, joint = joint_label(name, joints)
        label = labels.get(name, name) if labelled else label
        rows.append(
            {
                "name": name,
                "label": label,
                "joint": joint,
                "unit": values[have[0]][name][1],
                "units": {
                    r: {
                        "value": float(v[k]),
                        "std": float(s[k]),
                        "difference": float(diff[k]),
                        "z": float(zs[k]),
                    }  # fmt: skip
                    for k, r in enumerate(have)
                },
            }
        )
    n_tests = sum(len(row["units"]) for row in rows)
    threshold = z_threshold(alpha, n_tests) if z is None else float(z)
    off = []
    for row in rows:
        for r, u in row["units"].items():
            if abs(u["z"]) > threshold:
                off.append(
                    {
                        "unit": r,
                        "name": row["name"],
                        "label": row["label"],
                        "joint": row["joint"],
                        "difference": u["difference"],
                        "shown_unit": row["unit"],
                        "z": u["z"],
                        "text": f"{r}: {row['label']} {u['difference']:+.3g} {row['unit']}, "
                        f"{abs(u['z']):.1f} std from the fleet",
                    }
                )
    off.sort(key=lambda o: -abs(o["z"]))
    return {
        "robots": robots,
        "sessions": {r: units[r].get("session") for r in robots},
        "chosen_models": {r: (units[r].get("settings") or {}).get("chosen_model") for r in robots},
        "alpha": alpha,
        "n_tests": n_tests,
        "z_threshold": threshold,
        "parameters": rows,
        "off": off,
        "notes": [relabel(n, labels) for n in _notes(robots, values, units, rows)],
    }


def _notes(robots: list[str], values: dict, units: dict, rows: list[dict]) -> list[str]:
    notes = []
    if len(robots) == 2:
        notes.append(
            "two units: each is compared with the other, so both are named for any difference; "
            "which one is off needs a third unit"
        )
    chosen = {r: (units[r].get("settings") or {}).get("chosen_model") for r in robots}
    if len(set(chosen.values())) > 1:
        notes.append(
            "the units chose different models ("
            + ", ".join(f"{r}: {chosen[r]}" for r in robots)
            + "): a correction absorbs part of what another unit's extra terms explain; compare "
            "on one model (fleet calibrate --nongeometric none)"
        )
    held = {r: held_parameters(units[r]) for r in robots}
    if len(set(held.values())) > 1:
        common = frozenset.intersection(*held.values())
        notes.append(
            "the units hold different parameters at nominal ("
            + "; ".join(
                f"{r}: {', '.join(sorted(held[r] - common))}" for r in robots if held[r] - common
            )
            + "): the corrections near those absorb different things"
        )
    compared = {row["name"] for row in rows}
    one_sided = sorted({n for r in robots for n in values[r]} - compared)
    if one_sided:
        notes.append("estimated in one unit only (not compared): " + ", ".join(one_sided))
    partly = [row["label"] for row in rows if len(row["units"]) < len(robots)]
    if partly:
        notes.append("estimated in some units only (compared among those): " + ", ".join(partly))
    return notes


def compare_units(
    entries: list[dict], alpha: float = 0.01, z: float | None = None
) -> list[dict[str, Any]]:
    """Per robot model with two or more calibrated units in the fleet's ``entries`` (each unit's
    latest calibrated session, with its registry record): :func:`compare_model_units`, with
    ``model``. Models with one unit are listed with ``robots`` only (nothing to compare)."""
    out = []
    for model, units in sorted(_latest_units(entries).items()):
        if len(units) < 2:
            out.append({"model": model, "robots": sorted(units), "parameters": [], "off": []})
            continue
        out.append({"model": model, **compare_model_units(units, alpha, z)})
    return out
