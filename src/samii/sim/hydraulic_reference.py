"""Pure-Python reference of the ``samii.hydraulic`` actuator plugin (``hydraulic.c``).

This module exists so that tests can hold the C plugin to its equations; simulations use the
plugin. It also carries the configuration rules, which :mod:`samii.sim.plugin` uses to validate a
model before MuJoCo compiles it.

Servo-valve controlled rotary actuator (Merritt, *Hydraulic Control Systems*, 1967: ideal
critical-centre valve driving a motor through two compressible lines), with
``u`` the valve command [V] and ``theta``, ``theta_dot`` the joint angle [rad] and rate [rad/s]::

    v     = clip(u + Kp*(theta_ref - theta), -10, 10)          servo amplifier [V]
    x_dot = (v/V_rated - x)/tau_v,   |x| <= 1                  spool, 1 = full opening
    Q     = Kq * x * ssqrt((Ps - sign(x)*P)/Ps)                orifice flow [m³/s], ssqrt(u) = sign(u) sqrt(|u|)
    P_dot = 4*beta_e/Vt * (Q - Dm*theta_dot - Ctp*P)           load pressure [Pa/s]
    tau   = Dm*P                                               torque [N m]

The plugin keeps ``x`` and ``p = P/Ps`` in ``mjData.act``; so does this module.

Two integrators of the actuator on a plain rotational inertia are provided:
``method="mujoco"`` repeats exactly what ``mj_step`` (Euler integrator) does with the plugin, so
the two agree to rounding error; ``method="continuous"`` integrates the ODE with
:func:`scipy.integrate.solve_ivp` and shows that both discretisations converge to the same
solution.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

__all__ = [
    "AMPLIFIER_LIMIT_V",
    "ATTRIBUTES",
    "OPTIONAL_ATTRIBUTES",
    "VALVE_OPTIONS",
    "HydraulicConfigError",
    "HydraulicParams",
    "InertiaLoad",
    "NOMINAL",
    "ReferenceTrajectory",
    "hydraulic_energy",
    "load_flow",
    "simulate_inertia",
    "state_derivative",
    "valve_voltage",
]

AMPLIFIER_LIMIT_V = 10.0
"""Saturation of the servo amplifier output [V] (issue 2: valve command limited to +-10 V)."""

Rule = Literal["positive", "nonnegative", "finite"]

ATTRIBUTES: Mapping[str, tuple[str, Rule]] = {
    # name: (unit, rule); the order is the plugin's attribute order (hydraulic.c, kAttributes)
    "supply_pressure": ("Pa", "positive"),
    "bulk_modulus": ("Pa", "positive"),
    "total_volume": ("m³", "positive"),
    "displacement": ("m³/rad", "positive"),
    "leakage_coefficient": ("m³/(s Pa)", "nonnegative"),
    "valve_time_constant": ("s", "positive"),
    "rated_flow": ("m³/s", "positive"),
    "rated_voltage": ("V", "positive"),
    "position_gain": ("V/rad", "nonnegative"),
    "reference_angle": ("rad", "finite"),
}
"""Config attributes of the plugin: unit and rule. All are required."""

#: The valve between the amplifier and the spool (hydraulic.c's header): optional attributes,
#: absent or 0 for an ideal valve. name: (unit, lower bound, upper bound, upper bound included).
VALVE_OPTIONS: Mapping[str, tuple[str, float, float, bool]] = {
    "command_delay": ("s", 0.0, 1.0, True),
    "valve_dead_band": ("V", 0.0, AMPLIFIER_LIMIT_V, False),
    "valve_saturation": ("V", 0.0, AMPLIFIER_LIMIT_V, True),
    "valve_asymmetry": ("1", -1.0, 1.0, False),
}

#: Optional attributes after the ten physical ones (hydraulic.c, same order): the servo loop's
#: reference input and the digital controller card (samii.closedloop.card writes them).
OPTIONAL_ATTRIBUTES: tuple[str, ...] = (
    "reference_actuator",
    "controller_states",
    "controller_a",
    "controller_b",
    "controller_c",
    "controller_d",
    "controller_steps",
    "controller_delay_steps",
    "controller_replaces_servo",
    "controller_theta_sensor",
    "controller_accel_sensor",
    "controller_accel_direction",
    "controller_accel_offset",
    "controller_theta_noise",
    "controller_accel_noise",
    "controller_theta_lsb",
    "controller_accel_lsb",
    *VALVE_OPTIONS,
    "controller_theta_filter",
    "controller_theta_sos",
    "controller_theta_rest",
    "controller_accel_filter",
    "controller_accel_sos",
)

_EXPECTED = {
    "positive": "a finite number > 0",
    "nonnegative": "a finite number >= 0",
    "finite": "a finite number",
}


class HydraulicConfigError(ValueError):
    """A ``samii.hydraulic`` config attribute is missing, unparsable or non-physical."""


def _expected(name: str) -> str:
    unit, rule = ATTRIBUTES[name]
    return f"{_EXPECTED[rule]} in {unit}"


def _validated(name: str, raw, source: str) -> float:
    """``raw`` (number or MJCF text) as a float obeying the rule of attribute ``name``."""
    _, rule = ATTRIBUTES[name]
    try:
        # bools are not numbers here; "1_000" is a Python float but not a C strtod number
        value = math.nan if isinstance(raw, bool) or (isinstance(raw, str) and "_" in raw) else float(raw)
    except (TypeError, ValueError):
        value = math.nan
    ok = math.isfinite(value) and (rule == "finite" or (rule == "positive" and value > 0) or (rule == "nonnegative" and value >= 0))
    if not ok:
        raise HydraulicConfigError(f"{source}: config attribute '{name}' = {raw!r} is invalid (expected {_expected(name)})")
    return value


@dataclass(frozen=True, kw_only=True)
class HydraulicParams:
    """Parameters of the valve-controlled rotary actuator, SI units.

    Field names are the MJCF config keys of the plugin.

    Parameters
    ----------
    supply_pressure : float
        Ps [Pa], > 0.
    bulk_modulus : float
        Effective bulk modulus beta_e [Pa], > 0.
    total_volume : float
        Total oil volume of both lines and chambers Vt [m^3], > 0.
    displacement : float
        Motor displacement Dm [m³/rad], > 0.
    leakage_coefficient : float
        Total leakage coefficient Ctp [m³/(s Pa)], >= 0.
    valve_time_constant : float
        Spool lag tau_v [s], > 0.
    rated_flow : float
        Kq [m³/s]: load flow at full opening and zero load pressure, > 0.
    rated_voltage : float
        Command giving full opening [V], > 0.
    position_gain : float
        Servo amplifier position loop Kp [V/rad], >= 0 (0: open loop).
    reference_angle : float
        Set point of the position loop [rad], finite.
    source : str
        Where the values came from, for error messages (not a parameter; ignored by ``==``).
    """

    supply_pressure: float
    bulk_modulus: float
    total_volume: float
    displacement: float
    leakage_coefficient: float
    valve_time_constant: float
    rated_flow: float
    rated_voltage: float
    position_gain: float
    reference_angle: float
    source: str = field(default="samii.hydraulic", compare=False)

    def __post_init__(self) -> None:
        for name in ATTRIBUTES:
            object.__setattr__(self, name, _validated(name, getattr(self, name), self.source))

    @classmethod
    def from_config(cls, config: Mapping[str, str], *, source: str = "samii.hydraulic") -> HydraulicParams:
        """Parse MJCF config strings (key -> value), as the plugin does.

        Raises
        ------
        HydraulicConfigError
            Naming the first missing, unknown, unparsable or non-physical attribute.
        """
        unknown = sorted(set(config) - set(ATTRIBUTES) - set(OPTIONAL_ATTRIBUTES))
        if unknown:
            raise HydraulicConfigError(
                f"{source}: unknown config attribute '{unknown[0]}' (expected one of {', '.join([*ATTRIBUTES, *OPTIONAL_ATTRIBUTES])})"
            )
        for name, (unit, lo, hi, closed) in VALVE_OPTIONS.items():
            text = config.get(name)
            if text is None or str(text).strip() == "":
                continue
            try:
                value = math.nan if "_" in str(text) else float(text)
            except ValueError:
                value = math.nan
            if not (math.isfinite(value) and lo <= value and (value <= hi if closed else value < hi)):
                raise HydraulicConfigError(
                    f"{source}: config attribute '{name}' = {text!r} is invalid (expected a number in {unit} "
                    f"from {lo:g} to {hi:g}{'' if closed else ' (excluded)'}; 0 = none)"
                )
        values = {}
        for name in ATTRIBUTES:
            text = config.get(name)
            if text is None or str(text).strip() == "":
                raise HydraulicConfigError(f"{source}: missing config attribute '{name}' (expected {_expected(name)})")
            values[name] = _validated(name, str(text), source)
        return cls(**values, source=source)

    def to_config(self) -> dict[str, str]:
        """Config strings for MJCF (``repr`` keeps every digit)."""
        return {name: repr(getattr(self, name)) for name in ATTRIBUTES}

    @property
    def hydraulic_stiffness(self) -> float:
        """Oil-column stiffness 4*beta_e*Dm^2/Vt [N m/rad] (the closed-valve oil spring)."""
        return 4 * self.bulk_modulus * self.displacement**2 / self.total_volume

    def hydraulic_frequency(self, inertia: float) -> float:
        """Hydraulic natural frequency omega_h = sqrt(4 beta Dm^2/(Vt J)) [rad/s]."""
        return math.sqrt(self.hydraulic_stiffness / inertia)

    def hydraulic_damping_ratio(self, inertia: float) -> float:
        """Closed-valve damping ratio from leakage, zeta = 2 beta Ctp/(Vt omega_h)."""
        return 2 * self.bulk_modulus * self.leakage_coefficient / (self.total_volume * self.hydraulic_frequency(inertia))

    @property
    def velocity_gain(self) -> float:
        """Open-loop velocity gain K1 = Kq/(V_rated Dm) [rad/s per V] at zero load pressure."""
        return self.rated_flow / (self.rated_voltage * self.displacement)


NOMINAL = HydraulicParams(
    # DESIGN.md "Hydraulic actuator": consistent starting values
    supply_pressure=7e6,  # Ps 7-21 MPa: lower end
    bulk_modulus=0.7e9,  # beta_e ~ 0.7 GPa (oil with entrained air)
    total_volume=20e-6,  # Vt ~ 20 cm^3
    displacement=1.7e-6,  # Dm ~ 1.7 cm³/rad
    valve_time_constant=6.3e-3,  # 1/tau = 159 rad/s, eq 9.4 (tau = 158.869 rad/s)
    rated_voltage=10.0,  # full opening at the +-10 V amplifier limit
    # K1 = Kq/(V_rated*Dm) = 0.488 rad/s/V = 28.0 deg/s/V, eq 9.4 K1 = 27.9 (theta in degrees)
    rated_flow=8.3e-6,
    # zeta = 2 beta Ctp/(Vt omega_h) = 0.143 with J = 0.14 kg m^2 (omega_h = 53.8 rad/s);
    # eq 9.4 zeta_p = 0.140
    leakage_coefficient=1.1e-13,
    position_gain=57.2958,  # 1 V per degree: the rig's unity feedback with theta in degrees
    reference_angle=1.5708,  # joint 2 at the nominal pose, 90 deg
    source="samii.sim.hydraulic_reference.NOMINAL",
)
"""Starting values for tests and documentation; the model's MJCF carries the tuned ones."""


def valve_voltage(params: HydraulicParams, u, theta, *, ctrlrange: tuple[float, float] | None = (-10.0, 10.0)):
    """Servo amplifier output v [V]: command ``u`` (clipped to ``ctrlrange``) plus the position loop.

    ``v = clip(u + Kp*(theta_ref - theta), -10, 10)``. Non-finite ``u`` counts as 0, as in the plugin.
    """
    u = np.where(np.isfinite(u), u, 0.0)
    if ctrlrange is not None:
        u = np.clip(u, *ctrlrange)
    v = u + params.position_gain * (params.reference_angle - np.asarray(theta, float))
    return np.clip(v, -AMPLIFIER_LIMIT_V, AMPLIFIER_LIMIT_V)


def load_flow(params: HydraulicParams, spool, p_ratio):
    """Orifice load flow Q [m³/s] for spool position ``x`` (-1..1) and ``p_ratio`` = P/Ps."""
    x = np.clip(spool, -1.0, 1.0)
    drop = 1.0 - np.sign(x) * np.asarray(p_ratio, float)  # (Ps - sign(x) P) / Ps
    return params.rated_flow * x * np.sign(drop) * np.sqrt(np.abs(drop))  # reverse flow past supply (hydraulic.c)


def state_derivative(params: HydraulicParams, *, spool, p_ratio, theta_dot, voltage):
    """Time derivatives of the actuator states ``(x_dot [1/s], p_dot [1/s])``, p = P/Ps.

    ``voltage`` is the amplifier output (see :func:`valve_voltage`). At the travel limit the spool
    does not move further into the stop.
    """
    x = np.asarray(spool, float)
    x_dot = (np.asarray(voltage, float) / params.rated_voltage - x) / params.valve_time_constant
    x_dot = np.where(((x >= 1) & (x_dot > 0)) | ((x <= -1) & (x_dot < 0)), 0.0, x_dot)
    flow = (
        load_flow(params, x, p_ratio)
        - params.displacement * np.asarray(theta_dot, float)
        - params.leakage_coefficient * params.supply_pressure * np.asarray(p_ratio, float)
    )
    p_dot = 4 * params.bulk_modulus / (params.total_volume * params.supply_pressure) * flow
    return x_dot, p_dot


def hydraulic_energy(params: HydraulicParams, p_load_pa):
    """Energy stored by oil compressibility, ``Vt*P^2/(8*beta_e)`` [J].

    The two lines of volume Vt/2 each carry +-P/2 about the mean pressure; each stores
    (Vt/2)*(P/2)^2/(2*beta_e).
    """
    return params.total_volume * np.square(p_load_pa) / (8 * params.bulk_modulus)


@dataclass(frozen=True)
class InertiaLoad:
    """A plain rotational load on the actuator's hinge.

    Parameters
    ----------
    inertia : float
        J [kg m^2], > 0.
    damping : float
        Viscous damping [N m s/rad], >= 0 (MuJoCo joint ``damping``).
    """

    inertia: float
    damping: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.inertia) and self.inertia > 0):
            raise ValueError(f"inertia must be a finite number > 0 in kg m², got {self.inertia!r}")
        if not (math.isfinite(self.damping) and self.damping >= 0):
            raise ValueError(f"damping must be a finite number >= 0 in N m s/rad, got {self.damping!r}")


@dataclass(frozen=True)
class ReferenceTrajectory:
    """States of the actuator on an inertia at ``time_s`` (arrays of equal length)."""

    time_s: np.ndarray
    theta: np.ndarray
    theta_dot: np.ndarray
    spool: np.ndarray
    p_ratio: np.ndarray

    def p_load_pa(self, params: HydraulicParams) -> np.ndarray:
        """Load pressure [Pa]."""
        return self.p_ratio * params.supply_pressure


def simulate_inertia(
    params: HydraulicParams,
    load: InertiaLoad,
    ctrl: Callable[[float], float],
    *,
    timestep: float,
    n_steps: int,
    initial: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0),
    method: Literal["mujoco", "continuous"] = "mujoco",
    ctrlrange: tuple[float, float] | None = (-10.0, 10.0),
    rtol: float = 1e-10,
) -> ReferenceTrajectory:
    """Simulate the actuator driving a plain inertia.

    Parameters
    ----------
    params, load
        Actuator parameters and load.
    ctrl : callable
        Valve command u(t) [V]. ``method="mujoco"`` holds u(t_n) over step n, as ``data.ctrl``
        set before ``mj_step``.
    timestep : float
        Step [s]; with ``method="continuous"`` only the output grid.
    n_steps : int
        Number of steps; the trajectory has ``n_steps + 1`` samples from t = 0.
    initial : (theta, theta_dot, x, p)
        Initial state, p = P/Ps.
    method : {"mujoco", "continuous"}
        ``"mujoco"``: ``mj_step`` with the Euler integrator and the plugin's ``advance`` (explicit
        Euler of act from the state at t_n; qvel with the joint damping implicit, as MuJoCo's
        Euler does; qpos with the new qvel; then the pressure's ``-Dm*theta_dot`` term re-evaluated
        with the new velocity, the spool stepped exactly (its lag is linear with the command held
        over the step) and clipped to the travel limit). ``"continuous"``:
        :func:`scipy.integrate.solve_ivp` (DOP853) with tolerance ``rtol``.
    ctrlrange : (lo, hi) or None
        Clip of the command, as MuJoCo's ``ctrlrange``.
    """
    if not (timestep > 0 and n_steps >= 1):
        raise ValueError(f"timestep must be > 0 and n_steps >= 1, got {timestep!r}, {n_steps!r}")
    time = np.arange(n_steps + 1) * timestep
    if method == "mujoco":
        states = _simulate_mujoco_euler(params, load, ctrl, timestep, n_steps, initial, ctrlrange)
    elif method == "continuous":
        states = _simulate_continuous(params, load, ctrl, time, initial, ctrlrange, rtol)
    else:
        raise ValueError(f"method must be 'mujoco' or 'continuous', got {method!r}")
    return ReferenceTrajectory(time, *states)


def _simulate_mujoco_euler(params, load, ctrl, h, n_steps, initial, ctrlrange):
    # plain floats: this loop runs per step in tests
    Dm, Ps = params.displacement, params.supply_pressure
    c_p = 4 * params.bulk_modulus / (params.total_volume * Ps)  # d(P/Ps)/dt per unit flow
    J, b = load.inertia, load.damping
    out = np.empty((4, n_steps + 1))
    theta, w, x, p = (float(s) for s in initial)
    out[:, 0] = theta, w, x, p
    for n in range(n_steps):
        v = float(valve_voltage(params, ctrl(n * h), theta, ctrlrange=ctrlrange))
        x_dot, p_dot = (float(d) for d in state_derivative(params, spool=x, p_ratio=p, theta_dot=w, voltage=v))
        torque = Dm * Ps * p
        # mj_Euler: (M + h*B) qacc = qfrc_smooth, qfrc_smooth = torque - B*qvel
        qacc = (torque - b * w) / (J + h * b)
        # mj_advance: act, then qvel, then qpos with the new qvel
        x_n, p = x, p + h * p_dot
        w_new = w + h * qacc
        theta = theta + h * w_new
        # plugin advance: pressure sees the new velocity; exact spool step; spool travel limit
        p -= h * c_p * Dm * (w_new - w)
        if x_dot != 0.0:
            target = x_n + params.valve_time_constant * x_dot
            x = target + (x_n - target) * math.exp(-h / params.valve_time_constant)
        w = w_new
        x = min(max(x, -1.0), 1.0)
        out[:, n + 1] = theta, w, x, p
    return tuple(out)


def _simulate_continuous(params, load, ctrl, time, initial, ctrlrange, rtol):
    from scipy.integrate import solve_ivp  # (lazy: imports scipy, only when called)

    Dm, Ps = params.displacement, params.supply_pressure

    def rhs(t, y):
        theta, w, x, p = y
        v = valve_voltage(params, ctrl(t), theta, ctrlrange=ctrlrange)
        x_dot, p_dot = state_derivative(params, spool=x, p_ratio=p, theta_dot=w, voltage=v)
        return [w, (Dm * Ps * p - load.damping * w) / load.inertia, float(x_dot), float(p_dot)]

    sol = solve_ivp(rhs, (time[0], time[-1]), list(initial), method="DOP853", t_eval=time, rtol=rtol, atol=rtol * 1e-3)
    if not sol.success:
        raise RuntimeError(f"solve_ivp failed: {sol.message}")
    return tuple(sol.y)
