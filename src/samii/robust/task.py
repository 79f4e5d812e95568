"""One sample of a robustness study: a plant built from parameters, a closed-loop run, its figures.

A :class:`SampleTask` holds only plain data (a parameter dictionary, overrides, the controller's
matrices, the scenario's name, a seed), so it pickles to any worker; :func:`run_sample` builds
the MuJoCo model inside the task. An ``MjModel`` that uses the hydraulic plugin is never shipped:
unpickled in a process where the plugin is not registered it crashes that process.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from samii.errors import InputError
from samii.threads import one_blas_thread

__all__ = ["SampleTask", "SampleResult", "run_sample", "closed_loop_damping", "DAMPING_BAND_HZ"]


@dataclass(frozen=True)
class SampleTask:
    index: int
    base_params: dict  #: SamiiParams.as_dict() of the nominal plant
    overrides: dict[str, float]  #: this sample's drawn values
    controller: object  #: a SavedController, or None for the servo loop alone
    scenario: str  #: samii closedloop's scenario, at its default settings
    delay_samples: float = 0.0
    noise_seed: int | None = None  #: sensor noise on, with this seed (None: off)
    antialias_hz: float | None = None  #: the card's anti-alias filter's corner (None: none)


@dataclass(frozen=True)
class SampleResult:
    index: int
    stable: bool
    zeta: float | None  #: damping ratio of the least-damped closed-loop mode (negative: growing); closed_loop_damping
    mode_hz: float | None  #: that mode's frequency
    growth_rate_1_s: float | None
    base_settle_s: float | None
    theta_settle_s: float | None
    theta_overshoot_pct: float | None
    note: str = ""  #: why the run is unstable or could not be judged, in words
    valid: bool = True  #: False: no plant could be built (no static equilibrium near the nominal pose, a mode too stiff for the step); not counted
    linear_stable: bool = True  #: the closed loop linearised about the rest state is stable

    def table_row(self) -> dict:
        return {"index": self.index, "stable": self.stable, "zeta": self.zeta, "mode_hz": self.mode_hz, "growth_rate_1_s": self.growth_rate_1_s,
                "base_settle_s": self.base_settle_s, "theta_settle_s": self.theta_settle_s, "theta_overshoot_pct": self.theta_overshoot_pct,
                "note": self.note, "valid": self.valid, "linear_stable": self.linear_stable}  # fmt: skip


#: The band whose poles count for the closed-loop damping [Hz]: the swept-sine band the notebook measured and modelled
#: (0.1-40 Hz, where its controllers act), above the integrators and drifts near 0; structural modes above it (arm,
#: lateral bending, near 80 Hz) are no controller's business and would otherwise always be the least damped.
DAMPING_BAND_HZ = (0.1, 40.0)


def closed_loop_damping(stable: bool, poles_s, growth_rate_1_s: float | None, unstable_mode_hz: float | None) -> tuple[float | None, float | None]:
    """(zeta, freq_hz) of the least-damped closed-loop mode: the smallest damping ratio -Re(s)/|s| among the
    linearised closed loop's poles in :data:`DAMPING_BAND_HZ` (negative: growing). A mode a controller cancels
    stays there (it is only made unobservable from the reference), which a fit to the step response would miss.
    When the nonlinear run is unstable but the linear loop is not (the valve's rails, a limit cycle), the
    growing mode's: -sigma/|s| for s = sigma + j 2 pi f."""

    p = np.asarray(poles_s, complex).ravel()
    hz = np.abs(p) / (2 * math.pi)
    p = p[(hz >= DAMPING_BAND_HZ[0]) & (hz <= DAMPING_BAND_HZ[1]) & (p.imag >= 0)]
    if p.size:
        z = -p.real / np.abs(p)
        k = int(np.argmin(z))
        zeta, f = float(z[k]), float(np.abs(p[k]) / (2 * math.pi))
        if stable or zeta < 0:
            return zeta, f
    if stable:
        return None, None
    if growth_rate_1_s is None or not math.isfinite(growth_rate_1_s):
        return None, unstable_mode_hz
    w = 2 * math.pi * (unstable_mode_hz or 0.0)
    return -float(growth_rate_1_s) / math.hypot(growth_rate_1_s, w), unstable_mode_hz


def _num(x) -> float | None:
    return float(x) if x is not None and math.isfinite(float(x)) else None


def run_sample(task: SampleTask) -> SampleResult:
    """Build the task's plant and run its closed loop (the model is built here, in the worker).

    With one BLAS thread, as in a Dask worker (its nanny sets OMP_NUM_THREADS=1): a sum split over
    threads rounds differently, and the equilibrium and the fitted modes would differ in their last
    bits between engines; with it, every engine gives the same bits."""
    with one_blas_thread():
        return _run_sample(task)


def _run_sample(task: SampleTask) -> SampleResult:
    from samii.closedloop.scenario import NoiseSpec, run_closed_loop, scenario  # (lazy: imports mujoco, scipy, only when called)
    from samii.sim.model import compile_model, load_spec, params_from_dict  # (lazy: imports mujoco, only when called)
    from samii.sim.plugin import load_plugin  # (lazy: imports mujoco, only when called)

    load_plugin()  # idempotent; a fresh worker process has not registered the hydraulic plugin yet
    params = params_from_dict(task.base_params)
    try:
        spec, generated = load_spec(params=params, overrides=task.overrides)
        model = compile_model(spec, generated, params=params, overrides=task.overrides)
    except InputError as exc:  # no static equilibrium near the nominal pose, or too stiff for the step: a plant the rig could not be
        return SampleResult(task.index, False, None, None, None, None, None, None, note=f"no plant: {exc}", valid=False)
    qpos, act = model.key_qpos[0].copy(), model.key_act[0].copy()

    def factory():
        return spec.copy(), qpos, act  # (compiling left the spec as it was: the card is built on a copy)

    noise = NoiseSpec(seed=task.noise_seed) if task.noise_seed is not None else None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        r = run_closed_loop(task.controller, scenario(task.scenario), label=f"sample {task.index}",
                            spec_factory=factory, delay_samples=task.delay_samples, noise=noise, comparison=False,
                            details=False, antialias_hz=task.antialias_hz)  # fmt: skip
    # unstable: the nonlinear run diverges or oscillates without decaying, or its linearisation is unstable and only
    # the valve's +-10 V rails bound it (a limit cycle is no stable loop)
    # (a marginal prediction, an integrator at |z| = 1 to within rounding, is no instability: closedloop's verdict)
    linear_ok = bool(r.linear_stable or r.linear_marginal)
    stable = bool(r.stable and linear_ok)
    zeta, hz = closed_loop_damping(stable, r.linear_poles_s, r.growth_rate_1_s, r.unstable_mode_hz)
    note = (
        r.instability() if not r.stable else ("" if linear_ok else "the linearised loop is unstable: the run is bounded only by the valve's limits")
    )
    return SampleResult(
        index=task.index,
        stable=stable,
        linear_stable=bool(r.linear_stable),
        zeta=_num(zeta),
        mode_hz=_num(hz),
        growth_rate_1_s=_num(r.growth_rate_1_s),
        base_settle_s=_num(r.base.settle_s) if stable else None,
        theta_settle_s=_num(r.theta.settle_s) if stable else None,
        theta_overshoot_pct=_num(r.theta.overshoot_pct) if stable else None,
        note=note,
    )
