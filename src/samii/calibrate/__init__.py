"""Calibrate the simulator's physical parameters to FRF data (``samii calibrate``)."""

from samii.calibrate.calibrate import MODE_KNOBS, PHYSICAL_LIMITS, CalibrationResult, calibrate, default_bounds

__all__ = ["calibrate", "CalibrationResult", "default_bounds", "MODE_KNOBS", "PHYSICAL_LIMITS"]
