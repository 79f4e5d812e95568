"""Lack of fit: are the residuals of a fit random error, or is the model missing an effect?

A fit that converged can still be a poor description of the data. The test
here compares the residuals (model - data, dB and degrees, each channel over
the fitted band) with the random error the data themselves predict, and
reports the bands of consecutive frequencies where they are far larger. There
the model structure is wrong (a mode, a delay, a filter is missing), which no
amount of optimisation fixes.

Rule with coherence (every fitted channel has it). Bendat & Piersol, *Random
Data*, 4th ed., table 9.6: an H1 estimate from ``n`` averages with coherence
``g`` has random errors of standard deviation

    sigma_dB  = 8.686 sqrt((1 - g) / (2 n g))      (magnitude, dB)
    sigma_deg = 57.30 sqrt((1 - g) / (2 n g))      (phase, deg)

``g`` is clipped to ``COHERENCE_CLIP`` = [0.01, 0.999] first (an estimate from a
few averages cannot resolve coherence closer to 1), so sigma is at least
0.11 dB / 0.74 deg for 3 averages. ``n`` is read from the FRF metadata
``frf_records`` (written by ``samii measure``; "3 records of ...") or given;
otherwise 3 is assumed, the notebook's "3 averages" (chapter 9), and the
report says so. A point is *off* when its magnitude residual exceeds
``RATIO`` = 5 sigma_dB, or its phase residual 5 sigma_deg (phase only when the
phase is in the cost, phase weight > 0). Under the noise model a point is off
with probability 1.1e-6 (two quantities, two-sided 5 sigma), so a band of them
cannot be noise.

Rule without coherence (some fitted channel lacks it): the random error is
unknown, so only systematic residuals are flagged: a run of at least
``RUN_POINTS`` = 12 consecutive points whose magnitude residuals have the same
sign and exceed ``RUN_DB`` = 1 dB, or (phase in the cost) whose phase
residuals have the same sign and exceed ``RUN_DEG`` = 6.6 deg (the same error
of log H as 1 dB: 0.115 neper = 0.115 rad). Random errors of 1 dB standard
deviation produce such a run with probability about 0.16^12 = 3e-10 per start.

Points whose coherence is below ``MIN_COHERENCE`` = 0.5 are not tested: there the noise is as
large as the signal, the small-error formulas above no longer hold (log|H| of a ratio of noisy
spectra is heavy-tailed), and a large residual says the point is noise, not that the model lacks
an effect. How many were left out is reported (``n_untested``).

Either way, flagged points closer than ``MAX_GAP`` + 1 points, or within
``BRIDGE_REL`` = 5 % of each other in frequency, are merged into one band (a
residual that changes sign inside a band crosses zero, and a few noisy points
may fall below the threshold; on a dense grid, such as an FFT's thousands of
lines, ``MAX_GAP`` points are a sliver of the band and would cut one misfit into
dozens), and a band needs at least ``MIN_POINTS`` = 5 flagged points (with
coherence; the run length without). On the notebook's 400-point log grid over
0.1-40 Hz, 5 % is 3 points: the same bands as ``MAX_GAP`` alone.
Each band becomes a warning naming the channel and its span in Hz.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from samii.frequency_response import CHANNEL_NAMES
from samii.identify.cost import COHERENCE_CLIP, DB_PER_NEPER, DEG_PER_RAD, FitProblem

__all__ = [
    "RATIO",
    "MIN_COHERENCE",
    "BRIDGE_REL",
    "MisfitBand",
    "LackOfFit",
    "averages_from_metadata",
    "is_stepped_sine",
    "lack_of_fit",
    "noise_only",
    "refuse_noise",
    "roughness_variance",
    "ROUGHNESS_LAG",
    "ROUGHNESS_POOL",
]

RATIO = 5.0
#: Below this coherence a point is noise-dominated and is not tested.
MIN_COHERENCE = 0.5
MIN_POINTS = 5
MAX_GAP = 2
#: Flagged points at most this fraction apart in frequency are in one band, however many points lie between.
BRIDGE_REL = 0.05
RUN_POINTS = 12
RUN_DB = 1.0
RUN_DEG = 6.6
#: Averages assumed when the data do not say: chapter 9, "The swept sine data is based on 3 averages".
DEFAULT_AVERAGES = 3


@dataclass(frozen=True)
class MisfitBand:
    """A band of consecutive frequencies where the model misses the data.

    Attributes
    ----------
    channel : str
    f_lo_hz, f_hi_hz : float
        First and last frequency of the band.
    n_points : int
        Points in the band (flagged or bridged).
    max_db, max_deg : float
        Largest absolute magnitude [dB] and phase [deg] residual in the band.
    ratio : float or None
        Median over the band of |residual| / predicted random error (the larger
        of magnitude and phase at each point); None without coherence.
    """

    channel: str
    f_lo_hz: float
    f_hi_hz: float
    n_points: int
    max_db: float
    max_deg: float
    ratio: float | None

    def describe(self, n_averages: int | None) -> str:
        where = f"lack of fit in {CHANNEL_NAMES.get(self.channel, self.channel)} ({self.channel}) over {self.f_lo_hz:.3g}-{self.f_hi_hz:.3g} Hz ({self.n_points} points)"
        size = f"residuals up to {self.max_db:.3g} dB / {self.max_deg:.3g} deg"
        if self.ratio is not None:
            why = f"{self.ratio:.0f} times the random error the coherence predicts for {n_averages} averages"
        else:
            why = "of one sign throughout (no coherence in the data: random error unknown)"
        return f"{where}: {size}, {why}: structure error, the model is missing an effect there"

    def to_dict(self) -> dict:
        return {
            "channel": self.channel,
            "f_lo_hz": float(self.f_lo_hz),
            "f_hi_hz": float(self.f_hi_hz),
            "n_points": int(self.n_points),
            "max_db": float(self.max_db),
            "max_deg": float(self.max_deg),
            "ratio": None if self.ratio is None else float(self.ratio),
        }


@dataclass(frozen=True)
class LackOfFit:
    """Outcome of the lack-of-fit test (module docstring).

    Attributes
    ----------
    rule : str
        The rule applied, in words.
    n_averages : int or None
        Averages behind the coherence (None without coherence).
    n_averages_source : str
        Where ``n_averages`` came from (metadata, argument, or the stated assumption).
    bands : tuple of MisfitBand
    noise_ratio : mapping channel -> float or None
        RMS over the band of residual / predicted random error (magnitude, and
        phase when in the cost): about 1 or less when the model is right; None without coherence.
    """

    rule: str
    n_averages: int | None
    n_averages_source: str
    bands: tuple[MisfitBand, ...]
    noise_ratio: Mapping[str, float | None]
    #: channel -> points not tested because their coherence is below MIN_COHERENCE
    n_untested: Mapping[str, int] = field(default_factory=dict)
    #: channel -> points tested (coherence >= MIN_COHERENCE; every point without coherence)
    n_tested: Mapping[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "n_untested", MappingProxyType(dict(self.n_untested)))
        object.__setattr__(self, "noise_ratio", MappingProxyType(dict(self.noise_ratio)))
        object.__setattr__(self, "n_tested", MappingProxyType(dict(self.n_tested)))

    @property
    def band_points(self) -> int:
        """Flagged points a band needs under the rule applied: MIN_POINTS with coherence, RUN_POINTS without."""
        return MIN_POINTS if self.n_averages is not None else RUN_POINTS

    @property
    def too_few_points(self) -> bool:
        """Some point was tested, but no channel has as many tested points as one band needs: no band could be
        found, whatever the residuals (a file of 3 frequencies)."""
        return bool(self.n_tested) and any(self.n_tested.values()) and max(self.n_tested.values()) < self.band_points

    def summary(self) -> str:
        """The bands in one line: "act 0.3-2.6 Hz; base 1-35 Hz" ("" when none)."""
        return "; ".join(f"{b.channel} {b.f_lo_hz:.3g}-{b.f_hi_hz:.3g} Hz" for b in self.bands)

    @property
    def found(self) -> bool:
        return bool(self.bands)

    @property
    def nothing_tested(self) -> bool:
        """The data have coherence and no point of any channel reaches MIN_COHERENCE: no residual could be tested."""
        return self.n_averages is not None and bool(self.noise_ratio) and all(v is None for v in self.noise_ratio.values())

    def verdict(self) -> str:
        """ "FOUND", "none", or that nothing could be tested (never "none" for data that are all noise)."""
        if self.found:
            return "FOUND"
        if self.nothing_tested:
            return f"NOT TESTED: no point has coherence >= {MIN_COHERENCE:g} in any channel (the data are noise; nothing could be tested)"
        if self.too_few_points:
            tested = ", ".join(f"{c} {k}" for c, k in self.n_tested.items())
            return (
                f"NOT TESTED: too few points (tested: {tested}) for a band of {self.band_points}, the fewest a "
                "finding needs: a lack of fit could not show; measure more frequencies"
            )
        return "none"

    def warnings(self) -> list[str]:
        return [b.describe(self.n_averages) for b in self.bands]

    def to_dict(self) -> dict:
        return {
            "found": self.found,
            "nothing_tested": self.nothing_tested,
            "too_few_points": self.too_few_points,
            "rule": self.rule,
            "n_averages": self.n_averages,
            "n_averages_source": self.n_averages_source,
            "noise_ratio": {k: (None if v is None else float(v)) for k, v in self.noise_ratio.items()},
            "bands": [b.to_dict() for b in self.bands],
            "n_untested_low_coherence": dict(self.n_untested),
            "n_tested": dict(self.n_tested),
        }


def noise_only(data, channels=None) -> float | None:
    """The highest coherence when every channel (of ``channels``, default all the data's) has coherence and no
    point reaches MIN_COHERENCE: the data are noise and nothing can be tested or fitted to them; else None."""
    cohs = [data.coherence(c) for c in (data.channels if channels is None else channels)]
    if not cohs or any(c is None for c in cohs) or any(np.any(c >= MIN_COHERENCE) for c in cohs):
        return None
    return max(float(np.nanmax(c)) if np.any(np.isfinite(c)) else 0.0 for c in cohs)


def refuse_noise(data, channels, task: str) -> None:
    """ValueError when :func:`noise_only` says the fitted ``channels`` are noise: there is nothing to ``task`` (a fit on
    noise converges on something, and said "a sound fit with caveats")."""
    best = noise_only(data, channels)
    if best is not None:
        raise ValueError(
            f"no point has coherence >= {MIN_COHERENCE:g} in the fitted channels {', '.join(channels)} "
            f"(the highest is {best:.3g}): the data are noise (was the rig excited? are the sensors connected?) "
            f"and there is nothing to {task}; if the coherence columns hold no measurement, leave them out"
        )


#: Most averages a ``frf_records`` line may claim (as ``samii fit --averages``): a swept sine has a
#: few, a random test some hundreds; more is a damaged or mistaken header.
MAX_METADATA_AVERAGES = 10_000


def is_stepped_sine(metadata: Mapping[str, str]) -> bool:
    """The header says the excitation is a stepped sine (``# excitation: stepped sine, N frequencies``)."""
    return str(metadata.get("excitation", "")).strip().lower().startswith("stepped sine")


def averages_from_metadata(metadata: Mapping[str, str]) -> int | None:
    """Number of averages from ``frf_records`` ("3 records of 109.2 s ..." or "3"); 1 for a stepped sine (each dwell's
    coherence is its own sine fit's, |Y|^2/(|Y|^2 + 4 s^2/N): (1 - g)/g is the relative variance of the one estimate
    it has, Bendat & Piersol's random error with one average; samii.measure.stepped); else None (no such line).

    A line that is present but holds no count in 1 ... MAX_METADATA_AVERAGES is an error (ValueError), not
    a silent fallback: the count sets the random error every residual is judged against."""
    if "frf_records" not in metadata:
        return 1 if is_stepped_sine(metadata) else None
    text = str(metadata["frf_records"])
    m = re.match(r"\s*(\d+)", text)
    if not m or not 1 <= int(m.group(1)) <= MAX_METADATA_AVERAGES:
        raise ValueError(f"metadata '# frf_records: {text[:40]}': expected a number of averaged records in 1...{MAX_METADATA_AVERAGES}")
    return int(m.group(1))


def _bands(flag: np.ndarray, *, max_gap: int, min_points: int, freq: np.ndarray | None = None, bridge_rel: float = 0.0) -> list[tuple[int, int]]:
    """(first, last) index of each group of flagged points with gaps of at most ``max_gap`` points
    (or, given ``freq``, of at most ``bridge_rel`` relative frequency) holding ``min_points`` flagged points."""
    idx = np.flatnonzero(flag)
    if idx.size == 0:
        return []
    cut = np.diff(idx) - 1 > max_gap
    if freq is not None:
        cut &= freq[idx[1:]] > freq[idx[:-1]] * (1.0 + bridge_rel)
    first = np.concatenate([[0], np.flatnonzero(cut) + 1])
    last = np.concatenate([np.flatnonzero(cut), [idx.size - 1]])
    return [(int(idx[i]), int(idx[j])) for i, j in zip(first, last) if j - i + 1 >= min_points]


def _same_sign_runs(e: np.ndarray, threshold: float, min_len: int) -> np.ndarray:
    """Mask of the points in runs of at least ``min_len`` consecutive residuals beyond ``threshold`` with one sign."""
    mask = np.zeros(e.size, bool)
    for sign in (1.0, -1.0):
        for i, j in _bands(sign * e > threshold, max_gap=0, min_points=min_len):
            mask[i : j + 1] = True
    return mask


def lack_of_fit(
    problem: FitProblem, x: np.ndarray, *, n_averages: int | None = None, errors: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None
) -> LackOfFit:
    """Test the residuals of ``x`` on ``problem`` for structure error (module docstring).

    Parameters
    ----------
    problem : FitProblem
    x : array
        Parameters in ``structure.param_names`` order (the fit).
    n_averages : int, optional
        Averages behind the coherence; default from the metadata ``frf_records``, else 3 (stated).
    errors : mapping, optional
        ``problem.errors(x)`` if already computed.
    """
    data = problem.data
    f = data.freq_hz
    errs = problem.errors(x) if errors is None else errors
    with_phase = problem.with_phase
    has_coh = all(data.coherence(c) is not None for c in problem.channels)
    bands: list[MisfitBand] = []
    ratios: dict[str, float | None] = {}
    untested: dict[str, int] = {}
    n_tested: dict[str, int] = {}
    if has_coh:
        if n_averages is not None:
            n, source = int(n_averages), "given"
        else:
            n = averages_from_metadata(data.metadata)
            source = (
                "FRF metadata frf_records"
                if "frf_records" in data.metadata
                else "1, a stepped sine (each dwell's coherence is its own sine fit's)"
                if n is not None
                else f"assumed {DEFAULT_AVERAGES} (the notebook's 3 averages, chapter 9): the data do not say (no frf_records)"
            )
            n = n if n is not None else DEFAULT_AVERAGES
        if n < 1:
            raise ValueError(f"n_averages must be >= 1, got {n}")
        rule = (
            f"|residual| > {RATIO:g} x the random error coherence predicts (Bendat & Piersol table 9.6, {n} averages, "
            f"coherence clipped to {COHERENCE_CLIP}) in magnitude{' or phase' if with_phase else ''}; "
            f">= {MIN_POINTS} such points, gaps of <= {MAX_GAP} points or {100 * BRIDGE_REL:g} % in frequency bridged; points with coherence < {MIN_COHERENCE:g} (noise) not tested"
        )
        for c in problem.channels:
            raw = data.coherence(c)
            tested = raw >= MIN_COHERENCE
            untested[c] = int(np.count_nonzero(~tested))
            n_tested[c] = int(np.count_nonzero(tested))
            g = np.clip(raw, *COHERENCE_CLIP)
            eps = np.sqrt((1.0 - g) / (2.0 * n * g))
            z_db = np.abs(errs[c][0]) / (DB_PER_NEPER * eps)
            z_deg = np.abs(errs[c][1]) / (DEG_PER_RAD * eps)
            z = np.maximum(z_db, z_deg) if with_phase else z_db
            if np.any(tested):
                parts = [z_db[tested] ** 2, z_deg[tested] ** 2] if with_phase else [z_db[tested] ** 2]
                ratios[c] = float(np.sqrt(np.mean(np.concatenate(parts))))
            else:
                ratios[c] = None
            for i, j in _bands((z > RATIO) & tested, max_gap=MAX_GAP, min_points=MIN_POINTS, freq=f, bridge_rel=BRIDGE_REL):
                sl = slice(i, j + 1)
                bands.append(
                    MisfitBand(
                        c,
                        float(f[i]),
                        float(f[j]),
                        j - i + 1,
                        float(np.max(np.abs(errs[c][0][sl]))),
                        float(np.max(np.abs(errs[c][1][sl]))),
                        float(np.median(z[sl])),
                    )
                )
    else:
        n, source = None, "no coherence in the data"
        rule = f"no coherence: >= {RUN_POINTS} consecutive magnitude residuals of one sign beyond {RUN_DB:g} dB" + (
            f", or phase residuals beyond {RUN_DEG:g} deg" if with_phase else ""
        )
        for c in problem.channels:
            ratios[c] = None
            n_tested[c] = int(f.size)
            flag = _same_sign_runs(errs[c][0], RUN_DB, RUN_POINTS)
            if with_phase:
                flag |= _same_sign_runs(errs[c][1], RUN_DEG, RUN_POINTS)
            for i, j in _bands(flag, max_gap=MAX_GAP, min_points=RUN_POINTS, freq=f, bridge_rel=BRIDGE_REL):
                sl = slice(i, j + 1)
                bands.append(
                    MisfitBand(
                        c, float(f[i]), float(f[j]), j - i + 1, float(np.max(np.abs(errs[c][0][sl]))), float(np.max(np.abs(errs[c][1][sl]))), None
                    )
                )
    return LackOfFit(rule, n, source, tuple(bands), ratios, untested, n_tested)


#: Points apart whose log residuals are differenced, and points pooled, for a noise read off a residual's roughness.
ROUGHNESS_LAG, ROUGHNESS_POOL = 2, 9


def roughness_variance(e: np.ndarray, lag: int = ROUGHNESS_LAG, pool: int = ROUGHNESS_POOL) -> np.ndarray:
    """The relative variance of each point of a complex log residual ``e``, read off its roughness: ``|e[k+lag] -
    e[k]|^2 / 2`` (the variance of one of two independent errors), each difference the point midway's (the ends repeat
    the nearest), pooled by a moving mean over ``pool`` points (its window shrinking at the ends). Noise changes from
    point to point, a missed effect slowly: the roughness is the noise's whatever the model misses. For data that say
    nothing of their noise (no coherence, no records): samii.measure.measured.with_roughness_noise, and the check of
    where a fit's modes sit (samii.identify.fit)."""
    e = np.asarray(e)
    lag = min(lag, e.size - 1)
    if lag <= 0:
        return np.zeros(e.size)
    d2 = np.abs(e[lag:] - e[:-lag]) ** 2
    d2 = np.pad(d2, (lag // 2, e.size - d2.size - lag // 2), mode="edge")
    start = (pool - 1) // 2
    ones = np.ones(pool)
    return np.convolve(d2, ones)[start : start + e.size] / np.convolve(np.ones(e.size), ones)[start : start + e.size] / 2.0
