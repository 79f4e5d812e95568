"""The effect library: physical hypotheses about what a model lacks, each with parameters.

An effect changes the model's two channels, theta/v (``act``) and xdd/theta
(``base``), as a factor on a channel or, for a structural mode the base lacks,
as a term added to it::

    act'  = act  * M_act(s)
    base' = (base + A_base(s)) * M_base(s)

Each effect is the transfer function of its physics, stated with it below. The
total channel xdd/v is their product and needs nothing of its own. Parameters
are in SI units (s, Hz for frequencies a person reads, 1 for damping ratios,
(m/s²)/rad s^4 for a mode's residue); ``transform`` says how the optimiser
sees each: ``log`` (positive, relative steps) or ``lin``.

Categories and kinds (the ``--json`` names):

* ``delay``: ``command`` (the valve acts on v(t - T): act x e^-sT),
  ``theta_sensor`` (theta read T late: act x e^-sT, base x e^+sT),
  ``accel_sensor`` (base x e^-sT).
* ``extra_mode``: ``base_mode`` (a mode the modal sum lacks:
  + B s^4/(s^2 + 2 z w s + w^2), the notebook's eq 9.2 term), ``act_mode`` (a
  structural mode seen by the actuator: a lightly damped zero pair and pole
  pair, act x (w_p^2/w_z^2)(s^2 + 2 z_z w_z s + w_z^2)/(s^2 + 2 z_p w_p s + w_p^2)).
* ``sensor``: ``accel_lowpass`` (first-order roll-off 1/(1 + s/w_c)),
  ``accel_lowpass2`` (second-order Butterworth anti-alias filter), ``accel_highpass``
  (AC coupling s/(s + w_h)), ``accel_gain`` (a scale error k; only testable against
  a fixed baseline, since the fitted gains B_k absorb it).
* ``actuator``: ``pole_zero`` (a real pole and zero, (1 + s/w_z)/(1 + s/w_p)),
  ``leak`` (the integrator leaks: theta/v's 1/s is 1/(s - a), act x s/(s - a). A flow
  lost with the load pressure, Q = K_ce P (leakage across the piston, plus the valve's own
  flow-pressure coefficient), against a holding torque D P = tau_0 + k theta that changes with
  theta (k = d(holding torque)/d theta), gives D theta' = K_q v - K_ce (tau_0 + k theta)/D: a
  real pole at a = -K_ce k / D^2 (D the displacement). a < 0 for a restoring load, a > 0 for a
  destabilising one (negative stiffness: gravity on a link near upright), as in samii's
  simulator at its nominal pose (+0.199 1/s, proportional to its leakage coefficient, ~0 with
  gravity off). The notebook's model is a pure integrator),
  ``valve`` (second-order valve dynamics w_v^2/(s^2 + 2 z_v w_v s + w_v^2)).

Nonlinear effects are not factors: :mod:`samii.diagnose.nonlinear` decides them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["Param", "EffectKind", "LIBRARY", "library", "Effect"]

TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class Param:
    name: str
    unit: str
    lo: float
    hi: float
    transform: str = "log"  # "log" or "lin"
    #: The ends of the range ("lo", "hi") that are no limiting form the data can show: an effect fitted there is not
    #: placed (samii.diagnose.select). Others are kept: a pole-zero corner on its end is a gain or a lead, a valve
    #: damped 3 a first-order lag.
    not_a_limit: tuple[str, ...] = ()


@dataclass(frozen=True)
class EffectKind:
    """One hypothesis of the library.

    ``response(p, s) -> (M_act, M_base, A_base)`` with None for "no change", each an array of the points' shape
    (the fit evaluates them once on a dataset's points and picks each channel's).
    ``derivatives(p, s) -> (d ln M_act/dp, d ln M_base/dp, d A_base/dp)``, each (points, parameters) or None
    where the response has none: analytic, derived from the same laws (the fit's Jacobian is built from them).
    ``needs_fixed_baseline``: only identifiable when the baseline's parameters are not refitted.
    ``needs_pure_integrator``: only meaningful against a baseline whose theta/v integrates purely (the
    notebook's structure, a saved fit); the simulator's own pole near 0 is its leakage coefficient, which
    its calibration frees.
    """

    category: str
    kind: str
    channel: str  # "act", "base" or "both"
    params: tuple[Param, ...]
    response: Callable[[np.ndarray, np.ndarray], tuple]
    describe: Callable[[dict], str]
    derivatives: Callable[[np.ndarray, np.ndarray], tuple]
    needs_fixed_baseline: bool = False
    needs_pure_integrator: bool = False

    @property
    def label(self) -> str:
        return f"{self.category}/{self.kind}"

    @property
    def affects(self) -> tuple[str, ...]:
        return ("act", "base") if self.channel == "both" else (self.channel,)


@dataclass(frozen=True)
class Effect:
    """An effect kind with parameter values (SI) and their standard errors."""

    kind: EffectKind
    values: dict
    stderr: dict


def _second_order(s, f_hz, zeta):
    w = TWO_PI * f_hz
    return s * s + 2.0 * zeta * w * s + w * w


def _delay_command(p, s):
    return np.exp(-s * p[0]), None, None


def _delay_theta(p, s):
    return np.exp(-s * p[0]), np.exp(s * p[0]), None


def _delay_accel(p, s):
    return None, np.exp(-s * p[0]), None


def _base_mode(p, s):
    f, z, b = p
    s2 = s * s
    return None, None, b * s2 * s2 / _second_order(s, f, z)


def _act_mode(p, s):
    fp, zp, fz, zz = p
    return (fp / fz) ** 2 * _second_order(s, fz, zz) / _second_order(s, fp, zp), None, None


def _lowpass(p, s):
    return None, 1.0 / (1.0 + s / (TWO_PI * p[0])), None


def _lowpass2(p, s):
    w = TWO_PI * p[0]
    return None, w * w / (s * s + np.sqrt(2.0) * w * s + w * w), None


def _highpass(p, s):
    return None, s / (s + TWO_PI * p[0]), None


def _gain(p, s):
    return None, np.full(s.shape, p[0], complex), None


def _pole_zero(p, s):
    fz, fp = p
    return (1.0 + s / (TWO_PI * fz)) / (1.0 + s / (TWO_PI * fp)), None, None


def _leak(p, s):
    return s / (s - p[0]), None, None


def _valve(p, s):
    f, z = p
    w = TWO_PI * f
    return w * w / _second_order(s, f, z), None, None


# -- derivatives: d ln M / dp for the factors, dA/dp for the added term (columns in the parameters' order) ----------


def _col(*cols):
    """The 1-d columns (points,) side by side, (points, parameters), always complex: the values of
    ``np.stack(cols, axis=1)`` in a third of its time (the fit's Jacobian calls this for every effect at every step)."""
    out = np.empty((cols[0].shape[0], len(cols)), complex)
    for i, c in enumerate(cols):
        out[:, i] = c
    return out


def _d_delay_command(p, s):
    return _col(-s), None, None


def _d_delay_theta(p, s):
    return _col(-s), _col(s), None


def _d_delay_accel(p, s):
    return None, _col(-s), None


def _d_base_mode(p, s):
    f, z, b = p
    w = TWO_PI * f
    s2 = s * s
    inv_d = 1.0 / _second_order(s, f, z)
    t = s2 * s2 * inv_d
    # A = b s^4 / D,  dD/df = 2 pi (2 z s + 2 w),  dD/dz = 2 w s
    return None, None, _col(-b * t * inv_d * TWO_PI * (2.0 * z * s + 2.0 * w), -b * t * inv_d * 2.0 * w * s, t)


def _d_act_mode(p, s):
    fp, zp, fz, zz = p
    wp, wz = TWO_PI * fp, TWO_PI * fz
    inv_p, inv_z = 1.0 / _second_order(s, fp, zp), 1.0 / _second_order(s, fz, zz)
    # ln M = 2 ln fp - 2 ln fz + ln D(fz, zz) - ln D(fp, zp)
    return (
        _col(
            2.0 / fp - TWO_PI * (2.0 * zp * s + 2.0 * wp) * inv_p,
            -2.0 * wp * s * inv_p,
            -2.0 / fz + TWO_PI * (2.0 * zz * s + 2.0 * wz) * inv_z,
            2.0 * wz * s * inv_z,
        ),
        None,
        None,
    )


def _d_lowpass(p, s):
    u = s / (TWO_PI * p[0])  # ln M = -ln(1 + u), du/df = -u/f
    return None, _col(u / (p[0] * (1.0 + u))), None


def _d_lowpass2(p, s):
    w = TWO_PI * p[0]  # ln M = 2 ln w - ln(s^2 + sqrt2 w s + w^2)
    return None, _col(TWO_PI * (2.0 / w - (np.sqrt(2.0) * s + 2.0 * w) / (s * s + np.sqrt(2.0) * w * s + w * w))), None


def _d_highpass(p, s):
    return None, _col(-TWO_PI / (s + TWO_PI * p[0])), None  # ln M = ln s - ln(s + w_h)


def _d_gain(p, s):
    return None, _col(np.full(s.shape, 1.0 / p[0], complex)), None


def _d_pole_zero(p, s):
    fz, fp = p
    uz, up = s / (TWO_PI * fz), s / (TWO_PI * fp)  # ln M = ln(1 + uz) - ln(1 + up)
    return _col(-uz / (fz * (1.0 + uz)), up / (fp * (1.0 + up))), None, None


def _d_leak(p, s):
    return _col(1.0 / (s - p[0])), None, None  # ln M = ln s - ln(s - a)


def _d_valve(p, s):
    f, z = p
    w = TWO_PI * f
    inv_d = 1.0 / _second_order(s, f, z)  # ln M = 2 ln w - ln D
    return _col(2.0 / f - TWO_PI * (2.0 * z * s + 2.0 * w) * inv_d, -2.0 * w * s * inv_d), None, None


# not_a_limit (Param): a delay of 50 ms, a leak of +-10 1/s (a real pole at 1.6 Hz), an accelerometer gain of 0.01 or
# 100, a valve damped 0.05 are beyond what the library places, not limiting forms of it
_DELAY = (Param("delay_s", "s", 0.0, 0.05, "lin", ("hi",)),)

LIBRARY: tuple[EffectKind, ...] = (
    EffectKind(
        "delay",
        "command",
        "act",
        _DELAY,
        _delay_command,
        lambda v: f"the valve acts on the command {1e3 * v['delay_s']:.3g} ms late",
        _d_delay_command,
    ),
    EffectKind("delay", "theta_sensor", "both", _DELAY, _delay_theta, lambda v: f"theta is read {1e3 * v['delay_s']:.3g} ms late", _d_delay_theta),
    EffectKind(
        "delay", "accel_sensor", "base", _DELAY, _delay_accel, lambda v: f"the acceleration is read {1e3 * v['delay_s']:.3g} ms late", _d_delay_accel
    ),
    EffectKind(
        "extra_mode",
        "base_mode",
        "base",
        (Param("freq_hz", "Hz", 0.01, 1000.0), Param("zeta", "1", 1e-4, 0.5), Param("residue", "(m/s²)/rad s^4", -1e12, 1e12, "lin")),
        _base_mode,
        lambda v: f"a base mode at {v['freq_hz']:.4g} Hz, damping {v['zeta']:.3g}, that the modal sum lacks",
        _d_base_mode,
    ),
    EffectKind(
        "extra_mode",
        "act_mode",
        "act",
        (
            Param("freq_hz", "Hz", 0.01, 1000.0),
            Param("zeta", "1", 1e-4, 0.5),
            Param("zero_freq_hz", "Hz", 0.01, 1000.0),
            Param("zero_zeta", "1", 1e-4, 0.5),
        ),
        _act_mode,
        lambda v: f"a structural mode at {v['freq_hz']:.4g} Hz (antiresonance at {v['zero_freq_hz']:.4g} Hz) seen by the actuator",
        _d_act_mode,
    ),
    EffectKind(
        "sensor",
        "accel_lowpass",
        "base",
        (Param("corner_hz", "Hz", 0.5, 1e4),),
        _lowpass,
        lambda v: f"the accelerometer rolls off above {v['corner_hz']:.3g} Hz (first order)",
        _d_lowpass,
    ),
    EffectKind(
        "sensor",
        "accel_lowpass2",
        "base",
        (Param("corner_hz", "Hz", 0.5, 1e4),),
        _lowpass2,
        lambda v: f"the accelerometer's anti-alias filter rolls off above {v['corner_hz']:.3g} Hz (second-order Butterworth)",
        _d_lowpass2,
    ),
    EffectKind(
        "sensor",
        "accel_highpass",
        "base",
        (Param("corner_hz", "Hz", 1e-4, 20.0),),
        _highpass,
        lambda v: f"the accelerometer is AC coupled below {v['corner_hz']:.3g} Hz (first-order high-pass)",
        _d_highpass,
    ),
    EffectKind(
        "sensor",
        "accel_gain",
        "base",
        (Param("gain", "1", 0.01, 100.0, "log", ("lo", "hi")),),
        _gain,
        lambda v: f"the accelerometer reads {v['gain']:.4g} x the true acceleration",
        _d_gain,
        needs_fixed_baseline=True,
    ),
    EffectKind(
        "actuator",
        "pole_zero",
        "act",
        (Param("zero_hz", "Hz", 0.01, 1e4), Param("pole_hz", "Hz", 0.01, 1e4)),
        _pole_zero,
        lambda v: f"theta/v has an extra real zero at {v['zero_hz']:.3g} Hz and pole at {v['pole_hz']:.3g} Hz",
        _d_pole_zero,
    ),
    EffectKind(
        "actuator",
        "leak",
        "act",
        (Param("pole_per_s", "1/s", -10.0, 10.0, "lin", ("lo", "hi")),),
        _leak,
        lambda v: f"theta/v's integrator is a real pole at s = {v['pole_per_s']:+.3g} 1/s (leakage across the actuator against the load's stiffness)",
        _d_leak,
        needs_pure_integrator=True,
    ),
    EffectKind(
        "actuator",
        "valve",
        "act",
        (Param("freq_hz", "Hz", 1.0, 1e4), Param("zeta", "1", 0.05, 3.0, "log", ("lo",))),
        _valve,
        lambda v: f"valve dynamics: a second-order lag at {v['freq_hz']:.3g} Hz, damping {v['zeta']:.2g}",
        _d_valve,
    ),
)


def library(*, fixed_baseline: bool, channels: tuple[str, ...], pure_integrator: bool = True) -> list[EffectKind]:
    """The kinds that can be tested on these channels and baseline (``pure_integrator``: its theta/v has one)."""
    out = []
    for k in LIBRARY:
        if (k.needs_fixed_baseline and not fixed_baseline) or (k.needs_pure_integrator and not pure_integrator):
            continue
        if not all(c in channels for c in k.affects):
            continue
        out.append(k)
    return out
