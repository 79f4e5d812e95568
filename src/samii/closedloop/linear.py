"""Linear prediction of a closed loop: the same loop on the linearised simulator, in discrete time.

The plant is the simulator's own one-step map about the ``home`` equilibrium
(``mjd_transitionFD``: ``x[j+1] = Ad x[j] + Bd u[j]``, sensors ``y[j] = Cs x[j]``
at the physics step ``h``), which *is* the ZOH discretisation of the
linearised plant; the servo amplifier's gain is taken out of it
(``Ad + Kp Bd C_theta``) so that the loop logic can be put back exactly as the
controller card runs it (:mod:`samii.closedloop.card`): the controller as
designed (discrete, at its sample time), its delay as a delay line of held
commands (``z^-n``), the position loop added or replaced. Only the saturation
is missing. The input enters the map through the spool alone
(``Bd`` is zero but for the spool row, and the sensors do not feed through),
so a fractional delay, which splits a step in two, is exact too: the spool's
exact response to the two pieces weights ``Bd``.

python-control refuses to connect continuous and discrete systems; here
everything is discrete at the physics step, and the stability of the loop is
that of its one-sample map (the product of the per-step maps over one
controller sample), whose eigenvalues are returned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from samii.closedloop.card import CardModel, si_matrices

__all__ = ["LinearLoop", "linear_loop", "LinearResponse"]


@dataclass(frozen=True)
class LinearResponse:
    t: np.ndarray  #: s
    theta: np.ndarray  #: rad
    accel: np.ndarray  #: m/s^2
    v: np.ndarray  #: V, unsaturated


@dataclass
class LinearLoop:
    """The closed loop of a :class:`CardModel`, linearised."""

    Ad: np.ndarray  #: plant one-step map without the position loop (input: valve voltage)
    bd: np.ndarray  #: its input column [per V]
    c_theta: np.ndarray  #: theta row [rad]
    c_accel: np.ndarray  #: accel row [m/s^2]
    kp: float  #: servo amplifier gain [V/rad]
    dt_s: float  #: physics step
    A: np.ndarray  #: controller (SI inputs theta_ref, theta, accel), empty without one
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    steps: int  #: physics steps per controller sample
    delay_steps: float  #: computation delay [physics steps]
    replaces: bool
    has_controller: bool
    tau_v: float  #: valve time constant (splits a step for a fractional delay)

    @property
    def n_buffer(self) -> int:
        return int(math.floor(self.delay_steps)) + 2 if self.has_controller else 0

    def _weights(self) -> tuple[float, float]:
        """Weights of the older and the newer command in a step split by a fractional delay."""
        f = self.delay_steps - math.floor(self.delay_steps)
        if f == 0:
            return 0.0, 1.0
        h, tau = self.dt_s, self.tau_v
        full = 1 - math.exp(-h / tau)
        return (1 - math.exp(-f * h / tau)) * math.exp(-(1 - f) * h / tau) / full, (1 - math.exp(-(1 - f) * h / tau)) / full

    def simulate(self, theta_ref: np.ndarray, r: np.ndarray | None = None, *, enabled: np.ndarray | None = None,
                 x0: np.ndarray | None = None) -> LinearResponse:
        """Step the linear loop per physics step, as the card does (``enabled[j]``: the controller runs in step j).

        A run that starts enabled starts with the controller at rest; a
        switch-on mid-run initialises it bumplessly, as the nonlinear runner
        does (:func:`samii.closedloop.run.bumpless_state`). ``x0``: initial
        plant state (deviation from the equilibrium, mjd_transitionFD's coordinates).
        """
        from samii.closedloop.run import bumpless_state

        theta_ref = np.asarray(theta_ref, float)
        n = theta_ref.size
        r = np.zeros(n) if r is None else np.asarray(r, float)
        enabled = np.full(n, self.has_controller) if enabled is None else np.asarray(enabled, bool)
        x = np.zeros(self.Ad.shape[0]) if x0 is None else np.array(x0, float)
        nz = self.A.shape[0]
        z = np.zeros(nz)
        buf = np.zeros(max(self.n_buffer, 1))
        m = int(math.floor(self.delay_steps))
        a_old, a_new = self._weights()
        held, counter, was = 0.0, 0, False
        out_th, out_ac, out_v = np.empty(n), np.empty(n), np.empty(n)
        for j in range(n):
            th = float(self.c_theta @ x)
            ac = float(self.c_accel @ x)
            servo = self.kp * (theta_ref[j] - th)
            if enabled[j]:
                if not was:
                    counter = 0
                    if j > 0:
                        w = np.array([theta_ref[j], th, ac])
                        z, _ = bumpless_state((self.A, self.B, self.C, self.D), w, servo if self.replaces else 0.0)
                if counter % self.steps == 0:
                    w = np.array([theta_ref[j], th, ac])
                    held = float(self.C[0] @ z + self.D[0] @ w) if nz else float(self.D[0] @ w)
                    if nz:
                        z = self.A @ z + self.B @ w
                counter += 1
            else:
                held = servo if self.replaces else 0.0
            if self.has_controller:
                buf[1:] = buf[:-1]
                buf[0] = held
            if enabled[j]:
                base = r[j] + (0.0 if self.replaces else servo)
                v_new = base + buf[m]
                u = a_new * v_new + (a_old * (base + buf[m + 1]) if a_old else 0.0)
            else:
                v_new = u = r[j] + servo
            out_th[j], out_ac[j], out_v[j] = th, ac, v_new
            x = self.Ad @ x + self.bd * u
            was = bool(enabled[j])
        return LinearResponse(np.arange(n) * self.dt_s, out_th, out_ac, out_v)

    def sample_map(self) -> np.ndarray:
        """The loop's one-sample map (controller running, zero inputs) on ``(x, z, delay line)``."""
        nx, nz, nb = self.Ad.shape[0], self.A.shape[0], self.n_buffer
        dim = nx + nz + nb
        Phi = np.empty((dim, dim))
        m = int(math.floor(self.delay_steps))
        a_old, a_new = self._weights()
        for col in range(dim):
            X = np.zeros(dim)
            X[col] = 1.0
            x, z, buf = X[:nx].copy(), X[nx:nx + nz].copy(), X[nx + nz:].copy()
            held = 0.0
            for k in range(self.steps):
                th, ac = float(self.c_theta @ x), float(self.c_accel @ x)
                if k == 0:
                    w = np.array([0.0, th, ac])
                    held = float(self.C[0] @ z + self.D[0] @ w) if nz else float(self.D[0] @ w)
                    if nz:
                        z = self.A @ z + self.B @ w
                if nb:
                    buf[1:] = buf[:-1]
                    buf[0] = held
                base = 0.0 if self.replaces else -self.kp * th
                u = a_new * (base + (buf[m] if nb else 0.0)) + (a_old * (base + buf[m + 1]) if a_old else 0.0)
                x = self.Ad @ x + self.bd * u
            Phi[:, col] = np.concatenate([x, z, buf])
        return Phi

    def poles_z(self) -> np.ndarray:
        """Eigenvalues of the one-sample map (stable when all ``|z| < 1``)."""
        return np.linalg.eigvals(self.sample_map())

    def poles_s(self) -> np.ndarray:
        """``log(z) / T`` of :meth:`poles_z`, ``T`` the controller's sample time (zero eigenvalues dropped)."""
        z = self.poles_z()
        z = z[np.abs(z) > 1e-12]
        return np.log(z.astype(complex)) / (self.steps * self.dt_s)


def linear_loop(cm: CardModel, *, eps: float = 1e-6) -> LinearLoop:
    """The linearised closed loop of ``cm`` about its ``home`` equilibrium."""
    from samii.sim.linearize import _discrete, _sensor_rows
    from samii.sim.model import make_data
    from samii.sim.plugin import hydraulic_params

    m = cm.model
    data = make_data(m)
    if cm.controller is not None:
        # linearise the plant with the card switched off: the servo amplifier alone, whose gain is
        # taken out below (an enabled card would act inside the finite differences from its frozen
        # delay line and states, which mjd_transitionFD does not perturb)
        full = mujoco.mjtState.mjSTATE_FULLPHYSICS
        state = np.empty(mujoco.mj_stateSize(m, full))
        mujoco.mj_getState(m, data, state, full)
        mujoco.mj_setState(m, data, cm.set_enabled(state, False), full)
    Ad, Bd, Cs, Ds = _discrete(m, data, eps, True)
    if np.max(np.abs(Ds[:, 0])) > 1e-9 * max(1.0, np.max(np.abs(Cs))):
        raise RuntimeError("the sensors feed through from the valve command: the linear loop assumes they do not")
    hp = hydraulic_params(m)
    r_theta, w_accel = _sensor_rows(m)
    c_theta, c_accel = Cs[r_theta], w_accel @ Cs
    bd = Bd[:, 0]
    # the plugin's position loop (v = u + Kp (theta_0 + theta_r - theta)) taken out: input v
    Ad_v = Ad + hp.position_gain * np.outer(bd, c_theta)
    if cm.controller is not None:
        A, B, C, D = si_matrices(cm.controller)
    else:
        A, B, C, D = np.zeros((0, 0)), np.zeros((0, 3)), np.zeros((1, 0)), np.zeros((1, 3))
    return LinearLoop(
        Ad=Ad_v, bd=bd, c_theta=c_theta, c_accel=c_accel, kp=hp.position_gain, dt_s=float(m.opt.timestep),
        A=A, B=B, C=C, D=D, steps=cm.steps_per_sample, delay_steps=cm.delay_samples * cm.steps_per_sample,
        replaces=cm.replaces_servo, has_controller=cm.controller is not None, tau_v=hp.valve_time_constant,
    )  # fmt: skip
