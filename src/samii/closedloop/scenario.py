"""Closed-loop experiments: the scenarios, one run with its comparison and linear prediction, the result.

Scenarios (times in s, angles as offsets from the nominal pose):

- ``step``: the controller runs from t = 0; theta_ref steps by ``step_deg`` at
  t = 1; the comparison is the same step under the servo amplifier alone.
- ``loper``: the arm steps under the servo amplifier alone at t = 1 and the
  controller is switched on (bumplessly) at t = 2; the comparison is the same
  run never switched (the free decay). After Loper's thesis, as the notebook's
  Figure 11.5 tried it.
- ``release``: an impulse at the beam tip along the accelerometer's direction
  (``impulse_n_s``) at t = 0 sets the base vibrating; the controller runs from
  t = 0 with theta_ref held; the comparison is the servo amplifier alone.

Every run is also predicted by the linearised loop (:mod:`samii.closedloop.linear`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

from samii.closedloop.card import CardModel, build_card_model
from samii.closedloop.controllers import SavedController
from samii.closedloop.linear import LinearLoop, LinearResponse, linear_loop
from samii.closedloop.metrics import (
    BaseMetrics,
    FittedMode,
    Runaway,
    StepMetrics,
    base_metrics,
    envelope,
    growth,
    response_modes,
    runaway,
    step_metrics,
    sustained_oscillation,
)
from samii.closedloop.run import LoopSignals, measurements_at, run_loop
from samii.json_output import finite_or_none
from samii.measure.daq import SensorNoise
from samii.sim.hydraulic_reference import AMPLIFIER_LIMIT_V
from samii.sim.model import load_model, load_spec, make_data, reset_home
from samii.sim.sensors import accel_axis_world, accel_site
from samii.timeseries import TimeSeries

__all__ = [
    "SCENARIOS",
    "Scenario",
    "ClosedLoopResult",
    "NoiseSpec",
    "run_closed_loop",
    "scenario",
]

SCENARIOS = ("step", "loper", "release")

#: Release: the tip impulse [N s]. 0.5 N s starts the base at about 4 m/s² peak, the size of the
#: vibration a 5 degree step leaves (3.2 m/s²) and well inside the valve's linear range.
DEFAULT_IMPULSE_N_S = 0.5


@dataclass(frozen=True)
class Scenario:
    name: str
    duration_s: float = 10.0
    step_deg: float = 5.0
    t_step_s: float = 1.0  #: step time (step, loper)
    switch_on_s: float | None = None  #: loper: when the controller is switched on
    impulse_n_s: float = 0.0  #: release: tip impulse at t = 0 [N s]

    @property
    def t_event_s(self) -> float:
        """When the base vibration whose decay is measured starts (the step, the switch-on, the impulse)."""
        if self.name == "loper":
            return float(self.switch_on_s)
        if self.name == "release":
            return 0.0
        return self.t_step_s

    @property
    def t_disturbance_s(self) -> float:
        """When the vibration is excited (the step; the impulse): settle times count from here."""
        return 0.0 if self.name == "release" else self.t_step_s


def scenario(name: str, *, step_deg: float = 5.0, duration_s: float = 10.0, impulse_n_s: float = DEFAULT_IMPULSE_N_S) -> Scenario:
    """The named scenario with its defaults (module docstring)."""
    if name == "step":
        return Scenario("step", duration_s, step_deg, 1.0)
    if name == "loper":
        return Scenario("loper", duration_s, step_deg, 1.0, switch_on_s=2.0)
    if name == "release":
        return Scenario("release", duration_s, 0.0, 0.0, impulse_n_s=impulse_n_s)
    raise ValueError(f"unknown scenario {name!r}; expected one of {', '.join(SCENARIOS)}")


@dataclass(frozen=True)
class NoiseSpec:
    """Sensor noise and ADC quantisation of the controller's measurements (seeded)."""

    theta_std_rad: float = SensorNoise.theta_rad  #: as the DAQ's (samii.measure.daq.SensorNoise): a 4096-count/rev encoder
    accel_std_m_s2: float = SensorNoise.accel_m_s2  #: about 1 mg rms
    theta_lsb_rad: float = 2 * math.pi / 4096  #: the same encoder's count
    accel_lsb_m_s2: float = 20.0 / 65536 * 9.80665  #: a 16-bit +-10 V ADC on a 1 V/g accelerometer
    seed: int = 0


@dataclass(frozen=True)
class ClosedLoopResult:
    controller: str
    scenario: Scenario
    signals: LoopSignals  #: the run
    comparison: LoopSignals | None  #: the same scenario under the servo amplifier alone (None for the servo loop itself)
    linear: LinearResponse | None  #: the linear prediction (None if the linear loop is unstable, not marginal)
    linear_stable: bool
    linear_poles_s: np.ndarray
    stable: bool
    unstable_mode_hz: float | None
    growth_rate_1_s: float | None
    theta: StepMetrics
    base: BaseMetrics
    free_decay_rate_1_s: float | None
    modes: list[FittedMode]
    rms_error_pct: dict[str, float | None]
    delay_samples: float
    sample_time_s: float
    replaces_servo: bool
    noise: NoiseSpec | None
    notes: list[str] = field(default_factory=list)
    #: the sensor options the controller read through (samii.sim.sensor_dynamics, those not ideal; empty: ideal sensors,
    #: or no controller: the servo amplifier reads the joint directly)
    sensors: dict[str, float] = field(default_factory=dict)
    antialias_hz: float | None = None  #: the card's anti-alias corner (None: none)
    theta_rest_rad: float = 0.0  #: theta at the static equilibrium (the responses are relative to it)
    accel_rest_m_s2: float = 0.0  #: accelerometer reading there (after the gravity offset is removed: ~0)
    comparison_base: BaseMetrics | None = None  #: the base figures of the comparison run, over the same windows
    runaway: Runaway | None = None  #: theta left its band or the valve sat on its rail for good (then not stable)
    #: The run showed no growth, but the linear prediction has a pole growing faster than MARGINAL_GROWTH_1_S: the
    #: equilibrium is unstable (then not stable; the growth rate and frequency are the prediction's)
    linear_only: bool = False

    @property
    def linear_marginal(self) -> bool:
        """The linear prediction's least stable pole neither grows nor decays faster than MARGINAL_GROWTH_1_S: a pole at
        z = 1 to within rounding (an integrator nothing holds), whichever side of it rounding puts it."""
        return not self.linear_stable and _marginal(self.linear_poles_s)

    def instability(self) -> str:
        """How the run is unstable, in words ("" when stable)."""
        if self.stable:
            return ""
        ran = self.runaway.text() if self.runaway is not None else ""
        if self.linear_only:
            return (
                f"the linear prediction has {_worst_pole(self.linear_poles_s)}: the equilibrium is unstable (Lyapunov's "
                f"indirect method), whether or not this {self.scenario.duration_s:g} s run shows the growth (one this slow, "
                "or one the run's inputs barely set off, passes the run's own tests); a rig's noise and offsets set such "
                "a mode off"
            )
        if ran and self.growth_rate_1_s is None and self.unstable_mode_hz is None:
            return ran  # the base itself did not grow
        what = f"growing at {self.growth_rate_1_s:.4g} 1/s" if self.growth_rate_1_s is not None else "not decaying"
        if self.unstable_mode_hz is not None:
            what += ", without oscillating (a real pole)" if self.unstable_mode_hz < 0.01 else f", oscillating at {self.unstable_mode_hz:.4g} Hz"
        return f"{ran}; the base {what}" if ran else what

    def as_json(self) -> dict:
        def f(x):  # 12 significant digits: times like 59 * 0.001 print as 0.059, not 0.05899999999999994
            x = finite_or_none(x)
            return None if x is None else float(f"{x:.12g}")

        return {
            "controller": self.controller,
            "scenario": self.scenario.name,
            "stable": self.stable,
            "unstable_mode_hz": f(self.unstable_mode_hz),
            "growth_rate_1_s": f(self.growth_rate_1_s),
            "instability": self.instability() or None,
            "runaway": None
            if self.runaway is None
            else {
                "theta_out_since_s": f(self.runaway.theta_since_s),
                "valve_on_rail_since_s": f(self.runaway.valve_since_s),
                "theta_error_rad": f(self.runaway.theta_error_rad),
                "band_rad": f(self.runaway.band_rad),
                "valve_v": f(self.runaway.valve_v),
                "theta_moving": self.runaway.theta_moving,
            },
            "theta": {
                "rise_s": f(self.theta.rise_s),
                "overshoot_pct": f(self.theta.overshoot_pct),
                "settle_s": f(self.theta.settle_s),
                "final_pct": f(self.theta.final_pct),
            },
            "base": {
                "peak_m_s2": f(self.base.peak_m_s2),
                "residual_rms_m_s2": f(self.base.residual_rms_m_s2),
                "settle_s": f(self.base.settle_s),
                "decay_rate_1_s": f(self.base.decay_rate_1_s),
                "free_decay_rate_1_s": f(self.free_decay_rate_1_s),
            },
            "modes": [{"freq_hz": f(m.freq_hz), "zeta": f(m.zeta)} for m in self.modes],
            "linear_prediction": {
                "stable": self.linear_stable,
                "marginal": self.linear_marginal,
                "rms_error_pct": {k: f(v) for k, v in self.rms_error_pct.items()},
            },
        }

    def run_json(self) -> dict:
        """Everything of :meth:`as_json` and how the run was made (``run.json``)."""

        sc = self.scenario
        return {
            **self.as_json(),
            "scenario_settings": {"duration_s": sc.duration_s, "step_deg": sc.step_deg, "t_step_s": sc.t_step_s,
                                  "switch_on_s": sc.switch_on_s, "impulse_n_s": sc.impulse_n_s},
            "sample_time_s": self.sample_time_s,
            "delay_samples": self.delay_samples,
            "servo_loop": "replaced" if self.replaces_servo else "kept",
            "noise": None if self.noise is None else vars(self.noise),
            "sensors": dict(self.sensors) or None,
            "antialias_hz": finite_or_none(self.antialias_hz),
            "diverged_at_s": finite_or_none(self.signals.diverged_at_s),
            "switch_jump_v": finite_or_none(self.signals.switch_jump_v),
            "linear_poles": [[finite_or_none(p.real), finite_or_none(p.imag)] for p in self.linear_poles_s if p.imag >= 0],
            "modes_detail": [{"freq_hz": m.freq_hz, "zeta": m.zeta, "amplitude_m_s2": m.amplitude_m_s2} for m in self.modes],
            "notes": list(self.notes),
        }  # fmt: skip

    def timeseries(self, *, comparison: bool = False):
        """The run (``comparison``: the comparison run) in the standard time-series format (physics
        rate); ``command`` and ``controller_on`` as extra columns."""

        s = self.comparison if comparison else self.signals
        meta = {
            "source": (
                f"samii closedloop --controller {self.controller} --scenario {self.scenario.name} (simulated"
                + ("; the comparison: the servo amplifier alone)" if comparison else ")")
            ),
            "sample_rate_hz": f"{1.0 / s.dt_s:.12g}",
            "controller_sample_time_s": f"{self.sample_time_s:.12g}",
            "delay_samples": f"{self.delay_samples:.12g}",
        }
        extra = {"controller_on": s.enabled.astype(float)}
        if np.any(np.isfinite(s.command)):
            extra["command"] = s.command
        return TimeSeries(t=s.t, v=s.v, theta=s.theta, accel=s.accel, r=s.r, theta_ref=s.theta_ref, p_load=s.p_load,
                          spool=s.spool, extra=extra, metadata=meta)  # fmt: skip


def _impulse_state(cm: CardModel, impulse_n_s: float, data: mujoco.MjData) -> np.ndarray:
    """The ``home`` state with the velocity change of an impulse at the accelerometer's site along
    its measuring axis in the world frame (a body-fixed accelerometer's axis turned by its site); ``data``, a
    MjData of ``cm.model``, is left at ``home``."""

    m = cm.model
    d = reset_home(m, data)
    full = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(cm.layout.nstate)
    mujoco.mj_getState(m, d, state, full)
    if impulse_n_s == 0:
        return state
    direction = accel_axis_world(m, d)
    jacp = np.zeros((3, m.nv))
    mujoco.mj_jacSite(m, d, jacp, None, accel_site(m))
    f = jacp.T @ (impulse_n_s * np.asarray(direction))
    dq = np.zeros(m.nv)
    mujoco.mj_solveM(m, d, dq.reshape(1, -1), f.reshape(1, -1))
    state[1 + m.nq : 1 + m.nq + m.nv] += dq
    return state


#: A linear prediction's least stable pole growing or decaying slower than this [1/s] (e-fold in more than 1000 s) is
#: marginal: an integrator (a joint no loop holds, a controller's integrator) met in finite differences, at |z| = 1 to
#: within rounding, which puts it on one side or the other by machine (1 + 1e-15 on one, 1 - 4e-14 on another): not
#: an instability any test could show, nor a stability margin.
MARGINAL_GROWTH_1_S = 1e-3


def _linear_stable(poles_s: np.ndarray) -> bool:
    """Every pole of the linear prediction decays faster than MARGINAL_GROWTH_1_S."""
    return not poles_s.size or float(np.max(poles_s.real)) < -MARGINAL_GROWTH_1_S


#: A diverged run's base growth slower than this [1/s] (e-fold in 10 s, a run's length) is not said beside a runaway.
BASE_GROWTH_SAID_1_S = 0.1


def _marginal(poles_s: np.ndarray) -> bool:
    """No pole of the linear prediction grows faster than MARGINAL_GROWTH_1_S (an unstable one's |z| is 1 in rounding)."""
    return not poles_s.size or float(np.max(poles_s.real)) <= MARGINAL_GROWTH_1_S


def _worst_pole(poles_s: np.ndarray) -> str:
    """The linear prediction's least stable pole in words (one growing faster than MARGINAL_GROWTH_1_S): a real one's
    growth, a complex pair's frequency too."""
    p = poles_s[np.argmax(poles_s.real)]
    if abs(p.imag) < 1e-6 * max(abs(p.real), MARGINAL_GROWTH_1_S):
        return f"a real pole at s = +{p.real:.3g} 1/s (growing e-fold every {1.0 / p.real:.3g} s)"
    return f"a pair of poles at {abs(p.imag) / (2 * np.pi):.3g} Hz growing at {p.real:.3g} 1/s"


def _fd_deviation(cm: CardModel, state: np.ndarray, data: mujoco.MjData) -> np.ndarray:
    """``state`` as a deviation from ``home`` in mjd_transitionFD's coordinates (dqpos, qvel, act); ``data``, a
    MjData of ``cm.model``, is left at ``home``."""

    m = cm.model
    home = reset_home(m, data)
    qpos = state[1 : 1 + m.nq]
    dq = np.zeros(m.nv)
    mujoco.mj_differentiatePos(m, dq, 1.0, home.qpos, qpos)
    qvel = state[1 + m.nq : 1 + m.nq + m.nv] - home.qvel
    act = state[1 + m.nq + m.nv : 1 + m.nq + m.nv + m.na] - home.act
    return np.concatenate([dq, qvel, act])


def _inputs(cm: CardModel, sc: Scenario, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray | None, int | None]:
    dt = float(cm.model.opt.timestep)
    n = int(round(sc.duration_s / dt))
    theta_ref = np.zeros(n)
    if sc.name in ("step", "loper"):
        theta_ref[int(round(sc.t_step_s / dt)) :] = math.radians(sc.step_deg)
    initial = _impulse_state(cm, sc.impulse_n_s, data) if sc.name == "release" else None
    switch = int(round(sc.switch_on_s / dt)) if sc.name == "loper" and cm.controller is not None else None
    return theta_ref, initial, switch


def _rms_error_pct(nl: np.ndarray, lin: np.ndarray) -> float | None:
    den = float(np.sqrt(np.mean(lin**2)))
    if den == 0 or not np.all(np.isfinite(lin)) or nl.size != lin.size:
        return None
    return float(np.sqrt(np.mean((nl - lin) ** 2)) / den * 100.0)


def run_closed_loop(
    saved: SavedController | None,
    sc: Scenario,
    *,
    label: str,
    spec_factory=None,
    delay_samples: float = 0.0,
    noise: NoiseSpec | None = None,
    comparison: bool = True,
    qpos_every: int | None = None,
    details: bool = True,
    antialias_hz: float | None = None,
) -> ClosedLoopResult:
    """Run ``saved`` (None: the servo amplifier alone) through scenario ``sc`` on the model from ``spec_factory``.

    Parameters
    ----------
    spec_factory : callable() -> (MjSpec, home_qpos, home_act), optional
        A fresh spec of the model and its equilibrium; default the embedded model.
    comparison : bool
        Also run the scenario under the servo amplifier alone (for the plots and the free decay).
    qpos_every : int, optional
        Keep the joint positions every this many physics steps (an animation).
    details : bool
        Also compute the linear prediction's response (and its error against the run) and the response's
        fitted modes (matrix pencil). Off, the result has ``linear`` None, no errors and no ``modes``; its
        stability, growth, poles and step and base metrics are the same: what ``samii robust`` reads (the
        two cost about three times the nonlinear run itself).
    antialias_hz : float, optional
        The card's anti-alias filter on theta and accel at this corner (:func:`samii.closedloop.card.card_filters`).
    """
    if spec_factory is None:
        spec_factory = default_spec_factory()
    controller = saved.controller if saved is not None else None
    replaces = bool(saved.replaces_servo) if saved is not None else False
    q = noise or NoiseSpec(0.0, 0.0, 0.0, 0.0)
    spec, qpos, act = spec_factory()
    cm = build_card_model(spec, controller, replaces_servo=replaces, delay_samples=delay_samples,
                          theta_lsb_rad=q.theta_lsb_rad, accel_lsb_m_s2=q.accel_lsb_m_s2, home_qpos=qpos, home_act=act,
                          antialias_hz=antialias_hz)  # fmt: skip
    data = make_data(cm.model)  # (one MjData for the run, its rest readings and its linearisation: a new one costs 0.4 ms)
    theta_ref, initial, switch = _inputs(cm, sc, data)
    n = theta_ref.size
    noise_th = noise_ac = None
    if noise is not None:
        rng = np.random.default_rng(noise.seed)
        noise_th = rng.normal(0.0, noise.theta_std_rad, n)
        noise_ac = rng.normal(0.0, noise.accel_std_m_s2, n)
    sig = run_loop(cm, theta_ref, theta_noise_rad=noise_th, accel_noise_m_s2=noise_ac, switch_on_step=switch,
                   initial_state=initial, keep_partial=True, qpos_every=qpos_every, data=data)  # fmt: skip
    notes: list[str] = []
    # readings at rest (the static equilibrium): the responses are taken relative to them
    rest = measurements_at(cm, _impulse_state(cm, 0.0, data), 0.0, data)
    th_rest, ac_rest = float(rest[1]), float(rest[2])
    accel = sig.accel - ac_rest

    comp = None
    if comparison and controller is not None:
        spec0, qpos0, act0 = spec_factory()
        cm0 = build_card_model(spec0, None, home_qpos=qpos0, home_act=act0)
        data0 = make_data(cm0.model)
        comp = run_loop(cm0, theta_ref, initial_state=_impulse_state(cm0, sc.impulse_n_s, data0) if sc.name == "release" else None,
                        qpos_every=qpos_every, data=data0)  # fmt: skip

    # linear prediction
    ll: LinearLoop = linear_loop(cm, data=data)
    poles_s = ll.poles_s()
    linear_stable = _linear_stable(poles_s)
    lin = None
    err: dict[str, float | None] = {"theta": None, "accel": None}
    x0 = _fd_deviation(cm, initial, data) if initial is not None else None
    enabled = np.zeros(n, bool)
    if controller is not None:
        enabled[(switch or 0) :] = True
    if _marginal(poles_s) and details:  # (a marginal pole grows by at most e^(1e-3 t): its response over a run holds)
        lin = ll.simulate(theta_ref, enabled=enabled, x0=x0)
        k = sig.t.size
        if sig.diverged_at_s is None:
            err = {"theta": _rms_error_pct(sig.theta - th_rest, lin.theta[:k]), "accel": _rms_error_pct(accel, lin.accel[:k])}
    linear_note_at = None if linear_stable else len(notes)  # (its words wait for the nonlinear run's verdict, below)

    # stability from the nonlinear response
    t_ev = sc.t_event_s
    stable, mode_hz, rate = True, None, None
    shared_env = None
    if sig.diverged_at_s is not None or sig.t.size < 30:
        stable = False
        g = growth(sig.t, accel, min(t_ev, sig.t[-1] if sig.t.size else 0.0)) if sig.t.size >= 30 else None
        if g is None and not linear_stable:
            worst = poles_s[np.argmax(poles_s.real)]
            g = (float(worst.real), float(abs(worst.imag) / (2 * np.pi)))
            notes.append("the run diverged too fast to fit its growth; growth rate and frequency are the linear prediction's")
        if g is not None:
            rate, mode_hz = g
        notes.append(
            f"{sig.diverged_what} diverged at t = {sig.diverged_at_s:.4g} s" if sig.diverged_at_s is not None else "the simulation diverged at once"
        )
    else:
        if sc.t_disturbance_s == t_ev:  # (the step, the release: the oscillation test and the base's metrics read one envelope)
            shared_env = envelope(accel[int(np.searchsorted(sig.t, t_ev)) :], sig.dt_s)
        osc = sustained_oscillation(sig.t, accel, t_ev, env=shared_env)
        if osc is not None:
            stable, rate, mode_hz = False, osc.growth_rate_1_s, osc.freq_hz
            held = "the valve's +-10 V saturation" if np.mean(np.abs(sig.v) >= 9.999) > 0.01 else "the valve's pressure-flow law (no saturation)"
            if osc.kind == "limit cycle":
                notes.append(f"the base oscillation at {osc.freq_hz:.3g} Hz grew and is held at a constant level by {held} (a limit cycle)")
            else:
                notes.append(f"the base oscillation at {osc.freq_hz:.3g} Hz is still growing at the end of the run")
    ran_away = None
    if sig.t.size >= 30:  # (a diverged run too, up to its divergence: what ran away before it)
        ran_away = runaway(sig.t, sig.theta - th_rest - sig.theta_ref, sig.v, t_event=t_ev, rail_v=AMPLIFIER_LIMIT_V)
        if ran_away is not None:  # (said by instability(), not again as a note)
            stable = False
            if sig.diverged_at_s is not None and (rate is None or rate < BASE_GROWTH_SAID_1_S):
                # the joint ran away and the controller's output diverged while the base barely moved: its fitted growth
                # (0.0034 1/s at 1.9 Hz beside a real pole at +12 1/s and a joint 22 rad off) is not what went wrong
                rate, mode_hz = None, None

    linear_only = False
    if stable and not linear_stable and not _marginal(poles_s):
        # Lyapunov's indirect method: an equilibrium whose linearisation has a pole in the right half plane is
        # unstable, whether or not this run's inputs set the mode off fast enough to show (a joint no controller
        # holds creeps through the actuator's leakage at +0.197 1/s: the step run stays at rest, the Loper run
        # drifts from 5 to 23 deg in 8 s)
        worst = poles_s[np.argmax(poles_s.real)]
        stable, linear_only = False, True
        rate, mode_hz = float(worst.real), float(abs(worst.imag) / (2 * np.pi))
    if linear_note_at is not None:
        if _marginal(poles_s):
            said = (
                "the linear prediction has a marginal pole (|z| = 1 to within rounding: an integrator nothing holds, "
                f"growing or decaying slower than e-fold in {1 / MARGINAL_GROWTH_1_S:g} s)"
            )
        elif linear_only:  # (its pole is said by instability())
            said = "no linear response or error is given (the prediction is unstable)"
        else:
            said = f"the linear prediction is unstable ({_worst_pole(poles_s)}): no linear response or error is given"
        notes.insert(linear_note_at, said)
    theta_m = step_metrics(sig.t, sig.theta, sig.theta_ref, sc.t_step_s) if sc.name in ("step", "loper") else StepMetrics(None, None, None)
    residual_from = sc.t_disturbance_s + 2.0
    base = (
        base_metrics(sig.t, accel, sc.t_disturbance_s, t_decay_s=t_ev, residual_from_s=residual_from, env=shared_env)
        if sig.t.size > 1
        else BaseMetrics(float("nan"), None, None, None)
    )
    if not stable:
        # the run diverged, oscillates or ran away, or its equilibrium is unstable: a rise, an overshoot, a settling time
        # or a decay rate would describe a transient that never ends (an overshoot of 1,070 % on the way out; a joint
        # creeping from 5 to 24 deg "settled"); where theta ended and the base's peak and rms are what happened, and stay
        theta_m = StepMetrics(None, None, None, theta_m.final_pct)
        base = BaseMetrics(base.peak_m_s2, base.residual_rms_m_s2, None, None)
    comp_base = None
    if comp is not None:
        comp_base = base_metrics(comp.t, comp.accel - ac_rest, sc.t_disturbance_s, t_decay_s=t_ev, residual_from_s=residual_from)
    free = comp_base.decay_rate_1_s if comp_base is not None and sc.name in ("loper", "release") else None
    modes = response_modes(sig.t, accel, t_ev + 0.1) if stable and details else []
    return ClosedLoopResult(
        controller=label, scenario=sc, signals=sig, comparison=comp, linear=lin, linear_stable=linear_stable,
        linear_poles_s=poles_s, stable=stable, unstable_mode_hz=mode_hz, growth_rate_1_s=rate, theta=theta_m, base=base,
        free_decay_rate_1_s=free, modes=modes, rms_error_pct=err, delay_samples=float(delay_samples),
        sample_time_s=cm.sample_time_s, replaces_servo=cm.replaces_servo, noise=noise, notes=notes,
        theta_rest_rad=th_rest, accel_rest_m_s2=ac_rest, comparison_base=comp_base, runaway=ran_away, linear_only=linear_only,
        sensors=cm.sensors.changed() if controller is not None else {}, antialias_hz=cm.antialias_hz,
    )  # fmt: skip


def default_spec_factory(path=None, overrides=None):
    """A factory of fresh specs of a model (default the embedded one) with its static equilibrium."""

    model = load_model(path, overrides=overrides)
    qpos, act = model.key_qpos[0].copy(), model.key_act[0].copy()

    def factory():
        spec, _ = load_spec(path, overrides=overrides)
        return spec, qpos, act

    return factory
