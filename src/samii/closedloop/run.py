"""Run a closed loop in the nonlinear simulator: the controller card stepped by ``mujoco.rollout``.

The controller runs inside the hydraulic plugin (:mod:`samii.closedloop.card`),
so a run is a plain rollout of four input columns per physics step: the
excitation ``u`` [V], the reference offset ``theta_ref`` [rad] and the two
sensor-noise channels. A switch-on mid-run (the Loper test) splits the run in
two rollouts; between them the controller's state is initialised so that its
first command continues what the valve was getting (:func:`bumpless_state`).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import mujoco.rollout
import numpy as np

from samii.closedloop.card import CardModel, si_matrices
from samii.errors import SimulationUnstable
from samii.sim.model import make_data, reset_home
from samii.sim.plugin import hydraulic_params
from samii.sim.sensors import accel_weights
from samii.sim.simulate import check_rollout

__all__ = ["LoopSignals", "bumpless_state", "run_loop", "measurements_at"]

_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
#: A controller output beyond this has diverged numerically: the valve saturates at 10 V, so no working
#: controller's output comes within five orders of it, and a file reader refuses such a value as a
#: measurement (samii.formats bounds numbers at 1e100). The run ends there (``diverged_at_s``).
COMMAND_DIVERGED_V = 1e6


@dataclass(frozen=True)
class LoopSignals:
    """A closed-loop run at the physics rate; sample k at ``t[k]`` (SI units)."""

    t: np.ndarray  #: s
    theta_ref: np.ndarray  #: rad, reference offset from the nominal pose
    r: np.ndarray  #: V, the excitation added to the valve command
    theta: np.ndarray  #: rad, joint-2 angle from the nominal pose (true, not the noisy sample)
    accel: np.ndarray  #: m/s², base accelerometer (true)
    v: np.ndarray  #: V, valve voltage during step k (after saturation; the later piece of a split step)
    command: np.ndarray  #: V, the controller's held command after step k (NaN without a controller)
    p_load: np.ndarray  #: Pa
    spool: np.ndarray  #: -1...1
    enabled: np.ndarray  #: bool, the controller ran during step k
    final_state: np.ndarray  #: mjSTATE_FULLPHYSICS after the last step
    switch_on_s: float | None = None  #: when the controller was switched on (None: from the start or never)
    switch_jump_v: float | None = None  #: its first command minus what the valve got before (bumpless: ~0)
    diverged_at_s: float | None = None  #: the run stopped here: the simulation diverged (signals end before)
    diverged_what: str = "the simulation"  #: what diverged at ``diverged_at_s``: the simulation, or the controller's output
    frame_t: np.ndarray | None = None  #: s, times of kept qpos frames (``qpos_every``)
    frame_qpos: np.ndarray | None = None  #: (frames, nq)

    @property
    def dt_s(self) -> float:
        return float(self.t[1] - self.t[0]) if self.t.size > 1 else float("nan")


#: Index of the base's acceleration in the controller's inputs w = (theta_ref, theta, accel).
ACCEL_INPUT = 2


def measurements_at(cm: CardModel, state: np.ndarray, theta_ref_rad: float, data: mujoco.MjData | None = None) -> np.ndarray:
    """``w = (theta_ref, theta, accel)`` (SI, noise-free) the card would sample in ``state`` (computed in ``data``, a
    MjData of ``cm.model`` whose state it overwrites; default a new one)."""

    m = cm.model
    d = mujoco.MjData(m) if data is None else data
    mujoco.mj_setState(m, d, np.asarray(state, float), _FULL)
    d.ctrl[:] = 0.0
    d.ctrl[1] = theta_ref_rad
    mujoco.mj_forward(m, d)
    theta_adr = int(m.sensor_adr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, "theta")])
    adr, direction = accel_weights(m)
    theta0 = hydraulic_params(m).reference_angle
    return np.array([theta_ref_rad, d.sensordata[theta_adr] - theta0, d.sensordata[adr : adr + 3] @ direction - cm.accel_offset_m_s2])


def bumpless_state(matrices: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], w: np.ndarray, target_v: float) -> tuple[np.ndarray, float]:
    """Controller state ``z0`` for a switch-on with inputs ``w`` whose first command is ``target_v``.

    ``z0`` is the controller's steady state for the loop at rest at the angles
    of ``w`` (``(I - A) z = B w_rest``, ``w_rest`` = ``w`` with the base's
    acceleration 0: what it would hold had it run all along with the loop at
    rest), moved along ``C^T`` just enough that ``C z0 + D w`` equals
    ``target_v``: the command continues from what the valve was getting
    (bumpless transfer). The acceleration sampled at the switch-on is a moment
    of a vibration, not a level: taken as constant, it gave the damping
    controller (a low-pass of the acceleration, DC gain -8.3 V/(m/s²)) a
    steady command of 0.64 V for -0.077 m/s², and moving its state along its
    small ``C`` (|C| ~ 1e-4) to cancel that command put 1e3-1e4 into the
    filter's states: a transient that drove the valve to its 10 V rail for
    0.3 s and joint 2 to 76 deg in the Loper test. ``matrices`` are the controller's SI ``(A, B, C, D)``
    (:func:`samii.closedloop.card.si_matrices`). Returns ``(z0, jump)``, ``jump``
    the command step that remains (nonzero only for a static controller, which
    has no state to absorb it).
    """
    A, B, C, D = matrices
    n = A.shape[0]
    w = np.asarray(w, float)
    if n == 0:
        return np.zeros(0), float(D[0] @ w - target_v)
    w_rest = w.copy()
    w_rest[ACCEL_INPUT] = 0.0  # at rest the base does not accelerate
    z = np.linalg.lstsq(np.eye(n) - A, B @ w_rest, rcond=None)[0]
    c = C[0]
    cc = float(c @ c)
    if cc > 0:
        z = z + c * (target_v - float(c @ z + D[0] @ w)) / cc
    return z, float(c @ z + D[0] @ w - target_v)


def run_loop(
    cm: CardModel,
    theta_ref_rad: np.ndarray,
    *,
    r_v: np.ndarray | None = None,
    theta_noise_rad: np.ndarray | None = None,
    accel_noise_m_s2: np.ndarray | None = None,
    switch_on_step: int | None = None,
    initial_state: np.ndarray | None = None,
    chunk_steps: int = 2000,
    keep_partial: bool = False,
    qpos_every: int | None = None,
    data: mujoco.MjData | None = None,
) -> LoopSignals:
    """Run ``len(theta_ref_rad)`` physics steps of the closed loop.

    Parameters
    ----------
    cm : CardModel
        From :func:`samii.closedloop.card.build_card_model`.
    theta_ref_rad : array
        Reference offset per physics step [rad].
    r_v, theta_noise_rad, accel_noise_m_s2 : array, optional
        Excitation [V] and sensor noise per physics step (the card samples the
        noise at its sample instants); default zero.
    switch_on_step : int, optional
        The controller runs from this step on (bumplessly, :func:`bumpless_state`);
        before it the servo amplifier runs alone. Default: from step 0.
    initial_state : array, optional
        mjSTATE_FULLPHYSICS start; default the ``home`` keyframe (static equilibrium).
    keep_partial : bool
        On divergence return the signals up to the last good chunk (with
        ``diverged_at_s``) instead of raising :class:`SimulationUnstable`.
    qpos_every : int, optional
        Keep ``qpos`` every this many steps (``frame_t``, ``frame_qpos``: an animation).
    data : MjData, optional
        A MjData of ``cm.model`` to step in (its state is overwritten); default a new one.
    """

    m = cm.model
    theta_ref_rad = np.asarray(theta_ref_rad, float)
    n = theta_ref_rad.size
    if theta_ref_rad.ndim != 1 or n == 0:
        raise ValueError(f"theta_ref_rad must be a non-empty 1-D array, got shape {theta_ref_rad.shape}")
    cols = [np.zeros(n) if x is None else np.asarray(x, float) for x in (r_v, theta_noise_rad, accel_noise_m_s2)]
    for name, x in zip(("r_v", "theta_noise_rad", "accel_noise_m_s2"), cols):
        if x.shape != (n,):
            raise ValueError(f"{name} must have the shape of theta_ref_rad ({n},), got {x.shape}")
    ctrl = np.column_stack([cols[0], theta_ref_rad, cols[1], cols[2]])
    if not np.all(np.isfinite(ctrl)):
        raise ValueError("the closed-loop inputs have a NaN or infinite value")
    if switch_on_step is not None and cm.controller is None:
        raise ValueError("switch_on_step needs a controller")
    if switch_on_step is not None and not 0 <= switch_on_step < n:
        raise ValueError(f"switch_on_step must lie in 0...{n - 1}, got {switch_on_step}")

    data = make_data(m) if data is None else reset_home(m, data)
    L = cm.layout
    if initial_state is None:
        initial_state = np.empty(L.nstate)
        mujoco.mj_getState(m, data, initial_state, _FULL)
    state = np.array(initial_state, float)
    if cm.controller is not None:
        state = cm.set_enabled(state, switch_on_step is None)

    # MuJoCo prints "WARNING: Nan, Inf or huge value in QACC ..." when a run diverges; here divergence is
    # detected (check_rollout) and reported as a result, so the text is silenced for the run's rollouts
    # (they run in this thread) and the previous handler restored after.
    previous_handler = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(_quiet)
    try:
        return _run_segments(cm, ctrl, theta_ref_rad, state, data, switch_on_step, chunk_steps, keep_partial, qpos_every)
    finally:
        mujoco.set_mju_user_warning(previous_handler)


def _quiet(message: str) -> None:
    del message


def _run_segments(cm, ctrl, theta_ref_rad, state, data, switch_on_step, chunk_steps, keep_partial, qpos_every) -> LoopSignals:
    m = cm.model
    L = cm.layout
    n = theta_ref_rad.size
    hp = hydraulic_params(m)
    dt = float(m.opt.timestep)
    t0 = float(state[0])
    theta_adr = int(m.sensor_adr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, "theta")])
    acc_adr, direction = accel_weights(m)
    g_off = cm.accel_offset_m_s2
    segments = [(0, n)] if switch_on_step in (None, 0) else [(0, switch_on_step), (switch_on_step, n)]
    if switch_on_step == 0:
        segments = [(0, n)]
    # the run's states and sensor readings, written by the rollouts in place: row j of ``traj`` is the state before
    # step j and after step j - 1 (at a switch-on the card's flag, counter and states are set in it, which leaves the
    # valve and command slots read from "after" as the step before left them)
    traj = np.empty((n + 1, L.nstate))
    traj[0] = state
    sd_all = np.empty((n, m.nsensordata))
    jump = None
    diverged = None
    what = "the simulation"
    done = 0
    for a, b in segments:
        if switch_on_step is not None and a == switch_on_step:
            w = measurements_at(cm, state, float(theta_ref_rad[a]))
            target = hp.position_gain * (w[0] - w[1]) if cm.replaces_servo else 0.0  # (the servo reads the joint)
            z0, jump = bumpless_state(si_matrices(cm.controller), cm.reads(state, w), target)
            state = traj[a] = cm.set_enabled(state, True, z0)
        lo, size = a, chunk_steps
        while lo < b:
            hi = min(lo + size, b)
            mujoco.rollout.rollout(m, data, state[None, :], ctrl[None, lo:hi], state=traj[None, lo + 1 : hi + 1], sensordata=sd_all[None, lo:hi])
            try:
                check_rollout(data, traj[hi], t0 + hi * dt, hi * dt)
            except SimulationUnstable:
                if not keep_partial:
                    raise
                if size > 10:  # keep what can be kept: step up to the divergence in shorter pieces
                    size = max(10, size // 10)
                    continue
                diverged = t0 + lo * dt
                break
            state = traj[hi]
            done = lo = hi
        if diverged is not None:
            break

    before, after, sd = traj[:done], traj[1 : done + 1], sd_all[:done]
    k = np.arange(done)
    theta_abs = sd[:, theta_adr]
    theta = theta_abs - hp.reference_angle
    if cm.controller is not None:
        v = after[:, L.valve_index()]
        command = after[:, L.command_index()]
        enabled = before[:, L.enabled_index()] != 0
        # while disabled the card still records the servo loop's voltage
        runaway = np.flatnonzero(~(np.abs(command) <= COMMAND_DIVERGED_V))
        if runaway.size:  # the controller's own states have diverged (the plant may still be on the valve's rails)
            if not keep_partial:
                raise SimulationUnstable(
                    f"the controller's output diverged at t = {t0 + runaway[0] * dt:.4g} s "
                    f"(|command| above {COMMAND_DIVERGED_V:g} V); no result written"
                )
            done = int(runaway[0])
            diverged = t0 + done * dt
            what = f"the controller's output (|command| above {COMMAND_DIVERGED_V:g} V)"
            before, after, sd, k = before[:done], after[:done], sd[:done], k[:done]
            theta, v, command, enabled = theta[:done], v[:done], command[:done], enabled[:done]
    else:
        v = np.clip(ctrl[:done, 0] + hp.position_gain * (theta_ref_rad[:done] - theta), -10.0, 10.0)
        command = np.full(done, np.nan)
        enabled = np.zeros(done, bool)
    return LoopSignals(
        t=t0 + k * dt,
        theta_ref=theta_ref_rad[:done].copy(),
        r=ctrl[:done, 0].copy(),
        theta=theta,
        accel=sd[:, acc_adr : acc_adr + 3] @ direction - g_off,
        v=v,
        command=command,
        p_load=before[:, L.act_adr + 1] * hp.supply_pressure,
        spool=before[:, L.act_adr],
        enabled=enabled,
        final_state=state.copy(),
        switch_on_s=None if switch_on_step is None else t0 + switch_on_step * dt,
        switch_jump_v=jump,
        diverged_at_s=diverged,
        diverged_what=what,
        frame_t=None if qpos_every is None else t0 + k[::qpos_every] * dt,
        frame_qpos=None if qpos_every is None else before[::qpos_every, 1 : 1 + m.nq].copy(),
    )
