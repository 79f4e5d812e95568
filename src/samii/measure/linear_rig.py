"""A linear stand-in for the rig: the notebook's transfer functions under the position loop.

Used to prove the measurement chain (excitation -> DAQ -> estimator) on a system
whose frequency response is known exactly, and as a fast reference in
experiments. Not a model of SAMII's physics: that is :mod:`samii.sim`.

The loop is the rig's: ``v = r + Kp (theta_ref - theta)`` with ``theta_ref = 0``,
``theta = G(s) v`` (eq 9.1) and ``xdd = B(s) theta`` (eq 9.2). The notebook does
not state its units; like the rest of samii we read theta in degrees
(:mod:`samii.notebook`) and the acceleration in m/s², so in SI
``G = G_nb * pi/180`` [rad/V], ``B = B_nb * 180/pi`` [(m/s²)/rad], and the
notebook's unity feedback (1 V per degree) is ``Kp = 180/pi`` V/rad.

Because ``B`` is improper (s^4 over second order), the loop is assembled from
proper blocks, never from multiplied polynomials::

    w     = s^2 G(s) v          (biproper, 3 states: "theta double-dot")
    theta = w / s^2
    xdd   = [s^2 sum_i B_i / (s^2 + 2 z_i w_i s + w_i^2)] w

It is discretised with a first-order hold (the excitation is smooth, so the
samples are those of the continuous response to within O((w dt)^2)) and run in
modal coordinates with one first-order recursion per mode (scipy.signal.lfilter).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
from scipy import signal

from samii.frequency_response import FrequencyResponse
from samii.notebook import EQ9_4, actuator_tf, base_tf
from samii.timeseries import TimeSeries

__all__ = ["LinearRig", "DEG"]

#: Notebook theta unit (degree) in rad.
DEG = np.pi / 180.0


def _default_params() -> Mapping[str, float]:
    return EQ9_4


@dataclass(frozen=True)
class LinearRig:
    """Closed position loop around the notebook's actuator and 3-mode base.

    Parameters
    ----------
    params : mapping
        Notebook parameters (eq 9.4 by default; keys of ``samii.notebook.NAMES_3MODE``).
    position_gain_v_per_rad : float
        Kp of the position loop [V/rad]; default the notebook's unity feedback, 180/pi.
    """

    params: Mapping[str, float] = field(default_factory=_default_params)
    position_gain_v_per_rad: float = 1.0 / DEG

    def __post_init__(self) -> None:
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))
        if not self.position_gain_v_per_rad > 0:
            raise ValueError(f"position_gain_v_per_rad must be positive, got {self.position_gain_v_per_rad!r}")

    def open_loop_tf(self):
        """(G, B) as python-control transfer functions in SI: theta/v [rad/V], xdd/theta [(m/s²)/rad]."""

        return actuator_tf(self.params) * DEG, base_tf(self.params) * (1.0 / DEG)

    def exact_frf(self, freqs_hz) -> FrequencyResponse:
        """The exact open-loop channels act, base, total at ``freqs_hz``."""
        G, B = self.open_loop_tf()
        f = np.asarray(freqs_hz, float)
        s = 2j * np.pi * f
        g, b = G(s), B(s)
        return FrequencyResponse(f, act=g, base=b, total=g * b, metadata={"source": "LinearRig exact (notebook tfs, SI)"})

    def closed_loop(self):
        """python-control state space, input r [V], outputs v [V], theta [rad], accel [m/s²]."""
        import control  # (lazy: imports control, only when called)

        p = self.params
        K1, wp, zp, wz, zz, tau = (p[k] for k in ("K1", "wp", "zp", "wz", "zz", "tau"))
        # s^2 G(s) with G of eq 9.1 in SI
        num = K1 * DEG * wp**2 * tau * np.polymul([1.0, 2.0 * zz * wz, wz**2], [1.0, 0.0])
        den = wz**2 * np.polymul([1.0, 2.0 * zp * wp, wp**2], [1.0, tau])
        w_sys = control.ss(control.tf(num, den), inputs="v", outputs="w")
        integ2 = control.ss(control.tf([1.0], [1.0, 0.0, 0.0]), inputs="w", outputs="theta")
        modes = []
        k = 1
        while f"B{k}" in p:
            wk = p.get(f"w{k}", p["wz"] if k == 2 else None)
            zk = p.get(f"z{k}", p["zz"] if k == 2 else None)
            modes.append(control.ss(control.tf([p[f"B{k}"] / DEG, 0.0, 0.0], [1.0, 2.0 * zk * wk, wk**2])))
            k += 1
        base2 = modes[0]
        for m in modes[1:]:
            base2 = control.parallel(base2, m)
        base2 = control.ss(base2, inputs="w", outputs="accel")
        gain = control.ss([], [], [], [[self.position_gain_v_per_rad]], inputs="theta", outputs="ktheta")
        junction = control.summing_junction(inputs=["r", "-ktheta"], output="v")
        return control.interconnect([w_sys, integ2, base2, gain, junction], inplist=["r"], outlist=["v", "theta", "accel"])

    def simulate(self, r, *, sample_rate_hz: float, t0_s: float = 0.0) -> TimeSeries:
        """Response to the excitation samples ``r`` [V] from rest, at the physics rate ``sample_rate_hz``.

        Returns a physics-rate :class:`TimeSeries` with t, v, theta, accel, r and theta_ref (0).
        """
        r = np.asarray(r, float)
        sys = self.closed_loop()
        ad, bd, cd, dd, _ = signal.cont2discrete((sys.A, sys.B, sys.C, sys.D), 1.0 / sample_rate_hz, method="foh")
        lam, vec = np.linalg.eig(ad)
        b_modal = np.linalg.solve(vec, bd[:, 0])
        c_modal = cd @ vec
        y = np.outer(dd[:, 0], r)
        for i, li in enumerate(lam):
            z = signal.lfilter([0.0, b_modal[i]], [1.0, -li], r)  # z[n+1] = l z[n] + b r[n]
            y += np.real(np.outer(c_modal[:, i], z))
        t = t0_s + np.arange(r.size) / sample_rate_hz
        return TimeSeries(
            t=t,
            v=y[0],
            theta=y[1],
            accel=y[2],
            r=r,
            theta_ref=np.zeros_like(r),
            metadata={"source": "samii.measure.linear_rig.LinearRig (notebook eq 9.1/9.2 under the position loop)"},
        )
