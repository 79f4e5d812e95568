"""The controller card: a discrete controller compiled into the hydraulic plugin, so a closed loop runs at ``mj_step`` speed.

The rig's controller is a computer that samples the joint angle and the base
accelerometer, computes a valve command and holds it (zero-order hold) until
the next sample; the analog servo amplifier adds its own position loop. The
``samii.hydraulic`` plugin models both (``hydraulic.c``, "controller card"):

- the servo amplifier: ``v = clamp(u + Kp (theta_0 + theta_r - theta) [+ c], +-10 V)``,
  ``u`` the excitation (the hydraulic actuator's ctrl) and ``theta_r`` the
  reference offset (the ctrl of a second, force-free actuator ``theta_ref``);
- the card: every ``steps`` physics steps it samples ``w = (theta_r, theta, accel)``
  at ``t_k`` (SI; optional noise from two more force-free actuators and ADC
  quantisation) as the rig's sensors give them: through the model's sensor
  dynamics (:mod:`samii.sim.sensor_dynamics`: delays, an accelerometer's roll-off,
  an anti-alias filter, AC coupling, a gain error), the same filters at the
  physics rate as a measurement's, and optionally its own data acquisition's
  anti-alias filter on both (:func:`card_filters`), run every step; it computes ``c = C z + D w`` and ``z <- A z + B w``, and the valve
  sees ``c`` after ``delay_steps`` physics steps (fractional delays split the
  step and integrate the spool exactly over both pieces). While the card
  replaces the servo loop (``replaces_servo``) the ``Kp`` term is dropped.

The card's state (``plugin_state``: enabled flag, step counter, the applied valve
voltage, the held command, the delay line and ``z``) is part of
``mjSTATE_FULLPHYSICS``, so ``mujoco.rollout`` carries it and the runner can
switch the card on mid-run (:func:`CardModel.set_enabled`).

This module turns a :class:`samii.controller.LinearController` (in its
design units, with ``input_scale`` converting SI to them) into that configuration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

from samii.controller import LinearController
from samii.errors import InputError
from samii.measure.daq import antialias_cutoff_hz, antialias_sos
from samii.sim.model import ACTUATOR, JOINT
from samii.sim.plugin import command_ring_entries, compile_spec, hydraulic_params
from samii.sim.sensor_dynamics import SensorDynamics
from samii.sim.sensors import accel_offset, accel_weights

__all__ = [
    "CardFilters",
    "card_filters",
    "default_antialias_hz",
    "CardFitError",
    "CardModel",
    "CardLayout",
    "build_card_model",
    "check_fit",
    "si_matrices",
    "MAX_DELAY_STEPS",
    "MAX_SAMPLE_STEPS",
    "MAX_STATES",
    "INPUTS",
]

#: Column order of the card's inputs (SI: rad, rad, m/s²).
INPUTS = ("theta_ref", "theta", "accel")
#: Limits compiled into hydraulic.c (CTRL_MAX_STATES, CTRL_MAX_DELAY_STEPS).
MAX_STATES = 64
MAX_DELAY_STEPS = 200

REFERENCE_ACTUATOR = "theta_ref"
THETA_NOISE_ACTUATOR = "theta_noise"
ACCEL_NOISE_ACTUATOR = "accel_noise"

# plugin_state layout (hydraulic.c: ST_ENABLED, ST_COUNTER, ST_VALVE, ST_COMMAND, ST_BUFFER)
_ST_ENABLED, _ST_COUNTER, _ST_VALVE, _ST_COMMAND, _ST_BUFFER = range(5)
# the sensors' block after the controller's states (hydraulic.c: SN_COUNT, SN_RINGS)
_SN_COUNT, _SN_RINGS = range(2)


#: Longest controller sample [physics steps]: 1 s at 1 ms (base mode 1 has a 0.58 s period).
MAX_SAMPLE_STEPS = 1000


class CardFitError(InputError):
    """A controller the card cannot run: ``field`` is ``"states"``, ``"sample_time_s"`` or ``"delay_samples"``."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field


def check_fit(controller: LinearController, dt: float, delay_samples: float) -> int:
    """The controller's sample time in physics steps of ``dt``; :class:`CardFitError` if the card cannot run it."""
    if controller.n_states > MAX_STATES:
        raise CardFitError("states", f"{controller.n_states} states; the controller card holds at most {MAX_STATES}")
    T = controller.sample_time_s
    ratio = T / dt
    steps = round(ratio)
    if not (1 <= steps <= MAX_SAMPLE_STEPS and abs(ratio - steps) <= 1e-9 * max(1.0, ratio)):
        faster = f" (a controller faster than the physics runs on a model with a shorter step: --set timestep_s={T:g})" if T < dt else ""
        raise CardFitError("sample_time_s", f"field 'sample_time_s' = {T:g} s must be a whole number (1...{MAX_SAMPLE_STEPS}) of "
                                            f"the model's physics step {dt:g} s{faster}")  # fmt: skip
    delay_steps = float(delay_samples) * steps
    if not (math.isfinite(delay_steps) and 0.0 <= delay_steps <= MAX_DELAY_STEPS):
        raise CardFitError("delay_samples", f"{delay_steps:g} physics steps at the sample time {T:g} s; at most {MAX_DELAY_STEPS} "
                                            f"({MAX_DELAY_STEPS / steps:g} samples)")  # fmt: skip
    return int(steps)


def si_matrices(controller: LinearController) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, C, D)`` with inputs ``INPUTS`` in SI: the controller's input scale folded into B and D."""
    n = controller.n_states
    B = np.zeros((n, 3))
    D = np.zeros((1, 3))
    scale = controller.input_scale or {}
    for k, name in enumerate(controller.inputs):
        col = INPUTS.index(name)
        f = float(scale.get(name, 1.0))
        B[:, col] = controller.B[:, k] * f
        D[0, col] = controller.D[0, k] * f
    return np.array(controller.A, float).reshape(n, n), B, np.array(controller.C, float).reshape(1, n), D


@dataclass(frozen=True)
class CardLayout:
    """Where things are in a card model's state and ctrl vectors."""

    nstate: int  #: mjSTATE_FULLPHYSICS size
    plugin_adr: int  #: first plugin-state entry in the FULLPHYSICS vector (-1 without a card)
    n_buffer: int  #: delay line length
    n_states: int  #: controller states
    act_adr: int  #: the hydraulic actuator's act (spool x, P/Ps) in the FULLPHYSICS vector
    #: the card's filters' sizes (:meth:`CardFilters.sizes`: FIR taps on theta and on accel, sections on theta and on
    #: accel; zeros: no filters, no block in the state)
    sensor_sizes: tuple[int, int, int, int] = (0, 0, 0, 0)

    @property
    def n_sensor_state(self) -> int:
        """Entries of the sensors' block (0 without filters)."""
        taps_theta, taps_accel, sos_theta, sos_accel = self.sensor_sizes
        return _SN_RINGS + taps_theta + taps_accel + 2 * (sos_theta + sos_accel) if taps_theta else 0

    def enabled_index(self) -> int:
        return self.plugin_adr + _ST_ENABLED

    def valve_index(self) -> int:
        return self.plugin_adr + _ST_VALVE

    def command_index(self) -> int:
        return self.plugin_adr + _ST_COMMAND

    def buffer_slice(self) -> slice:
        a = self.plugin_adr + _ST_BUFFER
        return slice(a, a + self.n_buffer)

    def z_slice(self) -> slice:
        a = self.plugin_adr + _ST_BUFFER + self.n_buffer
        return slice(a, a + self.n_states)

    def sensor_slice(self) -> slice:
        """The sensors' block (empty without sensor filters)."""
        a = self.plugin_adr + _ST_BUFFER + self.n_buffer + self.n_states
        return slice(a, a + self.n_sensor_state)


@dataclass(frozen=True, eq=False)
class CardFilters:
    """What the card's readings pass through before it samples them, at the physics rate: per channel an FIR, then
    second-order sections (scipy's ``sos`` layout, ``(k, 6)``, ``k`` may be 0). The sensors' own dynamics
    (:meth:`samii.sim.sensor_dynamics.SensorDynamics.filters`, the same a measurement applies) and the card's
    anti-alias filter on both channels (the measurement DAQ's: :func:`samii.measure.daq.antialias_sos`)."""

    theta_taps: np.ndarray
    theta_sos: np.ndarray
    accel_taps: np.ndarray
    accel_sos: np.ndarray

    @classmethod
    def none(cls) -> CardFilters:
        """Nothing between the physics and the card."""
        return cls(np.ones(1), np.zeros((0, 6)), np.ones(1), np.zeros((0, 6)))

    @property
    def ideal(self) -> bool:
        """Nothing between the physics and the card."""
        one = np.ones(1)
        return (np.array_equal(self.theta_taps, one) and np.array_equal(self.accel_taps, one)
                and not self.theta_sos.size and not self.accel_sos.size)  # fmt: skip

    def sizes(self) -> tuple[int, int, int, int]:
        """FIR taps on theta and on accel, sections on theta and on accel."""
        return self.theta_taps.size, self.accel_taps.size, self.theta_sos.shape[0], self.accel_sos.shape[0]


def card_filters(sensors: SensorDynamics, antialias_hz: float | None, rate_hz: float) -> CardFilters:
    """The card's filters at the physics rate ``rate_hz``: the sensors', then, with ``antialias_hz``, the card's
    anti-alias filter at that corner on both channels."""
    theta_taps, accel_taps, sos = sensors.filters(rate_hz)
    none = np.zeros((0, 6))
    aa = none
    if antialias_hz is not None:
        if not (math.isfinite(antialias_hz) and 0 < antialias_hz < 0.5 * rate_hz):
            raise InputError(f"the card's anti-alias corner {antialias_hz:g} Hz must lie between 0 and half the physics rate ({0.5 * rate_hz:g} Hz)")
        aa = antialias_sos(antialias_hz, rate_hz)
    return CardFilters(theta_taps, aa, accel_taps, np.vstack([none if sos is None else sos, aa]))


def default_antialias_hz(sample_time_s: float) -> float:
    """The card's anti-alias corner when none is given: the measurement DAQ's rule at the controller's rate (a quarter
    of it, :func:`samii.measure.daq.antialias_cutoff_hz`)."""
    return antialias_cutoff_hz(1.0 / sample_time_s)


@dataclass(frozen=True)
class CardModel:
    """A compiled SAMII model with the reference input, noise inputs and (optionally) a controller card."""

    model: mujoco.MjModel
    controller: LinearController | None
    replaces_servo: bool
    delay_samples: float  #: computation delay in controller samples
    steps_per_sample: int
    layout: CardLayout
    #: m/s², what the accelerometer reads at rest (``home``), which the card and every reading of the run subtract
    accel_offset_m_s2: float
    #: the sensors' dynamics between the physics and the card (the model's, :mod:`samii.sim.sensor_dynamics`)
    sensors: SensorDynamics = SensorDynamics()
    antialias_hz: float | None = None  #: the card's anti-alias corner (None: none)
    #: everything between the physics and the card (the sensors', then the anti-alias filter)
    filters: CardFilters = field(default_factory=CardFilters.none)

    @property
    def sample_time_s(self) -> float:
        return self.steps_per_sample * float(self.model.opt.timestep)

    def reads(self, state: np.ndarray, w: np.ndarray) -> np.ndarray:
        """What the card samples in the FULLPHYSICS ``state`` whose true readings are ``w = (theta_ref, theta, accel)``
        (SI, noise-free): ``w`` through the card's filters, whose histories the state holds (hydraulic.c,
        ``path_step``: each filter on the deviation from its rest reading; ``w`` itself without filters)."""
        w = np.array(w, float)
        if not self.layout.n_sensor_state:
            return w
        f = self.filters
        taps_theta, taps_accel, sos_theta, _ = f.sizes()
        block = np.asarray(state, float)[self.layout.sensor_slice()]
        k = int(block[_SN_COUNT])
        rings = block[_SN_RINGS : _SN_RINGS + taps_theta + taps_accel]
        sections = block[_SN_RINGS + taps_theta + taps_accel :]

        def read(taps: np.ndarray, sos: np.ndarray, ring: np.ndarray, st: np.ndarray, x: float, rest: float) -> float:
            past = ring[(k - np.arange(1, taps.size)) % taps.size]  # deviations of samples k-1, k-2, ...
            y = float(taps[0] * (x - rest) + taps[1:] @ past)
            gain = float(np.sum(taps))
            for i, q in enumerate(sos):
                y = float(q[0] / q[3] * y + st[2 * i])  # direct form II transposed: y = b0 x + s0
                gain *= float(np.sum(q[:3]) / np.sum(q[3:]))
            return y + gain * rest

        w[1] = read(f.theta_taps, f.theta_sos, rings[:taps_theta], sections[: 2 * sos_theta], w[1], self.theta_rest_rad)
        w[2] = read(f.accel_taps, f.accel_sos, rings[taps_theta:], sections[2 * sos_theta :], w[2], 0.0)
        return w

    @property
    def theta_rest_rad(self) -> float:
        """What the card reads of theta at rest (the ``home`` keyframe): the joint's angle from the servo's reference."""
        return _theta_rest(self.model)

    def set_enabled(self, state: np.ndarray, enabled: bool, z0: np.ndarray | None = None) -> np.ndarray:
        """A copy of the FULLPHYSICS ``state`` with the card switched on (counter 0, states ``z0``) or off."""
        if self.controller is None:
            raise ValueError("this model has no controller card")
        s = np.array(state, float)
        L = self.layout
        s[L.enabled_index()] = 1.0 if enabled else 0.0
        s[L.plugin_adr + _ST_COUNTER] = 0.0
        if z0 is not None:
            s[L.z_slice()] = z0
        return s


def _theta_rest(model: mujoco.MjModel) -> float:
    """theta as the card reads it in the ``home`` keyframe (static equilibrium): the joint from the servo's reference."""
    qadr = int(model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, JOINT)])
    return float(model.key_qpos[0, qadr]) - hydraulic_params(model, ACTUATOR).reference_angle


def _plugin_offset(model: mujoco.MjModel) -> int:
    """Index of the first plugin-state entry in an mjSTATE_FULLPHYSICS vector (components are in bit order)."""
    full = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
    before = full & (int(mujoco.mjtState.mjSTATE_PLUGIN) - 1)
    return int(mujoco.mj_stateSize(model, before))


def _join(a: np.ndarray) -> str:
    return " ".join(repr(float(x)) for x in np.asarray(a, float).ravel())


def build_card_model(
    spec: mujoco.MjSpec,
    controller: LinearController | None,
    *,
    replaces_servo: bool = False,
    delay_samples: float = 0.0,
    theta_lsb_rad: float = 0.0,
    accel_lsb_m_s2: float = 0.0,
    home_qpos: np.ndarray | None = None,
    home_act: np.ndarray | None = None,
    antialias_hz: float | None = None,
) -> CardModel:
    """Compile ``spec`` (SAMII's, from :func:`samii.sim.model.load_spec`) with the card configured.

    Parameters
    ----------
    spec : MjSpec
        Modified in place (actuators ``theta_ref``, ``theta_noise``,
        ``accel_noise`` added, the hydraulic actuator's config extended); pass a copy.
    controller : LinearController or None
        None: the servo amplifier alone (the reference input still works).
    replaces_servo : bool
        The controller is the whole position loop (the notebook's designs) rather than an addition to it.
    delay_samples : float
        Computation delay in controller samples (whole or fractional), at most
        ``MAX_DELAY_STEPS`` physics steps.
    theta_lsb_rad, accel_lsb_m_s2 : float
        ADC quantisation steps (0: none).
    home_qpos, home_act : array, optional
        The ``home`` keyframe's values (static equilibrium) to keep: a generated
        model's equilibrium is set after compilation (:func:`samii.sim.model.load_model`).

    Raises
    ------
    InputError
        If the controller's sample time is not a whole number of physics steps,
        its delay is too long or it has too many states.
    """

    dt = float(spec.option.timestep)
    hyd = next((a for a in spec.actuators if a.name == ACTUATOR), None)
    if hyd is None:
        raise InputError(f"the model has no actuator named {ACTUATOR!r}")
    config = dict(hyd.plugin.config)
    if not config:
        raise InputError(
            f"actuator {ACTUATOR!r} is not configured on the actuator element (an explicit plugin instance is not supported by the closed loop)"
        )
    for name in (REFERENCE_ACTUATOR, THETA_NOISE_ACTUATOR, ACCEL_NOISE_ACTUATOR):
        a = spec.add_actuator(name=name, target=JOINT, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        a.gainprm[0] = 0.0  # force-free: only the plugin reads its ctrl
        a.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
    config["reference_actuator"] = REFERENCE_ACTUATOR
    for key in spec.keys:
        ctrl = list(key.ctrl)
        if ctrl:
            key.ctrl = ctrl + [0.0, 0.0, 0.0]

    def compile_with(cfg: dict) -> mujoco.MjModel:
        hyd.plugin.config = cfg
        m = compile_spec(spec)
        if home_qpos is not None:
            m.key_qpos[0] = home_qpos
        if home_act is not None:
            m.key_act[0] = home_act
        return m

    model = compile_with(config)
    # the accelerometer's measuring direction and rest reading, as samii.sim.simulate removes them
    _, direction = accel_weights(model)
    offset = float(accel_offset(model))
    sensors = SensorDynamics.from_model(model)
    # (without a controller nothing samples the sensors: the servo amplifier reads the joint)
    filters = card_filters(sensors, antialias_hz, 1.0 / dt) if controller is not None else CardFilters.none()
    steps, n_buffer, n, sensor_sizes = 1, 0, 0, (0, 0, 0, 0)
    if controller is not None:
        n = controller.n_states
        steps = check_fit(controller, dt, delay_samples)
        delay_steps = float(delay_samples) * steps
        A, B, C, D = si_matrices(controller)
        config.update({
            "controller_states": str(n),
            "controller_d": _join(D),
            "controller_steps": str(steps),
            "controller_delay_steps": repr(delay_steps),
            "controller_replaces_servo": "1" if replaces_servo else "0",
            "controller_theta_sensor": "theta",
            "controller_accel_sensor": "base_accel",
            "controller_accel_direction": _join(direction),
            "controller_accel_offset": repr(offset),
            "controller_theta_noise": THETA_NOISE_ACTUATOR,
            "controller_accel_noise": ACCEL_NOISE_ACTUATOR,
            "controller_theta_lsb": repr(float(theta_lsb_rad)),
            "controller_accel_lsb": repr(float(accel_lsb_m_s2)),
        })  # fmt: skip
        if n:
            config.update({"controller_a": _join(A), "controller_b": _join(B), "controller_c": _join(C)})
        if not filters.ideal:  # the card reads through the sensors' dynamics and its anti-alias filter, from rest
            config.update({"controller_theta_filter": _join(filters.theta_taps), "controller_accel_filter": _join(filters.accel_taps),
                           "controller_theta_rest": repr(_theta_rest(model))})  # fmt: skip
            if filters.theta_sos.size:
                config["controller_theta_sos"] = _join(filters.theta_sos)
            if filters.accel_sos.size:
                config["controller_accel_sos"] = _join(filters.accel_sos)
            sensor_sizes = filters.sizes()
        n_buffer = int(math.floor(delay_steps)) + 2
        model = compile_with(config)

    nstate = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    n_plugin = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_PLUGIN)
    act_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, ACTUATOR)
    layout = CardLayout(
        nstate=nstate,
        plugin_adr=_plugin_offset(model) if controller is not None else -1,
        n_buffer=n_buffer,
        n_states=n,
        act_adr=1 + model.nq + model.nv + int(model.actuator_actadr[act_id]),
        sensor_sizes=sensor_sizes,
    )

    # after the card's entries, the valve's command delay keeps its own (hydraulic.c)
    expected = (4 + n_buffer + n + layout.n_sensor_state if controller is not None else 0) + command_ring_entries(
        float(config.get("command_delay") or 0.0), dt
    )
    if n_plugin != expected:
        raise RuntimeError(f"the plugin's state has {n_plugin} entries, expected {expected}: plugin and samii.closedloop.card disagree")
    # without a controller the servo amplifier runs alone: nothing replaces it, nothing is delayed
    replaces = bool(replaces_servo) and controller is not None
    aa = float(antialias_hz) if antialias_hz is not None and controller is not None else None
    return CardModel(
        model, controller, replaces, float(delay_samples) if controller is not None else 0.0, steps, layout, offset, sensors, aa, filters
    )
