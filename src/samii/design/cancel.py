"""The pole-cancelling compensator of notebook chapter 10, and the loop it closes.

Compensator (eq 10.9)::

    G_c(s) = prod (s - z_i) / prod (s - p_i)      (monic numerator and denominator, Matlab poly())

zeros ``z_i``: the lightly damped poles to cancel, i.e. the complex pair of the
inner unity-theta loop (eq 10.1) and base modes 1 and 3 (eq 10.2; mode 2 is
already cancelled by the actuator zeros); poles ``p_i``: the desired
replacements, ``-zeta w +- j w sqrt(1 - zeta^2)`` at 3, 8 and 10 Hz with
zeta = 1 (eq 10.3-10.8, double real poles). (Eq 10.7 as printed omits the
factor ``w`` on the imaginary part; with zeta = 1 it does not matter.)

The loop. The notebook shows it only in a figure that did not survive
(figure 10.1) and picks the gain "using root locus so that the closed loop
poles have damping of approximately 0.7": 0.0666. Two readings fit the text:

``"theta"`` (default): ``K G_c`` in cascade in front of the inner loop, in an
outer unity theta loop::

    theta = G_cl u,   u = K G_c (theta_ref - theta),   G_cl = A/(1 + A)
    v = u - theta = K G_c (theta_ref - theta) - theta
    open loop K G_c G_cl;  closed loop theta/theta_ref = K G_c G_cl / (1 + K G_c G_cl)

At the notebook's K = 0.0666 the four moving closed-loop pairs have zeta
0.711, 0.514, 0.698 and 0.954 (slowest first): two of them are the
notebook's "approximately 0.7". The compensator's zeros remove base modes 1
and 3 and the inner-loop pair from theta_ref -> xdd entirely, which is the
"input shaper" behaviour chapter 11 reports, including "not capable of
quickly damping out a vibration disturbance" (no accelerometer in the loop).
The loop's DC gain is ``K G_c(0) / (1 + K G_c(0))`` (0.143 at our K, 0.133
at the notebook's): theta settles short of theta_ref unless the reference is
scaled, which the notebook does not mention. The runnable controller
(:meth:`PoleCancelDesign.controller`) scales it by default so that theta
tracks theta_ref with unit DC gain; :attr:`PoleCancelDesign.reference_gain`
is that prefilter.

``"accel"``: ``K G_c`` as the filter of the chapter-2 mass-damping loop,
``theta = G_cl (theta_ref - K G_c xdd)`` (figure 10.2's caption reads "root
locus of the mass damping system"; the sign is Matlab's ``rlocus``, 1 + K L = 0). At K = 0.0666 its pairs have zeta 0.710,
0.757 and 0.348, a poorer match.

In both, cancelled poles remain closed-loop poles (they become
uncontrollable or unobservable from the loop, not moved): the compensator
cannot damp them, only avoid exciting them.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import control
import numpy as np
from scipy import optimize

from samii import notebook as nb
from samii.controller import NOTEBOOK_UNITS, LinearController, from_discrete_zpk, unstable_poles
from samii.design.rootlocus import feedback_poles

__all__ = [
    "CancelLoop",
    "inner_loop_pair",
    "base_modes_to_cancel",
    "desired_compensator_poles",
    "compensator",
    "cancel_open_loop",
    "closed_loop_poles",
    "moving_pairs",
    "pair_zetas",
    "gain_at_zeta",
    "choose_gain",
    "PoleCancelDesign",
    "design_pole_cancel",
]

CancelLoop = Literal["theta", "accel"]


def inner_loop_pair(p: Mapping[str, float]) -> np.ndarray:
    """The complex pair of the unity theta loop (eq 10.1 from eq 9.4), negative imaginary part first."""
    cl = control.feedback(nb.actuator_tf(p), 1).poles()
    pair = cl[np.abs(cl.imag) > 1e-9 * np.abs(cl)]
    if len(pair) != 2:
        raise ValueError(f"the unity theta loop has {len(pair)} complex poles, expected one pair")
    return np.sort_complex(pair)


def base_modes_to_cancel(p: Mapping[str, float]) -> np.ndarray:
    """Base-mode poles other than mode 2 (eq 10.2 from eq 9.4), by frequency, negative imaginary part first."""
    poles = nb.base_tf(p).poles()
    m2 = np.roots([1.0, 2 * p["zz"] * p["wz"], p["wz"] ** 2])
    keep = np.array([x for x in poles if np.min(np.abs(m2 - x)) > 1e-6 * abs(x)])
    order = np.lexsort((keep.imag, np.abs(keep)))
    return keep[order]


def desired_compensator_poles(freqs_hz=nb.EQ10_3_HZ, zetas=nb.EQ10_ZETA) -> np.ndarray:
    """Poles ``-zeta w +- j w sqrt(1 - zeta^2)``, ``w = 2 pi f`` (eq 10.7-10.8; zeta = 1 gives double real poles)."""
    if len(freqs_hz) != len(zetas):
        raise ValueError(f"need one damping ratio per frequency, got {len(freqs_hz)} and {len(zetas)}")
    out = []
    for f, z in zip(freqs_hz, zetas):
        if not (f > 0 and 0 < z <= 1):
            raise ValueError(f"desired pole needs f > 0 and 0 < zeta <= 1, got f={f}, zeta={z}")
        w = 2 * np.pi * f
        d = w * np.sqrt(1 - z**2)
        out += [complex(-z * w, -d), complex(-z * w, d)]
    return np.array(out)


def compensator(zeros: np.ndarray, poles: np.ndarray) -> control.TransferFunction:
    """Monic ``poly(zeros) / poly(poles)`` (eq 10.9), real coefficients."""
    return control.tf(np.real(np.poly(zeros)), np.real(np.poly(poles)))


def cancel_open_loop(p: Mapping[str, float], Gc: control.TransferFunction, *, loop: CancelLoop = "theta") -> control.TransferFunction:
    """Open loop whose root locus in K picks the gain (see module docstring); closed loop ``1 + K L = 0``.

    Both use the notebook's (Matlab ``rlocus``) convention ``1 + K L = 0``. For
    ``"accel"`` that is ``theta = G_cl (theta_ref - K G_c xdd)``: chapter 2's
    ``K_a = -K`` in :mod:`samii.design.rootlocus` terms.
    """
    g_cl = control.feedback(nb.actuator_tf(p), 1)
    if loop == "theta":
        return Gc * g_cl
    if loop == "accel":
        return Gc * nb.base_tf(p) * g_cl
    raise ValueError(f"loop must be 'theta' or 'accel', got {loop!r}")


def closed_loop_poles(L: control.TransferFunction | _Locus, K: float) -> np.ndarray:
    """Roots of ``1 + K L = 0``, all of them including the cancelled ones (eigenvalues of a realisation of L)."""

    return _Locus.of(L).closed_loop_poles(K)


class _Locus:
    """``L``'s realisation and (when asked) its open-loop poles, which do not depend on K: computed once for the many
    gains a scan evaluates (:func:`gain_at_zeta`: about 400), not again at each (python-control's ``tf2ss`` and
    ``poles`` took 90 % of each evaluation). The same calls on the same ``L``, so the same numbers as computing them at
    every K."""

    def __init__(self, L: control.TransferFunction):
        self.L = L
        self.ss = control.tf2ss(L)

    @classmethod
    def of(cls, L: control.TransferFunction | _Locus) -> _Locus:
        return L if isinstance(L, _Locus) else cls(L)

    @functools.cached_property
    def open_loop_poles(self) -> np.ndarray:
        return self.L.poles()

    def closed_loop_poles(self, K: float) -> np.ndarray:
        ss = self.ss
        return feedback_poles(ss.A, ss.B, ss.C, ss.D, -K)  # 1 + K L = 0 is positive feedback with gain -K


def moving_pairs(L: control.TransferFunction | _Locus, K: float, *, cancel_tol: float = 1e-6) -> np.ndarray:
    """Upper-half-plane closed-loop poles of ``1 + K L = 0`` that are not open-loop poles, slowest first.

    Poles cancelled by the compensator's zeros stay where they are for every K
    and are left out (those within ``cancel_tol`` relative of an open-loop
    pole; a compensator built from rounded coefficients cancels only
    approximately and needs a looser tolerance, e.g. 1e-2). On the eq 9.4
    "theta" loop there are three moving pairs below K ~ 0.004 and four above
    (near 11, 36, 77 and 141 rad/s at K = 0.0666); their magnitudes stay
    apart, so the rank by magnitude names a pair.
    """
    locus = _Locus.of(L)
    ol = locus.open_loop_poles
    cl = locus.closed_loop_poles(K)
    cl = cl[cl.imag > 1e-9 * np.abs(cl)]
    moving = np.array([x for x in cl if np.min(np.abs(ol - x)) > cancel_tol * abs(x)], complex)
    return moving[np.argsort(np.abs(moving))]


def pair_zetas(L: control.TransferFunction | _Locus, K: float, *, cancel_tol: float = 1e-6) -> np.ndarray:
    """Damping ratios of :func:`moving_pairs` at gain K, slowest pair first."""
    p = moving_pairs(L, K, cancel_tol=cancel_tol)
    return -p.real / np.abs(p)


def gain_at_zeta(
    L: control.TransferFunction,
    zeta: float,
    *,
    pair: int | tuple[int, ...] = 0,
    bracket: tuple[float, float] = (1e-6, 10.0),
    cancel_tol: float = 1e-6,
) -> float:
    """Smallest K in ``bracket`` at which a moving pair's damping ratio crosses ``zeta``.

    Parameters
    ----------
    pair : int or tuple of int
        Rank of the pair by magnitude (0 = slowest, see :func:`moving_pairs`);
        a tuple: the mean damping ratio of those pairs.
    bracket : (float, float)
        Gains scanned (400 log-spaced points, then Brent's method). A rank
        is only meaningful where the number of pairs does not change.
    cancel_tol : float
        As :func:`moving_pairs`.

    Raises
    ------
    ValueError
        If the damping does not cross ``zeta`` in the bracket.
    """
    ranks = (pair,) if isinstance(pair, (int, np.integer)) else tuple(pair)
    locus = _Locus.of(L)

    def f(K: float) -> float:
        z = pair_zetas(locus, K, cancel_tol=cancel_tol)
        if z.size <= max(ranks):  # the pair has not split off the real axis yet: critically damped
            return 1.0 - zeta
        return float(np.mean(z[list(ranks)])) - zeta

    ks = np.geomspace(bracket[0], bracket[1], 400)
    vals = np.array([f(k) for k in ks])
    idx = np.flatnonzero(np.sign(vals[:-1]) != np.sign(vals[1:]))
    if idx.size == 0:
        what = f"moving pair {pair}" if len(ranks) == 1 else f"the mean damping of moving pairs {ranks}"
        raise ValueError(f"{what} does not reach zeta = {zeta} for {bracket[0]:g} <= K <= {bracket[1]:g}")
    i = int(idx[0])
    return float(optimize.brentq(f, ks[i], ks[i + 1], xtol=1e-12, rtol=1e-12))


def choose_gain(L: control.TransferFunction, *, zeta: float = 0.7, k_max: float = 10.0) -> float:
    """Smallest K > 0 at which the dominant (slowest) moving closed-loop pair reaches damping ``zeta``.

    The replacement poles start critically damped (K = 0) and every pair
    loses damping as K grows; the notebook chose its gain "so that the closed
    loop poles have damping of approximately 0.7" on the root-locus plot.
    This rule makes that explicit for the dominant pair. On eq 9.4 it gives
    K = 0.07212 against the notebook's 0.0666; no rule we found reproduces
    0.0666 (see :mod:`samii.design.seed_report`).
    """
    return gain_at_zeta(L, zeta, pair=0, bracket=(1e-6, k_max))


@dataclass(frozen=True)
class PoleCancelDesign:
    """The chapter-10 design: compensator, gain and the loop it closes.

    Attributes
    ----------
    zeros : ndarray
        Cancelled poles (eq 10.1 then eq 10.2).
    poles : ndarray
        Desired compensator poles (eq 10.8).
    Gc : control.TransferFunction
        Monic compensator (eq 10.9).
    gain : float
        K on the root locus.
    loop : {"theta", "accel"}
    open_loop : control.TransferFunction
        L with closed-loop poles at roots of ``1 + K L``.
    """

    params: Mapping[str, float]
    zeros: np.ndarray
    poles: np.ndarray
    Gc: control.TransferFunction
    gain: float
    loop: CancelLoop
    open_loop: control.TransferFunction

    @property
    def closed_loop(self) -> np.ndarray:
        return closed_loop_poles(self.open_loop, self.gain)

    @property
    def unstable_poles(self) -> np.ndarray:
        """Closed-loop poles with ``Re s >= 0`` (empty for a stable loop)."""

        return unstable_poles(self.closed_loop, discrete=False)

    @property
    def stable(self) -> bool:
        """Every closed-loop pole in the open left half plane."""
        return self.unstable_poles.size == 0

    @property
    def dc_gain_as_drawn(self) -> float:
        """theta/theta_ref at DC of the loop as drawn, without reference scaling (``inf`` if a closed-loop pole sits at s = 0).

        ``K G_c(0) / (1 + K G_c(0))`` for ``"theta"``; 1 for ``"accel"`` (xdd vanishes at DC).
        Meaningful only for a stable loop.
        """
        if self.loop == "accel":
            return 1.0
        g0 = self.dc_gain
        return float(g0 / (1.0 + g0)) if 1.0 + g0 != 0.0 else float("inf")

    @property
    def reference_gain(self) -> float:
        """Prefilter on theta_ref that makes theta/theta_ref = 1 at DC (``"theta"`` loop; 1 for ``"accel"``).

        ``(1 + K G_c(0)) / (K G_c(0))`` from the outer loop
        ``theta/theta_ref = K G_c G_cl / (1 + K G_c G_cl)`` with ``G_cl(0) = 1``
        (the actuator integrates).
        """
        if self.loop == "accel":
            return 1.0
        g0 = self.dc_gain
        return (1.0 + g0) / g0

    @property
    def dc_gain(self) -> float:
        """``K G_c(0) = K prod(-z_i) / prod(-p_i)``, from the roots (the expanded polynomials lose digits)."""
        return float(self.gain * np.real(np.prod(-self.zeros) / np.prod(-self.poles)))

    def controller(
        self,
        *,
        sample_time_s: float,
        method: Literal["matched", "zoh", "tustin"] = "matched",
        scale_reference: bool = True,
        input_scale: Mapping[str, float] | None = None,
        model_units: str = NOTEBOOK_UNITS,
    ) -> LinearController:
        """The runnable controller; ``K G_c`` discretised by ``method``.

        Parameters
        ----------
        sample_time_s : float
            Controller sample time [s].
        method : {"matched", "zoh", "tustin"}
            Discretisation of ``K G_c``. ``"matched"`` (pole-zero matching,
            ``z = exp(s T)`` for poles and zeros) is the default because it
            keeps the cancellation exact: the ZOH model of the plant has its
            poles at ``exp(p T)`` too.
        scale_reference : bool
            ``"theta"`` loop only. True (default): multiply theta_ref by
            ``r = (1 + K G_d(1)) / (K G_d(1))``, with ``G_d`` the discretised
            compensator, so that the sampled loop's theta/theta_ref is exactly
            1 at DC (``v = K G_d (r theta_ref - theta) - theta``; in steady
            state the integrating actuator needs ``v = 0``). All three methods
            keep the DC gain, so ``r`` is :attr:`reference_gain`. False: the
            notebook's loop as drawn, whose theta settles at ``1 / r`` of
            theta_ref (0.143 at K = 0.0721). The ``"accel"`` loop has unit DC gain
            without scaling (xdd vanishes at DC) and ignores it.
        input_scale, model_units
            As :class:`samii.controller.LinearController`.
        """
        T = sample_time_s
        if method == "matched":  # python-control's pole-zero matching (z = exp(s T)), from the unrounded roots
            zd, pd = np.exp(self.zeros * T), np.exp(self.poles * T)
        else:
            Gd = control.sample_system(self.gain * self.Gc, T, method=method)
            zd, pd = Gd.zeros(), Gd.poles()
        # All three methods keep the DC gain, K G_c(0) from the roots (dc_gain). The
        # realisation is a cascade of unit-DC sections scaled by it: the expanded
        # polynomials would cost ~1e-6 of DC gain at 1 ms (from_discrete_zpk).
        g0 = self.dc_gain
        A, B, C, D = from_discrete_zpk(zd, pd, g0, sample_time_s=T)
        n = A.shape[0]
        if self.loop == "theta":
            r = (1.0 + g0) / g0 if scale_reference else 1.0
            # v = K Gc (r theta_ref - theta) - theta
            Bw = np.concatenate([r * B, -B], axis=1)
            Dw = np.array([[r * D.item(), -D.item() - 1.0]])
            inputs = ("theta_ref", "theta")
            ref = f", theta_ref scaled by {r:.6g} for unit DC gain" if scale_reference else ", reference not scaled"
        else:
            # v = theta_ref - theta - K Gc accel
            Bw = np.concatenate([np.zeros((n, 2)), -B], axis=1)
            Dw = np.array([[1.0, -1.0, -D.item()]])
            inputs = ("theta_ref", "theta", "accel")
            ref = ""
        return LinearController(
            A, Bw, C.reshape(1, n), Dw,
            sample_time_s=sample_time_s, inputs=inputs, input_scale=input_scale,
            name=f"pole-cancelling compensator ({self.loop} loop, K = {self.gain:.4g}{ref})",
            method=f"K Gc discretised by {method}" + (" (realised as a cascade of unit-DC sections)" if method == "matched" else ""),
            model_units=model_units,
        )  # fmt: skip


def design_pole_cancel(
    p: Mapping[str, float] = nb.EQ9_4,
    *,
    freqs_hz=nb.EQ10_3_HZ,
    zetas=nb.EQ10_ZETA,
    loop: CancelLoop = "theta",
    gain: float | None = None,
    target_zeta: float = 0.7,
) -> PoleCancelDesign:
    """Design the compensator on parameters ``p`` (default eq 9.4); ``gain=None`` picks it by :func:`choose_gain`."""
    zeros = np.concatenate([inner_loop_pair(p), base_modes_to_cancel(p)])
    poles = desired_compensator_poles(freqs_hz, zetas)
    Gc = compensator(zeros, poles)
    L = cancel_open_loop(p, Gc, loop=loop)
    if gain is not None and not (np.isfinite(gain) and gain != 0):
        raise ValueError(f"gain must be a finite, nonzero number, got {float(gain):g} (K = 0 opens the loop)")
    k = choose_gain(L, zeta=target_zeta) if gain is None else float(gain)
    return PoleCancelDesign(p, zeros, poles, Gc, k, loop, L)
