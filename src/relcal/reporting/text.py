"""Every text table and summary that the commands print, for a person (mm and degrees).

The domain modules compute; these functions only format what they return.
"""

from __future__ import annotations

import numpy as np

from relcal.calibration.compensate import Compensation
from relcal.calibration.identify import Result
from relcal.calibration.uncertainty import Accuracy, Uncertainty
from relcal.design.criteria import Quality
from relcal.design.observability import Report
from relcal.design.plan import PlanResult
from relcal.geometry import DEG, MM
from relcal.io import csv_line
from relcal.reporting.documents import accuracy_document
from relcal.robot.kinematics import DISPLAY_UNITS, Layout, parameter_labels, relabel
from relcal.sim.simulate import Simulation
from relcal.sim.study import StudyResult, worst

# --- the published simulation ---------------------------------------------------------------------


def comparison_text(formulation: str, pairing: str) -> str:
    """How the poses are compared, for a heading: ``board formulation (each pose against the
    fitted board frame)``, or ``invariant formulation, all pairs``."""
    if formulation == "board" or pairing == "board":
        return "board formulation (each pose against the fitted board frame)"
    return f"{formulation} formulation, {pairing} pairs"


def simulated_text(sim: Simulation) -> str:
    """What a simulation measured and how it compared it, for a heading: ``relative position
    only, published formulation, consecutive pairs``, or ``position and orientation, board
    formulation (...)``."""
    what = "position only" if sim.measure == "position" else "position and orientation"
    lead = "" if sim.formulation == "board" else "relative "
    return f"{lead}{what}, {comparison_text(sim.formulation, sim.pairing)}"


_KIND_UNITS = {"theta_off": ("dtheta", "deg"), "alpha": ("dalpha", "deg"), "a": ("da", "mm")}
_KIND_UNITS["d"] = ("dd", "mm")


def _display(sim: Simulation, p: int, value: float) -> float:
    """``value`` of parameter ``p`` in the unit a person reads (mm, deg, ppm, urad/Nm)."""
    unit = sim.layout.units()[p]
    if unit in ("m", "rad"):
        return float(np.degrees(value)) if unit == "rad" else value / MM
    return float(value * sim.layout.display()[0][p])


def format_simulation(sim: Simulation) -> str:
    """Per joint the specified and identified errors of theta, alpha, a and d with percent error,
    RMS per kind, then beta/hand-eye rows, rank, residual, iterations, time and the unidentifiable
    combinations. Unidentifiable parameters show ``n/i`` instead of a number."""
    layout, r = sim.layout, sim.result
    where = {(k, i): p for p, (k, i) in enumerate(layout)}
    kinds = ("theta_off", "alpha", "a", "d")
    head = " | ".join(f"{_KIND_UNITS[k][0] + ' (' + _KIND_UNITS[k][1] + ')':^27s}" for k in kinds)
    sub = " | ".join(f"{'specified':>9s} {'identified':>10s} {'err%':>6s}" for _ in kinds)
    lines = [f"joint | {head}", f"      | {sub}"]
    sq_err: dict[str, list[float]] = {k: [] for k in kinds}
    n_joints = sim.problem.model.n_joints
    for j in range(n_joints):
        cells = [_cell(sim, where.get((k, j)), sq_err[k]) for k in kinds]
        lines.append(f"{j + 1:^5d} | " + " | ".join(cells))
    rms = []
    for k in kinds:
        e = sq_err[k]
        rms.append(f"{np.sqrt(np.mean(np.square(e))):>27.3g}" if e else f"{'-':>27s}")
    lines.append("  RMS | " + " | ".join(rms) + "   (identified - specified, identifiable only)")
    extra = [p for p, (k, _) in enumerate(layout) if k not in kinds]
    if extra:
        units = layout.display()[1]
        width = max(4, *(len(units[p]) for p in extra))
        lines.append("")
        lines.append(
            f"{'parameter':<14s} {'unit':>{width}s} {'specified':>10s} {'identified':>10s}"
        )
        for p in extra:
            lines.append(f"{layout.names[p]:<14s} {units[p]:>{width}s} " + _cell(sim, p, None))
    lines += [
        "",
        f"rank {r.identifiability.rank} of {len(r.params)} parameters (scaled Jacobian at the "
        f"nominal model, tolerance {r.identifiability.rcond:g} x the largest singular value); "
        f"the solver's last step kept {r.rank}",
    ]
    if r.identifiability.determined:
        lines.append(
            f"{', '.join(r.identifiability.determined)}: a symmetry of the nominal model only, "
            "determined by the data at the estimate, so estimated too"
        )
    lines += [
        f"{r.n_residuals} measurement rows; "
        f"{'converged' if r.converged else 'NOT converged'} in {r.iterations} iterations, "
        f"{r.seconds * 1e3:.1f} ms",
        f"residual norm {r.initial_residual_norm:.3e} -> {r.residual_norm:.3e} (m and rad)",
    ]
    if r.unidentifiable:
        lines.append("unidentifiable (n/i), with the reason:")
        lines += [f"  - {c}" for c in r.unidentifiable]
    named = {n for c in r.identifiability.combinations for n in c.names}
    curved = [
        n for n, ok in zip(layout.names, r.identifiable, strict=True) if not ok and n not in named
    ]
    if curved:
        lines.append(
            f"  - {', '.join(curved)}: drawn into one of these combinations at the estimate "
            "(the symmetry is curved), so not determined individually"
        )
    return "\n".join(lines)


def _cell(sim: Simulation, p: int | None, errors: list[float] | None) -> str:
    """``specified identified err%`` for parameter ``p`` (blank if not in the model)."""
    if p is None:
        return f"{'(fixed)':>27s}"
    spec = _display(sim, p, sim.specified[p])
    if not sim.result.identifiable[p]:
        return f"{spec:>9.4f} {'n/i':>10s} {'':>6s}"
    ident = _display(sim, p, sim.result.params[p])
    if errors is not None:
        errors.append(ident - spec)
    pct = f"{100 * abs(ident - spec) / abs(spec):6.2f}" if spec != 0 else f"{'-':>6s}"
    return f"{spec:>9.4f} {ident:>10.4f} {pct}"


def format_truth(
    layout: Layout, truth: np.ndarray, result: Result, shown: np.ndarray | None = None
) -> str:
    """True against identified error of the parameters of ``layout`` (mm, deg; ppm, urad/Nm for
    non-geometric terms); ``truth`` ``(layout.size,)`` on the same layout (e.g.
    :meth:`relcal.sim.synth.Truth.errors_on`). ``shown`` masks the rows to print (default: every
    identifiable parameter)."""
    truth = np.asarray(truth, dtype=float)
    if truth.shape != (layout.size,):
        raise ValueError(f"truth has shape {truth.shape}, the layout {layout.size} parameters")
    if shown is None:
        shown = result.identifiable[: layout.size]
    lines = ["", f"{'parameter':<14s} {'unit':>4s} {'true':>9s} {'identified':>10s}"]
    factors, units = layout.display()
    for k, name in enumerate(layout.names):
        if shown[k]:
            scale, unit = factors[k], units[k]
            lines.append(
                f"{name:<14s} {unit:>4s} {truth[k] * scale:9.4f} {result.params[k] * scale:10.4f}"
            )
    return "\n".join(lines)


# --- parameter uncertainty ------------------------------------------------------------------------


def _unit(is_angle: bool, unit: str | None = None) -> tuple[float, str]:
    if unit not in (None, "m", "rad"):
        return DISPLAY_UNITS[unit]  # scale (ppm), compliance (urad/Nm, um/N)
    return (np.degrees(1.0), "deg") if is_angle else (1e3, "mm")


def format_uncertainty(
    unc: Uncertainty,
    accuracy: Accuracy | None = None,
    correlations: int = 8,
    labels: dict[str, str] | None = None,
) -> str:
    """Standard deviation of every estimated parameter (mm, deg) for the noise-weighted estimator
    (the Cramer-Rao bound) and for least squares, the strongest correlations (of the chosen
    estimator) and the predicted accuracy; parameters shown by their ``labels``
    (:func:`relcal.robot.kinematics.parameter_labels`) where given."""
    labels = labels or {}
    crb, ls = unc.crb_std, unc.least_squares_std
    shown = [labels.get(n, n) for n in unc.names]
    w = max([14, *(len(n) for n in shown)])
    lines = [f"{'parameter':<{w}s} {'unit':>4s} {'std CRB':>10s} {'std LS':>10s} {'LS/CRB':>6s}"]
    for p, name in enumerate(shown):
        scale, unit = _unit(bool(unc.is_angle[p]), unc.units[p] if unc.units else None)
        if np.isnan(crb[p]):
            lines.append(f"{name:<{w}s} {unit:>4s} {'not estimated':>21s}")
            continue
        row = f"{name:<{w}s} {unit:>4s} {crb[p] * scale:>10.4g} {ls[p] * scale:>10.4g}"
        row += f" {ls[p] / crb[p]:>6.2f}"
        if not unc.identifiable[p]:
            row += "  (absorbs an unidentifiable combination)"
        lines.append(row)
    strongest = unc.strongest_correlations(correlations)
    if strongest:
        which = "CRB" if unc.estimator == "weighted" else "least squares"
        lines += ["", f"strongest correlations ({which}):"]
        pairs = [(labels.get(a, a), labels.get(b, b), rho) for a, b, rho in strongest]
        lines += [f"  {a:<{w}s} {b:<{w}s} {rho:+.3f}" for a, b, rho in pairs]
    if accuracy is not None:
        s = accuracy_document(accuracy)
        lines += [
            "",
            f"predicted accuracy after calibration ({len(accuracy.pairs)} validation pairs, "
            "RMS over repeated calibrations):",
            f"  position    mean {s['position_mm']['mean']:.4f} mm, p95 "
            f"{s['position_mm']['p95']:.4f} mm, max {s['position_mm']['max']:.4f} mm",
            f"  orientation mean {s['orientation_deg']['mean']:.5f} deg, p95 "
            f"{s['orientation_deg']['p95']:.5f} deg, max {s['orientation_deg']['max']:.5f} deg",
        ]
    return "\n".join(lines)


# --- identifiability report (observability) -------------------------------------------------------


def _wrap(items: list[str], width: int = 96, indent: str = "  ") -> list[str]:
    lines, line = [], indent
    for item in items:
        if len(line) + len(item) + 1 > width and line.strip():
            lines.append(line.rstrip())
            line = indent
        line += item + " "
    if line.strip():
        lines.append(line.rstrip())
    return lines


_FORMULATION_TEXT = {
    "invariant": "frame-invariant formulation",
    "board": "board formulation (board transform W estimated)",
    "published": "published formulation (base-aligned)",
    "absolute": "absolute poses",
}


def format_observability(rep: Report) -> str:
    """The report as text for a person (mm and degrees)."""
    ident = rep.identifiability
    what = "relative position only" if rep.measure == "position" else "relative full pose"
    if rep.formulation == "absolute":
        what = "position only" if rep.measure == "position" else "full pose"
    elif rep.formulation == "board":
        what = "camera position" if rep.measure == "position" else "camera pose"
        what += " against the board"
    he = {"estimated": "hand-eye estimated", "known": "hand-eye known"}[rep.handeye]
    lines = [
        f"{rep.robot}: {_FORMULATION_TEXT[rep.formulation]}, {what}, {he}",
        f"{rep.n_poses} poses, {rep.n_measurements} measurements, {rep.n_rows} rows, "
        f"{len(rep.names)} parameters",
        "",
        "singular values of the identification Jacobian (unit-norm columns), largest first:",
    ]
    s = ident.singular_values
    shown = [f"{v:.3g}" for v in s[: ident.rank]]
    if ident.rank < len(s):
        shown += ["|"] + [f"{v:.1e}" for v in s[ident.rank :]]
    lines += _wrap(shown)
    lines.append(
        f"rank {ident.rank} of {len(s)} (relative tolerance {ident.rcond:g}; values after '|' "
        "are zero up to round-off or too small to identify)"
    )
    ind = rep.indices
    lines += [
        "",
        f"observability indices of the identifiable subset ({len(ident.subset)} parameters, "
        f"m = {rep.n_measurements}):",
        f"  O1 Borm-Menq (prod s)^(1/L)/sqrt(m)      {ind.O1:.4g}",
        f"  O2 inverse condition number s_min/s_max  {ind.O2:.4g}"
        f"   (condition number {ind.condition_number:.4g})",
        f"  O3 minimum singular value s_min          {ind.O3:.4g}",
        f"  O4 noise amplification s_min^2/s_max     {ind.O4:.4g}",
        f"  O5 1 / sum(1/s_i)                        {ind.O5:.4g}",
        "",
        f"identifiable subset (QR with column pivoting), {len(ident.subset)} parameters:",
    ]
    lines += _wrap([rep.label(rep.names[k]) for k in ident.subset])
    if rep.not_estimated:
        lines.append("not estimated (held at nominal; each is part of a combination below):")
        lines += _wrap([rep.label(n) for n in rep.not_estimated])
    if ident.combinations:
        lines += ["", "unidentifiable combinations, with the reason:"]
        lines += [f"  - {relabel(c.describe(), rep.labels)}" for c in ident.combinations]
    else:
        lines += ["", "every parameter is identifiable"]
    for p in rep.parallel:
        a, b = p.joints
        lines.append("")
        if p.hayati:
            lines.append(
                f"parallel axes {a} and {b} ({p.angle_deg:.3g} deg apart): Hayati's beta[{a}] "
                f"replaces d[{a}], so the pair is resolved"
            )
            continue
        lines.append(
            f"parallel axes {a} and {b} ({p.angle_deg:.3g} deg apart): with standard DH d[{a}] "
            f"and d[{b}] are inseparable (only their sum is identifiable)."
        )
        if p.std_d is not None:
            lines.append(
                f"  Real axes are never exactly parallel: {p.misalignment_deg:g} deg off, both "
                f"count as identifiable and their standard deviations explode to "
                f"{p.std_d[0] * 1e3:.3g} mm and {p.std_d[1] * 1e3:.3g} mm at this noise."
            )
        lines.append("  Cure: --hayati auto (Hayati's beta for the pair), or hayati: true in YAML")
    if rep.uncertainty is not None and rep.noise is not None:
        n = rep.noise
        lines += [
            "",
            f"uncertainty with noise {n.position * 1e3:g} mm, {n.orientation / DEG:g} deg per "
            f"pose, {np.max(n.joints) / DEG:g} deg per joint reading "
            f"({rep.uncertainty.estimator.replace('_', ' ')} estimator):",
            format_uncertainty(rep.uncertainty, rep.accuracy, labels=rep.labels),
        ]
    return "\n".join(lines)


# --- pose plan ------------------------------------------------------------------------------------


def _quality_row(label: str, q: Quality, labels: dict[str, str] | None = None) -> str:
    name, eq = q.worst
    name = (labels or {}).get(name, name)
    ln, lv = q.worst_length
    an, av = q.worst_angle
    acc = ""
    if q.accuracy is not None:
        s = accuracy_document(q.accuracy)
        acc = (
            f" {s['position_mm']['mean']:>8.4f} {s['position_mm']['p95']:>8.4f}"
            f" {s['orientation_deg']['mean']:>9.5f}"
        )
    return (
        f"{label:<22s} {eq * 1e3:>8.4f} {name:<13s} {q.median * 1e3:>8.4f} {lv * 1e3:>8.4f} "
        f"{np.degrees(av):>9.5f} {q.indices.O1:>7.3g}{acc}"
    )


def format_motion(res: PlanResult) -> list[str]:
    """A hand-eye plan (``--for handeye``): the predicted standard deviations of ``X`` in the
    flange frame and the spread of the motions, for the plan and the median random set."""
    head = (
        "hand-eye X, the board on the flange (flange frame; Cramer-Rao bound, kinematics known, "
        "camera pose eliminated):"
        if res.mode == "eye_to_hand"
        else "hand-eye X (flange frame; Cramer-Rao bound, kinematics known, board pose eliminated):"
    )
    lines = [
        head,
        f"{'':<22s} {'std x y z mm':>26s} {'std about x y z deg':>26s} {'axis spread':>12s} "
        f"{'pair turns deg':>15s} {'pairs':>6s}",
    ]
    rows = [("plan", res.motion)]
    if res.random_motion is not None:
        rows.append((f"random (median of {len(res.random)})", res.random_motion))
    for label, m in rows:
        xyz = " ".join(f"{v * 1e3:8.4f}" for v in m.xyz_std)
        rot = " ".join(f"{np.degrees(v):8.5f}" for v in m.rotation_std)
        spread = f"{m.axis_spread[1]:.2f} {m.axis_spread[2]:.2f}"
        turns = f"{np.degrees(m.min_rotation):.1f}..{np.degrees(m.max_rotation):.1f}"
        lines.append(
            f"{label:<22s} {xyz:>26s} {rot:>26s} {spread:>12s} {turns:>15s} {m.bad_pairs:>6d}"
        )
    lines.append(
        "axis spread: the second and third singular values of the pairs' rotation vectors over "
        "the first (0: every motion turns about one or two axes); pairs: turning near 180 deg "
        "or barely moving (the closed forms leave such samples out)"
    )
    fixed = [(label, m.camera_std) for label, m in rows if m.camera_std is not None]
    if fixed:
        lines += [
            "what eye-to-hand delivers, the fixed camera in the base frame (Cramer-Rao bound):",
            f"{'':<22s} {'std x y z mm':>26s} {'std about x y z deg':>26s}",
        ]
        for label, (xyz, rot) in fixed:
            xyz_text = " ".join(f"{v * 1e3:8.4f}" for v in xyz)
            rot_text = " ".join(f"{np.degrees(v):8.5f}" for v in rot)
            lines.append(f"{label:<22s} {xyz_text:>26s} {rot_text:>26s}")
    return lines


def format_travel(res: PlanResult, model=None) -> str:
    """One line: the route's longest single joint move and the sum of the largest joint moves
    (``model`` names the joints and tells prismatic ones)."""
    route = res.route
    move, joint, value = route.longest
    prismatic = model is not None and bool(model.prismatic[joint])
    unit, f = ("m", 1.0) if prismatic else ("deg", np.degrees(1.0))
    name = model.joint_names[joint] if model is not None else f"q{joint + 1}"
    line = (
        f"travel order: longest single move {value * f:.1f} {unit} ({name}, pose {move + 1} to "
        f"{move + 2}); largest joint moves add up to {route.total * np.degrees(1.0):.0f} deg"
    )
    if route.max_move is None:
        return line
    bound = f"{np.degrees(route.max_move):.0f} deg"
    over = route.over
    if len(over):
        names = model.joint_names if model is not None else [f"q{j + 1}" for j in range(99)]
        shown = ", ".join(
            f"{names[j]} {np.degrees(route.moves[m, j]):.1f} deg (pose {m + 1} to {m + 2})"
            for m, j in over[:3]
        )
        line += (
            f"\nwarning: {len(over)} joint move(s) beyond the bound of {bound}: {shown}; more "
            "candidates (--n-candidates) or a larger --max-move"
        )
    else:
        line += f"; every joint move within {bound}"
    notes = []
    if res.move_exchanges:
        notes.append(f"{res.move_exchanges} pose(s) exchanged")
    if res.requested and len(res.q) > res.requested:
        notes.append(f"{len(res.q) - res.requested} pose(s) added between poses")
    if notes:
        line += f" ({' and '.join(notes)} to keep the moves within {bound})"
    return line


def format_plan(res: PlanResult, length_scale: float, model=None) -> str:
    """The plan against random sets: predicted standard deviations and accuracy (parameters
    named as ``model`` names them, :func:`relcal.robot.kinematics.parameter_labels`)."""
    k = len(res.q)
    labels = {}
    if model is not None:
        labels = parameter_labels(model, res.plan.uncertainty.names)
    lines = [
        f"{k} poses selected from {res.n_candidates} feasible candidates by {res.algorithm} "
        f"({res.swaps} exchanges) maximising {res.criterion}"
        + (" of the hand-eye X alone" if res.purpose == "handeye" else "")
        + f", {res.seconds:.1f} s",
        "rejected IK solutions: " + ", ".join(f"{n} {c}" for n, c in res.rejected.items()),
        "",
        f"predicted standard deviations (noise-weighted estimator, Cramer-Rao bound); angles "
        f"count as the displacement {length_scale:g} m away:",
        f"{'':<22s} {'worst':>8s} {'(param)':<13s} {'median':>8s} {'worst mm':>8s} "
        f"{'worst deg':>9s} {'O1':>7s} {'acc mean':>8s} {'acc p95':>8s} {'acc deg':>9s}",
        f"{'':<22s} {'mm':>8s} {'':<13s} {'mm':>8s} {'length':>8s} {'angle':>9s} {'':>7s} "
        f"{'mm':>8s} {'mm':>8s} {'mean':>9s}",
        _quality_row("plan", res.plan, labels),
    ]
    if res.random:
        worst = np.array([r.worst[1] for r in res.random])
        median_set = res.random[int(np.argsort(worst)[len(worst) // 2])]
        best_set = res.random[int(np.argmin(worst))]
        lines += [
            _quality_row(f"random (median of {len(res.random)})", median_set, labels),
            _quality_row("random (best)", best_set, labels),
            "",
            f"worst-parameter std: plan {res.plan.worst[1] * 1e3:.4f} mm, random sets median "
            f"{res.random_median_worst * 1e3:.4f} mm: {res.improvement:.2f}x lower",
        ]
    lines += [
        "predicted accuracy: RMS error of relative camera poses between validation poses "
        "caused by the parameter uncertainty alone",
    ]
    if res.motion is not None:
        lines += ["", *format_motion(res)]
    if res.route is not None and len(res.q) > 1:
        lines.append(format_travel(res, model))
    if res.random:
        lines += ["", *_parameter_table(res.plan, median_set, len(res.random), labels)]
    return "\n".join(lines)


def _parameter_table(
    plan_q: Quality, random_q: Quality, n_sets: int, labels: dict[str, str] | None = None
) -> list[str]:
    """Per estimated parameter (shown by its label): predicted std for the plan and the median
    random set."""
    a, b = plan_q.uncertainty, random_q.uncertainty
    shown = [(labels or {}).get(n, n) for n in a.names]
    w = max([14, *(len(shown[p]) for p in a.subset)])
    lines = [
        f"{'parameter':<{w}s} {'unit':>4s} {'plan':>10s} {'random':>10s} {'ratio':>6s}"
        f"   (predicted std; random = the median of {n_sets} sets)"
    ]
    for p in a.subset:
        scale, unit = _unit(bool(a.is_angle[p]), a.units[p] if a.units else None)
        sa, sb = a.crb_std[p], b.crb_std[p]
        lines.append(
            f"{shown[p]:<{w}s} {unit:>4s} {sa * scale:>10.4g} {sb * scale:>10.4g} {sb / sa:>6.2f}"
        )
    return lines


# --- Monte Carlo study ----------------------------------------------------------------------------


def format_study(res: StudyResult, length_scale: float = 0.5) -> str:
    """Per parameter: predicted and empirical standard deviation, their ratio, the bias in
    standard errors; then the overall ratio, the worst parameter and the bias test."""
    lo, hi = res.ratio_interval()
    lines = [
        f"{'parameter':<14s} {'unit':>4s} {'predicted':>10s} {'empirical':>10s} {'ratio':>6s} "
        f"{'bias/se':>7s}"
    ]
    for k, p in enumerate(res.subset):
        angle = bool(res.is_angle[p])
        units = res.predicted.units
        scale, unit = _unit(angle, units[p] if units else None)  # urad/Nm, ppm: never mm
        flag = "" if lo <= res.ratio[k] <= hi else "  outside 95% interval"
        if not res.predicted.identifiable[p]:
            flag += "  (absorbs an unidentifiable combination)"
        lines.append(
            f"{res.names[p]:<14s} {unit:>4s} {res.predicted_std[k] * scale:>10.4g} "
            f"{res.empirical_std[k] * scale:>10.4g} {res.ratio[k]:>6.3f} {res.bias_t[k]:>+7.2f}"
            + flag
        )
    chi2, p = res.bias_test()
    wp, pv, we, ev = worst(res, length_scale)
    what = "Cramer-Rao bound" if res.estimator == "weighted" else "least-squares covariance"
    outside = int(np.sum((res.ratio < lo) | (res.ratio > hi)))
    lines += [
        "",
        f"{res.trials} trials ({int(res.converged.sum())} converged), {res.sampling} sampling, "
        f"{res.estimator} estimator, predicted = {what}, {res.seconds:.1f} s",
        f"empirical / predicted std: overall {res.overall_ratio:.3f}, per parameter "
        f"{res.ratio.min():.3f} .. {res.ratio.max():.3f}, max |ratio - 1| "
        f"{np.abs(res.ratio - 1).max():.3f}",
        f"  {outside} of {len(res.ratio)} outside the 95% sampling interval "
        f"[{lo:.3f}, {hi:.3f}] of {res.trials} independent trials",
        f"worst parameter (angles x {length_scale:g} m): predicted {wp} {pv * 1e3:.4f} mm, "
        f"empirical {we} {ev * 1e3:.4f} mm",
        f"bias: max |mean - noise-free| = {np.abs(res.bias_t).max():.2f} standard errors; "
        f"chi-square {chi2:.1f} on {len(res.subset)} dof, p = {p:.3f}"
        + (" (unbiased)" if p > 0.01 else " (BIASED)"),
    ]
    return "\n".join(lines)


# --- calibration ----------------------------------------------------------------------------------


def pose_noise_parts(noise: dict) -> tuple[str, str, str]:
    """The learned pose noise of a results document as text: the standard deviations in mm and
    in deg (comma-separated) and the largest translation-rotation correlation."""
    mm = ", ".join(f"{v:.3g}" for v in noise["std_mm"])
    deg = ", ".join(f"{v:.3g}" for v in noise["std_deg"])
    return mm, deg, f"{noise['max_translation_rotation_correlation']:.2f}"


def _ratio_text(ratio: dict) -> str:
    lo, hi = ratio["ci95"]
    return f"x{ratio['after_over_before']:.3g}, 95% interval {lo:.3g}..{hi:.3g}"


def placement_lines(val: dict, what: str) -> list[str]:
    """Held-out placements of coincidence data (:func:`documents.placement_document`): the
    spread of the predicted points and the distance error, baseline against calibrated."""
    lines = [
        f"{what} ({val['n_samples']} samples of {val['n_groups']} groups; their points refitted, "
        "kinematics and tool point frozen), RMS / max mm:"
    ]
    for key, label in (("spread_mm", "spread of the points"), ("distance_error_mm", "distance")):
        b, a = val["baseline"][key], val["calibrated"][key]
        if b is None or a is None:
            continue
        line = (
            f"  {label:<20} baseline (nominal, tool point and points fitted) {b['rms']:.3f} / "
            f"{b['max']:.3f}, calibrated {a['rms']:.3f} / {a['max']:.3f}"
        )
        if key == "spread_mm":
            line += f" ({_ratio_text(val['ratio_to_baseline']['spread_mm'])} of the baseline)"
        lines.append(line)
    return lines


def calibration_summary(doc: dict) -> str:
    """The terminal summary: the chosen model and why, held-out errors against the baselines,
    the parameters with their standard deviations, and what the data cannot determine."""
    ident = doc["identification"]
    lines = [
        f"{doc['robot']}: {doc['n_used']} of {doc['n_samples']} samples used, "
        f"{len(doc['held_out_ids'])} held out",
    ]
    lines += coverage_lines(doc["settings"].get("coverage"))
    formulation = doc["settings"].get("formulation")
    points = formulation in ("tracker", "coincidence")
    frames = {
        "tracker": "the instrument transform and marker",
        "coincidence": "the tool point and the group points",
    }.get(formulation, "the hand-eye transform")
    sel = doc.get("model_selection")
    if sel and sel.get("candidates"):
        lines.append(
            f"model selection ({sel['folds']}-fold cross-validation on the training samples):"
        )
        for c in sel["candidates"]:
            mark = "*" if c["chosen"] else " "
            lines.append(
                f"  {mark} {c['name']:<32} {c['weighting']:<12} {c['n_params']:>3} parameters  "
                f"held-out position RMS {c['cv_position_rms_mm']:.4f} mm"
                + (
                    f", orientation {c['cv_orientation_rms_deg']:.4f} deg"
                    if c["cv_orientation_rms_deg"] is not None
                    else ""
                )
            )
        lines.append(f"  chosen: {sel['chosen']} ({sel['weighting']}): {sel['reason']}")
        if sel["exported"] == "baseline":
            reason = sel.get("export_reason") or "the data support no kinematic correction"
            lines.append(
                f"  {reason}: the exported model is the nominal kinematics with {frames} fitted"
            )
    lines.append(identification_line(ident))
    val = doc["validation"]
    if val and val.get("held_out") == "placements":
        lines += placement_lines(val, "held-out placements " + ", ".join(val["placements"]))
    elif val:
        base = "baseline" if "baseline" in val else "baseline_handeye_guess"
        for key, unit in (("position_mm", "mm"), ("orientation_deg", "deg")):
            if key not in val["calibrated"]:
                continue
            g, b, a = val["baseline_handeye_guess"][key], val[base][key], val["calibrated"][key]
            if points:
                what = f"absolute {key.split('_')[0]} error over {val['n_samples']} points"
                guesses, fitted = "instrument and marker guesses", "instrument and marker fitted"
            elif val.get("held_out") == "poses":
                what = (
                    f"{key.split('_')[0]} error of the poses in the world frame over "
                    f"{configurations(val)}"
                )
                guesses, fitted = "frame guesses", "hand-eye and world fitted"
            else:
                what = (
                    f"relative {key.split('_')[0]} error over {val['n_pairs']} pairs of "
                    f"{val['n_samples']} samples"
                )
                guesses, fitted = "hand-eye guess", "hand-eye fitted"
            lines.append(
                f"held-out {what}, RMS: nominal with the {guesses} {g['rms']:.3f}, "
                f"baseline (nominal, {fitted}) {b['rms']:.3f}, calibrated {a['rms']:.3f} "
                f"{unit} ({_ratio_text(val['ratio_to_baseline'][key])} of the baseline)"
            )
    shown = [r for r in doc["parameters"] if r["status"] in ("estimated", "combination")]
    labels = doc.get("parameter_labels") or {}
    width = max([14, *(len(r.get("label", r["name"])) for r in shown)])
    if shown:
        lines.append("parameters (error from nominal +- std; bootstrap std; |error| / std):")
        for r in shown:
            boot = f"{r['bootstrap_std']:.3g}" if r["bootstrap_std"] is not None else "-"
            std = f"{r['std']:.3g}" if r["std"] is not None else "-"
            sig = f"{r['significance']:.1f}" if r["significance"] is not None else "-"
            note = "  (carries a combination)" if r["status"] == "combination" else ""
            lines.append(
                f"  {r.get('label', r['name']):<{width}} {r['error']:+.4g} +- {std} {r['unit']}"
                f"  bootstrap {boot}  z {sig}{note}"
            )
    for c in doc.get("identifiable_combinations", []):
        std = f" +- {c['std']:.3g}" if c["std"] is not None else ""
        text = relabel(c["text"], labels)
        lines.append(f"  {text} = {c['value']:+.4g}{std} {c['unit']} (identifiable sum)")
    noise = doc.get("noise_model")
    if noise:
        mm, deg, rho = pose_noise_parts(noise)
        lines.append(
            f"learned pose noise (camera frame): std {mm} mm, {deg} deg; largest "
            f"translation-rotation correlation {rho}"
        )
    if doc["rejected"]:
        lines.append(f"rejected frames ({len(doc['rejected'])}):")
        lines.extend(f"  {r['id']}: {r['reason']}" for r in doc["rejected"])
    if doc["outliers"]:
        fit = "they fit badly" if points else "their pairs fit badly"
        lines.append(
            f"outliers ({fit}; left out unless --keep-outliers): " + ", ".join(doc["outliers"])
        )
    if doc.get("held_out_outliers"):
        lines.append(
            "held-out outliers (they fit badly under the baseline and the calibrated model "
            "alike: a wrong row? check them; left out of the held-out errors unless "
            "--keep-outliers): " + ", ".join(doc["held_out_outliers"])
        )
    cv = doc.get("cross_validation")
    if cv and cv["pooled"].get("held_out") == "placements":
        lines += placement_lines(cv["pooled"], f"{cv['k']}-fold cross-validation over placements")
        lines.append("  chosen per fold: " + ", ".join(cv["chosen"]))
    elif cv:
        pooled = cv["pooled"]
        base = "baseline" if "baseline" in pooled else "baseline_handeye_guess"
        b, a = pooled[base]["position_mm"], pooled["calibrated"]["position_mm"]
        held = pooled.get("held_out", "points" if points else "pairs of poses")
        count = pooled["n_samples"] if held in ("points", "poses") else pooled["n_pairs"]
        lines.append(
            f"{cv['k']}-fold cross-validation over {count} held-out "
            f"{'pairs' if held == 'pairs of poses' else held}: position "
            f"RMS baseline {b['rms']:.3f} -> calibrated {a['rms']:.3f} mm "
            f"({_ratio_text(pooled['ratio_to_baseline']['position_mm'])}); chosen per fold: "
            + ", ".join(cv["chosen"])
        )
    for name, entry in ((cv or {}).get("artifacts") or {}).items():
        lines.append(
            f"  {name} ({entry['holds']}) over the folds: {entry['position_rms_mm']:.3f} mm "
            f"({_ratio_text(entry['ratio_to_baseline'])} of the baseline)"
        )
    for text in ident["unidentifiable"]:
        lines.append(f"  not identifiable: {relabel(text, labels)}")
    for text in ident.get("weak_directions", []):
        lines.append(f"  weakly determined: {text}")
    for text in ident.get("dropped_candidates", []):
        lines.append(f"  candidates dropped: {text}")
    for text in ident.get("plausibility_warnings", []):
        lines.append(f"  plausibility warning: {text}")
    lines += artifact_lines(doc.get("artifacts"))
    lines += verdict_lines(doc.get("verdict"))
    return "\n".join(lines)


def configurations(val: dict) -> str:
    """``12 held-out samples`` or ``30 held-out samples in 10 distinct configurations``."""
    n, k = val["n_samples"], val.get("n_configurations", val["n_samples"])
    text = f"{n} held-out sample{'s' if n != 1 else ''}"
    if k != n:
        text += f" in {k} distinct configuration{'s' if k != 1 else ''}"
    return text


def coverage_lines(cov: dict | None) -> list[str]:
    """What the samples cover (:func:`relcal.calibration.coverage.describe`): repeated
    configurations, joints that never moved, singular samples."""
    if not cov:
        return []
    lines = []
    if cov["repeated_samples"]:
        lines.append(
            f"  {cov['configurations']} distinct configurations ({cov['repeated_samples']} "
            "samples repeat one: held out together with it)"
        )
    for j in cov["still_joints"]:
        lines.append(
            f"  joint {j['joint']} ({j['name']}) never moved: at {j['value']:.1f} {j['unit']} in "
            "every sample"
        )
    singular = cov["singular_samples"]
    if singular:
        shown = ", ".join(singular[:5]) + (", ..." if len(singular) > 5 else "")
        lines.append(
            f"  {len(singular)} sample(s) at a singular configuration (the flange Jacobian loses "
            f"rank): {shown}"
        )
    return lines


def identification_line(ident: dict) -> str:
    """The identification in one line: the rank of the identification Jacobian (the one rank
    figure every output shows), how many parameters the chosen model estimates, convergence and
    the weighted residual RMS with its unit."""
    estimated = ident.get("n_estimated")
    chosen = f", {estimated} estimated in the chosen model" if estimated is not None else ""
    unit = ident.get("residual_unit", "weighted rows")
    return (
        f"identification: rank {ident['rank']} of {ident['n_params']} parameters{chosen}; "
        f"{'converged' if ident['converged'] else 'NOT converged'}; weighted residual RMS "
        f"{ident['initial_residual_rms']:.3g} -> {ident['residual_rms']:.3g} {unit}"
    )


def artifact_text(entry: dict) -> str:
    """One loadable file and its own held-out error: ``robot.urdf (geometry only, refitted):
    12.0 mm (x0.39 of the baseline)``, or why it was not written."""
    what = entry["holds"] + (", refitted" if entry["model"] == "geometry-only refit" else "")
    held = entry["held_out"]
    if held is None:
        shown = "no held-out error (no held-out samples)"
    else:
        key = "spread_mm" if "spread_mm" in held["ratio_to_baseline"] else "position_mm"
        ratio = held["ratio_to_baseline"][key]
        shown = f"{held['position_rms_mm']:.3f} mm ({_ratio_text(ratio)} of the baseline)"
    if not entry["written"]:
        shown += f"; NOT WRITTEN: {entry['refused']}"
    return f"{entry['file']} ({what}): {shown}"


def artifact_lines(doc: dict | None) -> list[str]:
    """Every loadable file with its own held-out RMS, measured on the file read back."""
    if not doc or not doc.get("files"):
        return []
    lines = ["each file's own held-out RMS (measured on its bytes read back by a loader):"]
    lines += [f"  {artifact_text(f)}" for f in doc["files"]]
    if doc.get("geometry_is_validated_model"):
        lines.append(
            "  the geometry-only files hold the validated model itself (no non-geometric term "
            "chosen; nothing refitted)"
        )
    else:
        lines.append(
            "  the geometry-only files cannot hold the chosen model's non-geometric terms: they "
            "hold the geometry refitted without them; use model.yaml (relcal compensate) for the "
            "validated accuracy"
        )
    return lines


def verdict_lines(v: dict | None) -> list[str]:
    """The verdict last, after its warnings."""
    if not v:
        return []
    return [f"warning: {w}" for w in v["warnings"]] + [f"verdict: {v['text']}"]


# --- compensation ---------------------------------------------------------------------------------


def compensation_csv(
    ids: list[str],
    q: np.ndarray,
    comp: Compensation,
    dq: np.ndarray | None,
    status: list[str] | None = None,
) -> str:
    """The output CSV: corrected joints ``q`` and corrections ``dq`` (display units) per id, and
    with ``status`` a last column saying why a target has none (empty cells: not written)."""

    def cell(v: float, digits: str) -> str:
        return f"{v:{digits}}" if np.isfinite(v) else ""

    n = q.shape[1]
    header = ["id", *[f"q{i + 1}" for i in range(n)], "converged"]
    if dq is not None:
        header += [f"dq{i + 1}" for i in range(n)]
        header += ["predicted_position_mm", "predicted_rotation_deg"]
    if status is not None:
        header.append("status")
    lines = [csv_line(header)]
    for k, sid in enumerate(ids):
        cells = [sid, *[cell(v, ".10g") for v in q[k]], str(bool(comp.converged[k]))]
        if dq is not None:
            cells += [cell(v, ".6g") for v in dq[k]]
            cells += [
                f"{comp.predicted_position_mm[k]:.6g}",
                f"{comp.predicted_rotation_deg[k]:.6g}",
            ]
        if status is not None:
            cells.append(status[k])
        lines.append(csv_line(cells))
    return "\n".join(lines) + "\n"


# --- verification ---------------------------------------------------------------------------------


def _with_interval(summary: dict, digits: str = ".3f") -> str:
    ci = summary.get("ci95")
    shown = f"{summary['rms']:{digits}}"
    return shown + (f" ({ci[0]:{digits}}..{ci[1]:{digits}})" if ci else "")


def _range_unit(entry: dict) -> tuple[float, str]:
    return (1e3, "mm") if entry["unit"] == "m" else (float(np.degrees(1.0)), "deg")


def verification_text(doc: dict, per_sample: bool = True) -> str:
    """The terminal output of ``relcal verify``: what was verified on which session and how, the
    error of every sample under both models, the RMS errors with their intervals, the ratio to
    the baseline and to the calibration's held-out error, warnings, and the verdict last."""
    cal, ses, nui = doc["calibration"], doc["session"], doc["nuisance"]
    points = ses["kind"] != "pose"
    what = {"pose": "poses", "position": "points", "coincidence": "coincidence samples"}
    lines = [
        f"calibration: {cal['source']}"
        + (f" ({cal['chosen_model']})" if cal.get("chosen_model") else ""),
        f"session: {ses['dataset']} (robot {ses['robot_id']}): {ses['n_evaluated']} of "
        f"{ses['n_samples']} {what[ses['kind']]} evaluated",
        f"refitted for both models: {nui['refitted']}; frozen: {nui['frozen']}",
        f"how: {nui['scheme']}",
    ]
    rows = doc["samples"]
    if per_sample and rows:
        orient = any(r["baseline_deg"] is not None for r in rows)
        head = ["id", "fold", "baseline mm", "calibrated mm"]
        if orient:
            head += ["baseline deg", "calibrated deg"]
        head.append("outside the covered range" if doc["joint_ranges"]["checked"] else "")
        names = {o["index"]: o["joint"] for o in doc["joint_ranges"]["outside"]}
        table = [head]
        for r in rows:
            cells = [r["id"], str(r["fold"] + 1), f"{r['baseline_mm']:.3f}"]
            cells.append(f"{r['calibrated_mm']:.3f}")
            if orient:
                cells += [f"{r['baseline_deg']:.4f}", f"{r['calibrated_deg']:.4f}"]
            cells.append(", ".join(names.get(j, str(j + 1)) for j in r.get("outside_range", [])))
            table.append(cells)
        widths = [max(len(t[k]) for t in table) for k in range(len(head))]
        lines.append("")
        lines.append(
            "per sample ("
            + ("error of the point" if points else "RMS over its pairs in its fold")
            + "; fold of the cross-fitting):"
        )
        for t in table:
            lines.append(
                "  "
                + "  ".join(
                    c.ljust(w) if k in (0, len(head) - 1) else c.rjust(w)
                    for k, (c, w) in enumerate(zip(t, widths, strict=True))
                ).rstrip()
            )
    lines.append("")
    n = ses["n_evaluated"]
    over = f"{n} points" if points else f"pairs within folds of {n} samples"
    lines.append(f"overall (RMS over {over}, 95% intervals from a bootstrap over samples):")
    base, after, ratio = doc["baseline"], doc["calibrated"], doc["ratio_to_baseline"]
    for key, unit, digits in (("position_mm", "mm", ".3f"), ("orientation_deg", "deg", ".4f")):
        if key not in ratio:
            continue
        r = ratio[key]
        lines.append(
            f"  {key.split('_')[0]:<11}  baseline (nominal) {_with_interval(base[key], digits)} "
            f"{unit}  calibrated {_with_interval(after[key], digits)} {unit}  ratio "
            f"x{r['after_over_before']:.3f} ({r['ci95'][0]:.3f}..{r['ci95'][1]:.3f})"
        )
    at, to = doc.get("at_calibration"), doc.get("ratio_to_calibration")
    if at and to:
        for key, unit, digits in (("position_mm", "mm", ".3f"), ("orientation_deg", "deg", ".4f")):
            if key not in to:
                continue
            ref, r = at[key], to[key]
            count = f", {ref['n_samples']} samples" if ref.get("n_samples") else ""
            lines.append(
                f"  at calibration (its own held-out {key.split('_')[0]}{count}): "
                f"{_with_interval(ref, digits)} {unit}; on this session x{r['ratio']:.2f} "
                f"(99% interval {r['ci99'][0]:.2f}..{r['ci99'][1]:.2f})"
            )
    elif not at:
        why = "see the note below" if cal.get("notes") else "calibrated with --holdout 0?"
        lines.append(f"  at calibration: no comparable held-out error ({why})")
    ranges = doc["joint_ranges"]
    if not ranges["checked"]:
        lines.append(f"joint ranges not checked: {ranges['source']}")
    for o in ranges["outside"]:
        scale, unit = _range_unit(o)
        lo, hi = (v * scale for v in o["covered"])
        lines.append(
            f"  {o['joint']}: {o['n_samples']} sample(s) outside the covered {lo:.1f}..{hi:.1f} "
            f"{unit}, up to {o['largest_excess'] * scale:.1f} {unit} beyond"
        )
    lines += [f"warning: {w}" for w in doc["warnings"]]
    lines += [f"note: {w}" for w in doc["calibration"].get("notes", [])]
    v = doc["verdict"]
    label = {"holds": "HOLDS", "degraded": "DEGRADED", "inconclusive": "INCONCLUSIVE"}
    lines.append(f"verdict: {label.get(v['code'], 'WORSE')}: {v['reason']}")
    return "\n".join(lines)
