"""Every file a user can load, validated on its own: what is exported is what was validated.

A calibration's model file (``model.yaml``) holds the chosen model whole, non-geometric terms
included; a URDF, UR's ``calibration.yaml`` and Franka's ``kinematics.yaml`` hold geometry only.
When model selection keeps a non-geometric term (joint compliance, a harmonic), those files
cannot hold the validated model: they get the best model they can express instead (the chosen
columns without the non-geometric terms, refitted on the same training samples:
:attr:`~relcal.calibration.outcome.Calibration.geometry`), and each file carries its own held-out
error.

That error is measured on the file as written: its bytes are written to a scratch folder, read
back by relcal's loaders (``model.yaml`` by :func:`relcal.robot.model.load_model`, a URDF by
:func:`relcal.robot.urdf.load_urdf`, the vendor files written into the nominal URDF's joint
origins as their drivers do), and the forward kinematics of what was read is evaluated on
exactly the held-out samples (and pairs) of the main validation, with the measurement frames
(hand-eye, instrument and marker, tool point) of the fit the file came from. A geometry-only file
whose held-out error exceeds the baseline's is refused (not written, with the reason): the nominal
files the user has are the better choice. Without held-out samples a file that differs from the
validated model has no measured error and is refused too.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol

import numpy as np

from relcal import geometry as tf
from relcal.calibration.identify import Result, calibrated_handeye
from relcal.calibration.measurement import Problem, tracker_frames, world_of
from relcal.calibration.validate import PlacementValidation, Validation
from relcal.errors import RelcalError
from relcal.io import load_yaml
from relcal.robot.export import UR_SEGMENTS, _replace_origins, robot_files
from relcal.robot.kinematics import make_layout
from relcal.robot.model import RobotModel, dump_model, load_model
from relcal.robot.urdf import load_urdf

RUN_ID_PREFIX = "# relcal run "  # first line of model.yaml: the run that wrote it

if TYPE_CHECKING:
    from relcal.data.dataset import Dataset
    from relcal.data.imaging import Measurements

Holds = Literal["full model", "geometry only"]


class Calibration(Protocol):
    """What exporting and validating the files reads of a calibration: the attributes of
    :class:`relcal.calibration.outcome.Calibration` used here (that class calls
    :func:`export_artifacts` for its ``artifacts``; named here, this module does not import the
    one that imports it)."""

    dataset: Dataset
    measurements: Measurements
    problem: Problem  # the training samples
    result: Result
    geometry: Result | None
    validation: Validation | PlacementValidation | None
    settings: dict
    kind: Any  # relcal.calibration.kinds.MeasurementKind

    @property
    def exported(self) -> str: ...

    @property
    def exported_fit(self) -> Result: ...

    @property
    def model(self) -> RobotModel: ...

    @property
    def geometry_model(self) -> RobotModel: ...


@dataclass(frozen=True)
class Artifact:
    """One file of a calibration set that a user can load as a robot model.

    ``content``: the file's bytes (``model.yaml`` without the run-id comment line that the
    writer puts first). ``holds``: ``full model`` or ``geometry only``; ``refit``: the file holds
    the geometry-only refit, not the validated model (the chosen model has non-geometric terms).
    ``validation``: its held-out errors, measured on ``content`` read back (None without held-out
    samples). ``fit``: the fit whose measurement frames accompany it. ``refused``: why it is not
    written (None: it is).
    """

    name: str
    content: bytes
    holds: Holds
    refit: bool
    validation: Validation | PlacementValidation | None
    fit: Result
    refused: str | None = None

    @property
    def written(self) -> bool:
        return self.refused is None

    def rms(self) -> float | None:
        """Held-out position RMS (mm; the spread of coincidences), None if unmeasured."""
        return None if self.validation is None else self.validation.rms("calibrated")


def held_out_errors(
    cal: Calibration, model: RobotModel, params: np.ndarray, name: str = "model.yaml"
) -> Validation | PlacementValidation | None:
    """The held-out errors of ``model`` (e.g. read back from a written file, its own kinematics
    exactly as loaded) on the held-out samples of ``cal.validation``, measured by the
    validation's own metric: the measurement kind's
    :meth:`~relcal.calibration.kinds.MeasurementKind.validate`, handed ``model`` as the robot
    (its errors zero) and the measurement frames of ``params`` (a parameter vector on
    ``cal.problem.full_layout``: its kinematic part is ignored) as they accompany the file
    ``name`` (:func:`accompanying`). The baseline and guess errors are ``cal.validation``'s; the
    ``calibrated`` errors are those of ``model``. None without a validation.

    Raises
    ------
    RelcalError
        The kind scored other held-out evidence (pairs, samples) than the validation's.
    """
    from relcal.calibration.kinds import Training

    val = cal.validation
    if val is None:
        return None
    if cal.kind is None:
        raise RelcalError("a calibration without its measurement kind: its files cannot be scored")
    layout = make_layout(model)
    nuisance = accompanying(cal, params, name)[cal.problem.layout.size :]
    problem = replace(cal.problem, model=model, layout=layout)
    kind = replace(cal.kind, dataset=replace(cal.kind.dataset, model=model))
    training = Training(cal.train, problem, cal.result.identifiability, np.zeros(0, dtype=int))
    fit = replace(cal.result, params=np.concatenate([np.zeros(layout.size), nuisance]))
    # the samples the validation scored: its held-out samples less those it left out as
    # outliers (screened once, there; not again here)
    test = np.setdiff1d(cal.test, val.outliers)
    mine = kind.validate(training, fit, fit, test, screen=False)
    if not _same_evidence(mine, val):
        raise RelcalError("the held-out samples of an artifact differ from the validation's")
    return replace(val, calibrated=mine.calibrated)


def _same_evidence(
    mine: Validation | PlacementValidation | None, val: Validation | PlacementValidation
) -> bool:
    """Both validations scored the same held-out pairs (or samples), in the same order."""
    if mine is None or type(mine) is not type(val):
        return False
    if isinstance(val, PlacementValidation):
        return np.array_equal(mine.samples, val.samples)
    return np.array_equal(mine.pairs, val.pairs)


#: The files that hold the whole chain to the tip, its tool transform included (the others, UR's
#: and Franka's kinematics files, hold the joints' origins only: the tool stays the nominal one).
HOLD_THE_TOOL = ("model.yaml", "robot.urdf", "origin_corrections.yaml")


def accompanying(cal: Calibration, params: np.ndarray, name: str = "model.yaml") -> np.ndarray:
    """``params`` (on ``cal.problem.full_layout``) with the measurement frames as they accompany
    the exported file ``name``: unchanged, except for coincidences when the file holds the tool
    transform (:data:`HOLD_THE_TOOL`): it ends at the tool point
    (:attr:`~relcal.calibration.outcome.Calibration.model`), so the tool point that accompanies
    the file is zero in its tip frame (adding the fitted one again would count it twice)."""
    params = np.array(params, dtype=float)
    if cal.problem.formulation == "coincidence" and name in HOLD_THE_TOOL:
        n = cal.problem.layout.size
        params[n : n + 3] = -cal.problem.coincidence.tool_point  # guess + delta = 0
    return params


def frames(cal: Calibration, fit: Result, name: str = "model.yaml") -> dict[str, np.ndarray]:
    """The measurement frames that accompany file ``name``'s kinematics in its validation (SI):
    ``handeye`` and ``world`` ``(4, 4)`` (poses: ``W F(q) X``), ``instrument`` ``(4, 4)`` and
    ``marker`` ``(3,)``
    (points), ``tool_point`` ``(3,)`` (coincidences: zero for a file that holds it,
    :func:`accompanying`)."""
    problem = cal.problem
    if problem.formulation == "tracker":
        instrument, marker = tracker_frames(problem, fit.params)
        return {"instrument": instrument, "marker": np.asarray(marker, dtype=float)}
    if problem.formulation == "coincidence":
        from relcal.calibration.coincidence import split_params

        _, tool, _ = split_params(problem, accompanying(cal, fit.params, name))
        return {"tool_point": np.asarray(tool, dtype=float)}
    if problem.formulation in ("invariant", "board"):  # each held-out pose at W F(q) X
        return {"handeye": calibrated_handeye(problem, fit), "world": world_of(problem, fit.params)}
    return {}


# --- reading the files back ----------------------------------------------------------------------


def read_back(name: str, content: bytes, nominal: RobotModel, folder: Path) -> RobotModel:
    """The robot model that file ``name`` with ``content`` gives a user, read back from a copy
    written into ``folder``: ``model.yaml`` by relcal's model loader; ``robot.urdf`` by relcal's
    URDF loader (the chain of the ``nominal`` model's URDF, or ``base_link`` -> ``tool0`` of a
    generated one); ``origin_corrections.yaml``, ``ur_calibration.yaml`` and
    ``franka_kinematics.yaml`` written into the nominal URDF's joint origins, as xacro and the
    drivers do, then read as a URDF."""
    path = folder / name
    path.write_bytes(content)
    if name == "model.yaml":
        return load_model(path)
    chain = nominal.urdf
    if name == "robot.urdf":
        if chain is None:
            return load_urdf(path, "base_link", "tool0")
        return load_urdf(path, chain.root, chain.tip, chain.parametrisation)
    if chain is None:
        raise RelcalError(f"{name}: written only for robots loaded from a URDF")
    data, _ = load_yaml(path)
    origins = _vendor_origins(name, data, [j.name for j in chain.joints])
    urdf_path = folder / f"{name}.urdf"
    urdf_path.write_bytes(_replace_origins(str(urdf_path), chain.data, origins))
    return load_urdf(urdf_path, chain.root, chain.tip, chain.parametrisation)


def _vendor_origins(name: str, data: dict, joints: list[str]) -> dict[str, np.ndarray]:
    """Joint origins ``(4, 4)`` by URDF joint name from a vendor file's entries."""

    def origin(entry: dict) -> np.ndarray:
        xyz = [entry[k] for k in ("x", "y", "z")]
        rpy = [entry[k] for k in ("roll", "pitch", "yaw")]
        return tf.from_xyz_rpy(np.array(xyz, float), np.array(rpy, float))

    def joint(suffix: str) -> str:
        (found,) = [j for j in joints if j == suffix or j.endswith("_" + suffix)]
        return found

    if name == "origin_corrections.yaml":
        out = {}
        for jname, entry in data["joints"].items():
            c = entry["calibrated"]
            out[jname] = tf.from_xyz_rpy(np.array(c["xyz"], float), np.array(c["rpy"], float))
        return out
    if name == "ur_calibration.yaml":
        by_key = {key: suffix for suffix, key in UR_SEGMENTS.items()}
        kin = data["kinematics"]
        return {joint(by_key[k]): origin(v) for k, v in kin.items() if k in by_key}
    if name == "franka_kinematics.yaml":
        return {joint(k): origin(v["kinematic"]) for k, v in data.items()}
    raise RelcalError(f"{name}: not a file relcal reads back")


# --- the artifacts of a calibration ---------------------------------------------------------------


def export_artifacts(cal: Calibration) -> tuple[Artifact, ...]:
    """``model.yaml`` and the robot's geometry files (:func:`relcal.robot.export.robot_files`)
    of a calibration, each read back and validated on the held-out samples (see the module
    docstring); a geometry-only file worse than the baseline, or unmeasured while it differs
    from the validated model, is refused."""
    nominal = cal.dataset.model
    exported = cal.exported_fit
    refit = cal.geometry is not None and exported is cal.result
    geometry_fit = cal.geometry if refit else exported
    entries = [("model.yaml", dump_model(cal.model).encode(), "full model", False, exported)]
    for name, content in robot_files(cal.geometry_model).items():
        entries.append((name, content, "geometry only", refit, geometry_fit))
    out = []
    with tempfile.TemporaryDirectory(prefix="relcal-artifacts-") as tmp:
        for name, content, holds, is_refit, fit in entries:
            loaded = read_back(name, content, nominal, Path(tmp))
            validation = held_out_errors(cal, loaded, fit.params, name)
            refused = _refusal(cal, validation, is_refit) if holds == "geometry only" else None
            out.append(Artifact(name, content, holds, is_refit, validation, fit, refused))
    return tuple(out)


def _refusal(
    cal: Calibration, validation: Validation | PlacementValidation | None, refit: bool
) -> str | None:
    """Why a geometry-only file is not written, or None."""
    if validation is None:
        if not refit:
            return None  # the validated model's own geometry: as the model file itself
        return (
            "no held-out samples (--holdout 0): the geometry-only refit differs from the chosen "
            "model and its error cannot be measured"
        )
    if cal.exported == "baseline":
        return None  # the nominal geometry: nothing to refuse
    before, after = validation.rms("before"), validation.rms("calibrated")
    if after > before:
        unit = "spread" if isinstance(validation, PlacementValidation) else "position"
        return (
            f"its held-out {unit} RMS {after:.3f} mm is worse than the baseline's {before:.3f} mm "
            "(the nominal files are better): geometry alone cannot hold this robot's correction"
        )
    return None
