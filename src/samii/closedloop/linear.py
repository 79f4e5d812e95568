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
exact response to the two pieces weights ``Bd``. The card reads theta and accel
through the sensors' dynamics (:meth:`samii.sim.sensor_dynamics.SensorDynamics.filters`,
run every physics step as the plugin runs them): here they are linear
state-space filters on the plant's outputs, from rest, exactly the same filters.

python-control refuses to connect continuous and discrete systems; here
everything is discrete at the physics step, and the stability of the loop is
that of its one-sample map (the product of the per-step maps over one
controller sample), whose eigenvalues are returned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

from samii.closedloop.card import CardModel, si_matrices
from samii.closedloop.run import bumpless_state
from samii.sim.model import make_data, reset_home
from samii.sim.one_step import transition
from samii.sim.plugin import hydraulic_params
from samii.sim.sensors import output_rows

__all__ = ["LinearLoop", "linear_loop", "LinearResponse", "SensorPath", "sensor_paths"]


@dataclass(frozen=True, eq=False)
class SensorPath:
    """A sensor's dynamics as a discrete state-space filter at the physics step: ``s[j+1] = A s[j] + b y[j]``, what the
    card reads ``c s[j] + d y[j]`` (``y`` the plant's output at step j). Zero states are the sensor at rest."""

    A: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: float

    @property
    def n(self) -> int:
        return self.A.shape[0]

    @classmethod
    def fir(cls, taps: np.ndarray) -> SensorPath:
        """``sum_k taps[k] y[j-k]``: the states are the previous inputs, newest first."""
        taps = np.asarray(taps, float)
        n = taps.size - 1
        return cls(np.eye(n, k=-1), np.eye(n)[:, 0] if n else np.zeros(0), taps[1:].copy(), float(taps[0]))

    @classmethod
    def section(cls, q: np.ndarray) -> SensorPath:
        """A second-order section ``(b0, b1, b2, a0, a1, a2)`` in direct form II transposed (its two states as scipy's
        sosfilt and the plugin keep them)."""
        b0, b1, b2, a0, a1, a2 = np.asarray(q, float) / float(q[3])
        return cls(np.array([[-a1, 1.0], [-a2, 0.0]]), np.array([b1 - a1 * b0, b2 - a2 * b0]), np.array([1.0, 0.0]), b0)

    def then(self, other: SensorPath) -> SensorPath:
        """This filter followed by ``other``."""
        n1, n2 = self.n, other.n
        A = np.zeros((n1 + n2, n1 + n2))
        A[:n1, :n1], A[n1:, :n1], A[n1:, n1:] = self.A, np.outer(other.b, self.c), other.A
        return SensorPath(A, np.concatenate([self.b, other.b * self.d]), np.concatenate([other.d * self.c, other.c]), other.d * self.d)


def sensor_paths(cm: CardModel) -> tuple[SensorPath, SensorPath]:
    """(theta, accel): what the card of ``cm`` reads through (its sensors' dynamics and its anti-alias filter) as
    state-space filters at the physics step (pass-through for ideal sensors and no anti-alias filter)."""
    f = cm.filters
    theta, accel = SensorPath.fir(f.theta_taps), SensorPath.fir(f.accel_taps)
    for q in f.theta_sos:
        theta = theta.then(SensorPath.section(q))
    for q in f.accel_sos:
        accel = accel.then(SensorPath.section(q))
    return theta, accel


@dataclass(frozen=True)
class LinearResponse:
    t: np.ndarray  #: s
    theta: np.ndarray  #: rad
    accel: np.ndarray  #: m/s²
    v: np.ndarray  #: V, unsaturated


@dataclass
class LinearLoop:
    """The closed loop of a :class:`CardModel`, linearised."""

    Ad: np.ndarray  #: plant one-step map without the position loop (input: valve voltage)
    bd: np.ndarray  #: its input column [per V]
    c_theta: np.ndarray  #: theta row [rad]
    c_accel: np.ndarray  #: accel row [m/s²]
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
    #: what the card reads of theta and accel: the sensors' dynamics (default ideal sensors)
    sensor_theta: SensorPath = field(default_factory=lambda: SensorPath.fir(np.ones(1)))
    sensor_accel: SensorPath = field(default_factory=lambda: SensorPath.fir(np.ones(1)))

    @property
    def n_sensor(self) -> int:
        return self.sensor_theta.n + self.sensor_accel.n

    def reads(self, s, th, ac):
        """What the card reads of theta and accel, ``th`` and ``ac`` the plant's, ``s`` the sensors' states."""
        st, sa, n_th = self.sensor_theta, self.sensor_accel, self.sensor_theta.n
        return st.c @ s[:n_th] + st.d * th, sa.c @ s[n_th:] + sa.d * ac

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

    def _step(self, x, s, z, buf, held, *, sample: bool, enabled: bool, theta_ref, r):
        """One physics step as the card runs it: the sensors, sample (every ``steps``), the delay line, the valve, the
        plant; of one loop (``x``, ``s``, ``z``, ``buf`` vectors, the rest numbers) or of a batch of ``k`` loops at
        once (each a column: ``x`` (nx, k), ``s`` (ns, k), ``z`` (nz, k), ``buf`` (nb, k), ``held``, ``theta_ref`` and
        ``r`` (k,)). ``s``: the sensors' states, theta's then accel's.

        Returns ``(x, s, z, buf, held, theta, accel, v)``: the next plant, sensor and controller states and delay
        line, the held command, the outputs at this step's start and the valve voltage (the step's later piece).
        """
        th, ac = self.c_theta @ x, self.c_accel @ x
        servo = self.kp * (theta_ref - th)  # (the servo amplifier reads the joint directly)
        read_th, read_ac = self.reads(s, th, ac)
        st, sa, n_th = self.sensor_theta, self.sensor_accel, self.sensor_theta.n
        s = np.concatenate([st.A @ s[:n_th] + np.multiply.outer(st.b, th), sa.A @ s[n_th:] + np.multiply.outer(sa.b, ac)])
        if enabled:
            if sample:
                w = np.stack([theta_ref, read_th, read_ac])
                held = self.C[0] @ z + self.D[0] @ w
                z = self.A @ z + self.B @ w
        else:
            held = servo if self.replaces else np.zeros_like(th)  # the card records what the servo loop commands
        if buf.shape[0]:
            buf = np.concatenate([np.asarray(held)[None], buf[:-1]])
        if enabled:
            m = int(math.floor(self.delay_steps))
            a_old, a_new = self._weights()
            base = r + (0.0 if self.replaces else servo)
            v = base + buf[m]
            u = a_new * v + a_old * (base + buf[m + 1])
        else:
            v = u = r + servo
        return self.Ad @ x + np.multiply.outer(self.bd, u), s, z, buf, held, th, ac, v

    def simulate(
        self, theta_ref: np.ndarray, r: np.ndarray | None = None, *, enabled: np.ndarray | None = None, x0: np.ndarray | None = None
    ) -> LinearResponse:
        """Step the linear loop per physics step, as the card does (``enabled[j]``: the controller runs in step j),
        each step one matrix product (:meth:`step_map`; 3x faster than calling :meth:`_step`, the same to rounding).

        A run that starts enabled starts with the controller at rest; a
        switch-on mid-run initialises it bumplessly, as the nonlinear runner
        does (:func:`samii.closedloop.run.bumpless_state`, from what the card reads).
        ``x0``: initial plant state (deviation from the equilibrium,
        mjd_transitionFD's coordinates); the sensors start at rest.
        """

        theta_ref = np.asarray(theta_ref, float)
        n = theta_ref.size
        r = np.zeros(n) if r is None else np.asarray(r, float)
        enabled = np.full(n, self.has_controller) if enabled is None else np.asarray(enabled, bool)
        nx, ns, nz = self.Ad.shape[0], self.n_sensor, self.A.shape[0]
        dim = nx + ns + nz + self.n_buffer + 1
        state = np.zeros(dim)  # (x, sensors, z, delay line, held command)
        if x0 is not None:
            state[:nx] = x0
        inputs = np.stack([theta_ref, r])
        maps: dict[tuple[bool, bool], tuple[np.ndarray, np.ndarray]] = {}
        counter = 0
        out = np.empty((3, n))
        for j in range(n):
            if enabled[j] and (j == 0 or not enabled[j - 1]):
                counter = 0
                if j > 0:  # switched on mid-run
                    x, s = state[:nx], state[nx : nx + ns]
                    th, ac = float(self.c_theta @ x), float(self.c_accel @ x)
                    read = np.array([theta_ref[j], *self.reads(s, th, ac)])
                    target = self.kp * (theta_ref[j] - th) if self.replaces else 0.0
                    state[nx + ns : nx + ns + nz], _ = bumpless_state((self.A, self.B, self.C, self.D), read, target)
            key = (bool(enabled[j]), counter % self.steps == 0)
            if key not in maps:
                maps[key] = self.step_map(*key)
            m_state, m_input = maps[key]
            nxt = m_state @ state + m_input @ inputs[:, j]
            state, out[:, j] = nxt[:dim], nxt[dim:]
            counter += bool(enabled[j])
        return LinearResponse(np.arange(n) * self.dt_s, out[0], out[1], out[2])

    def step_map(self, enabled: bool, sample: bool) -> tuple[np.ndarray, np.ndarray]:
        """One physics step (:meth:`_step`) as the linear map it is: ``[X'; y] = Ms X + Mu (theta_ref, r)``, ``X`` the
        plant state, the sensors' states, the controller state, the delay line and the held command, ``y`` theta,
        accel and the valve voltage at the step's start. Built from :meth:`_step` itself, every unit column probed at
        once as a batch (exact: the step has no constant term), so the loop that applies it is the card's logic, one
        matrix product per step."""
        nx, ns, nz, nb = self.Ad.shape[0], self.n_sensor, self.A.shape[0], self.n_buffer
        dim = nx + ns + nz + nb + 1
        e = np.eye(dim + 2)
        x, s, z, buf, held = e[:nx], e[nx : nx + ns], e[nx + ns : nx + ns + nz], e[nx + ns + nz : dim - 1], e[dim - 1]
        x2, s2, z2, buf2, held2, th, ac, v = self._step(x, s, z, buf, held, sample=sample, enabled=enabled, theta_ref=e[dim], r=e[dim + 1])
        M = np.vstack([x2, s2, z2, buf2, held2, th, ac, v])
        return M[:, :dim], M[:, dim:]

    def sample_map(self) -> np.ndarray:
        """The loop's one-sample map (controller running, zero inputs) on ``(x, sensors, z, delay line)``: the sampling
        step's map, then ``steps - 1`` steps holding the command (:meth:`step_map`). The held command starts
        no sample's map: the sampling step overwrites it, controller running or not."""
        first, _ = self.step_map(self.has_controller, True)
        hold, _ = self.step_map(self.has_controller, False)
        dim = first.shape[1]
        phi = first[:dim]
        for _ in range(self.steps - 1):
            phi = hold[:dim] @ phi
        return phi[:-1, :-1]

    def poles_z(self) -> np.ndarray:
        """Eigenvalues of the one-sample map (stable when all ``|z| < 1``)."""
        return np.linalg.eigvals(self.sample_map())

    def poles_s(self) -> np.ndarray:
        """``log(z) / T`` of :meth:`poles_z`, ``T`` the controller's sample time (zero eigenvalues dropped)."""
        z = self.poles_z()
        z = z[np.abs(z) > 1e-12]
        return np.log(z.astype(complex)) / (self.steps * self.dt_s)


def linear_loop(cm: CardModel, *, eps: float = 1e-6, data: mujoco.MjData | None = None) -> LinearLoop:
    """The linearised closed loop of ``cm`` about its ``home`` equilibrium (computed in ``data``, a MjData of
    ``cm.model`` whose state it overwrites; default a new one)."""

    m = cm.model
    data = make_data(m) if data is None else reset_home(m, data)
    if cm.controller is not None:
        # linearise the plant with the card switched off: the servo amplifier alone, whose gain is
        # taken out below (an enabled card would act inside the finite differences from its frozen
        # delay line and states, which mjd_transitionFD does not perturb)
        full = mujoco.mjtState.mjSTATE_FULLPHYSICS
        state = np.empty(mujoco.mj_stateSize(m, full))
        mujoco.mj_getState(m, data, state, full)
        mujoco.mj_setState(m, data, cm.set_enabled(state, False), full)
    Ad, Bd, Cs, Ds = transition(m, data, eps, True)
    if np.max(np.abs(Ds[:, 0])) > 1e-9 * max(1.0, np.max(np.abs(Cs))):
        raise RuntimeError("the sensors feed through from the valve command: the linear loop assumes they do not")
    hp = hydraulic_params(m)
    r_theta, w_accel = output_rows(m)
    c_theta, c_accel = Cs[r_theta], w_accel @ Cs
    bd = Bd[:, 0]
    # the plugin's position loop (v = u + Kp (theta_0 + theta_r - theta)) taken out: input v
    Ad_v = Ad + hp.position_gain * np.outer(bd, c_theta)
    if cm.controller is not None:
        A, B, C, D = si_matrices(cm.controller)
    else:
        A, B, C, D = np.zeros((0, 0)), np.zeros((0, 3)), np.zeros((1, 0)), np.zeros((1, 3))
    sensor_theta, sensor_accel = sensor_paths(cm)
    return LinearLoop(
        Ad=Ad_v, bd=bd, c_theta=c_theta, c_accel=c_accel, kp=hp.position_gain, dt_s=float(m.opt.timestep),
        A=A, B=B, C=C, D=D, steps=cm.steps_per_sample, delay_steps=cm.delay_samples * cm.steps_per_sample,
        replaces=cm.replaces_servo, has_controller=cm.controller is not None, tau_v=hp.valve_time_constant,
        sensor_theta=sensor_theta, sensor_accel=sensor_accel,
    )  # fmt: skip
