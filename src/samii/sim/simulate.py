"""Step SAMII with a valve command and return its sensor signals.

The servo amplifier's position loop runs inside the hydraulic plugin
(v = clamp(ctrl + Kp (theta_ref - theta), +-10 V)), so an open-loop
``mujoco.rollout`` of the excitation ``ctrl`` is the closed-loop experiment,
at the speed of plain ``mj_step``.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import mujoco
import mujoco.rollout
import numpy as np

from samii.errors import SimulationUnstable
from samii.progress import SILENT, Progress
from samii.sim.model import ACTUATOR, make_data
from samii.sim.plugin import hydraulic_params
from samii.sim.sensors import accel_offset, accel_weights

__all__ = ["SimResult", "SimulationUnstable", "check_rollout", "simulate", "tip_accel_offset"]


@dataclass(frozen=True)
class SimResult:
    """Signals at the physics rate, sample k at t = k * dt (SI units)."""

    t: np.ndarray  #: s
    ctrl: np.ndarray  #: V, the excitation r added to the servo amplifier's position loop
    v: np.ndarray  #: V, valve voltage the valve received (after the loop and saturation)
    theta: np.ndarray  #: rad, joint-2 angle relative to the nominal pose (reference angle)
    accel: np.ndarray  #: m/s², the base accelerometer along its measuring direction minus its reading at rest (samii.sim.sensors)
    p_load: np.ndarray  #: Pa, load pressure
    spool: np.ndarray  #: -1...1, spool position
    final_state: np.ndarray  #: mjSTATE_FULLPHYSICS after the last step (to continue a run)
    frame_t: np.ndarray | None = None  #: s, times of the kept qpos frames (``qpos_every``)
    frame_qpos: np.ndarray | None = None  #: (frames, nq) joint positions at ``frame_t``

    @property
    def dt_s(self) -> float:
        return float(self.t[1] - self.t[0]) if self.t.size > 1 else float("nan")


def tip_accel_offset(model: mujoco.MjModel) -> float:
    """What the base accelerometer reads at rest (``samii.sim.sensors.accel_offset``): removed from ``accel``."""

    return accel_offset(model)


def check_rollout(data: mujoco.MjData, last_state: np.ndarray, t_end_s: float, span_s: float) -> None:
    """Raise :class:`SimulationUnstable` if a ``mujoco.rollout`` chunk ending at ``t_end_s`` diverged.

    ``mujoco.rollout`` clears the warning counters at every call and stops
    stepping at the first warning of any kind (bad qacc/qvel/qpos reset the
    state to finite defaults), copying that state into the rest of the chunk:
    any warning, a non-finite state or a clock that did not reach the chunk's
    end (``last_state[0]``, mjSTATE_FULLPHYSICS) is a diverged run.
    """
    warned = [mujoco.mjtWarning(int(i)).name for i in np.flatnonzero(data.warning.number)]
    clock_ok = abs(float(last_state[0]) - t_end_s) <= 1e-6 * max(1.0, span_s)
    finite = bool(np.all(np.isfinite(last_state)))
    if warned or not clock_ok or not finite:
        why = ", ".join(warned) if warned else "non-finite state" if not finite else "the clock stopped"
        raise SimulationUnstable(f"simulation diverged before t = {t_end_s:.4g} s ({why}); no result written")


def simulate(
    model: mujoco.MjModel,
    ctrl_v: np.ndarray,
    *,
    data: mujoco.MjData | None = None,
    initial_state: np.ndarray | None = None,
    chunk_steps: int = 20000,
    progress: Progress | None = None,
    on_chunk: Callable[[SimResult], None] | None = None,
    qpos_every: int | None = None,
) -> SimResult:
    """Run ``len(ctrl_v)`` physics steps applying ``ctrl_v[k]`` during step k.

    The steps run in chunks of ``mujoco.rollout`` on a worker thread (rollout
    releases the GIL), so whatever ``on_chunk`` does with chunk k (a DAQ
    writing to disk, say) runs on the other core while chunk k+1 is stepped.

    Parameters
    ----------
    model : MjModel
        From :func:`samii.sim.model.load_model`.
    ctrl_v : array of float
        Excitation [V] per physics step (``model.opt.timestep`` apart); values
        outside the actuator's ctrlrange (+-10 V) are clamped by MuJoCo.
    data : MjData, optional
        Scratch data; default a new one.
    initial_state : array, optional
        mjSTATE_FULLPHYSICS state to start from; default the ``home`` keyframe
        (static equilibrium).
    chunk_steps : int
        Steps per rollout call.
    progress : samii.progress.Progress, optional
        Told the run's physics steps (``expect``), then advanced by each chunk's as it is stepped.
    on_chunk : callable(SimResult), optional
        Called in the calling thread with each chunk's signals, in order, while
        the next chunk is stepped (so it must not touch ``data``). The chunk in
        which a run diverges is never passed on, but the chunks before it have
        been: a consumer must discard what it got when ``SimulationUnstable``
        is raised (``samii.measure.campaign.record`` deletes its file).
    qpos_every : int, optional
        Keep ``qpos`` every this many steps (for an animation): ``frame_t`` and
        ``frame_qpos`` of the result.

    Raises
    ------
    SimulationUnstable
        If the state becomes non-finite or MuJoCo raises any warning (bad
        acceleration, velocity or position).
    """

    ctrl_v = np.asarray(ctrl_v, float)
    if ctrl_v.ndim != 1 or ctrl_v.size == 0:
        raise ValueError(f"ctrl_v must be a non-empty 1-D array of volts, got shape {ctrl_v.shape}")
    if not np.all(np.isfinite(ctrl_v)):
        raise ValueError(f"ctrl_v has a NaN or infinite value at step {int(np.flatnonzero(~np.isfinite(ctrl_v))[0])}")
    if chunk_steps < 1:
        raise ValueError(f"chunk_steps must be >= 1, got {chunk_steps}")
    if qpos_every is not None and qpos_every < 1:
        raise ValueError(f"qpos_every must be >= 1, got {qpos_every}")
    if data is None:
        data = make_data(model)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    nstate = mujoco.mj_stateSize(model, spec)
    if initial_state is None:
        home = make_data(model)
        initial_state = np.empty(nstate)
        mujoco.mj_getState(model, home, initial_state, spec)
    initial_state = np.asarray(initial_state, float)

    act_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, ACTUATOR)
    act_adr = int(model.actuator_actadr[act_id])
    act_start = 1 + model.nq + model.nv  # FULLPHYSICS layout: time, qpos, qvel, act, ...
    theta_sensor = int(model.sensor_adr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, "theta")])

    accel_sensor, accel_dir = accel_weights(model)
    hp = hydraulic_params(model, ACTUATOR)
    dt = float(model.opt.timestep)
    g_offset = tip_accel_offset(model)
    n = ctrl_v.size
    out = {k: np.empty(n) for k in ("v", "theta", "accel", "p_load", "spool")}
    frames_t, frames_q = [], []

    def step(state: np.ndarray, lo: int, hi: int):
        return mujoco.rollout.rollout(model, data, state[None, :], ctrl_v[None, lo:hi, None])

    bounds = [(lo, min(lo + chunk_steps, n)) for lo in range(0, n, chunk_steps)]
    progress = progress or SILENT
    progress.expect(n)
    state = initial_state
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="samii-rollout") as pool:
        pending = pool.submit(step, state, *bounds[0])
        for i, (lo, hi) in enumerate(bounds):
            s, sd = pending.result()
            s, sd = s[0], sd[0]
            last = s[-1]
            check_rollout(data, last, float(initial_state[0]) + hi * dt, hi * dt)
            if i + 1 < len(bounds):
                pending = pool.submit(step, last, *bounds[i + 1])
            # the state before step k: the chunk's start state, then the state after step k-1
            before = np.vstack([state[None, :], s[:-1]])
            theta_abs = sd[:, theta_sensor]
            chunk = SimResult(
                t=initial_state[0] + np.arange(lo, hi) * dt,
                ctrl=ctrl_v[lo:hi].copy(),
                v=np.clip(ctrl_v[lo:hi] + hp.position_gain * (hp.reference_angle - theta_abs), -10.0, 10.0),
                theta=theta_abs - hp.reference_angle,
                accel=sd[:, accel_sensor : accel_sensor + 3] @ accel_dir - g_offset,
                p_load=before[:, act_start + act_adr + 1] * hp.supply_pressure,
                spool=before[:, act_start + act_adr],
                final_state=last.copy(),
            )
            for k in out:
                out[k][lo:hi] = getattr(chunk, k)
            if qpos_every is not None:
                rows = np.arange(-lo % qpos_every, hi - lo, qpos_every)  # states after steps 0, q, 2q, ...
                frames_t.append(s[rows, 0])
                frames_q.append(s[rows, 1 : 1 + model.nq])
            state = last
            if on_chunk is not None:
                on_chunk(chunk)
            progress.advance(hi - lo)

    return SimResult(
        t=initial_state[0] + np.arange(n) * dt,
        ctrl=ctrl_v.copy(),
        **out,
        final_state=state.copy(),
        frame_t=np.concatenate(frames_t) if qpos_every is not None else None,
        frame_qpos=np.concatenate(frames_q) if qpos_every is not None else None,
    )
