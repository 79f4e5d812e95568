"""The rig's Bode measurement run in the simulator: excitation -> MuJoCo -> DAQ -> estimate.

``measure_swept`` and ``measure_stepped`` are the library form of ``samii
measure``; ``linearised_frf`` is the small-signal reference they are checked
against. MuJoCo is imported only when these functions run.

The servo amplifier's position loop runs inside the hydraulic plugin
(v = clamp(ctrl + Kp (theta_ref - theta), +-10 V)), so the excitation is the
actuator's ``ctrl`` and the simulator's signals are those a rig records.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from samii.frequency_response import FrequencyResponse
from samii.measure.daq import DEFAULT_SAMPLE_RATE_HZ, SensorNoise, acquire
from samii.measure.excitation import SteppedSine, SweptSine
from samii.measure.frf import estimate_frf
from samii.measure.stepped import estimate_stepped
from samii.measure.timeseries import TimeSeries

__all__ = ["Run", "Measurement", "simulate_excitation", "measure_swept", "measure_stepped", "linearised_frf"]

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class Run:
    """Physics-rate signals of one simulated run, and body poses for animation.

    Attributes
    ----------
    physics : TimeSeries
        t, v, theta, accel, r (= ctrl), theta_ref (0: theta is relative to the reference), p_load, spool.
    frame_t_s : array or None
        Times of the stored frames [s].
    frame_qpos : array (frames, nq) or None
        Joint positions at those times (for a Rerun animation).
    wall_s : float
        Wall time of the simulation [s].
    """

    physics: TimeSeries
    frame_t_s: np.ndarray | None
    frame_qpos: np.ndarray | None
    wall_s: float


@dataclass(frozen=True)
class Measurement:
    """Result of a measurement: the DAQ record and the estimated frequency response."""

    timeseries: TimeSeries
    frf: FrequencyResponse
    run: Run


def simulate_excitation(model, excitation: SweptSine | SteppedSine, *, frame_steps: int | None = None, progress: Progress | None = None) -> Run:
    """Run the simulator from its equilibrium with ``excitation`` on the valve command.

    Parameters
    ----------
    model : mujoco.MjModel
        From :func:`samii.sim.model.load_model`.
    excitation : SweptSine or SteppedSine
        Evaluated at every physics step, for ``excitation.duration_s``.
    frame_steps : int, optional
        Store qpos every this many steps (for animation); the run is then made
        in chunks of that length, which costs ~0.2 ms per chunk.
    progress : callable(done_steps, total_steps), optional
    """
    import time

    import mujoco

    from samii.sim.simulate import simulate

    dt = float(model.opt.timestep)
    n = int(round(excitation.duration_s / dt))
    ctrl = excitation.signal(np.arange(n) * dt)
    data = mujoco.MjData(model)
    t0 = time.perf_counter()
    if frame_steps is None:
        res = simulate(model, ctrl, data=data, progress=progress)
        parts, frames_t, frames_q = [res], None, None
    else:
        parts, frames_t, frames_q = [], [], []
        state = None
        nq = model.nq
        for start in range(0, n, frame_steps):
            res = simulate(model, ctrl[start : start + frame_steps], data=data, initial_state=state)
            state = res.final_state
            parts.append(res)
            frames_t.append(state[0])
            frames_q.append(state[1 : 1 + nq].copy())
            if progress is not None:
                progress(min(start + frame_steps, n), n)
        frames_t, frames_q = np.asarray(frames_t), np.asarray(frames_q)
    wall = time.perf_counter() - t0
    cat = {k: np.concatenate([getattr(p, k) for p in parts]) for k in ("t", "ctrl", "v", "theta", "accel", "p_load", "spool")}
    physics = TimeSeries(
        t=cat["t"] - cat["t"][0],
        v=cat["v"],
        theta=cat["theta"],
        accel=cat["accel"],
        r=cat["ctrl"],
        theta_ref=np.zeros(n),
        p_load=cat["p_load"],
        spool=cat["spool"],
        metadata={"source": "samii simulator (MuJoCo + samii.hydraulic plugin)", "physics_timestep_s": f"{dt:g}"},
    )
    return Run(physics, frames_t, frames_q, wall)


def _acquire(run: Run, excitation, sample_rate_hz: float, noise: SensorNoise | None, rng) -> TimeSeries:
    """DAQ record of ``run``, its metadata extended by every setting of the excitation."""
    ts = acquire(run.physics, sample_rate_hz=sample_rate_hz, noise=noise, rng=rng)
    meta = dict(ts.metadata)
    meta.update({k: str(v) for k, v in excitation.describe().items()})
    return replace(ts, metadata=meta)


def measure_swept(
    model,
    sweep: SweptSine = SweptSine(),
    *,
    sample_rate_hz: float = DEFAULT_SAMPLE_RATE_HZ,
    noise: SensorNoise | None = None,
    rng: np.random.Generator | None = None,
    frame_steps: int | None = None,
    progress: Progress | None = None,
) -> Measurement:
    """Swept-sine Bode measurement of joint 2 in the simulator (issue 3, item 2-3).

    Returns the DAQ time series and the instrument-variable FRF over the sweep band.
    """
    run = simulate_excitation(model, sweep, frame_steps=frame_steps, progress=progress)
    ts = _acquire(run, sweep, sample_rate_hz, noise, rng)
    frf = estimate_frf(ts, record_s=sweep.record_s, baseline_s=sweep.lead_s, band_hz=(sweep.start_hz, sweep.stop_hz))
    return Measurement(ts, frf, run)


def measure_stepped(
    model,
    stepped: SteppedSine = SteppedSine(),
    *,
    sample_rate_hz: float = DEFAULT_SAMPLE_RATE_HZ,
    noise: SensorNoise | None = None,
    rng: np.random.Generator | None = None,
    frame_steps: int | None = None,
    progress: Progress | None = None,
) -> Measurement:
    """Stepped-sine measurement at ``stepped.freqs_hz`` in the simulator (issue 3, item 4)."""
    run = simulate_excitation(model, stepped, frame_steps=frame_steps, progress=progress)
    ts = _acquire(run, stepped, sample_rate_hz, noise, rng)
    frf = estimate_stepped(ts, freqs_hz=stepped.freqs_hz, windows_s=stepped.windows_s)
    return Measurement(ts, frf, run)


def linearised_frf(model, freqs_hz, *, linear_model=None) -> FrequencyResponse:
    """Small-signal FRF of the simulator as it is sampled: discrete time at the physics step.

    The simulator holds the valve voltage over each physics step (it is computed
    once per step from that step's theta), so sampled data obey the one-step map
    ``x[k+1] = Ad x[k] + Bd ctrl[k]`` of :func:`samii.sim.linearize.linearize`
    with the loop opened in discrete time, ``Ad_ol = Ad + Kp Bd C_theta``
    (v = ctrl - Kp theta). Its response at ``z = exp(j w dt)`` is what a
    measurement of sampled v, theta, accel converges to; the continuous model's
    ``G(jw)`` differs by the hold's half-step delay (7 deg at 40 Hz for 1 ms).

    Parameters
    ----------
    model : mujoco.MjModel
    freqs_hz : array
    linear_model : samii.sim.linearize.LinearModel, optional
        Reuse a linearisation (default: linearise ``model`` at its equilibrium).
    """
    import scipy.linalg

    if linear_model is None:
        import warnings

        from samii.sim.linearize import linearize

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # scipy logm accuracy notes
            linear_model = linearize(model)
    lm = linear_model
    n = lm.A.shape[0]
    block = np.zeros((n + 1, n + 1))
    block[:n, :n], block[:n, n:] = lm.A, lm.B
    e = scipy.linalg.expm(block * lm.dt_s)  # back to the exact one-step map
    ad, bd = e[:n, :n], e[:n, n:]
    kp = lm.position_gain_v_per_rad
    c_theta, c_accel = lm.C[0:1], lm.C[1:2]
    d_accel = lm.D[1, 0]
    a_ol = ad + kp * bd @ c_theta
    c_accel_ol = c_accel + kp * d_accel * c_theta
    f = np.asarray(freqs_hz, float)
    theta = np.empty(f.size, complex)
    accel = np.empty(f.size, complex)
    eye = np.eye(n)
    for i, z in enumerate(np.exp(2j * np.pi * f * lm.dt_s)):
        x = np.linalg.solve(z * eye - a_ol, bd[:, 0])
        theta[i] = (c_theta @ x)[0]
        accel[i] = (c_accel_ol @ x)[0] + d_accel
    meta = {"source": "linearised simulator, discrete time at the physics step (samii.sim.linearize)", "physics_timestep_s": f"{lm.dt_s:g}"}
    return FrequencyResponse(f, act=theta, base=accel / theta, total=accel, metadata=meta)
