"""Manufacturing tolerances of a robot's parameters: the priors that hold weakly determined
directions.

A calibration estimates errors from nominal. Where the data barely determine a direction (a
joint that hardly moved, two axes nearly parallel), a plain least-squares estimate wanders by
centimetres or tens of degrees along it; a machined arm is not off by that much. The priors say
how far each kind of parameter plausibly is from its nominal value (one standard deviation), and
the fit becomes a maximum a posteriori estimate: one residual row ``error / std`` per estimated
parameter is appended to the data's rows. ``priors: none`` in the model file switches them off
(the plain least squares).

In a model file::

    priors:              # one standard deviation of the error from nominal, per kind
      length_mm: 1       # a, d, URDF origin x, y, z, prismatic zero offsets
      angle_deg: 0.5     # alpha, beta, URDF origin rx, ry, rz
      offset_deg: 1      # joint zero offsets (theta_off)
      scale_ppm: 10000   # joint scale
      compliance_deg_per_nm: 0.5
      harmonic_deg: 0.5

or ``priors: none``. Keys left out take the defaults above. The measurement frames (hand-eye,
a tracker's instrument transform and marker, a coincidence's tool point and group points) and
the base and tool frames have no prior: they are nuisance frames, free by design.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from relcal.errors import RelcalError

# Display units of each key: factor from the display value to SI.
_UNITS = {
    "length_mm": 1e-3,
    "angle_deg": np.pi / 180,
    "offset_deg": np.pi / 180,
    "scale_ppm": 1e-6,
    "compliance_deg_per_nm": np.pi / 180,
    "harmonic_deg": np.pi / 180,
}


@dataclass(frozen=True)
class Priors:
    """One standard deviation of each kind of parameter error from nominal (display units:
    mm, deg, ppm, deg/(N m)); ``enabled=False`` is ``priors: none``."""

    length_mm: float = 1.0
    angle_deg: float = 0.5
    offset_deg: float = 1.0
    scale_ppm: float = 10000.0
    compliance_deg_per_nm: float = 0.5
    harmonic_deg: float = 0.5
    enabled: bool = True

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name == "enabled":
                continue
            v = getattr(self, f.name)
            number = isinstance(v, int | float) and not isinstance(v, bool)
            if not number or not np.isfinite(v) or v <= 0:
                raise RelcalError(f"priors: {f.name} must be a positive number, got {v!r}")

    @classmethod
    def parse(cls, value: object, where: str = "priors") -> Priors:
        """From a model file's ``priors:`` entry: ``none``, a mapping of the keys above (the
        others at their defaults), or absent (``None``: the defaults)."""
        if value is None:
            return cls()
        if isinstance(value, str) and value.strip().lower() == "none":
            return cls(enabled=False)
        if not isinstance(value, dict):
            raise RelcalError(
                f"{where}: priors must be 'none' or a mapping of {', '.join(_UNITS)}, got {value!r}"
            )
        unknown = sorted(set(value) - set(_UNITS))
        if unknown:
            raise RelcalError(
                f"{where}: unknown prior(s) {', '.join(map(str, unknown))}; use "
                f"{', '.join(_UNITS)} (or priors: none)"
            )
        return cls(**value)

    def to_dict(self) -> dict | str:
        """What a model file writes (``"none"`` when switched off)."""
        if not self.enabled:
            return "none"
        return {k: float(getattr(self, k)) for k in _UNITS}

    def si(self, key: str) -> float:
        """The standard deviation of ``key`` in SI units (m, rad, 1, rad/(N m))."""
        return float(getattr(self, key)) * _UNITS[key]


def prior_key(name: str, kind: str, prismatic: bool = False) -> str | None:
    """Which prior holds a parameter of ``kind`` (its layout ``name`` tells a URDF origin's
    component); None for the frames, which have none."""
    if kind == "theta_off":
        return "offset_deg"
    if kind in ("a", "d"):
        return "length_mm"
    if kind in ("alpha", "beta"):
        return "angle_deg"
    if kind == "origin":
        return "length_mm" if name.rsplit(".", 1)[-1] in ("x", "y", "z") else "angle_deg"
    if kind == "scale":
        return "scale_ppm"
    if kind == "compliance":
        return "compliance_deg_per_nm" if not prismatic else None
    if kind in ("harmonic_c", "harmonic_s"):
        return "harmonic_deg"
    return None


def prior_std(names, kinds, priors: Priors, prismatic_of=None) -> np.ndarray:
    """``(P,)`` standard deviations of the parameters ``names``/``kinds`` (SI units), ``inf``
    where there is no prior (the frames, or ``priors.enabled`` false). ``prismatic_of(k)``:
    whether parameter ``k`` belongs to a prismatic joint (its zero offset is a length)."""
    out = np.full(len(kinds), np.inf)
    if not priors.enabled:
        return out
    for k, (name, kind) in enumerate(zip(names, kinds, strict=True)):
        prismatic = bool(prismatic_of(k)) if prismatic_of is not None else False
        key = prior_key(name, kind, prismatic)
        if key is not None:
            out[k] = priors.si(key)
    return out
