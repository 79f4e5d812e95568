"""A closed-loop run's ``run.json`` (``samii closedloop --out``, each of the main job's ``closedloop/<name>/``): what
the run found (:class:`ClosedLoopFigures`, the part ``samii closedloop --json`` prints) and how it was made
(:class:`ClosedLoopRecord`). Written by :mod:`samii.closedloop.trial` from
:meth:`samii.closedloop.scenario.ScenarioResult.run_json`; SI units, times in s, rates in 1/s. A figure a run does not
have is null (the settling time of a joint that did not follow its step; every figure of a run that diverged)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

__all__ = [
    "Runaway",
    "ThetaFigures",
    "BaseFigures",
    "ModeFigures",
    "LinearPrediction",
    "ClosedLoopFigures",
    "ScenarioSettings",
    "ModeDetail",
    "ModelUsed",
    "ControllerDetail",
    "ClosedLoopRecord",
]


@dataclass(frozen=True)
class Runaway:
    """The joint run away from its reference with the valve on a rail (samii.closedloop.scenario): since when, by how
    much."""

    theta_out_since_s: float | None
    valve_on_rail_since_s: float | None
    theta_error_rad: float | None
    band_rad: float | None
    valve_v: float | None
    theta_moving: bool


@dataclass(frozen=True)
class ThetaFigures:
    """The joint's step response (samii.closedloop.metrics)."""

    rise_s: float | None
    overshoot_pct: float | None
    settle_s: float | None  #: the last time outside 5 % of the step
    final_pct: float | None


@dataclass(frozen=True)
class BaseFigures:
    """The base's vibration (samii.closedloop.metrics)."""

    peak_m_s2: float | None
    residual_rms_m_s2: float | None
    settle_s: float | None  #: the last time outside 5 % of its peak excursion
    decay_rate_1_s: float | None  #: the envelope's exponential rate (after the switch-on in the Loper test)
    free_decay_rate_1_s: float | None  #: the servo loop alone's over the same time (the Loper test)


@dataclass(frozen=True)
class ModeFigures:
    """A mode of the base's vibration, fitted to the run (matrix pencil)."""

    freq_hz: float | None
    zeta: float | None


@dataclass(frozen=True)
class LinearPrediction:
    """The linearised closed loop beside the nonlinear run."""

    stable: bool
    marginal: bool
    rms_error_pct: Mapping[str, float | None]  #: signal -> rms of (linear - nonlinear) in % of the nonlinear's


@dataclass(frozen=True)
class ClosedLoopFigures:
    """What a closed-loop run found (``samii closedloop --json``)."""

    controller: str
    scenario: str
    stable: bool
    unstable_mode_hz: float | None
    growth_rate_1_s: float | None
    instability: str | None  #: in words, for an unstable run
    runaway: Runaway | None
    theta: ThetaFigures
    base: BaseFigures
    modes: tuple[ModeFigures, ...]
    linear_prediction: LinearPrediction


@dataclass(frozen=True)
class ScenarioSettings:
    duration_s: float
    step_deg: float
    t_step_s: float
    switch_on_s: float | None  #: the Loper test's switch-on; None in the step test
    impulse_n_s: float


@dataclass(frozen=True)
class ModeDetail:
    freq_hz: float | None
    zeta: float | None
    amplitude_m_s2: float | None


@dataclass(frozen=True)
class ModelUsed:
    file: str  #: "embedded default" or the model's path
    overrides: Mapping[str, float]  #: --set NAME=VALUE


@dataclass(frozen=True)
class ControllerDetail:
    """A saved controller's own description (samii.closedloop.controllers.SavedController)."""

    name: str
    method: str
    model_units: str
    servo_loop: str  #: "kept" or "replaced"
    provenance: Mapping  #: how it was designed, as its file says


@dataclass(frozen=True)
class ClosedLoopRecord(ClosedLoopFigures):
    """``run.json``: the figures and how the run was made."""

    scenario_settings: ScenarioSettings
    sample_time_s: float
    delay_samples: float
    servo_loop: str  #: "kept" or "replaced"
    noise: Mapping | None  #: the sensor noise (samii.closedloop.scenario.NoiseSpec); None: none
    diverged_at_s: float | None
    switch_jump_v: float | None
    linear_poles: tuple[tuple[float | None, float | None], ...]  #: (real, imaginary) [1/s], upper half plane
    modes_detail: tuple[ModeDetail, ...]
    notes: tuple[str, ...]
    model: ModelUsed | None = None  #: (None: ScenarioResult.run_json alone, before the trial adds it)
    controller_detail: ControllerDetail | None = None  #: None: a built-in controller
    recorded: bool = True  #: false: the run diverged in its first step and run.json alone was written
    #: the sensor options the controller read through (samii.sim.sensor_dynamics: those not at their ideal value);
    #: None: ideal sensors, or no controller (the servo amplifier reads the joint)
    sensors: Mapping[str, float] | None = None
    antialias_hz: float | None = None  #: the controller's anti-alias filter's corner (None: none)
