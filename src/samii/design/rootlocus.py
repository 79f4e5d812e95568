"""Mass-damping acceleration feedback (notebook chapters 2 and 3): loop, root loci, stability and damping summary.

The loop
--------
Joint 2 is under a unity position loop: ``v = theta_cmd - theta``. The
accelerometer signal ``y`` (base acceleration ``xdd``; or the base position
``x`` for the "position sensor" variant), through a filter ``F(s)`` and a gain
``K_a``, is added to the angle command (issue 4)::

    theta_cmd = theta_ref + K_a F(s) y,       y = H(s) theta

    H = xdd/theta  (accelerometer)   or   H = x/theta = (xdd/theta) / s^2  (position sensor)

With ``A = theta/v`` and the inner loop closed, ``G_cl = A / (1 + A)``, so::

    theta = G_cl (theta_ref + K_a F H theta)
    theta / theta_ref = G_cl / (1 - K_a L),       L(s) = F(s) H(s) G_cl(s)

The accelerometer loop's open-loop transfer function is ``L = F H G_cl`` and
the closed-loop poles are the roots of ``1 - K_a L(s) = 0``: with ``K_a > 0``
the locus follows the 0-degree criterion of ``L``, with ``K_a < 0`` the
180-degree one. (Matlab's ``rlocus(L)`` draws ``1 + k L = 0``, i.e. our
``K_a = -k``.) ``K_a`` is in the units of the model's theta per unit of its
acceleration (the notebook's own units for eq 1.4).

The closed-loop poles are those of the whole interconnection, including the
roots that cancel between blocks: for the notebook's tied models the base's
mode-2 poles equal the actuator zeros (``w2 = wz``, eq 1.2/9.2), so mode 2 is a
closed-loop pole for every ``K_a`` (the loop cannot see or move it) unless the
actuator is replaced by a pure integrator with lag.

Variants (chapter 2, figures 2.1-2.18; chapter 3, figures 3.1-3.28)
--------------------------------------------------------------------
as built; actuator as a pure integrator with first-order lag
(``K1 tau / (s (s + tau))``: eq 1.1 without its second-order pole and zero,
whose DC gains are 1); base position sensor instead of accelerometer; both;
2nd-order Butterworth low-pass at 2 Hz and at 4 Hz; band-pass. The notebook
gives no corners for its band-pass; :data:`BANDPASS_CORNERS_HZ` documents ours.

Which model
-----------
Chapters 2 and 3 used a 2-mode fit: the pole and zero values quoted in
chapter 2 are those of the manual fit eq 1.3 (see :func:`default_models`). The
notebook prints no 2-mode s^2 fit (chapter 4's s^2 coefficients are missing),
so :func:`s2_params_matching_s4` derives one from the s^4 fit (see there); that
choice reproduces the notebook's remark that ``B2 < 0`` in the s^2 model.

Sign convention
---------------
Chapter 2 says that for its "K_a > 0" two poles of the s^2 loop leave along
the real axis to +-infinity (a 0-degree locus, "because B2 is negative").
With the leading coefficient of L negative that happens here for K_a < 0:
the notebook's K_a is minus ours (it drew Matlab's ``rlocus(L)``, i.e.
``1 + K_a L = 0``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

import control
import numpy as np
from scipy import linalg, optimize, signal
from scipy.optimize import linear_sum_assignment

from samii import notebook as nb

__all__ = [
    "BANDPASS_CORNERS_HZ",
    "SIGNIFICANT_GAIN",
    "EXCLUSION_REASON",
    "ROBUST_GAIN_MARGIN",
    "AccelFilter",
    "LoopVariant",
    "NOTEBOOK_VARIANTS",
    "MassDampingLoop",
    "ModeDamping",
    "SignResult",
    "RootLocusSummary",
    "RootLocusData",
    "s2_params_matching_s4",
    "mass_damping_loop",
    "closed_loop_poles",
    "feedback_poles",
    "stable_gain_intervals",
    "intervals_of_sign",
    "stability_limit",
    "track_branches",
    "summarize",
    "root_locus_data",
    "study",
    "default_models",
    "summary_table",
]

Actuator = Literal["as_built", "integrator_lag"]
Sensor = Literal["accelerometer", "position"]
Numerator = Literal["s4", "s2"]

#: Band-pass corners [Hz] (our choice; the notebook gives none): a 2nd-order
#: Butterworth prototype (4th-order band-pass, 40 dB/decade on both sides like
#: the notebook's 2nd-order low-pass) whose geometric centre sqrt(1*3) = 1.73 Hz
#: is base mode 1 (eq 9.4: w1 = 10.886 rad/s = 1.73 Hz), passing mode 1 while
#: removing the accelerometer's DC offset and attenuating mode 2 (~9.8 Hz).
BANDPASS_CORNERS_HZ = (1.0, 3.0)

#: A variant "beats no acceleration feedback" when some stable K_a raises the
#: damping ratio of the least-damped base mode that the feedback can move by at
#: least this factor while no closed-loop pole ends up less damped than the
#: least-damped pole without feedback. 1.10 = 10 % more damping, i.e. vibration
#: decaying 10 % faster; the notebook's wording is "significantly improved", so
#: the threshold is ours.
SIGNIFICANT_GAIN = 1.10

#: Why a base mode is left out of the verdict (:attr:`ModeDamping.fixed`).
EXCLUSION_REASON = (
    "pole-zero cancellation: its poles do not move with K_a (for the notebook's tied models the base's mode-2 "
    "poles equal the actuator zeros, w2 = wz and z2 = zz in eq 1.2/9.2), so no K_a of either sign can change its damping"
)

#: Gain margin kept by the "robust" optimum (a factor 2 = 6 dB, the textbook minimum):
#: the gain may double before the loop goes unstable.
ROBUST_GAIN_MARGIN = 2.0


@dataclass(frozen=True)
class AccelFilter:
    """Butterworth filter on the accelerometer signal.

    Parameters
    ----------
    kind : {"lowpass", "bandpass"}
    corners_hz : tuple of float
        One corner for a low-pass, (low, high) for a band-pass [Hz].
    order : int
        Butterworth prototype order (2 in the notebook; a band-pass has twice
        as many poles).
    """

    kind: Literal["lowpass", "bandpass"]
    corners_hz: tuple[float, ...]
    order: int = 2

    def __post_init__(self) -> None:
        n = {"lowpass": 1, "bandpass": 2}.get(self.kind)
        if n is None:
            raise ValueError(f"AccelFilter.kind must be 'lowpass' or 'bandpass', got {self.kind!r}")
        if len(self.corners_hz) != n or not all(np.isfinite(c) and c > 0 for c in self.corners_hz):
            raise ValueError(f"AccelFilter.corners_hz must be {n} positive frequencies for a {self.kind}, got {self.corners_hz}")
        if n == 2 and not self.corners_hz[0] < self.corners_hz[1]:
            raise ValueError(f"AccelFilter band-pass corners must increase, got {self.corners_hz}")
        if self.order < 1:
            raise ValueError(f"AccelFilter.order must be >= 1, got {self.order}")

    def tf(self) -> control.TransferFunction:
        """The analog filter (unity gain in its pass band)."""
        wc = [2.0 * np.pi * f for f in self.corners_hz]
        b, a = signal.butter(self.order, wc if len(wc) == 2 else wc[0], btype=self.kind, analog=True)
        return control.tf(b, a)

    def label(self) -> str:
        corners = "-".join(f"{f:g}" for f in self.corners_hz)
        return (
            f"{self.order}nd-order Butterworth {self.kind} {corners} Hz"
            if self.order == 2
            else f"order-{self.order} Butterworth {self.kind} {corners} Hz"
        )


@dataclass(frozen=True)
class LoopVariant:
    """One modification of the mass-damping loop studied in chapters 2 and 3."""

    name: str
    actuator: Actuator = "as_built"
    sensor: Sensor = "accelerometer"
    filter: AccelFilter | None = None

    def __post_init__(self) -> None:
        if self.actuator not in ("as_built", "integrator_lag"):
            raise ValueError(f"LoopVariant.actuator must be 'as_built' or 'integrator_lag', got {self.actuator!r}")
        if self.sensor not in ("accelerometer", "position"):
            raise ValueError(f"LoopVariant.sensor must be 'accelerometer' or 'position', got {self.sensor!r}")

    def describe(self) -> str:
        act = "eq 1.1 actuator" if self.actuator == "as_built" else "actuator = K1 tau/(s (s+tau))"
        sen = "accelerometer" if self.sensor == "accelerometer" else "base position sensor"
        filt = "no filter" if self.filter is None else self.filter.label()
        return f"{act}, {sen}, {filt}"


#: The notebook's variants (figures 2.1-2.18 and 3.1-3.28).
NOTEBOOK_VARIANTS: tuple[LoopVariant, ...] = (
    LoopVariant("as_built"),
    LoopVariant("integrator_actuator", actuator="integrator_lag"),
    LoopVariant("position_sensor", sensor="position"),
    LoopVariant("integrator_and_position", actuator="integrator_lag", sensor="position"),
    LoopVariant("lowpass_2hz", filter=AccelFilter("lowpass", (2.0,))),
    LoopVariant("lowpass_4hz", filter=AccelFilter("lowpass", (4.0,))),
    LoopVariant("bandpass", filter=AccelFilter("bandpass", BANDPASS_CORNERS_HZ)),
)


def s2_params_matching_s4(p: Mapping[str, float]) -> dict[str, float]:
    """Parameters of an s^2 base model equivalent to the s^4 model ``p`` at its resonances.

    The notebook fitted an s^2 model (chapters 2-4) but printed no 2-mode s^2
    coefficients. Our clearly-labelled substitute keeps every frequency and
    damping ratio of ``p`` and matches each mode's residue at its own
    resonance: at ``s = j w_k``, ``s^4 = -w_k^2 s^2``, so
    ``B_k(s^2) = -w_k^2 B_k(s^4)``. The two models then agree near every mode
    and differ away from them by ``-s^2/w_k^2`` per term (the s^2 model rolls off
    at high frequency, as chapter 4 describes). The sign flip gives ``B2 < 0``
    for eq 1.4, as chapter 2 says of the s^2 model.

    Replace this with a real s^2 fit when one is available.
    """
    q = dict(p)
    k = 1
    while f"B{k}" in p:
        wk = p.get(f"w{k}", p["wz"] if k == 2 else None)
        if wk is None:
            raise KeyError(f"parameter set has B{k} but no w{k}")
        q[f"B{k}"] = -(wk**2) * p[f"B{k}"]
        k += 1
    return q


def _integrator_lag_actuator(p: Mapping[str, float]) -> control.TransferFunction:
    # eq 1.1 with wp^2/(s^2+2 zp wp s+wp^2) and (s^2+2 zz wz s+wz^2)/wz^2 removed (both have DC gain 1)
    return control.tf([p["K1"] * p["tau"]], [1.0, p["tau"], 0.0])


@dataclass(frozen=True)
class MassDampingLoop:
    """The open loop ``L = F H G_cl`` of one variant on one model (see module docstring).

    Attributes
    ----------
    open_loop : control.TransferFunction
        ``L(s)``; closed-loop poles are the roots of ``1 - K_a L(s) = 0``.
    base_modes : ndarray of complex
        Open-loop base-mode poles (upper half plane), mode 1 first.
    """

    variant: LoopVariant
    numerator: Numerator
    model: str
    actuator: control.TransferFunction
    g_cl: control.TransferFunction
    sensor: control.TransferFunction
    filter: control.TransferFunction
    open_loop: control.TransferFunction
    base_modes: np.ndarray
    statespace: control.StateSpace = field(repr=False)

    @property
    def label(self) -> str:
        return f"{self.model} ({self.numerator} base), {self.variant.name}"


def mass_damping_loop(
    p: Mapping[str, float], *, numerator: Numerator = "s4", variant: LoopVariant = NOTEBOOK_VARIANTS[0], model: str = "eq 1.4"
) -> MassDampingLoop:
    """Build the mass-damping open loop ``L = F H G_cl`` for parameters ``p`` (notebook names).

    ``p`` is used as given with ``numerator``: pass :func:`s2_params_matching_s4`
    of an s^4 parameter set for the s^2 model.
    """
    if numerator not in ("s4", "s2"):
        raise ValueError(f"numerator must be 's4' or 's2', got {numerator!r}")
    act = nb.actuator_tf(p) if variant.actuator == "as_built" else _integrator_lag_actuator(p)
    g_cl = control.feedback(act, 1)
    base = nb.base_tf(p, numerator=numerator)
    sensor = base if variant.sensor == "accelerometer" else base * control.tf([1.0], [1.0, 0.0, 0.0])
    sensor = control.minreal(sensor, verbose=False) if variant.sensor == "position" else sensor
    filt = variant.filter.tf() if variant.filter is not None else control.tf([1.0], [1.0])
    L = filt * sensor * g_cl
    # H alone is improper for the s^4 model (eq 2.3: "non causal"), L is proper. The product is
    # formed without cancellation, so the roots shared by blocks (mode 2 vs the actuator zeros)
    # stay closed-loop poles, as they are in the real interconnection.
    ss = control.tf2ss(L)
    bp = base.poles()
    modes = np.sort_complex(bp[bp.imag > 0])
    modes = modes[np.argsort(np.abs(modes))]
    return MassDampingLoop(variant, numerator, model, act, g_cl, sensor, filt, L, modes, ss)


#: Below this ``|1 - k D|`` the feedback poles come from the descriptor pencil (see :func:`feedback_poles`).
_ILL_POSED_TOL = 1e-6


def feedback_poles(A, B, C, D, k: float) -> np.ndarray:
    """Eigenvalues of ``x' = A x + B u`` under positive feedback ``u = k y``, ``y = C x + D u`` (one input, one output).

    Eliminating ``u = k (1 - k D)^-1 C x`` gives ``A + B k/(1 - k D) C``, which
    is what is used while ``|1 - k D| > 1e-6``. A biproper loop (``D != 0``) is
    ill-posed at ``k = 1/D``: ``u`` is no longer determined by ``x``, the
    characteristic polynomial ``den - k num`` loses its leading term and one
    root passes through infinity (from ``-inf`` to ``+inf`` along the real axis
    as ``k D`` crosses 1). That gain is exactly a stability limit of such
    loops, so it is evaluated, not avoided: near and at it the poles are the
    finite generalised eigenvalues of the descriptor system in ``(x, u)``::

        [I 0] d/dt [x]   [A      B    ] [x]
        [0 0]      [u] = [k C  k D - 1] [u]

    (balanced, as LAPACK's standard eigensolver does on its own), whose one
    always-infinite eigenvalue (the algebraic equation for ``u``) is dropped. A root at infinity (``k D = 1`` exactly) is returned as
    ``complex(inf, 0)``, so there are always ``n`` values and ``max(real)`` is
    ``inf`` (not asymptotically stable) there.
    """
    A, B, C = (np.asarray(m, float) for m in (A, B, C))
    d = float(np.asarray(D, float).reshape(-1)[0]) if np.size(D) else 0.0
    k = float(k)
    if not np.isfinite(k):
        raise ValueError(f"feedback gain must be finite, got {k}")
    den = 1.0 - k * d
    if abs(den) > _ILL_POSED_TOL:
        return np.linalg.eigvals(A + B @ ((k / den) * C))

    n = A.shape[0]
    M = np.block([[A, B], [k * C, np.array([[k * d - 1.0]])]])
    # balance first (a diagonal similarity leaves E = diag(I, 0) unchanged): the QZ algorithm does not, and
    # the companion realisations here span 25 orders of magnitude (1e-6 relative errors without it, 1e-15 with)
    M, _ = linalg.matrix_balance(M, permute=False, separate=True)
    E = np.zeros((n + 1, n + 1))
    E[:n, :n] = np.eye(n)
    alpha, beta = linalg.eigvals(M, E, homogeneous_eigvals=True)
    # |beta|/|alpha| is 0 (to rounding) for an infinite eigenvalue; the smallest one is the algebraic equation
    ratio = np.abs(beta) / np.maximum(np.abs(alpha), np.finfo(float).tiny)
    order = np.argsort(ratio)[1:]
    scale = max(np.linalg.norm(M, 1), 1.0)
    out = np.empty(n, complex)
    for i, j in enumerate(order):
        out[i] = alpha[j] / beta[j] if ratio[j] > 1e3 * np.finfo(float).eps / scale else complex(np.inf, 0.0)
    return out


def _closed_loop_poles_at(ss: control.StateSpace, k: float) -> np.ndarray:
    return feedback_poles(ss.A, ss.B, ss.C, ss.D, k)


def closed_loop_poles(loop: MassDampingLoop, gains: np.ndarray) -> np.ndarray:
    """Closed-loop poles (roots of ``1 - K_a L = 0``) for each gain; shape (n_gains, n_states).

    At ``K_a = 1/D`` of a biproper loop one root is at infinity and is
    returned as ``inf`` (see :func:`feedback_poles`).
    """
    gains = np.atleast_1d(np.asarray(gains, float))
    return np.array([_closed_loop_poles_at(loop.statespace, k) for k in gains])


def _max_real(loop: MassDampingLoop, k: float) -> float:
    return float(np.max(_closed_loop_poles_at(loop.statespace, k).real))


def _crossing_gains(loop: MassDampingLoop) -> np.ndarray:
    """Every real K_a at which a closed-loop root lies on the imaginary axis or passes through infinity.

    Roots of ``den(s) - K num(s)`` reach ``s = j w`` where ``den(jw)/num(jw)`` is
    real; that ratio is then the gain. Found as sign changes of
    ``Im(den conj(num))/(|den||num|)`` on a dense log grid over 1e-3 to 1e5
    rad/s (40001 points; the models' dynamics lie within 1 to 1000 rad/s),
    refined by Brent's method; plus ``w = 0`` and the gain
    ``lead(den)/lead(num)`` at which a root passes through infinity (biproper loops).
    """
    num = np.asarray(loop.open_loop.num[0][0], float)
    den = np.asarray(loop.open_loop.den[0][0], float)

    def g(w: float) -> float:
        n, d = np.polyval(num, 1j * w), np.polyval(den, 1j * w)
        return float((d * np.conj(n)).imag / (abs(d) * abs(n) + 1e-300))

    w = np.logspace(-3, 5, 40001)
    n, d = np.polyval(num, 1j * w), np.polyval(den, 1j * w)
    gv = (d * np.conj(n)).imag / (np.abs(d) * np.abs(n) + 1e-300)
    ks: list[float] = []
    for i in np.flatnonzero(np.sign(gv[:-1]) * np.sign(gv[1:]) < 0):
        wc = optimize.brentq(g, w[i], w[i + 1], xtol=1e-14, rtol=1e-14)
        ratio = np.polyval(den, 1j * wc) / np.polyval(num, 1j * wc)
        ks.append(float(ratio.real))
    if abs(np.polyval(num, 0.0)) > 0:
        ks.append(float(np.polyval(den, 0.0) / np.polyval(num, 0.0)))
    numt = np.trim_zeros(num, "f")
    if len(numt) == len(np.trim_zeros(den, "f")):
        ks.append(float(np.trim_zeros(den, "f")[0] / numt[0]))
    ks = [k for k in ks if np.isfinite(k) and k != 0.0]
    return np.unique(np.array(ks))


def _interior_gain(lo: float, hi: float, big: float) -> float:
    """A gain strictly inside (lo, hi); the edges share a sign or one of them is 0 or infinite."""
    if lo == -np.inf:
        return 10.0 * hi if hi < 0 else -big
    if hi == np.inf:
        return 10.0 * lo if lo > 0 else big
    if lo == 0.0 or hi == 0.0:
        return 0.5 * (lo + hi)
    return float(np.sign(hi) * np.sqrt(lo * hi))


def stable_gain_intervals(loop: MassDampingLoop) -> tuple[tuple[float, float], ...]:
    """The K_a intervals (open, notebook units) for which every closed-loop pole has a negative real part.

    Exact up to root finding: stability can change only at the gains of
    :func:`_crossing_gains`; each interval between them is classified by the
    eigenvalues of the closed loop at an interior point. Intervals touching
    +-inf are reported with ``inf``. The interval containing 0 is present when
    the loop without acceleration feedback is stable.
    """
    cands = _crossing_gains(loop)
    edges = np.concatenate([[-np.inf], cands[cands < 0], [0.0], cands[cands > 0], [np.inf]])
    big = 1e6 * (float(np.abs(cands).max()) if cands.size else 1.0)
    stable: list[tuple[float, float]] = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        k = _interior_gain(lo, hi, big)
        if _max_real(loop, k) < 0:
            if stable and stable[-1][1] == lo and lo != 0.0:
                stable[-1] = (stable[-1][0], hi)  # a crossing that did not change stability
            else:
                stable.append((float(lo), float(hi)))
    # join the two halves around K_a = 0 (0 itself is the open loop)
    merged: list[tuple[float, float]] = []
    for iv in stable:
        if merged and merged[-1][1] == iv[0] == 0.0:
            merged[-1] = (merged[-1][0], iv[1])
        else:
            merged.append(iv)
    return tuple(merged)


def intervals_of_sign(intervals, sign: int) -> tuple[tuple[float, float], ...]:
    """The parts of stable ``intervals`` with K_a of the given sign (0 excluded), e.g. for a plot of that sign."""
    if sign not in (1, -1):
        raise ValueError(f"sign must be +1 or -1, got {sign}")
    out = []
    for a, b in intervals:
        lo, hi = (max(a, 0.0), b) if sign > 0 else (a, min(b, 0.0))
        if lo < hi:
            out.append((float(lo), float(hi)))
    return tuple(out)


def stability_limit(intervals, sign: int) -> float:
    """The K_a of the given sign at which the loop first goes unstable, starting from K_a = 0.

    ``inf`` (or ``-inf``) if never; ``nan`` if the loop without acceleration feedback is unstable.
    """
    iv = next(((a, b) for a, b in intervals if a < 0 < b), None)
    if iv is None:
        return float("nan")
    return float(iv[1] if sign > 0 else iv[0])


def _gain_grid(cands: np.ndarray, sign: float, n: int) -> np.ndarray:
    kabs = np.abs(cands[np.sign(cands) == sign]) if cands.size else np.array([1.0])
    lo = (kabs.min() if kabs.size else np.abs(cands).min() if cands.size else 1.0) * 1e-5
    hi = (kabs.max() if kabs.size else np.abs(cands).max() if cands.size else 1.0) * 1e3
    grid = np.concatenate([np.logspace(np.log10(lo), np.log10(hi), n), kabs * (1 - 1e-9), kabs * (1 + 1e-9)])
    return sign * np.unique(grid)


def track_branches(loop: MassDampingLoop, gains: np.ndarray, *, start: np.ndarray | None = None) -> np.ndarray:
    """Closed-loop poles along ``gains`` (monotone in |K_a|), each column one continuous branch.

    Columns follow ``start`` (default: the open-loop eigenvalues, K_a = 0);
    each row is matched to the previous one by minimum total distance
    (Hungarian method).
    """
    poles = closed_loop_poles(loop, gains)
    out = np.empty_like(poles)
    prev = closed_loop_poles(loop, [0.0])[0] if start is None else np.asarray(start)
    for i in range(len(poles)):
        _, col = linear_sum_assignment(np.abs(prev[:, None] - poles[i][None, :]))
        out[i] = prev = poles[i][col]
    return out


@dataclass(frozen=True)
class ModeDamping:
    """Damping of one base mode's root-locus branch.

    ``best_zeta_pos``/``best_zeta_neg`` are the largest damping ratios the
    branch reaches over the stable gains with K_a > 0 / K_a < 0 (``nan`` if no
    stable gain of that sign), attained at ``best_gain_pos``/``best_gain_neg``
    (0 when no gain of that sign raises it). That maximum is often at the edge
    of stability, where another pole is undamped: :class:`SignResult` gives the
    balanced answer. ``fixed`` is true when the mode cancels out of the loop
    (its pole does not move with K_a).
    """

    mode: int
    open_loop_pole: complex
    open_loop_zeta: float
    best_zeta_pos: float
    best_gain_pos: float
    best_zeta_neg: float
    best_gain_neg: float
    fixed: bool

    @property
    def best_zeta(self) -> float:
        """The larger of :attr:`best_zeta_pos` and :attr:`best_zeta_neg` (``nan`` if neither sign has a stable gain)."""
        zs = [z for z in (self.best_zeta_pos, self.best_zeta_neg) if np.isfinite(z)]
        return float(max(zs)) if zs else float("nan")

    @property
    def best_gain(self) -> float:
        """The K_a at which :attr:`best_zeta` is reached (0 when no gain raises it)."""
        if not np.isfinite(self.best_zeta):
            return float("nan")
        if np.isfinite(self.best_zeta_pos) and self.best_zeta_pos == self.best_zeta:
            return self.best_gain_pos
        return self.best_gain_neg

    @property
    def ratio(self) -> float:
        """Best damping over stable K_a of either sign / damping without acceleration feedback."""
        return float(self.best_zeta / self.open_loop_zeta)


@dataclass(frozen=True)
class SignResult:
    """The best one sign of K_a does for the base vibration.

    ``best_gain`` maximises, over the stable gains of this sign, the damping
    ratio of the least-damped base mode among those that move with K_a
    (modes fixed by pole-zero cancellation are excluded: no gain changes
    them), subject to every other complex closed-loop pole staying at least
    as damped as the least-damped pole without feedback (no new, worse
    oscillation). ``min_moving_zeta`` is that least damping of the moving
    base modes there, ``mode_zetas`` every base mode's (fixed ones included),
    ``min_zeta_all`` the least damping of all complex closed-loop poles, and
    ``gain_margin`` the factor by which ``best_gain`` could grow before the loop
    goes unstable. ``best_gain`` is 0 when no gain of this sign beats K_a = 0;
    all values are ``nan`` when no gain of this sign is stable.
    """

    best_gain: float
    min_moving_zeta: float
    mode_zetas: tuple[float, ...]
    min_zeta_all: float
    gain_margin: float


@dataclass(frozen=True)
class RootLocusSummary:
    """Quantitative answer to the notebook's question for one variant on one model.

    The variant "beats no acceleration feedback" when a stable K_a of either
    sign raises the least damping ratio of the base modes the feedback can
    move by the factor :data:`SIGNIFICANT_GAIN` under the constraint of
    :class:`SignResult`. Modes fixed by pole-zero cancellation
    (:attr:`excluded_modes`, reason :data:`EXCLUSION_REASON`) are left out:
    counting them would cap every ratio at their damping over the moving
    modes' (e.g. 0.06/0.05 = 1.2 on eq 1.3). Each mode's own best damping
    and ratio are in :attr:`modes`.
    """

    model: str
    numerator: Numerator
    variant: LoopVariant
    stable_intervals: tuple[tuple[float, float], ...]
    modes: tuple[ModeDamping, ...]
    open_loop_min_moving_zeta: float
    open_loop_min_zeta_all: float
    positive: SignResult
    negative: SignResult
    robust_positive: SignResult
    robust_negative: SignResult

    @property
    def excluded_modes(self) -> tuple[int, ...]:
        """Base modes left out of the verdict because they cannot move (see :data:`EXCLUSION_REASON`)."""
        return tuple(m.mode for m in self.modes if m.fixed)

    @property
    def best_ratio(self) -> float:
        """Best least damping of the moving base modes over both signs (constrained) / its value without feedback."""
        best = np.nanmax([self.positive.min_moving_zeta, self.negative.min_moving_zeta, self.open_loop_min_moving_zeta])
        return float(best / self.open_loop_min_moving_zeta)

    @property
    def robust_ratio(self) -> float:
        """As :attr:`best_ratio`, keeping a gain margin of :data:`ROBUST_GAIN_MARGIN` (6 dB)."""
        best = np.nanmax([self.robust_positive.min_moving_zeta, self.robust_negative.min_moving_zeta, self.open_loop_min_moving_zeta])
        return float(best / self.open_loop_min_moving_zeta)

    @property
    def beats_no_feedback(self) -> bool:
        return self.best_ratio >= SIGNIFICANT_GAIN

    def as_dict(self) -> dict:
        def num(x: float):
            return None if not np.isfinite(x) else float(x)

        def edge(x: float):
            return "inf" if x == np.inf else "-inf" if x == -np.inf else float(x)

        def sign(r: SignResult) -> dict:
            return {
                "best_K_a": num(r.best_gain),
                "min_moving_mode_zeta": num(r.min_moving_zeta),
                "base_mode_zetas": [num(z) for z in r.mode_zetas],
                "min_zeta_all_poles": num(r.min_zeta_all),
                "gain_margin": num(r.gain_margin),
            }

        return {
            "model": self.model,
            "numerator": self.numerator,
            "variant": self.variant.name,
            "description": self.variant.describe(),
            "stable_K_a_intervals": [[edge(a), edge(b)] for a, b in self.stable_intervals],
            "modes": [
                {
                    "mode": m.mode,
                    "open_loop_pole": [m.open_loop_pole.real, m.open_loop_pole.imag],
                    "open_loop_zeta": m.open_loop_zeta,
                    "best_zeta_K_a_pos": num(m.best_zeta_pos),
                    "at_K_a_pos": num(m.best_gain_pos),
                    "best_zeta_K_a_neg": num(m.best_zeta_neg),
                    "at_K_a_neg": num(m.best_gain_neg),
                    "best_zeta": num(m.best_zeta),
                    "best_ratio_vs_open_loop": num(m.ratio),
                    "fixed_by_cancellation": m.fixed,
                }
                for m in self.modes
            ],
            "excluded_modes": [{"mode": k, "reason": EXCLUSION_REASON} for k in self.excluded_modes],
            "open_loop_min_moving_mode_zeta": self.open_loop_min_moving_zeta,
            "open_loop_min_zeta_all_poles": self.open_loop_min_zeta_all,
            "K_a_pos": sign(self.positive),
            "K_a_neg": sign(self.negative),
            "K_a_pos_6dB_margin": sign(self.robust_positive),
            "K_a_neg_6dB_margin": sign(self.robust_negative),
            "best_ratio": self.best_ratio,
            "best_ratio_6dB_margin": self.robust_ratio,
            "beats_no_acceleration_feedback": self.beats_no_feedback,
        }


def _zeta(p: np.ndarray) -> np.ndarray:
    p = np.asarray(p, complex)
    mag = np.abs(p)
    return np.where(mag > 0, -p.real / np.where(mag > 0, mag, 1.0), 1.0)


def _min_zeta(poles: np.ndarray) -> float:
    poles = np.asarray(poles, complex)
    c = np.abs(poles.imag) > 1e-9 * np.maximum(1.0, np.abs(poles))
    return float(_zeta(poles[c]).min()) if c.any() else 1.0


def _in_intervals(k: np.ndarray, intervals) -> np.ndarray:
    ok = np.zeros(k.shape, bool)
    for lo, hi in intervals:
        ok |= (k > lo) & (k < hi)
    return ok


def _shrink(intervals, gm: float) -> list[tuple[float, float]]:
    """The gains of ``intervals`` that may be multiplied or divided by ``gm`` and stay inside (K_a = 0 only scales up)."""
    out = []
    for a, b in intervals:
        if a < 0 < b:
            out.append((a / gm, b / gm))
        elif a >= 0:
            out.append((a * gm, b / gm))
        else:
            out.append((a / gm, b * gm))
    return [(a, b) for a, b in out if a < b]


def _gain_margin(k: float, intervals) -> float:
    """Factor by which K_a can change before leaving its stable interval (upward only for the interval around 0)."""
    a, b = next((a, b) for a, b in intervals if a < k < b)
    if a < 0 < b:
        return float((b if k > 0 else a) / k)
    return float(min(b / k, k / a) if k > 0 else min(a / k, k / b))


def _best_for_sign(
    loop: MassDampingLoop,
    intervals: tuple[tuple[float, float], ...],
    mode_cols: list[int],
    is_fixed: np.ndarray,
    gains: np.ndarray,
    br: np.ndarray,
    ok: np.ndarray,
    *,
    min_gain_margin: float = 1.0,
) -> SignResult:
    """Constrained optimum of the least moving base-mode damping along one sign's tracked branches (see SignResult)."""
    n_modes = len(mode_cols)

    def margin_ok(k: np.ndarray) -> np.ndarray:
        return _in_intervals(k, _shrink(intervals, min_gain_margin))

    ok = ok & margin_ok(gains)
    if not ok.any():
        return SignResult(np.nan, np.nan, (np.nan,) * n_modes, np.nan, np.nan)
    ol = closed_loop_poles(loop, [0.0])[0]
    others = np.array([c for c in range(len(ol)) if c not in mode_cols and not is_fixed[c]], int)
    floor = _min_zeta(ol) * (1 - 1e-9)

    moving = [c for c in mode_cols if not is_fixed[c]]
    if not moving:
        return SignResult(0.0, np.nan, tuple(float(z) for z in _zeta(ol[mode_cols])), _min_zeta(ol), np.nan)

    def score(rows: np.ndarray) -> np.ndarray:
        # least damping of the base modes that move (a cancelled mode keeps its damping for every K_a)
        zb = _zeta(rows[:, moving]).min(axis=1)
        zo = np.array([_min_zeta(r[others]) for r in rows]) if others.size else np.ones(len(rows))
        return np.where(zo >= floor, zb, -np.inf)

    def result(k: float, row: np.ndarray) -> SignResult:
        zs = tuple(float(z) for z in _zeta(row[mode_cols]))
        zm = float(_zeta(row[moving]).min())
        if k == 0.0:
            return SignResult(0.0, zm, zs, _min_zeta(row), np.nan)
        return SignResult(k, zm, zs, _min_zeta(row), _gain_margin(k, intervals))

    sc = np.where(ok, score(br), -np.inf)
    j = int(np.argmax(sc))
    if sc[j] <= _zeta(ol[moving]).min() * (1 + 1e-9):  # no gain of this sign helps: K_a = 0 is best
        return result(0.0, ol)
    # refine between the neighbouring grid gains, tracking on from the row before
    lo, hi = max(j - 1, 0), min(j + 1, len(gains) - 1)
    fine = np.linspace(gains[lo], gains[hi], 201)
    rows = track_branches(loop, fine, start=br[lo])
    sf = np.where(_in_intervals(fine, intervals) & margin_ok(fine), score(rows), -np.inf)
    i = int(np.argmax(sf))
    if sf[i] > sc[j]:
        return result(float(fine[i]), rows[i])
    return result(float(gains[j]), br[j])


def summarize(loop: MassDampingLoop, *, n_gains: int = 3000) -> RootLocusSummary:
    """Stable K_a intervals and the best damping of every base mode, for both signs of K_a."""
    intervals = stable_gain_intervals(loop)
    cands = _crossing_gains(loop)
    ol = closed_loop_poles(loop, [0.0])[0]
    # which open-loop eigenvalue is base mode i (closest to the base pole)
    mode_cols = [int(np.argmin(np.abs(ol - m))) for m in loop.base_modes]

    per_sign = {}
    for sign in (1.0, -1.0):
        gains = _gain_grid(cands, sign, n_gains)
        per_sign[sign] = (gains, track_branches(loop, gains), _in_intervals(gains, intervals))
    moved = np.max([np.max(np.abs(br - ol[None, :]), axis=0) for _, br, _ in per_sign.values()], axis=0)
    is_fixed = moved < 1e-6 * np.maximum(np.abs(ol), 1.0)

    modes = []
    for i, col in enumerate(mode_cols):
        z0 = float(_zeta(ol[col]))
        best = {}
        for sign, (gains, br, ok) in per_sign.items():
            z = np.where(ok, _zeta(br[:, col]), -np.inf)
            j = int(np.argmax(z))
            if not ok.any():
                best[sign] = (np.nan, np.nan)
            elif z[j] > z0 * (1 + 1e-9) and not is_fixed[col]:
                best[sign] = (float(z[j]), float(gains[j]))
            else:  # no gain of this sign raises it: K_a = 0 is best
                best[sign] = (z0, 0.0)
        modes.append(
            ModeDamping(
                mode=i + 1,
                open_loop_pole=complex(loop.base_modes[i]),
                open_loop_zeta=z0,
                best_zeta_pos=best[1.0][0],
                best_gain_pos=best[1.0][1],
                best_zeta_neg=best[-1.0][0],
                best_gain_neg=best[-1.0][1],
                fixed=bool(is_fixed[col]),
            )
        )
    return RootLocusSummary(
        model=loop.model,
        numerator=loop.numerator,
        variant=loop.variant,
        stable_intervals=intervals,
        modes=tuple(modes),
        open_loop_min_moving_zeta=float(min((_zeta(ol[c]) for c in mode_cols if not is_fixed[c]), default=np.nan)),
        open_loop_min_zeta_all=_min_zeta(ol),
        positive=_best_for_sign(loop, intervals, mode_cols, is_fixed, *per_sign[1.0]),
        negative=_best_for_sign(loop, intervals, mode_cols, is_fixed, *per_sign[-1.0]),
        robust_positive=_best_for_sign(loop, intervals, mode_cols, is_fixed, *per_sign[1.0], min_gain_margin=ROBUST_GAIN_MARGIN),
        robust_negative=_best_for_sign(loop, intervals, mode_cols, is_fixed, *per_sign[-1.0], min_gain_margin=ROBUST_GAIN_MARGIN),
    )


@dataclass(frozen=True)
class RootLocusData:
    """Root-locus branches of one loop for one sign of K_a, ready to plot.

    ``loci[i, j]`` is closed-loop pole j at gain ``gains[i]`` (python-control's
    :func:`control.root_locus_map` ordering); ``poles``/``zeros`` are those of ``L``.
    """

    label: str
    sign: int
    gains: np.ndarray
    loci: np.ndarray
    poles: np.ndarray
    zeros: np.ndarray
    base_modes: np.ndarray


def root_locus_data(loop: MassDampingLoop, *, sign: int, n_gains: int = 1500) -> RootLocusData:
    """Root locus of ``1 - K_a L = 0`` for K_a of the given sign, via :func:`control.root_locus_map`.

    python-control draws ``1 + k G = 0`` with ``k >= 0``; ``G = -sign L`` makes ``K_a = sign k``.
    """
    if sign not in (1, -1):
        raise ValueError(f"sign must be +1 or -1, got {sign}")
    cands = _crossing_gains(loop)
    k = np.concatenate([[0.0], np.abs(_gain_grid(cands, float(sign), n_gains))])
    rl = control.root_locus_map(-sign * loop.open_loop, gains=k)
    return RootLocusData(
        label=loop.label,
        sign=sign,
        gains=sign * np.asarray(rl.gains),
        loci=np.asarray(rl.loci),
        poles=loop.open_loop.poles(),
        zeros=loop.open_loop.zeros(),
        base_modes=loop.base_modes,
    )


def study(
    models: Mapping[str, tuple[Mapping[str, float], Numerator]] | None = None,
    *,
    variants: tuple[LoopVariant, ...] = NOTEBOOK_VARIANTS,
    n_gains: int = 3000,
) -> tuple[RootLocusSummary, ...]:
    """Summaries for every variant on every model.

    ``models`` maps a label to (parameters, numerator); default :func:`default_models`.
    """
    if models is None:
        models = default_models()
    out = []
    for label, (p, numerator) in models.items():
        for v in variants:
            out.append(summarize(mass_damping_loop(p, numerator=numerator, variant=v, model=label), n_gains=n_gains))
    return tuple(out)


def default_models() -> dict[str, tuple[Mapping[str, float], Numerator]]:
    """The models of the study (labels used in tables and file names).

    Chapter 2's loci were drawn on the manual fit eq 1.3: its text quotes the
    actuator zeros -3.77 +- 62.7j and the unity-feedback poles -2.21 +- 50.7j,
    which are eq 1.3's (eq 1.4 gives -4.72 +- 61.34j and -2.99 +- 51.56j).
    Chapter 3's s^2 model is not printed: :func:`s2_params_matching_s4` of
    eq 1.3 stands in for it. eq 1.4 (the optimised 2-mode fit used in chapter 8)
    and eq 9.4 (3 modes, chapter 10) check that the verdicts do not hinge on
    the fit.
    """
    return {
        "eq1.3_s4": (nb.EQ1_3_MANUAL, "s4"),
        "eq1.3_s2equiv": (s2_params_matching_s4(nb.EQ1_3_MANUAL), "s2"),
        "eq1.4_s4": (nb.EQ1_4_OPTIMIZED, "s4"),
        "eq9.4_s4": (nb.EQ9_4, "s4"),
    }


def _fmt_interval(a: float, b: float) -> str:
    def f(x: float) -> str:
        return "inf" if x == np.inf else "-inf" if x == -np.inf else f"{x:.4g}"

    return f"({f(a)}, {f(b)})"


def summary_table(summaries: tuple[RootLocusSummary, ...] | list[RootLocusSummary]) -> str:
    """A markdown table of the study: one row per model and variant."""
    lines = [
        "Mass-damping acceleration feedback, theta = G_cl (theta_ref + K_a F y) (notebook's K_a = -ours).",
        "Per base mode: open-loop damping -> best damping over stable K_a > 0 / K_a < 0 (often at the edge of stability),",
        "and the better of the two / open loop. 'excluded': modes fixed by pole-zero cancellation (the base's mode-2 poles equal",
        "the actuator zeros, eq 1.2/9.2): their poles do not move with K_a, so they are left out of the verdict.",
        "'best K_a (6 dB)' maximises the least damping of the moving base modes, keeping every other pole at least as damped",
        "as the least-damped pole without feedback and a 6 dB gain margin; ratio = that least damping / without feedback,",
        f"without (with) the margin. Verdict: the notebook's 'no K_a beats K_a = 0' holds unless the ratio without margin is >= {SIGNIFICANT_GAIN}.",
        "",
        "| model | variant | stable K_a | base modes: zeta open -> best K_a>0 / best K_a<0 (best/open) | excluded | best K_a (6 dB) | base zetas there | ratio (6 dB) | finding |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for s in summaries:
        modes = "; ".join(
            f"{m.mode}: {m.open_loop_zeta:.4f} fixed"
            if m.fixed
            else f"{m.mode}: {m.open_loop_zeta:.4f} -> {m.best_zeta_pos:.4f} / {m.best_zeta_neg:.4f} ({m.ratio:.2f}x)"
            for m in s.modes
        )
        excluded = ", ".join(str(k) for k in s.excluded_modes) + " (cancelled)" if s.excluded_modes else "none"
        rob = max((s.robust_positive, s.robust_negative), key=lambda r: -np.inf if not np.isfinite(r.min_moving_zeta) else r.min_moving_zeta)
        k = "0 (none helps)" if rob.best_gain == 0 else f"{rob.best_gain:.4g}"
        zs = ", ".join(f"{z:.4f}" for z in rob.mode_zetas)
        verdict = "holds" if not s.beats_no_feedback else "does not hold"
        lines.append(
            f"| {s.model} | {s.variant.name} | {', '.join(_fmt_interval(a, b) for a, b in s.stable_intervals)} | {modes} | {excluded} | {k} | {zs} | "
            f"{s.best_ratio:.2f} ({s.robust_ratio:.2f}) | {verdict} |"
        )
    return "\n".join(lines) + "\n"
