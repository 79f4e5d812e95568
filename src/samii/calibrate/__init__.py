"""Calibrate the simulator's physical parameters to FRF data (``samii calibrate``)."""

from samii.calibrate.calibrate import CalibrationResult, calibrate, default_bounds, PHYSICAL_LIMITS

__all__ = ["calibrate", "CalibrationResult", "default_bounds", "PHYSICAL_LIMITS"]
