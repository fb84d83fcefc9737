"""relcal: kinematic calibration of serial robot arms from relative camera measurements.

The Python API, in the order of the flow of data::

    import relcal

    dataset = relcal.load_dataset("positioner")  # dataset.yaml + samples (+ images)
    # or from arrays in memory: relcal.Dataset.from_arrays(model, q, poses, mode=, handeye=)
    cal = relcal.calibrate(dataset)              # measure, identify, validate
    cal.result.converged, cal.result.std         # the Result: estimate, covariance, costs
    cal.validation.improvement()                 # held-out position RMS, before / after
    cal.model                                    # the calibrated RobotModel
    relcal.write_calibration(cal, "out/")        # model.yaml, robot.urdf, results.json, ...

Lower-level pieces: :func:`get_robot`, :func:`load_model` and :func:`load_urdf` (robot
models; a URDF chain converts exactly to modified DH), :func:`calibrated_urdf` and
:func:`robot_files` (the calibrated robot's files, for a URDF robot its own URDF with the
calibrated joint origins),
:func:`make_layout` and :func:`fk` (parameters and kinematics), :class:`Problem` (an
identification problem), :func:`identify` with :class:`SolverOptions` giving a :class:`Result`,
:func:`analyse_problem` (identifiability), :func:`simulate` (the published simulation),
:func:`import_rosbag` (a recorded calibration run to a dataset folder), :func:`plan` with a
:class:`Cell` (joint configurations that identify the parameters well), :func:`write_calibration`
(a calibration's files, written as one set), :func:`verify_session` (a finished calibration on a
new session: does it still hold?), :func:`handeye` (the hand-eye transform alone, every closed
form beside the refined estimate, scored on the same held-out samples).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.1.0"

# Where each public name lives. They load on first use (PEP 562), so that ``relcal`` on the
# command line starts without importing SciPy, OpenCV and Matplotlib for a ``--help``.
_API = {
    "Calibration": "relcal.calibration.outcome",
    "Cell": "relcal.design.cell",
    "Dataset": "relcal.data.dataset",
    "FixedCameraCell": "relcal.design.cell",
    "Identifiability": "relcal.calibration.identifiability",
    "Layout": "relcal.robot.kinematics",
    "Measurements": "relcal.data.imaging",
    "Noise": "relcal.calibration.noise",
    "Problem": "relcal.calibration.measurement",
    "RelcalError": "relcal.errors",
    "Result": "relcal.calibration.identify",
    "RobotModel": "relcal.robot.model",
    "Simulation": "relcal.sim.simulate",
    "SolverOptions": "relcal.calibration.identify",
    "analyse_problem": "relcal.calibration.identifiability",
    "apply_errors": "relcal.robot.kinematics",
    "calibrate": "relcal.calibration.pipeline",
    "calibrated_model": "relcal.robot.export",
    "calibrated_urdf": "relcal.robot.export",
    "fk": "relcal.robot.kinematics",
    "get_robot": "relcal.robot.loading",
    "handeye": "relcal.calibration.handeye_job",
    "HandEye": "relcal.calibration.handeye_job",
    "identify": "relcal.calibration.identify",
    "import_rosbag": "relcal.data.rosbag",
    "load_dataset": "relcal.data.dataset",
    "load_model": "relcal.robot.model",
    "load_urdf": "relcal.robot.urdf",
    "make_layout": "relcal.robot.kinematics",
    "make_pairs": "relcal.calibration.measurement",
    "measure": "relcal.data.imaging",
    "plan": "relcal.design.plan",
    "robot_files": "relcal.robot.export",
    "simulate": "relcal.sim.simulate",
    "verify_session": "relcal.calibration.verify",
    "write_calibration": "relcal.reporting.outputs",
}

__all__ = [
    "Calibration",
    "Cell",
    "Dataset",
    "FixedCameraCell",
    "HandEye",
    "Identifiability",
    "Layout",
    "Measurements",
    "Noise",
    "Problem",
    "RelcalError",
    "Result",
    "RobotModel",
    "Simulation",
    "SolverOptions",
    "analyse_problem",
    "apply_errors",
    "calibrate",
    "calibrated_model",
    "calibrated_urdf",
    "fk",
    "get_robot",
    "handeye",
    "identify",
    "import_rosbag",
    "load_dataset",
    "load_model",
    "load_urdf",
    "make_layout",
    "make_pairs",
    "measure",
    "plan",
    "robot_files",
    "simulate",
    "verify_session",
    "write_calibration",
]


def __getattr__(name: str):
    if name in _API:
        value = getattr(importlib.import_module(_API[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'relcal' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_API])


if TYPE_CHECKING:  # for type checkers and editors: the same names, imported eagerly
    from relcal.calibration.handeye_job import HandEye, handeye
    from relcal.calibration.identifiability import Identifiability, analyse_problem
    from relcal.calibration.identify import Result, SolverOptions, identify
    from relcal.calibration.measurement import Problem, make_pairs
    from relcal.calibration.noise import Noise
    from relcal.calibration.outcome import Calibration
    from relcal.calibration.pipeline import calibrate
    from relcal.calibration.verify import verify_session
    from relcal.data.dataset import Dataset, load_dataset
    from relcal.data.imaging import Measurements, measure
    from relcal.data.rosbag import import_rosbag
    from relcal.design.cell import Cell, FixedCameraCell
    from relcal.design.plan import plan
    from relcal.errors import RelcalError
    from relcal.reporting.outputs import write_calibration
    from relcal.robot.export import calibrated_model, calibrated_urdf, robot_files
    from relcal.robot.kinematics import Layout, apply_errors, fk, make_layout
    from relcal.robot.loading import get_robot
    from relcal.robot.model import RobotModel, load_model
    from relcal.robot.urdf import load_urdf
    from relcal.sim.simulate import Simulation, simulate

    __version__ = "0.1.0"
