"""Which :class:`~relcal.calibration.kinds.MeasurementKind` a dataset is (:func:`kind_of`):
apart from the kinds' package, which the kinds import (imports go one way)."""

from __future__ import annotations

from relcal.calibration.kinds import MeasurementKind
from relcal.calibration.kinds.coincidence import CoincidenceKind
from relcal.calibration.kinds.points import PointKind
from relcal.calibration.kinds.poses import PoseKind
from relcal.calibration.measurement import PairStrategy
from relcal.data.dataset import Dataset
from relcal.data.imaging import Measurements


def kind_of(
    dataset: Dataset, measurements: Measurements, pairing: PairStrategy = "auto"
) -> MeasurementKind:
    """The measurement kind of ``dataset``: coincidence groups, position-only points, or poses."""
    if dataset.measured == "coincidence":
        return CoincidenceKind(dataset, measurements, pairing)
    if dataset.measured == "position":
        return PointKind(dataset, measurements, pairing)
    return PoseKind(dataset, measurements, pairing)
