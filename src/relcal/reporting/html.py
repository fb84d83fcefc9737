"""The HTML reports, by their historical import path: the calibration report
(:mod:`relcal.reporting.calibration_report`) and the simulation report
(:mod:`relcal.reporting.simulation_report`). The pieces they are made of live in
:mod:`relcal.reporting.htmlkit` (markup, page, styles) and :mod:`relcal.reporting.plots`."""

from relcal.reporting.calibration_report import calibration_report
from relcal.reporting.simulation_report import simulation_report

__all__ = ["calibration_report", "simulation_report"]
