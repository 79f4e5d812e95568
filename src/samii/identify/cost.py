"""The notebook's curve-fitting cost, as a residual vector with its Jacobian.

Chapter 9 (``samiierr.m``) defines, over the swept-sine points::

    ev1 = 20 log10|act_data| - 20 log10|act_model|      (dB)
    ev2 = 20 log10|base_data| - 20 log10|base_model|    (dB)
    phe1 = act_phase_data - act_phase_model              (deg)
    phe2 = base_phase_data - base_phase_model            (deg)
    evt = [ev1; ev2; phaseweight*phe1; phaseweight*phe2];  errout = sum(evt.^2)

so the phase weight multiplies the phase error *before* squaring (the prose
says "phase weight times the squared phase error"; the code is what ran).
Chapter 1 (eq 1.4) is the same with phase weight 0 over 1-12 Hz.

The residual here is ``log(H_model / H_data)``: its real part times
20/ln 10 is the dB error, its imaginary part times 180/pi the phase error,
taken as the principal value of the phase *difference*. That equals the
notebook's difference of unwrapped phases wherever the two curves are within
180 deg of each other (every point of any sensible fit) and, unlike it, does
not depend on where each curve's unwrapping started.

Optional, and not the notebook's: ``weighting="coherence"`` multiplies each
point's residuals by sqrt(g/(1-g)) (g = coherence, clipped to [0.01, 0.999]),
normalised to unit mean square. That is the inverse of the random error of an
H1 estimate (Bendat & Piersol, *Random Data*, 4th ed., table 9.6:
eps = sqrt(1-g)/sqrt(2 n_avg g) for the gain; the same in rad for the phase)
up to a constant, so points measured badly count less.

The g in the weights is the coherence **pooled over neighbouring frequencies**
(``pooled_coherence``: its mean over +-``POOL_HALFWIDTH`` in log frequency, five
points of a 100-per-decade grid), not each point's own estimate. A rig's few
averages (3 records) make a point's coherence estimate scatter widely where the
response is near its noise (0.18, 0.89, 0.99, 0.80 on four neighbouring points
of a notch), and that estimate comes from the same records as the point's
response: a point whose records happened to agree gets both a high coherence and
a response off the truth, and with weight sqrt(g/(1-g)) one such point (g 0.99,
weight 10 against 2 for its neighbours' 0.8) decided an actuator zero 5 % (3.3
standard errors) from the truth. Weights taken from the data they weigh bias a
weighted least-squares fit, and sample-variance weights from M records need
M >= 4 for the estimate to have a finite variance (Schoukens, Pintelon,
Vandersteen & Guillaume, Automatica 33(6), 1997); pooling k points is frequency
smoothing (Bendat & Piersol section 11.5: k n degrees of freedom, 15 for five
3-record points) and dilutes a point's own estimate to 1/k of its weight.
Coherence changes over a resonance's or notch's width, so the window is narrow;
on a coarser grid (fewer than one neighbour within it) a point keeps its own.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal, get_args

import numpy as np

from samii.frequency_response import Channel, FrequencyResponse
from samii.identify.structures import ModelStructure

__all__ = [
    "DB_PER_NEPER",
    "DEG_PER_RAD",
    "FREQ_RANGE_HZ",
    "MIN_FREQUENCIES",
    "Weighting",
    "FitProblem",
    "frequency_out_of_range",
    "notebook_cost",
    "pooled_coherence",
    "thinning_step",
]

#: 20 log10|H| = DB_PER_NEPER * ln|H|.
DB_PER_NEPER = 20.0 / np.log(10.0)
DEG_PER_RAD = 180.0 / np.pi
#: Coherence is clipped to this range before forming weights or noise profiles:
#: 0.999 because a 3-average estimate cannot resolve coherence closer to 1
#: (and noise-free data have exactly 1); 0.01 to keep weights finite.
COHERENCE_CLIP = (0.01, 0.999)
#: Half-width, in natural log of frequency, of the window over which coherence is pooled before it
#: weighs a point (``pooled_coherence``): +-5 %, two neighbours either side on a 100-per-decade grid
#: (``samii measure``'s). That is the half-power band of a mode damped 0.05 and wider than a lighter
#: one's (eq 9.4: 0.030, 0.034): across a resonance the coherence is high throughout and pooling
#: changes little; at a notch it lends the dip's low coherence to its neighbours, which then weigh less.
POOL_HALFWIDTH = 0.05
#: Frequencies [Hz] a fit accepts: 1e-6 Hz (one cycle in 11.6 days, longer than any
#: record) to 1e6 Hz (far above the hydraulics, the beam and the sensors). The
#: model's own frequencies are bounded to 1e-3...1e6 rad/s (``fit.BOUNDS``); far
#: outside, its s^4 numerator underflows to 0 (below about 1e-77 Hz) and the
#: cost and its Jacobian are no longer numbers.
FREQ_RANGE_HZ = (1e-6, 1e6)
#: Fewest frequency points a fit (or a calibration) takes: a resonance is located only by a point either side of
#: its peak. One point gave a calibration that ran and then failed writing its curves (issue 36).
MIN_FREQUENCIES = 3

Weighting = Literal["none", "coherence"]


def thinning_step(n_points: int, max_points: int) -> int:
    """The smallest k such that every k-th of ``n_points`` points are at most ``max_points``."""
    return max(1, -(-int(n_points) // int(max_points)))


def pooled_coherence(freq_hz: np.ndarray, coherence: np.ndarray, halfwidth: float = POOL_HALFWIDTH) -> np.ndarray:
    """Mean coherence over the points within ``halfwidth`` of each point in ln(frequency) (itself included).

    ``freq_hz`` positive and strictly increasing, ``coherence`` finite, of the same length (else
    ValueError). A point with no neighbour in its window keeps its own value; noise-free data
    (coherence 1) stay 1; a point near an end of the data (or of a fit's band, which is applied
    first) pools over one side. See the module docstring for why the weights use it.
    """
    f = np.asarray(freq_hz, float)
    g = np.asarray(coherence, float)
    if f.ndim != 1 or g.shape != f.shape:
        raise ValueError(f"pooled_coherence: {g.size} coherence values for {f.size} frequencies")
    if not (np.all(np.isfinite(f)) and np.all(f > 0) and np.all(np.diff(f) > 0)):
        raise ValueError("pooled_coherence: frequencies must be positive, finite and strictly increasing")
    if not np.all(np.isfinite(g)):
        raise ValueError(f"pooled_coherence: coherence is not finite at {f[~np.isfinite(g)][0]:g} Hz")
    lf = np.log(f)
    lo = np.searchsorted(lf, lf - halfwidth, side="left")
    hi = np.searchsorted(lf, lf + halfwidth, side="right")
    csum = np.concatenate([[0.0], np.cumsum(g)])
    return (csum[hi] - csum[lo]) / (hi - lo)


def frequency_out_of_range(freq_hz: np.ndarray) -> tuple[int, str] | None:
    """(index, reason) of the first frequency outside ``FREQ_RANGE_HZ``, or None if all are inside."""
    f = np.asarray(freq_hz, float)
    lo, hi = FREQ_RANGE_HZ
    bad = np.flatnonzero(~((f >= lo) & (f <= hi)))
    if bad.size == 0:
        return None
    k = int(bad[0])
    return k, (
        f"frequency {float(f[k]):g} Hz is outside {lo:g}...{hi:g} Hz, the range a fit of this model accepts "
        f"({lo:g} Hz is one cycle in {1 / lo / 86400:.3g} days; the model's frequencies are bounded to "
        "1e-3...1e6 rad/s and its s^4 terms underflow far below)"
    )


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class FitProblem:
    """The data, the structure and the cost settings of one fit.

    Parameters
    ----------
    data : FrequencyResponse
        Measured or synthetic responses.
    structure : ModelStructure
    phase_weight : float
        Multiplies the phase error in degrees before squaring (chapter 9).
    band_hz : (lo, hi), optional
        Fit only the points with lo <= f <= hi (eq 1.4 used 1-12 Hz). Default: all.
    channels : tuple of channels, optional
        Channels in the cost. Default: ``act`` and ``base`` where present (the
        notebook's choice), with ``total`` in place of a missing ``base``.
        Parameters no fitted channel depends on are not fitted (``fitted``).
    weighting : {"none", "coherence"}
        ``"none"`` is the notebook's cost; ``"coherence"`` is described in the module docstring.
    coherence_from : {"data", "scatter"}
        Where ``data``'s coherence comes from: the file, or the data's scatter read as one estimate's coherence
        (``samii.identify.fit``'s second reading of data without coherence): its findings say so.
    """

    data: FrequencyResponse
    structure: ModelStructure
    phase_weight: float = 0.1
    band_hz: tuple[float, float] | None = None
    channels: tuple[Channel, ...] | None = None
    weighting: Weighting = "none"
    coherence_from: Literal["data", "scatter"] = "data"
    # derived
    w: np.ndarray = field(init=False, repr=False)
    _inv_data: Mapping[Channel, np.ndarray] = field(init=False, repr=False)
    _weights: Mapping[Channel, np.ndarray] = field(init=False, repr=False)
    _noise: Mapping[Channel, np.ndarray] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not np.isfinite(self.phase_weight) or self.phase_weight < 0:
            raise ValueError(f"phase_weight must be finite and >= 0, got {float(self.phase_weight):g}")
        if self.weighting not in get_args(Weighting):
            raise ValueError(f"weighting must be one of {get_args(Weighting)}, got {self.weighting!r}")
        data = self.data
        if self.band_hz is not None:
            lo, hi = (float(v) for v in self.band_hz)
            if not 0 < lo < hi:
                raise ValueError(f"band_hz must be 0 < lo < hi, got {lo:g} {hi:g}")
            if not np.any((data.freq_hz >= lo) & (data.freq_hz <= hi)):
                raise ValueError(f"no frequency point in the band {lo:g}-{hi:g} Hz (the data span {data.freq_hz[0]:g}-{data.freq_hz[-1]:g} Hz)")
            data = data.band(lo, hi)
            object.__setattr__(self, "band_hz", (lo, hi))
        if data.freq_hz.size < MIN_FREQUENCIES:
            where = f" in the band {self.band_hz[0]:g}-{self.band_hz[1]:g} Hz" if self.band_hz is not None else ""
            raise ValueError(
                f"{data.freq_hz.size} frequency point(s){where}: a fit to a frequency response needs at least "
                f"{MIN_FREQUENCIES} (a resonance is located by a point either side of its peak); measure more "
                "frequencies or widen the band"
            )
        out_of_range = frequency_out_of_range(data.freq_hz)
        if out_of_range is not None:
            raise ValueError(f"point {out_of_range[0] + 1} of the data: {out_of_range[1]}")
        object.__setattr__(self, "data", data)
        channels = self.channels
        if channels is None:
            channels = tuple(c for c in ("act", "base") if c in data.channels)
            if "base" not in channels and "total" in data.channels:
                channels += ("total",)  # xdd/v stands in for a missing xdd/theta
        missing = [c for c in channels if c not in data.channels]
        if missing:
            raise ValueError(f"channel(s) {', '.join(map(str, missing))} not in the data (it has {', '.join(data.channels)})")
        object.__setattr__(self, "channels", tuple(channels))
        n_min = int(self.fitted.sum())
        if self.n_residuals < n_min:
            raise ValueError(f"{self.n_residuals} residuals for {n_min} parameters: widen the band or add channels/phase")
        object.__setattr__(self, "w", data.w)
        inv, weights, noise = {}, {}, {}
        for c in channels:
            h = data.response(c)
            if np.any(h == 0):
                raise ValueError(
                    f"channel {c} has a zero response at {float(data.freq_hz[np.flatnonzero(h == 0)[0]]):g} Hz; its dB error is undefined"
                )
            inv[c] = 1.0 / h  # stored as the reciprocal: log(H_model / H_data) is one complex log
            coh = data.coherence(c)
            # noise profile: variance of log H at each point, up to one common factor, from the pooled coherence
            g = np.ones_like(data.freq_hz) if coh is None else np.clip(pooled_coherence(data.freq_hz, coh), *COHERENCE_CLIP)
            noise[c] = (1.0 - g) / g if coh is not None else g
            weights[c] = np.ones_like(g)
        if self.weighting == "coherence":
            if any(data.coherence(c) is None for c in channels):
                raise ValueError("weighting='coherence' needs coherence for every fitted channel (columns *_coh)")
            for c in channels:
                weights[c] = 1.0 / np.sqrt(noise[c])
            rms = np.sqrt(np.mean(np.concatenate([v**2 for v in weights.values()])))
            weights = {c: v / rms for c, v in weights.items()}
        object.__setattr__(self, "_inv_data", inv)
        object.__setattr__(self, "_weights", weights)
        object.__setattr__(self, "_noise", noise)

    # -- size ------------------------------------------------------------------------
    @property
    def n_points(self) -> int:
        """Frequency points in the cost (after the band)."""
        return int(self.data.freq_hz.size)

    def thinned(self, max_points: int) -> FitProblem:
        """The same problem on every k-th frequency point, k the smallest giving at most ``max_points``.

        Taking every k-th point keeps the data's spacing (log or linear), so the
        thinned cost is about the full one divided by k: its minimum lies near
        the full problem's. ``self`` if it has ``max_points`` or fewer.
        """
        k = thinning_step(self.n_points, max_points)
        if k == 1:
            return self
        d = self.data
        kw = {}
        for c in d.channels:
            kw[c] = d.response(c)[::k]
            coh = d.coherence(c)
            if coh is not None:
                kw[f"{c}_coh"] = coh[::k]
        data = FrequencyResponse(d.freq_hz[::k], metadata=d.metadata, **kw)
        out = FitProblem(
            data, self.structure, phase_weight=self.phase_weight, channels=self.channels, weighting=self.weighting, coherence_from=self.coherence_from
        )
        # the weights of the points kept, pooled over all points (the thinned grid is too sparse to pool on)
        object.__setattr__(out, "_noise", {c: v[::k] for c, v in self._noise.items()})
        object.__setattr__(out, "_weights", {c: v[::k] for c, v in self._weights.items()})
        return out

    # -- what the channels determine -------------------------------------------------
    @property
    def fitted(self) -> np.ndarray:
        """Mask (``structure.param_names`` order) of the parameters the fitted channels depend on.

        With theta/v alone the base modes and gains are not fitted; with xdd/theta
        alone K1, wp, zp and tau are not (``ModelStructure.channel_params``).
        """
        used = set(self.structure.channel_params(tuple(self.channels)))
        return np.array([n in used for n in self.structure.param_names])

    # -- layout of the residual vector ---------------------------------------------
    @property
    def with_phase(self) -> bool:
        return self.phase_weight > 0

    @property
    def blocks(self) -> tuple[tuple[Channel, str], ...]:
        """(channel, "mag"|"phase") of each block of residuals, in order (the notebook's evt)."""
        mags = tuple((c, "mag") for c in self.channels)
        return mags + (tuple((c, "phase") for c in self.channels) if self.with_phase else ())

    @property
    def n_residuals(self) -> int:
        m = self.data.freq_hz.size
        return m * len(self.channels) * (2 if self.phase_weight > 0 else 1)

    # -- evaluation ----------------------------------------------------------------
    def _log_ratio(self, h: np.ndarray, c: Channel) -> tuple[np.ndarray, np.ndarray]:
        """(ln|H_model/H_data|, arg(H_model/H_data)), the phase on the principal branch (-pi, pi].

        The same as ``np.log`` of the complex ratio, computed from its real and
        imaginary parts (about three times faster than numpy's complex log).
        """
        q = h * self._inv_data[c]
        re, im = q.real, q.imag
        return 0.5 * np.log(re * re + im * im), np.arctan2(im, re)

    def errors(self, x: np.ndarray) -> dict[Channel, tuple[np.ndarray, np.ndarray]]:
        """Unweighted model - data errors per channel: (dB, deg)."""
        out = {}
        for c, (h, _) in self.structure.log_responses(x, self.w, self.channels, derivatives=False).items():
            mag, ph = self._log_ratio(h, c)  # principal branch: the phase difference wrapped to +-180 deg
            out[c] = (DB_PER_NEPER * mag, DEG_PER_RAD * ph)
        return out

    def residuals_and_jacobian(self, x: np.ndarray, *, jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Residual vector r (model - data; cost = sum r^2) and dr/dx (analytic)."""
        resp = self.structure.log_responses(x, self.w, self.channels, derivatives=jacobian)
        m = self.w.size
        blocks = self.blocks
        r = np.empty(m * len(blocks))
        J = np.empty((m * len(blocks), len(self.structure.param_names))) if jacobian else None
        logs = {c: self._log_ratio(resp[c][0], c) for c in self.channels}
        unweighted = self.weighting == "none"
        for b, (c, kind) in enumerate(blocks):
            rows = slice(b * m, (b + 1) * m)
            if kind == "mag":
                k, e = DB_PER_NEPER, logs[c][0]
            else:
                k, e = self.phase_weight * DEG_PER_RAD, logs[c][1]
            kw = k if unweighted else k * self._weights[c]
            np.multiply(kw, e, out=r[rows])
            if jacobian:
                dL = resp[c][1]
                part = dL.real if kind == "mag" else dL.imag
                np.multiply(kw if unweighted else kw[:, None], part, out=J[rows])
        return r, J

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return self.residuals_and_jacobian(x, jacobian=False)[0]

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        return self.residuals_and_jacobian(x)[1]

    def cost(self, x: np.ndarray) -> float:
        """sum of squared residuals: the notebook's ``errout`` when weighting is "none"."""
        r = self.residuals(x)
        return float(r @ r)

    def noise_profile(self) -> np.ndarray:
        """Relative variance of every residual under circular complex noise.

        The random errors of |H| (relative) and of its phase (rad) have equal
        standard deviations (Bendat & Piersol table 9.6), so a dB residual has
        DB_PER_NEPER^2 and a weighted degree residual (pw DEG_PER_RAD)^2 times
        the same variance; along frequency it follows (1-g)/g when coherence g
        is given (g pooled over neighbours, ``pooled_coherence``), else it is
        flat. One common factor remains unknown. (``lack_of_fit`` judges each
        point by its own coherence instead, at 5 sigma, and names runs of such
        points: left as it was; a point whose coherence reads high by chance
        can only make it see a misfit sooner.)
        """
        out = []
        for c, kind in self.blocks:
            k = DB_PER_NEPER if kind == "mag" else self.phase_weight * DEG_PER_RAD
            out.append(k**2 * self._weights[c] ** 2 * self._noise[c])
        return np.concatenate(out)


def notebook_cost(
    params: Mapping[str, float],
    data: FrequencyResponse,
    structure: ModelStructure,
    *,
    phase_weight: float,
    band_hz: tuple[float, float] | None = None,
) -> float:
    """The notebook's ``errout`` for named parameters (act and base channels)."""
    problem = FitProblem(data, structure, phase_weight=phase_weight, band_hz=band_hz)
    return problem.cost(structure.vector(params))
