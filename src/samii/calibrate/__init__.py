"""Calibrate the simulator's physical parameters to FRF data (``samii calibrate``).

:mod:`samii.calibrate.calibrate` fits (``calibrate``), :mod:`samii.calibrate.simulator` is the linearised simulator as a
model structure, :mod:`samii.calibrate.calibrate_file` is the command's call (a file or eq 9.4 in, a folder out),
:mod:`samii.calibrate.targets` the fidelity targets against eq 9.4.
"""

from samii.calibrate.calibrate import MODE_KNOBS, PHYSICAL_LIMITS, CalibrationResult, calibrate, default_bounds

__all__ = ["calibrate", "CalibrationResult", "default_bounds", "MODE_KNOBS", "PHYSICAL_LIMITS"]
