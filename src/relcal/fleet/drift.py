"""Did the robot change? The difference of two calibrations and its uncertainty.

Two calibrations ``A`` and ``B`` of one robot estimate the same geometric errors from independent
data, so their difference ``d = p_B - p_A`` over the parameters both determine has covariance
``C = C_A + C_B`` (each record's covariance of its estimated subset,
:func:`relcal.fleet.records.covariance`). Each covariance rests on a noise level estimated from
that session's residuals (the MAD of the translation and of the rotation rows), which is itself
uncertain: with ``r`` residual degrees of freedom (6 per training sample but one, less the
estimated parameters) each level carries about ``0.37 r / 2`` degrees of freedom (the MAD's
efficiency), and the two sessions together ``nu`` (Welch-Satterthwaite). A coincidence
calibration's covariance is scaled by its placements' design effect (placements are clusters,
:func:`relcal.calibration.uncertainty.clustered_covariance`): its degrees of freedom are that
estimate's (``settings.covariance.dof`` of the record, far fewer than the rows'). Two tests, each at
level ``alpha`` (default 0.01):

- over the common identifiable subset, ``T^2 = d^T C^+ d`` with ``k`` the rank of ``C``:
  ``T^2 / k`` against ``F(k, nu)`` (the chi-square test when the noise level is known): are the
  two sessions compatible as a whole?
- per parameter, ``z_i = d_i / sqrt(C_ii)`` against Student's ``t(nu_i)`` with a Bonferroni
  correction over the ``k`` compared parameters (``alpha / k``, two-sided): which one moved?

Drift is flagged when either rejects; with no change, the chance of a false flag is at most
``2 alpha`` (2 % by default). Otherwise the sessions agree, and ``sqrt(C_ii)`` is the
repeatability of each parameter: the smallest change one pair of sessions resolves.

**Both runs on one model.** Model selection may choose different terms for two sessions of an
unchanged robot (a joint scale in one of them, by a small margin). Each run's geometric
parameters are then estimates within different models, and their difference is partly a
difference of models. So when the runs' chosen models differ in their non-geometric families,
the run(s) with more are refitted (the dataset read again and checked against the recorded
hashes, calibrated with the recorded settings) on the **common candidate**: the geometric model
with the families both chose, every identifiable parameter of it estimated (``--selection all``, or
the run's own selection when that one is not determined). Measured on 12 pairs of sessions of a
synthetic A465 with a planted joint scale of 1000 ppm on two joints, one run choosing geometry +
scale and the other geometry alone: compared as recorded, 5 of 12 were flagged; on the common
(geometric) model none, with p-values from 0.08 to 0.95. (On the union, geometry + scale for
both, none was flagged either, but every p-value was 1.00: the recorded standard deviations of
models with joint scales are 4 to 8 times the spread of their estimates over sessions, so a test
on such a model has no power. That is a matter of the calibration's covariance, not of the
drift test.) When a refit is impossible (the dataset moved or changed, or the common model is
not determined by a session), the runs are compared as recorded, over the parameters both
estimated, and a note says so.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.stats

from relcal.calibration.uncertainty import DESIGN_EFFECT
from relcal.errors import RelcalError
from relcal.fleet import ALPHA
from relcal.fleet.registry import Run

MAD_EFFICIENCY = 0.37  # of the median absolute deviation against the standard deviation (normal)


@dataclass(frozen=True)
class ParameterChange:
    """One compared parameter, SI units (``unit`` is ``m`` or ``rad``)."""

    name: str
    unit: str
    a: float
    b: float
    std: float  # of the difference, sqrt(C_A,ii + C_B,ii)
    z: float
    p_value: float  # two-sided, uncorrected
    flagged: bool  # beyond the Bonferroni-corrected threshold

    @property
    def difference(self) -> float:
        return self.b - self.a


NONGEOMETRIC_FAMILIES = ("scale", "compliance", "harmonic")


def families(run: Run) -> tuple[str, ...]:
    """The non-geometric families of the parameters a run estimated (its chosen model's)."""
    found = set()
    for p in run.parameters:
        if p.get("estimated"):
            kind = p["name"].split("[")[0]
            found.add("harmonic" if kind.startswith("harmonic") else kind)
    return tuple(f for f in NONGEOMETRIC_FAMILIES if f in found)


def refit(run: Run, terms: tuple[str, ...]) -> Run:
    """``run`` calibrated again from its dataset with its recorded settings on the geometric
    model plus the non-geometric ``terms`` (every identifiable parameter of it: ``--select
    all``, or the run's own selection when that one is not determined); the run's id, robot,
    session and time kept. Raises :class:`RelcalError` naming why it cannot."""
    from dataclasses import replace
    from pathlib import Path

    from relcal.calibration.pipeline import calibrate
    from relcal.data.dataset import load_dataset
    from relcal.data.imaging import measure
    from relcal.fleet.records import calibration_record, input_hashes
    from relcal.fleet.registry import run_from_record
    from relcal.reporting.documents import results_document

    root = Path(run.dataset_path)
    if not (root / "dataset.yaml").is_file():
        raise RelcalError(f"run {run.id}: its dataset {root} is not there any more")
    dataset = load_dataset(root)
    if input_hashes(root, dataset.images) != run.input_hashes:
        raise RelcalError(f"run {run.id}: its dataset {root} changed since it was calibrated")
    s = run.settings or {}
    options = {
        "holdout": s.get("holdout_fraction", 0.25),
        "seed": s.get("seed", 0),
        "pairing": s.get("pairing") or "all",
        "method": s.get("method", "lm"),
        "loss": s.get("loss", "linear"),
        "keep_outliers": not s.get("reject_outliers", True),  # the recorded settings key
        "nongeometric": list(terms) if terms else "none",
    }
    if s.get("weighting"):
        options["weightings"] = (s["weighting"],)
    m = measure(dataset, workers=1, progress=False)
    failure = None
    for selection in dict.fromkeys(("all", s.get("selection", "cv"))):
        try:
            cal = calibrate(dataset, m, selection=selection, **options)
        except RelcalError as exc:
            failure = exc
            continue
        record = calibration_record(cal, results_document(cal), robot_id=run.robot_id)
        fitted = run_from_record(record, id=run.id)
        return replace(
            fitted,
            uid=run.uid,
            session=run.session,
            created_at=run.created_at,
            outputs_path=run.outputs_path,
        )
    raise RelcalError(f"run {run.id} on the common model: {failure}")


def on_common_model(a: Run, b: Run) -> tuple[Run, Run, str | None, list[str]]:
    """Runs ``a`` and ``b`` on one model: as recorded when their chosen models have the same
    non-geometric families, else the run(s) with more refitted on the geometric model with the
    families both chose (:func:`refit`); the common model's name (None when not refitted) and
    notes."""
    fa, fb = families(a), families(b)
    if fa == fb:
        return a, b, None, []
    common = tuple(f for f in NONGEOMETRIC_FAMILIES if f in fa and f in fb)
    name = " + ".join(("geometric", *common))
    try:
        ra = a if fa == common else refit(a, common)
        rb = b if fb == common else refit(b, common)
    except RelcalError as exc:
        return (
            a,
            b,
            None,
            [
                "the runs chose different models and could not be refitted on a common one "
                f"({exc}): compared as recorded; a difference of model terms may show as drift"
            ],
        )
    done = [f"run {r.id}" for r, f in ((a, fa), (b, fb)) if f != common]
    note = (
        f"the runs chose different models ({_chosen(a)}, {_chosen(b)}): both compared on the "
        f"common model {name} ({' and '.join(done)} refitted from the dataset with the recorded "
        "settings)"
    )
    return ra, rb, name, [note]


def _chosen(run: Run) -> str:
    name = (run.settings or {}).get("chosen_model") or "its model"
    return f"run {run.id}: {name}"


@dataclass(frozen=True)
class Comparison:
    """The outcome of :func:`compare`."""

    run_a: Run
    run_b: Run
    alpha: float
    chi2: float
    dof: int
    p_value: float
    z_threshold: float  # |z| above it flags a parameter (Bonferroni over the compared ones)
    parameters: tuple[ParameterChange, ...]
    left_out: tuple[str, ...]  # estimated in at most one run, or not identifiable in both
    notes: tuple[str, ...] = field(default=())
    noise_dof: float = float("inf")  # degrees of freedom of the noise levels (inf: known)
    one_sided: tuple[str, ...] = ()  # of left_out: estimated in one run, not in the other
    common_model: str | None = None  # the model both were refitted on, when they differed

    @property
    def drift(self) -> bool:
        return self.p_value < self.alpha or any(p.flagged for p in self.parameters)

    @property
    def verdict(self) -> str:
        return "drift" if self.drift else "agree"

    @property
    def flagged(self) -> list[str]:
        return [p.name for p in self.parameters if p.flagged]

    @property
    def labels(self) -> dict[str, str]:
        """``{name: label}`` of both runs (:attr:`Run.labels`; the later run's where both
        name a parameter)."""
        return {**self.run_a.labels, **self.run_b.labels}

    def label(self, name: str) -> str:
        """The name parameter ``name`` is shown by (:func:`relcal.robot.kinematics.parameter_label`,
        as the calibrations showed it)."""
        return self.labels.get(name, name)


def common_parameters(a: Run, b: Run, include_handeye: bool = False) -> tuple[list[str], list[str]]:
    """Names compared (estimated and identifiable in both, hand-eye only if asked) and the names
    left out, in the order of run ``a`` (then those only ``b`` has)."""
    usable_a, usable_b = _usable(a), _usable(b)
    common, left_out = [], []
    in_a = set(a.names)
    for name in [*a.names, *(n for n in b.names if n not in in_a)]:
        if name.startswith("board.") or (name.startswith("handeye.") and not include_handeye):
            left_out.append(name)  # the board moves between sessions: never compared
        elif name in usable_a and name in usable_b:
            common.append(name)
        else:
            left_out.append(name)
    return common, left_out


def one_sided(a: Run, b: Run, include_handeye: bool = False) -> tuple[list[str], list[str]]:
    """Parameters estimated (and identifiable) in ``a`` but not estimated in ``b``, and the other
    way round: where model selection chose different terms for the two runs (e.g. a joint scale
    in one of them)."""
    usable_a, usable_b = _usable(a), _usable(b)
    estimated_a, estimated_b = _estimated(a), _estimated(b)

    def keep(name: str) -> bool:
        return not name.startswith("board.") and (
            include_handeye or not name.startswith("handeye.")
        )

    only_a = [n for n in a.names if n in usable_a and n not in estimated_b and keep(n)]
    only_b = [n for n in b.names if n in usable_b and n not in estimated_a and keep(n)]
    return only_a, only_b


def _estimated(run: Run) -> set[str]:
    return {p["name"] for p in run.parameters if p["estimated"]}


def _usable(run: Run) -> set[str]:
    return {p["name"] for p in run.parameters if p["estimated"] and p["identifiable"]}


def _one_sided_note(a: Run, b: Run, only_a: list[str], only_b: list[str], k: int) -> str:
    """Which parameters one run estimated and the other did not, and what was compared."""

    def model(run: Run) -> str:
        name = (run.settings or {}).get("chosen_model")
        return f" ({name})" if name else ""

    runs = ((a, only_a), (b, only_b))
    parts = [f"run {r.id}{model(r)} only: {', '.join(o)}" for r, o in runs if o]
    return (
        "the runs estimated different parameters (model selection chose different terms): "
        + "; ".join(parts)
        + f"; only the {k} parameters both estimated are compared"
    )


def compare(
    a: Run,
    b: Run,
    alpha: float = ALPHA,
    include_handeye: bool = False,
    common: bool = True,
) -> Comparison:
    """Compare calibration ``b`` with the earlier ``a`` of the same robot model; ``common``:
    on one model (:func:`on_common_model`) when their chosen models differ."""
    if not 0 < alpha < 1:
        raise RelcalError(f"--alpha {alpha}: expected a significance level between 0 and 1")
    if a.model_name != b.model_name:
        raise RelcalError(
            f"runs {a.id} and {b.id} calibrate different robot models ({a.model_name!r} and "
            f"{b.model_name!r}): their parameters do not compare"
        )
    notes, model = [], None
    if common:
        a, b, model, notes = on_common_model(a, b)
    if a.robot_id != b.robot_id:
        notes.append(
            f"different robots ({a.robot_id} and {b.robot_id}): the difference is between two "
            "arms of one model, not a change of one arm"
        )
    names, left_out = common_parameters(a, b, include_handeye)
    if not names:
        raise RelcalError(f"runs {a.id} and {b.id} have no identifiable parameter in common")
    only_a, only_b = one_sided(a, b, include_handeye)
    if only_a or only_b:
        notes.append(_one_sided_note(a, b, only_a, only_b, len(names)))
    sub_a = sorted(n for n in a.covariance["names"] if n in names)
    sub_b = sorted(n for n in b.covariance["names"] if n in names)
    if sub_a != sub_b:  # pragma: no cover - guarded by common_parameters
        raise RelcalError(f"runs {a.id} and {b.id}: covariances miss compared parameters")
    value_a = np.array([a.parameter(n)["value"] for n in names], dtype=float)
    value_b = np.array([b.parameter(n)["value"] for n in names], dtype=float)
    cov_a, nu_a = _estimated_covariance(a, names)
    cov_b, nu_b = _estimated_covariance(b, names)
    cov = cov_a + cov_b
    d = value_b - value_a
    chi2, dof = _chi_square(d, cov)
    # per parameter: Welch-Satterthwaite degrees of freedom of the summed variance
    va, vb = np.diag(cov_a), np.diag(cov_b)
    denom = va**2 / nu_a + vb**2 / nu_b
    nu = np.where(denom > 0, (va + vb) ** 2 / np.where(denom > 0, denom, 1.0), np.inf)
    nu_all = float(np.median(nu)) if np.isfinite(nu).all() else np.inf
    if not dof:
        p_value = 1.0
    elif np.isfinite(nu_all):  # the noise scale is estimated: chi2 / k ~ F(k, nu)
        p_value = float(scipy.stats.f.sf(chi2 / dof, dof, nu_all))
    else:
        p_value = float(scipy.stats.chi2.sf(chi2, dof))
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    z = d / np.where(std > 0, std, np.inf)
    level = alpha / (2 * len(names))
    thresholds = np.where(np.isfinite(nu), scipy.stats.t.isf(level, np.minimum(nu, 1e6)), 0.0)
    thresholds = np.where(np.isfinite(nu), thresholds, scipy.stats.norm.isf(level))
    z_threshold = float(np.median(thresholds))
    changes = tuple(
        ParameterChange(
            name=n,
            unit=a.parameter(n)["unit"],
            a=float(value_a[i]),
            b=float(value_b[i]),
            std=float(std[i]),
            z=float(z[i]),
            p_value=float(2 * _tail(abs(z[i]), nu[i])),
            flagged=bool(abs(z[i]) > thresholds[i]),
        )
        for i, n in enumerate(names)
    )
    if a.settings.get("hayati_joints") != b.settings.get("hayati_joints"):
        notes.append("the runs use different Hayati joints: parameters may not correspond")
    return Comparison(
        a,
        b,
        alpha,
        chi2,
        dof,
        p_value,
        z_threshold,
        changes,
        tuple(left_out),
        tuple(notes),
        nu_all,
        (*only_a, *only_b),
        model,
    )


def _tail(z: float, nu: float) -> float:
    return float(scipy.stats.t.sf(z, nu) if np.isfinite(nu) else scipy.stats.norm.sf(z))


def _estimated_covariance(run: Run, names: list[str]) -> tuple[np.ndarray, float]:
    """A run's covariance of ``names`` and the degrees of freedom of its noise estimate (MAD of
    the translation and of the rotation rows: half the residual degrees of freedom each, at the
    MAD's efficiency); infinite when the record does not say (the noise level taken as known).

    (Scaling the covariance up for the fit's shrinkage of the residuals, ``rows / (rows - k)``,
    made noise-only comparisons too conservative on the synthetic fleets: p-values piled up
    near 1. The records keep ``noise_rows`` for that question.) A covariance scaled by the
    placements' design effect has that estimate's degrees of freedom, when fewer."""
    cov = run.covariance_of(names)
    dof = run.covariance.get("residual_dof")
    nu = np.inf if not dof or dof <= 0 else max(MAD_EFFICIENCY * dof / 2, 1.0)
    clustered = (run.settings or {}).get("covariance") or {}
    if clustered.get("method") == DESIGN_EFFECT and clustered.get("dof"):
        # the variances rest on the placements' design effect, estimated from few clusters
        nu = min(nu, max(float(clustered["dof"]), 1.0))
    return cov, nu


def _chi_square(d: np.ndarray, cov: np.ndarray) -> tuple[float, int]:
    """``d^T C^+ d`` and the rank of ``C``, on unit-diagonal scaling (metres and radians mix)."""
    s = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    unit = cov / np.outer(s, s)
    w, v = np.linalg.eigh(unit)
    keep = w > 1e-10 * max(w.max(initial=0.0), 1e-300)
    y = v[:, keep].T @ (d / s)
    return float(np.sum(y**2 / w[keep])), int(keep.sum())


def display(value: float, unit: str) -> tuple[float, str]:
    """An SI value in the unit people read: mm for lengths, degrees for angles, ppm for scales,
    urad/Nm or um/N for compliances (never a compliance in mm)."""
    from relcal.robot.kinematics import DISPLAY_UNITS

    factor, shown = DISPLAY_UNITS.get(unit, (1.0, unit))
    return float(value) * factor, shown


def consecutive(
    runs: list[Run], alpha: float = ALPHA, common: bool = True
) -> list[Comparison | None]:
    """Each run against the one before it (None for the first, and where they do not compare:
    another robot model, or no common identifiable parameter); ``common``: as :func:`compare`."""
    out: list[Comparison | None] = [None]
    for before, after in zip(runs, runs[1:], strict=False):
        try:
            out.append(compare(before, after, alpha, common=common))
        except RelcalError:
            out.append(None)
    return out[: len(runs)]
