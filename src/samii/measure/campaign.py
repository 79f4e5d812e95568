"""The rig's Bode measurement run in the simulator: excitation -> MuJoCo -> DAQ -> estimate.

``measure_swept`` and ``measure_stepped`` are the library form of ``samii
measure``; ``linearised_frf`` is the small-signal reference they are checked
against. MuJoCo is imported only when these functions run.

The servo amplifier's position loop runs inside the hydraulic plugin
(v = clamp(ctrl + Kp (theta_ref - theta), +-10 V)), so the excitation is the
actuator's ``ctrl`` and the simulator's signals are those a rig records.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import mujoco
import numpy as np
import scipy.linalg

from samii.formats import TimeSeriesCsvWriter
from samii.frequency_response import FrequencyResponse
from samii.measure.daq import DEFAULT_SAMPLE_RATE_HZ, Daq, SensorNoise, daq_timeseries
from samii.measure.excitation import SteppedSine, SweptSine
from samii.measure.frf import estimate_frf
from samii.measure.stepped import estimate_stepped
from samii.progress import Progress
from samii.sim.linearize import linearize_discrete
from samii.sim.sensor_dynamics import SensorDynamics
from samii.sim.simulate import simulate
from samii.timeseries import SIGNAL_COLUMNS, TimeSeries

__all__ = ["Run", "Measurement", "record", "measure", "measure_swept", "measure_stepped", "linearised_frf"]


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


def _physics_columns(chunk) -> dict[str, np.ndarray]:
    """Time-series columns (``SIGNAL_COLUMNS``, DATA_FORMATS.md) of a :func:`samii.sim.simulate.simulate` result.

    The excitation ``r`` is the simulator's ``ctrl``; ``theta_ref`` is 0 (theta is relative to it).
    """
    cols = {
        "v": chunk.v,
        "theta": chunk.theta,
        "accel": chunk.accel,
        "r": chunk.ctrl,
        "theta_ref": np.zeros(chunk.t.size),
        "p_load": chunk.p_load,
        "spool": chunk.spool,
    }
    return {k: cols[k] for k in SIGNAL_COLUMNS}


def record(
    model,
    excitation: SweptSine | SteppedSine,
    *,
    sample_rate_hz: float = DEFAULT_SAMPLE_RATE_HZ,
    noise: SensorNoise | None = None,
    rng: np.random.Generator | None = None,
    timeseries_path=None,
    overwrite: bool = False,
    frame_steps: int | None = None,
    progress: Progress | None = None,
) -> tuple[Run, TimeSeries]:
    """Run the simulator from its equilibrium with ``excitation`` on the valve command, and record it.

    The DAQ samples each chunk of the run as it comes out of the simulator and,
    with ``timeseries_path``, writes it to the time-series CSV while the next
    chunk is stepped on the other core (as a rig's acquisition streams to disk).
    The file appears only when the run has finished; a diverged run leaves none.

    Parameters
    ----------
    model : mujoco.MjModel
        From :func:`samii.sim.model.load_model`.
    excitation : SweptSine or SteppedSine
        Evaluated at every physics step, for ``excitation.duration_s``.
    sample_rate_hz, noise, rng
        The DAQ (:class:`samii.measure.daq.Daq`).
    timeseries_path : path-like, optional
        Write the DAQ record there (DATA_FORMATS.md time-series CSV).
    overwrite : bool
        Replace an existing ``timeseries_path``.
    frame_steps : int, optional
        Keep qpos every this many physics steps (for a Rerun animation).
    progress : samii.progress.Progress, optional
        Told the run's physics steps, advanced as they are stepped (:func:`samii.sim.simulate.simulate`).

    Returns
    -------
    (Run, TimeSeries)
        The physics-rate run and the DAQ record (metadata: source, DAQ and every
        excitation setting).

    Raises
    ------
    samii.sim.simulate.SimulationUnstable
        If the run diverges; nothing is written.
    """

    dt = float(model.opt.timestep)
    n = int(round(excitation.duration_s / dt))
    ctrl = excitation.signal(np.arange(n) * dt)
    daq = Daq(1.0 / dt, sample_rate_hz=sample_rate_hz, noise=noise, rng=rng, sensors=SensorDynamics.from_model(model))
    meta = {"source": "samii simulator (MuJoCo + samii.hydraulic plugin)", "physics_timestep_s": f"{dt:g}"}
    daq_meta = {**meta, **daq.metadata(), **{k: str(v) for k, v in excitation.describe().items()}}
    writer = None
    if timeseries_path is not None:
        writer = TimeSeriesCsvWriter(timeseries_path, SIGNAL_COLUMNS, daq_meta, overwrite=overwrite)
    daq_t, daq_cols = [], []

    def on_chunk(chunk) -> None:
        # the DAQ clock starts at 0 with the run (the keyframe's own time is not the record's)
        t, cols = daq.process(0.0, _physics_columns(chunk))
        daq_t.append(t)
        daq_cols.append(cols)
        if writer is not None:
            writer.write(t, cols)

    t0 = time.perf_counter()
    try:
        res = simulate(model, ctrl, data=mujoco.MjData(model), progress=progress, on_chunk=on_chunk, qpos_every=frame_steps)
        if writer is not None:
            writer.close()
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    wall = time.perf_counter() - t0
    physics = TimeSeries(t=res.t - res.t[0], **_physics_columns(res), metadata=meta)
    ts = daq_timeseries(np.concatenate(daq_t), {k: np.concatenate([c[k] for c in daq_cols]) for k in SIGNAL_COLUMNS}, daq_meta)
    frame_t = None if res.frame_t is None else res.frame_t - res.t[0]
    return Run(physics, frame_t, res.frame_qpos, wall), ts


def measure(
    model,
    excitation: SweptSine | SteppedSine,
    *,
    sample_rate_hz: float = DEFAULT_SAMPLE_RATE_HZ,
    noise: SensorNoise | None = None,
    rng: np.random.Generator | None = None,
    timeseries_path=None,
    overwrite: bool = False,
    frame_steps: int | None = None,
    progress: Progress | None = None,
) -> Measurement:
    """Bode measurement of joint 2 in the simulator: :func:`record`, then the estimator the excitation calls for.

    A swept sine gives the instrument-variable FRF over its band (issue 3, items
    2-3), with its record signs; a stepped sine the correlation estimate at its
    dwell frequencies (item 4). Keyword arguments are those of :func:`record`:
    ``timeseries_path`` streams the record to that CSV as it is made.
    """
    run, ts = record(
        model,
        excitation,
        sample_rate_hz=sample_rate_hz,
        noise=noise,
        rng=rng,
        timeseries_path=timeseries_path,
        overwrite=overwrite,
        frame_steps=frame_steps,
        progress=progress,
    )
    if isinstance(excitation, SweptSine):
        frf = estimate_frf(
            ts,
            record_s=excitation.record_s,
            baseline_s=excitation.lead_s,
            band_hz=(excitation.start_hz, excitation.stop_hz),
            record_signs=excitation.record_signs,
        )
    else:
        frf = estimate_stepped(ts, freqs_hz=excitation.freqs_hz, windows_s=excitation.windows_s)
    return Measurement(ts, frf, run)


def measure_swept(model, sweep: SweptSine = SweptSine(), **kwargs) -> Measurement:
    """Swept-sine measurement: :func:`measure` with ``sweep`` (default: the rig's 0.1-40 Hz, 3 averages)."""
    return measure(model, sweep, **kwargs)


def measure_stepped(model, stepped: SteppedSine = SteppedSine(), **kwargs) -> Measurement:
    """Stepped-sine measurement: :func:`measure` with ``stepped`` (default: 14 points over 0.5-35 Hz)."""
    return measure(model, stepped, **kwargs)


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
    if linear_model is None:  # the one-step map itself: no matrix logarithm and exponential (a third of a calibration's time)
        lm = linearize_discrete(model)
        ad, bd = lm.A, lm.B
    else:
        lm = linear_model
        n = lm.A.shape[0]
        block = np.zeros((n + 1, n + 1))
        block[:n, :n], block[:n, n:] = lm.A, lm.B
        e = scipy.linalg.expm(block * lm.dt_s)  # back to the exact one-step map
        ad, bd = e[:n, :n], e[:n, n:]
    n = ad.shape[0]
    kp = lm.position_gain_v_per_rad
    c_theta, c_accel = lm.C[0:1], lm.C[1:2]
    d_accel = lm.D[1, 0]
    a_ol = ad + kp * bd @ c_theta
    c_accel_ol = c_accel + kp * d_accel * c_theta
    f = np.asarray(freqs_hz, float)
    z = np.exp(2j * np.pi * f * lm.dt_s)
    # (zI - A_ol) x = b at every frequency, in one batched solve
    x = np.linalg.solve(z[:, None, None] * np.eye(n) - a_ol, np.broadcast_to(bd[:, :1], (f.size, n, 1)))[..., 0]
    theta = x @ c_theta[0]
    accel = x @ c_accel_ol[0] + d_accel
    meta = {"source": "linearised simulator, discrete time at the physics step (samii.sim.linearize)", "physics_timestep_s": f"{lm.dt_s:g}"}
    # The valve's command delay (the held signal shifted by T exactly, hydraulic.c) and the
    # sensors' own dynamics (the DAQ's filters at the physics rate) multiply the responses to v.
    delay = np.exp(-2j * np.pi * f * lm.command_delay_s)
    g_theta, g_accel = SensorDynamics.from_model(model).response(f, 1.0 / lm.dt_s)
    theta, accel = theta * delay * g_theta, accel * delay * g_accel
    if lm.command_delay_s:
        meta["command_delay_s"] = f"{lm.command_delay_s:g}"
    return FrequencyResponse(f, act=theta, base=accel / theta, total=accel, metadata=meta)
