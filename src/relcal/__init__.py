"""relcal: kinematic calibration of serial robot arms from relative camera measurements."""

__version__ = "0.1.0"
