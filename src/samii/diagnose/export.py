"""The augmented model as a python-control system: the baseline with the effects a diagnosis found.

Each effect of :mod:`samii.diagnose.effects` becomes the same transfer function
as a ``control.TransferFunction``; a delay ``e^-sT`` becomes a Padé approximant
of the order asked (``control.pade``: its phase is right to about
``order`` x 1.2 rad of ``wT``; at order 3 and T = 4 ms, to some 140 Hz) or, with
``pade_order=None``, the model is returned as an exact ``control.FRD`` on a
frequency grid. tests/test_diagnose_export.py checks both against the
responses the fit used.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from samii.diagnose.effects import TWO_PI, EffectKind

__all__ = ["effect_tfs", "augmented_tf", "augmented_frd"]


def _delay(t: float, order: int | None):
    import control  # (lazy: imports control, only when called)

    if order is None:
        raise ValueError("a delay needs a Pade order for a transfer function (pade_order=N), or use augmented_frd")
    if t <= 0:
        return control.tf([1.0], [1.0])
    num, den = control.pade(t, order)
    return control.tf(num, den)


def effect_tfs(kind: EffectKind, values: Mapping[str, float], *, pade_order: int | None = 3):
    """(M_act, M_base, A_base) of one effect as python-control transfer functions (None: no change)."""
    import control  # (lazy: imports control, only when called)

    s = control.tf("s")
    k, v = kind.kind, values
    if kind.category == "delay":
        d = _delay(v["delay_s"], pade_order)
        if k == "command":
            return d, None, None
        if k == "accel_sensor":
            return None, d, None
        if k == "theta_sensor":  # theta read late: theta/v x e^-sT, xdd/theta x e^+sT (xdd/v unchanged; see augmented_tf)
            return d, None, None
    if k == "base_mode":
        w = TWO_PI * v["freq_hz"]
        return None, None, v["residue"] * s**4 / (s**2 + 2 * v["zeta"] * w * s + w * w)
    if k == "act_mode":
        wp, wz = TWO_PI * v["freq_hz"], TWO_PI * v["zero_freq_hz"]
        return (wp / wz) ** 2 * (s**2 + 2 * v["zero_zeta"] * wz * s + wz**2) / (s**2 + 2 * v["zeta"] * wp * s + wp**2), None, None
    if k == "accel_lowpass":
        return None, 1 / (1 + s / (TWO_PI * v["corner_hz"])), None
    if k == "accel_lowpass2":
        w = TWO_PI * v["corner_hz"]
        return None, w * w / (s**2 + np.sqrt(2.0) * w * s + w * w), None
    if k == "accel_highpass":
        return None, s / (s + TWO_PI * v["corner_hz"]), None
    if k == "accel_gain":
        return None, control.tf([v["gain"]], [1.0]), None
    if k == "pole_zero":
        return (1 + s / (TWO_PI * v["zero_hz"])) / (1 + s / (TWO_PI * v["pole_hz"])), None, None
    if k == "leak":
        return s / (s - v["pole_per_s"]), None, None
    if k == "valve":
        w = TWO_PI * v["freq_hz"]
        return w * w / (s**2 + 2 * v["zeta"] * w * s + w * w), None, None
    raise ValueError(f"no transfer function for {kind.label}")


def augmented_tf(fit, i: int = 0, channel: str = "total", *, pade_order: int = 3):
    """Channel ``act`` (theta/v), ``base`` (xdd/theta, improper with the s^4 numerator) or ``total``
    (xdd/v) of ``fit``'s model for file ``i``, as a ``control.TransferFunction``.

    A theta-sensor delay is a lag in theta/v and an advance in xdd/theta: ``base`` is refused then,
    and ``total`` leaves both out (they cancel exactly). A leaky integrator moves theta/v's pole at 0
    to ``a`` (no pole-zero pair at 0 left to cancel)."""
    import control  # (lazy: imports control, only when called)

    st = fit.baseline.structure
    if st is None or not fit.baseline_params or not hasattr(st, "to_tf"):
        raise ValueError("the baseline has no transfer function to export (the simulator as baseline: use augmented_frd)")
    if channel not in ("act", "base", "total"):
        raise ValueError(f"channel must be 'act', 'base' or 'total', got {channel!r}")
    theta_late = [e for e in fit.effects if e.kind.label == "delay/theta_sensor"]
    if theta_late and channel == "base":
        raise ValueError(
            "xdd/theta with theta read late is xdd/theta x e^+sT, a time advance with no causal transfer function "
            "(its Pade inverse has right-half-plane poles); use augmented_frd, or the act and total channels"
        )
    p = fit.baseline_params[i]
    act, base = st.to_tf(p, "act"), st.to_tf(p, "base")
    m_act, m_base = [], []
    for e in fit.effects:
        if e.kind.label == "delay/theta_sensor" and channel == "total":
            continue  # theta's late reading cancels in xdd/v, which does not pass through theta
        if e.kind.label == "actuator/leak" and act.den[0][0][-1] == 0.0:  # 1/s becomes 1/(s - a) (no s/s left to cancel)
            act = control.tf(act.num[0][0], np.polymul(act.den[0][0][:-1], [1.0, -e.values["pole_per_s"]]))
            continue
        a, b, add = effect_tfs(e.kind, e.values, pade_order=pade_order)
        if a is not None:
            m_act.append(a)
        if b is not None:
            m_base.append(b)
        if add is not None:
            base = base + add
    for m in m_act:
        act = act * m
    for m in m_base:
        base = base * m
    return {"act": act, "base": base}.get(channel, act * base)


def augmented_frd(fit, freq_hz, i: int = 0, channel: str = "total"):
    """The same model as an exact ``control.FRD`` (delays exact) at ``freq_hz`` [Hz] (e.g. ``Diagnosis.datasets[i].freq_hz``):
    the rig's, without the DAQ's sampling of xdd/v's feedthrough (samii.diagnose.sampling), as augmented_tf."""
    import control  # (lazy: imports control, only when called)

    from samii.diagnose.residuals import model_response  # (lazy: imports scipy, only when called)

    f = np.asarray(freq_hz, float)
    return control.frd(model_response(fit, i, f, sampled=False)[channel], TWO_PI * f)
