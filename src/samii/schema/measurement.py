"""A measurement's ``run.json`` (``samii measure --out``, the main job's ``measure/``): how the Bode test was made
and what it checked. Written by :func:`samii.measure.bode_test.run_bode_test`; SI units (pressures in Pa, angles in
rad). The excitation's settings, the FRF estimator's description and the model's parameters are kept as written
(objects whose keys are those of the excitation, the estimator and the parameter file)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from samii.schema.typed import OPTIONAL, key

__all__ = ["Daq", "MeasuredModel", "Timing", "Deviation", "Peaks", "MeasurementRecord", "LINEAR_CHECK"]

#: The key of the measurement's check against the linearised simulator, and its band [Hz].
LINEAR_CHECK = "vs_linearised_simulator_0.5_35_hz"


@dataclass(frozen=True)
class Daq:
    """The simulated data acquisition (samii.measure.daq)."""

    sample_rate_hz: float
    antialias: str | None  #: the anti-alias filter, in words
    sensor_noise: Mapping[str, float | None] | None  #: rms of each sensor's noise (samii.measure.daq.SensorNoise)
    seed: int | None


@dataclass(frozen=True)
class MeasuredModel:
    file: str  #: "embedded default" or the model's path
    overrides: Mapping[str, float]  #: --set NAME=VALUE
    timestep_s: float
    params: Mapping | None  #: the physical parameters by group (samii params); None for an MJCF file
    hydraulic: Mapping[str, float | None]  #: the hydraulic plugin's parameters (samii.sim.hydraulic)


@dataclass(frozen=True)
class Timing:
    simulated_s: float
    simulation_wall_s: float
    total_wall_s: float
    real_time_factor: float | None


@dataclass(frozen=True)
class Deviation:
    """A channel's deviation from the linearised simulator (samii.frequency_response.max_deviation)."""

    max_abs_db: float | None
    max_abs_deg: float | None
    sustained_db: float | None
    sustained_deg: float | None
    points: int


@dataclass(frozen=True)
class Peaks:
    """The largest excursions of the record."""

    load_pressure_pa: float | None  #: None: a model without the hydraulic plugin's pressure
    valve_command_v: float
    joint_angle_rad: float


@dataclass(frozen=True)
class MeasurementRecord:
    """``run.json`` of a measurement."""

    command: str
    argv: tuple[str, ...]
    method: str  #: "swept", "stepped" or "both"
    excitation: Mapping[str, Mapping]  #: method -> its settings (samii.measure.excitation's describe())
    daq: Daq
    frf: Mapping[str, str]  #: the estimator, in words (frf_estimator, frf_records, ...)
    model: MeasuredModel
    versions: Mapping[str, str]
    timing: Timing
    vs_linearised: Mapping[str, Deviation] = field(metadata=key(LINEAR_CHECK))  #: channel -> deviation, the first method's
    peaks: Peaks
    outputs: tuple[str, ...]
    vs_linearised_by_method: Mapping[str, Mapping[str, Deviation]] | None = field(
        default=None, metadata=key(LINEAR_CHECK + "_by_method", **OPTIONAL)
    )  #: "both": each method's
    peaks_by_method: Mapping[str, Peaks] | None = field(default=None, metadata=OPTIONAL)  #: "both": each method's
    warnings: tuple[str, ...] | None = field(default=None, metadata=OPTIONAL)  #: what the checks said, in words
