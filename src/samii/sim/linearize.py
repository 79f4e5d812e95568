"""Linearise the simulator at static equilibrium; modes and transfer functions.

MuJoCo's finite-difference transition derivatives (``mjd_transitionFD``) give
the one-step map of the simulator, hydraulic plugin states included::

    x[k+1] = Ad x[k] + Bd u[k],   y[k] = C x[k] + D u[k]

with x = (dqpos, qvel, act) and u = ctrl (the excitation in volts added to the
servo amplifier's position loop). The continuous-time model is the exact
zero-order-hold inverse, ``[[A, B], [0, 0]] = logm([[Ad, Bd], [0, I]]) / dt``,
so its poles are ``log(z)/dt``: what the simulator does, not an approximation
of it, and close to the ODE for dt well below the fastest mode.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import scipy.linalg

from samii.sim.equilibrium import static_equilibrium
from samii.sim.model import held_joint2_model, load_model, load_spec, make_data
from samii.sim.one_step import one_step_poles, transition
from samii.sim.plugin import hydraulic_params, valve_options
from samii.sim.sensors import output_rows

__all__ = [
    "LinearModel",
    "BaseCoefficient",
    "Mode",
    "UNSTABLE_RATE_1_S",
    "discrete_poles",
    "poles_per_s",
    "linearize",
    "modes_from_poles",
    "base_modes",
    "ModesReport",
    "modes_report",
]


@dataclass(frozen=True)
class Mode:
    freq_hz: float  #: undamped natural frequency |s|/2pi
    zeta: float  #: damping ratio -Re(s)/|s|

    @property
    def pole(self) -> complex:
        wn = 2 * np.pi * self.freq_hz
        return complex(-self.zeta * wn, wn * np.sqrt(max(0.0, 1 - self.zeta**2)))


@dataclass(frozen=True)
class BaseCoefficient:
    """One mode of xdd/theta in the notebook's eq 9.2 form (see :meth:`LinearModel.base_coefficients`)."""

    freq_hz: float
    zeta: float
    B: float  #: the modal coefficient's real part [m/rad]
    B_imag: float  #: imaginary part (0 for a proportionally damped mode)


@dataclass(frozen=True)
class _StateSpace:
    """``A, B, C, D`` of the simulator about its equilibrium at the physics step ``dt_s``. Input: ctrl [V]; outputs:
    theta [rad], accel [m/s²]."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray  #: rows: theta, accel
    D: np.ndarray
    dt_s: float
    #: servo amplifier position gain [V/rad] the model was linearised with
    position_gain_v_per_rad: float


@dataclass(frozen=True)
class LinearModel(_StateSpace):
    """Continuous-time linearisation. Input: ctrl [V]; outputs: theta [rad], accel [m/s²]."""

    outputs: tuple[str, ...] = ("theta", "accel")
    #: The valve's command delay [s] (``hydraulic.command_delay``): not in A, B (the state space is
    #: the plant with an ideal valve); the responses to v are multiplied by exp(-s T)
    #: (``samii.measure.campaign.linearised_frf``). Poles and closed-loop responses here leave it out.
    command_delay_s: float = 0.0

    @property
    def poles(self) -> np.ndarray:
        return np.linalg.eigvals(self.A)

    def open_loop(self) -> LinearModel:
        """The same system with the position loop opened: input v [V], the valve voltage.

        With v = r - Kp theta (unsaturated) the state equation in terms of v is
        dx = (A - B Kp C_theta) x + B r = (A_cl + B Kp C_theta) ... i.e. A_ol = A_cl + Kp B C_theta.
        """
        kp = self.position_gain_v_per_rad
        A = self.A + kp * self.B @ self.C[:1]
        C = self.C + kp * self.D @ self.C[:1]
        return LinearModel(A, self.B, C, self.D, self.dt_s, 0.0, self.outputs, self.command_delay_s)

    def frequency_response(self, freq_hz: np.ndarray) -> dict[str, np.ndarray]:
        """Complex response of each output to ctrl at ``freq_hz``: C (jw - A)^-1 B + D."""
        freq_hz = np.atleast_1d(np.asarray(freq_hz, float))
        n = self.A.shape[0]
        out = np.empty((len(self.outputs), freq_hz.size), complex)
        eye = np.eye(n)
        for k, f in enumerate(freq_hz):
            x = np.linalg.solve(2j * np.pi * f * eye - self.A, self.B[:, 0])
            out[:, k] = self.C @ x + self.D[:, 0]
        return dict(zip(self.outputs, out))

    def base_coefficients(self, *, max_freq_hz: float = 45.0) -> list[BaseCoefficient]:
        """The simulator's xdd/theta in the notebook's modal form (eq 9.2),
        ``xdd/theta = s^4 sum_k B_k / (s^2 + 2 zeta_k w_k s + w_k^2)``, one term per complex
        pole pair of xdd/theta below ``max_freq_hz``.

        The poles of xdd/theta are the zeros of theta/v (joint 2 held still); B_k is the residue
        of xdd/theta at the upper pole p_k times (p_k - conj p_k)/p_k^4, taken as a contour
        integral on a small circle about p_k (exact for a simple pole, no polynomial fitting).
        Units: xdd/theta is (m/s²)/rad and s^4/(s^2 + ...) is s^-2, so B_k is in m/rad
        (the tip displacement per radian of joint 2 that mode k contributes above its
        frequency). Its imaginary part (``B_imag``) measures how far the true response is from
        the real-coefficient form of eq 9.2.
        """
        import control  # (lazy: imports control, only when called)

        ol = self.open_loop()
        n = ol.A.shape[0]
        eye = np.eye(n)

        def base(s: complex) -> complex:
            y = ol.C @ np.linalg.solve(s * eye - ol.A, ol.B[:, 0]) + ol.D[:, 0]
            return complex(y[1] / y[0])

        zeros = control.zeros(control.ss(ol.A, ol.B, ol.C[:1], ol.D[:1]))
        zeros = zeros[(zeros.imag > 1e-9) & (np.abs(zeros) <= 2 * np.pi * max_freq_hz)]
        out = []
        ring = np.exp(2j * np.pi * np.arange(32) / 32)
        for p in sorted(zeros, key=abs):
            r = 1e-4 * abs(p)
            residue = np.mean([base(p + r * e) * r * e for e in ring])
            b = residue * (p - np.conj(p)) / p**4
            out.append(BaseCoefficient(float(abs(p) / (2 * np.pi)), float(-p.real / abs(p)), float(b.real), float(b.imag)))
        return out


def _to_continuous(Ad: np.ndarray, Bd: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    n, m = Bd.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = Ad
    M[:n, n:] = Bd
    M[n:, n:] = np.eye(m)
    L = scipy.linalg.logm(M).real / dt
    return L[:n, :n], L[:n, n:]


def linearize(
    model: mujoco.MjModel, data: mujoco.MjData | None = None, *, position_gain_v_per_rad: float | None = None, eps: float = 1e-6
) -> LinearModel:
    """Linearise ``model`` about ``data`` (default: its ``home`` keyframe), with an ideal valve
    (its command delay kept aside in ``command_delay_s``; a dead band or saturation left out:
    the plant without the valve's law).

    ``position_gain_v_per_rad`` is the servo amplifier gain compiled into the
    model (read from the plugin config when not given).
    """
    d = linearize_discrete(model, data, position_gain_v_per_rad=position_gain_v_per_rad, eps=eps)
    A, B = _to_continuous(d.A, d.B, d.dt_s)
    # Sensor derivatives are taken against the discrete state at the same instant,
    # so they carry over to continuous time unchanged.
    return LinearModel(A, B, d.C, d.D, d.dt_s, d.position_gain_v_per_rad, command_delay_s=d.command_delay_s)


@dataclass(frozen=True)
class DiscreteLinearModel(_StateSpace):
    """The one-step map ``x[k+1] = A x[k] + B ctrl[k]``, ``y = C x + D ctrl`` at the physics step (what
    :func:`linearize` takes the matrix logarithm of): for responses of the sampled simulator, which need
    no continuous-time model (``samii.measure.campaign.linearised_frf``)."""

    command_delay_s: float = 0.0  #: as :attr:`LinearModel.command_delay_s`


def linearize_discrete(
    model: mujoco.MjModel, data: mujoco.MjData | None = None, *, position_gain_v_per_rad: float | None = None, eps: float = 1e-6
) -> DiscreteLinearModel:
    """:func:`linearize`'s one-step map, before its conversion to continuous time."""
    if data is None:
        data = make_data(model)
    if position_gain_v_per_rad is None:
        position_gain_v_per_rad = hydraulic_params(model).position_gain
    Ad, Bd, Cs, Ds = transition(model, data, eps, True)
    r_theta, w_accel = output_rows(model)
    C = np.vstack([Cs[r_theta], w_accel @ Cs])
    D = np.vstack([Ds[r_theta], w_accel @ Ds])
    delay = 0.0
    if model.nplugin:
        delay = valve_options(model)["command_delay"]
    return DiscreteLinearModel(Ad, Bd, C, D, float(model.opt.timestep), float(position_gain_v_per_rad), delay)


#: Growth rate [1/s] above which a pole counts as unstable: a time constant of 11.6 days. Anything
#: slower is round-off about a marginal pole (the logarithm of |z| = 1 + 1e-13 at dt = 1 ms is 1e-10 1/s).
UNSTABLE_RATE_1_S = 1e-6


def discrete_poles(model: mujoco.MjModel, data: mujoco.MjData | None = None, *, eps: float = 1e-6) -> np.ndarray:
    """Eigenvalues z of the one-step map about ``data`` (default the ``home`` keyframe): the simulator is
    stable there when every ``|z| <= 1``; ``log(z)/dt`` are its poles, with no matrix logarithm taken."""
    return one_step_poles(model, make_data(model) if data is None else data, eps=eps)


def poles_per_s(model: mujoco.MjModel, data: mujoco.MjData | None = None) -> np.ndarray:
    """The poles [1/s] of :func:`discrete_poles`' one-step map, ``log(z)/dt`` (no matrix logarithm): a real part above
    :data:`UNSTABLE_RATE_1_S` grows."""
    return np.log(discrete_poles(model, data).astype(complex)) / float(model.opt.timestep)


def modes_from_poles(poles: np.ndarray, *, max_freq_hz: float = np.inf) -> list[Mode]:
    """Oscillatory modes (one per complex pair, Im > 0), sorted by frequency."""
    poles = np.asarray(poles, complex)
    osc = poles[poles.imag > 1e-9]
    wn = np.abs(osc)
    modes = [Mode(float(w / (2 * np.pi)), float(-p.real / w)) for p, w in zip(osc, wn) if w / (2 * np.pi) <= max_freq_hz]
    return sorted(modes, key=lambda m: m.freq_hz)


def base_modes(spec: mujoco.MjSpec, theta2_rad: float, *, max_freq_hz: float = 45.0) -> list[Mode]:
    """Modes with joint 2 held at ``theta2_rad`` (link 2 welded), below ``max_freq_hz``."""

    held = held_joint2_model(spec, theta2_rad)
    eq = static_equilibrium(held)
    data = mujoco.MjData(held)
    data.qpos[:] = eq.qpos
    data.act[:] = eq.act
    mujoco.mj_forward(held, data)
    z = one_step_poles(held, data).astype(complex)
    s = np.log(z) / held.opt.timestep
    return modes_from_poles(s, max_freq_hz=max_freq_hz)


@dataclass(frozen=True)
class ModesReport:
    pose_deg: tuple[float, ...]  #: arm joint angles at equilibrium [deg]
    base_modes: tuple[Mode, ...]  #: joint 2 held
    coupled_poles: np.ndarray  #: whole system, servo position loop closed (all poles, sorted by |s|)
    position_gain_v_per_rad: float

    def as_json(self) -> dict:
        return {
            "pose_deg": [round(a, 6) for a in self.pose_deg],
            "base_modes": [{"freq_hz": m.freq_hz, "zeta": m.zeta} for m in self.base_modes],
            "coupled_poles": [[float(p.real), float(p.imag)] for p in self.coupled_poles],
            "stable": self.stable,
            "unstable_poles": [[float(p.real), float(p.imag)] for p in self.unstable_poles],
        }

    @property
    def unstable_poles(self) -> list[complex]:
        """Poles of the coupled system (servo loop closed) growing faster than ``UNSTABLE_RATE_1_S``."""
        return [p for p in self.coupled_poles if p.real > UNSTABLE_RATE_1_S]

    @property
    def stable(self) -> bool:
        """Whether the nominal pose is a stable rest state of the simulator under its servo loop."""
        return not self.unstable_poles


def modes_report(path=None, *, overrides=None, max_freq_hz: float = 45.0) -> ModesReport:
    """Base modes (joint 2 held) and the coupled system's poles below ``max_freq_hz``."""
    spec, _ = load_spec(path, overrides=overrides)
    model = load_model(path, overrides=overrides)
    data = make_data(model)
    arm = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"joint{i}") for i in range(1, 7)]
    pose = tuple(float(np.degrees(data.qpos[model.jnt_qposadr[j]])) for j in arm)
    theta2 = float(data.qpos[model.jnt_qposadr[arm[1]]])
    lin = linearize(model, data)
    poles = lin.poles
    poles = poles[np.abs(poles) <= 2 * np.pi * max_freq_hz]
    poles = poles[np.argsort(np.abs(poles) + 1e-9 * poles.imag)]
    return ModesReport(pose, tuple(base_modes(spec, theta2, max_freq_hz=max_freq_hz)), poles, lin.position_gain_v_per_rad)
