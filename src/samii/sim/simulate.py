"""Step SAMII with a valve command and return its sensor signals.

The servo amplifier's position loop runs inside the hydraulic plugin
(v = clamp(ctrl + Kp (theta_ref - theta), +-10 V)), so an open-loop
``mujoco.rollout`` of the excitation ``ctrl`` is the closed-loop experiment,
at the speed of plain ``mj_step``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import mujoco
import mujoco.rollout
import numpy as np

__all__ = ["SimResult", "SimulationUnstable", "simulate", "tip_accel_offset"]


class SimulationUnstable(RuntimeError):
    """The simulation diverged (non-finite state or MuJoCo's bad-acceleration reset)."""


@dataclass(frozen=True)
class SimResult:
    """Signals at the physics rate, sample k at t = k * dt (SI units)."""

    t: np.ndarray  #: s
    ctrl: np.ndarray  #: V, the excitation r added to the servo amplifier's position loop
    v: np.ndarray  #: V, valve voltage the valve received (after the loop and saturation)
    theta: np.ndarray  #: rad, joint-2 angle relative to the nominal pose (reference angle)
    accel: np.ndarray  #: m/s^2, vertical acceleration of the beam tip, gravity removed
    p_load: np.ndarray  #: Pa, load pressure
    spool: np.ndarray  #: -1...1, spool position
    final_state: np.ndarray  #: mjSTATE_FULLPHYSICS after the last step (to continue a run)

    @property
    def dt_s(self) -> float:
        return float(self.t[1] - self.t[0]) if self.t.size > 1 else float("nan")


def tip_accel_offset(model: mujoco.MjModel) -> float:
    """What the tip's framelinacc z reads at rest: -g_z (it measures a - g)."""
    return float(-model.opt.gravity[2])


def simulate(
    model: mujoco.MjModel,
    ctrl_v: np.ndarray,
    *,
    data: mujoco.MjData | None = None,
    initial_state: np.ndarray | None = None,
    chunk_steps: int = 20000,
    progress: Callable[[int, int], None] | None = None,
) -> SimResult:
    """Run ``len(ctrl_v)`` physics steps applying ``ctrl_v[k]`` during step k.

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
        Steps per rollout call (``progress(done, total)`` is called after each).

    Raises
    ------
    SimulationUnstable
        If the state becomes non-finite or MuJoCo reports a bad acceleration.
    """
    from samii.sim.model import ACTUATOR, make_data
    from samii.sim.plugin import hydraulic_params

    ctrl_v = np.asarray(ctrl_v, float)
    if ctrl_v.ndim != 1 or ctrl_v.size == 0:
        raise ValueError(f"ctrl_v must be a non-empty 1-D array of volts, got shape {ctrl_v.shape}")
    if not np.all(np.isfinite(ctrl_v)):
        raise ValueError(f"ctrl_v has a NaN or infinite value at step {int(np.flatnonzero(~np.isfinite(ctrl_v))[0])}")
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
    qpos_start = 1  # FULLPHYSICS layout: time, qpos, qvel, act, ...
    act_start = 1 + model.nq + model.nv
    theta_sensor = int(model.sensor_adr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, "theta")])
    accel_sensor = int(model.sensor_adr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, "base_accel")]) + 2
    hp = hydraulic_params(model, ACTUATOR)

    n = ctrl_v.size
    states = np.empty((n, nstate))
    sensors = np.empty((n, model.nsensordata))
    warn_before = int(data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number)
    state = initial_state
    done = 0
    while done < n:
        k = min(chunk_steps, n - done)
        s, sd = mujoco.rollout.rollout(model, data, state[None, :], ctrl_v[None, done : done + k, None])
        states[done : done + k] = s[0]
        sensors[done : done + k] = sd[0]
        state = s[0, -1]
        bad = not np.all(np.isfinite(state)) or int(data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number) > warn_before
        if bad:
            t_bad = float(initial_state[0] + (done + k) * model.opt.timestep)
            raise SimulationUnstable(f"simulation diverged before t = {t_bad:.4g} s (non-finite state or bad acceleration); no result written")
        done += k
        if progress is not None:
            progress(done, n)

    # state before step k: the initial state, then the state after step k-1
    before = np.vstack([initial_state[None, :], states[:-1]])
    spool = before[:, act_start + act_adr]
    p_load = before[:, act_start + act_adr + 1] * hp.supply_pressure
    theta_abs = sensors[:, theta_sensor]
    v = np.clip(ctrl_v + hp.position_gain * (hp.reference_angle - theta_abs), -10.0, 10.0)
    t = initial_state[0] + np.arange(n) * model.opt.timestep
    del qpos_start
    return SimResult(
        t=t,
        ctrl=ctrl_v.copy(),
        v=v,
        theta=theta_abs - hp.reference_angle,
        accel=sensors[:, accel_sensor] - tip_accel_offset(model),
        p_load=p_load,
        spool=spool,
        final_state=state.copy(),
    )
