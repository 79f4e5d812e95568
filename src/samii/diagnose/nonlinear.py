"""Nonlinearity: evidence a linear system cannot produce, and amplitude dependence across files.

Within one time series: harmonics of the sweep
----------------------------------------------
A linear system driven by a sine answers at that frequency only. A sweep
``r = A(t) cos phi(t)`` through a static nonlinearity in the valve leaves the
loop with components at ``k phi(t)``, k = 2, 3, ..., and they are the same in
every record (the excitation repeats) while the noise is not.

Each record is cut into segments of ``SEGMENT_CYCLES`` whole cycles of the
sweep's phase ``phi`` (from the analytic signal of ``r``; only where its
envelope is above ``ENVELOPE`` of its peak: the rests and fades are left out). In each
segment the complex amplitude of every signal at ``k phi`` is its Hann-weighted
mean of ``2 y e^{-i k phi}`` over ``phi`` (not time: a whole number of cycles of
``phi`` with a Hann window in ``phi`` rejects the other harmonics, DC and the
fundamental exactly, and a sweep's slow change of amplitude to a Hann
sidelobe's level).

The distortion is referred to the valve's input: with the measured best
linear approximation ``G`` of theta/v (or ``T`` of xdd/v) at ``k f``,
``D_k = Theta_k / G(k f) - V_k`` (or ``X_k / T(k f) - V_k``), zero for a linear
plant whatever the feedback carries; the two routes are combined by inverse
variance (each route's own: its records' spread, its FRF's error referred and its
rounding, all below). ``D_k`` is tested against its record-to-record spread (pooled over
``POOL`` neighbouring segments) plus the measured FRF's own error referred the
same way: ``G`` is an estimate, and its random error is common to every record,
so referred through it the error repeats in each record like a distortion,
which the record spread cannot see. Its variance comes from ``H_DRAWS`` draws
of ``G`` within its own variance, each referred like the data. (On the
battery's stable linear rigs the term changed no verdict: 0 significant
segments in 24 files either way; it matters where the FRF is noisier than
the records, few averages or low coherence.) ``|mean D_k|^2 /
(var_records/n + var_G)`` is F(2, dof) under linearity (dof by
Welch-Satterthwaite, the FRF's share counted with the records' dof: it was
estimated from them); a segment
is significant at ``ALPHA`` / (segments x harmonics) (Bonferroni) and *material* when ``|D_k| / |V_1|`` is at least
``MATERIAL`` (1 %, -40 dB: below that no linear model's fit is affected
beyond what a rig's own small nonlinearities, the orifice law's among them,
leave everywhere). Nonlinearity is claimed from at least ``MIN_SEGMENTS``
such segments.

The kind, from the harmonics over the sweep. Even harmonics dominant: the two
directions differ (the valve's orifice under load, unequal piston areas). Odd:
for a static law fed ``a cos theta`` the output's 3rd harmonic is in phase with
``cos 3 theta`` for a dead band (``a - clip``: the centre of the wave removed)
and in antiphase for a saturation (its peaks clipped); a play (hysteresis,
backlash) flattens the peaks too, but turns the harmonic, and its share falls
as the amplitude grows where a saturation's grows. Each law's describing
function ``c3/c1`` as a function of ``level / a`` (tabulated from the law
itself) is fitted to the segments' complex ratios at their command amplitudes
``a = |V_1|`` by weighted least squares; the law that fits best names the kind
and gives the level in volts. This assumes the law acts on the command
itself; one after the valve's own dynamics (on the spool's position) turns the
harmonic by ``3 arg Gv(f) - arg Gv(3f)``, small while the valve is much faster
than ``3 f``.

Across files: amplitude dependence
----------------------------------
Two files of one rig at different excitation amplitudes measure the same
frequency response if the rig is linear. For each pair of files, the
difference of their theta/v log responses (xdd/v when theta/v is missing: the
two share v's noise and the records and would count it twice) on the common
points, normalised by the sum of their variances, is averaged over windows
and tested as chi-square against its own point-to-point scatter
(:func:`amplitude_test`) at ``ALPHA`` / pairs; amplitudes at least
``MIN_AMPLITUDE_RATIO`` apart make a difference an amplitude dependence. The
direction names the kind: the response grows with amplitude for a dead band
(or friction: small commands lose more) and shrinks for a saturation. Files
at the same amplitude that differ say the rig changed between the runs, not
that it is nonlinear (a note, not an effect). Harmonic findings of one kind in
several files are one finding (from the file with the most significant
segments; the others named in its evidence).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cache

import numpy as np
from scipy import signal, stats
from scipy.interpolate import CubicSpline
from scipy.optimize import minimize_scalar

from samii.diagnose.evidence import p_text
from samii.frequency_response import CHANNEL_NAMES
from samii.measure.floor import PRACTICAL_FACTOR, REL_FLOOR
from samii.measure.frf_variance import moving_sum

__all__ = [
    "HarmonicAnalysis",
    "AmplitudeTest",
    "NonlinearFinding",
    "NonlinearEvidence",
    "HarmonicEvidence",
    "AlsoIn",
    "LAW_WORDS",
    "amplitude_kind",
    "amplitude_text",
    "harmonic_analysis",
    "excess_over",
    "amplitude_test",
    "find_nonlinear",
    "describing_ratio",
    "describing_gain",
    "linearised",
    "distortion_var",
    "asymmetry_ratio",
    "asymmetry_fraction",
    "predicted_ratio",
    "HarmonicError",
    "harmonic_errors",
    "PARAM_UNITS",
    "ALPHA",
    "MATERIAL",
    "SEGMENT_CYCLES",
    "MIN_SEGMENTS",
    "MIN_AMPLITUDE_RATIO",
]

ALPHA = 1e-3
#: Units of a nonlinear finding's parameters (for printing).
PARAM_UNITS = {
    "asymmetry_fraction": "1",
    "ratio_chi2": "1",
    "harmonic": "1",
    "max_ratio": "1",
    "at_hz": "Hz",
    "phase_deg": "deg",
    "phase_spread_deg": "deg",
    "dead_band_v": "V",
    "saturation_v": "V",
    "hysteresis_v": "V",
    "gain_change_db": "dB",
    "amplitude_low_v": "V",
    "amplitude_high_v": "V",
}
#: Smallest distortion, relative to the fundamental of the valve command, claimed as a nonlinearity.
MATERIAL = 0.01
#: Whole cycles of the sweep per segment (>= 2: with one cycle, Hann leaks the fundamental into k = 2).
SEGMENT_CYCLES = 4
#: Significant and material segments needed to claim a nonlinearity.
MIN_SEGMENTS = 2
#: Neighbouring segments whose spreads are pooled. Over 12 clean EffectRig seeds (540 segment tests) 9 gave p < 1e-3 in
#: 0.74 % of them (the noise of ``D_k`` changes over 9 segments, ~2x in frequency); 5 gives 0.37 % and none below 1e-4.
POOL = 5
HARMONICS = (2, 3)
#: Describing-function misfit (chi2 per dof) beyond which the fit is discussed in the evidence.
MAX_DF_CHI2 = 10.0
#: Files whose amplitudes differ by less than this factor are compared as repeats, not as an amplitude test.
MIN_AMPLITUDE_RATIO = 1.25
#: Only where the sweep's envelope is at least this fraction of its level (not in its fades or rests). The level is
#: the envelope's ENVELOPE_LEVEL percentile, not its peak: the analytic signal of a record cut from back-to-back
#: sweeps of alternating sign spikes in the record's last 0.1 s (0.135 against the sweep's 0.1 on the second rig),
#: and against that peak only the last seconds of a 40 Hz sweep were tested (a 150 mV saturation missed, no segment
#: below 36 Hz). A high percentile: where there is no spike it is the peak within the sweep's ripple, and the
#: segments stay where they were.
ENVELOPE = 0.9
ENVELOPE_LEVEL = 99.0
#: A segment whose frequency changes by more than this factor is not tested (the slowest part of a sweep).
MAX_SPAN = 2.0
#: A segment's fundamental must stand this far above its spread (|mean|^2 / var of the mean) to be referred to.
MIN_FUNDAMENTAL_SNR = 100.0
#: Draws of the measured FRF's random error referred to the valve's input with the data (module docstring).
H_DRAWS = 16
#: The largest variance of a point's relative error drawn (beyond, the point is noise: log magnitude sd 0.7).
MAX_H_VAR = 1.0
#: The 2nd and 3rd harmonics of a sine of amplitude A rounded to a step q: the rounding error is
#: -(q/pi) sum_m ((-1)^m/m) sin(2 pi m A sin(phi)/q), whose harmonic k is (2q/pi) sum_m ((-1)^m/m) J_k(2 pi m A/q);
#: with |J_k(x)| <= sqrt(2/(pi x)) that is at most (2/pi^2) zeta(3/2) q sqrt(q/A) = 0.53 q sqrt(q/A) (a finely sampled sine; with
#: few samples a cycle the rounding errors decorrelate less and it is exceeded, 2.3x at 25 a cycle). Numerically, over
#: the offsets of the sine on the lattice for A = 3 ... 2000 q, the largest |c_2|, |c_3| are 0.55-0.72 of that bound
#: and their rms 0.12 q sqrt(q/A). The standard deviation the harmonic test grants the rounding: 0.25 q sqrt(q/A),
#: twice the rms, so that the largest (0.38) tests at (0.38/0.25)^2 = 2.3, far from significant, while a 10 %
#: asymmetry's 2.2 % 2nd harmonic on 18 counts of a 16-bit encoder (0.33 % granted) still is.
QUANT_HARMONIC = 0.25


@dataclass(frozen=True)
class HarmonicAnalysis:
    """One time series' harmonics of the sweep, per segment (module docstring)."""

    source: str
    freq_hz: np.ndarray  # fundamental of each segment
    command_v: np.ndarray  # |V_1|, the valve command's amplitude
    ratio: dict  # k -> complex D_k e^{-ik arg V_1} / |V_1| (the distortion in the fundamental's phase frame)
    ratio_sd: dict  # k -> standard deviation of each real part of ratio, from the spread
    log10_p: dict  # k -> log10 p of each segment under linearity (NaN where not testable)
    n_records: int
    threshold_log10_p: float
    cycle_freq_hz: np.ndarray = field(default_factory=lambda: np.zeros(0))  # every whole cycle of the sweep
    cycle_command_v: np.ndarray = field(default_factory=lambda: np.zeros(0))  # |V_1| over that cycle, mean of the records
    dof: dict = field(default_factory=dict)  # k -> the test's denominator dof per segment
    reference: str = ""  # what the ratios are in excess of (excess_over), else empty

    def significant(self, k: int) -> np.ndarray:
        p = self.log10_p[k]
        with np.errstate(invalid="ignore"):
            return np.isfinite(p) & (p <= self.threshold_log10_p) & (np.abs(self.ratio[k]) >= MATERIAL)

    @property
    def n_significant(self) -> int:
        return int(sum(self.significant(k).sum() for k in self.ratio))

    @property
    def claimed(self) -> bool:
        """At least ``MIN_SEGMENTS`` significant, material segments of one harmonic."""
        return any(self.significant(k).sum() >= MIN_SEGMENTS for k in self.ratio)


@dataclass(frozen=True)
class AmplitudeTest:
    """Two files at different (or equal) amplitudes compared on their common points."""

    sources: tuple[str, str]
    amplitudes_v: tuple[float, float]
    chi2: float
    dof: float
    log10_p: float
    gain_change_db: float  # inverse-variance weighted mean of 20 log10 |H_large / H_small| over the common points
    n_points: int
    channel: str = "act"  # the channel compared: theta/v, else xdd/v
    #: The largest change |ln(H_large/H_small)| of a window of WINDOW points (inverse-variance weighted): what an
    #: amplitude dependence must show beyond the floor of the two files (samii.measure.floor.PRACTICAL_FACTOR)
    max_change: float = float("nan")

    @property
    def significant(self) -> bool:
        return self.log10_p <= np.log10(ALPHA)


#: What each odd law's 3rd harmonic says of the wave (HarmonicEvidence's words).
LAW_WORDS = {
    "dead_band": "the centre of the wave is missing: a dead band (spool overlap; Coulomb friction that holds the joint "
    "at small commands looks alike)",
    "saturation": "the peaks are flattened: a saturation (spool travel, flow limit)",
    "hysteresis": "the output holds at each reversal: a play (hysteresis of the spool or the torque motor, backlash)",
}


@dataclass(frozen=True)
class AlsoIn:
    """Another file that shows the same kind of nonlinearity in its harmonics."""

    source: str
    n_significant: int
    level_v: float | None = None  #: its law's level, for an odd law


@dataclass(frozen=True)
class HarmonicEvidence:
    """What a nonlinear finding from the sweep's harmonics rests on, as figures (Hz, V; ratios of the harmonic to the
    fundamental, both referred to the valve command); :meth:`text` words it.

    The harmonic (2 or 3) with the most energy where it repeats in every record beyond their spread: in how many of
    the tested segments, over which band, its largest ratio (at which frequency and command amplitude), the strongest
    segment's log10 p; ``reference``: the harmonics were tested in excess of this (a model's own, measured like the
    file), None: against none (a linear system makes none).

    2nd harmonic, one constant ratio c2/c1 read as a gain asymmetry: ``mean_ratio`` over ``ratio_segments`` (None:
    fewer than 2 segments tested), ``asymmetry`` the fraction d a direction's gain is lower by with its standard error
    (None with a mean ratio: beyond any gain asymmetry's), ``ratio_chi2`` how well one constant fits (per dof).

    3rd harmonic, the odd laws' describing functions: the harmonic's phase, the ``law`` that fits best with its level
    and standard error, each law's chi2 per dof where the harmonic is significant (``law_chi2``) and over every tested
    segment (``every_chi2``, where more segments were tested than are significant), the correlation of the distortion
    with the command's amplitude (``trend``), the harmonic's phase spread over the segments, and whether a law on the
    command alone explains it (``law_fits``: its describing function can be divided out)."""

    source: str
    harmonic: int
    n_records: int
    n_significant: int
    n_tested: int
    band_hz: tuple[float, float]
    peak_ratio: float
    peak_hz: float
    peak_command_v: float
    log10_p: float
    reference: str | None = None
    mean_ratio: float | None = None
    ratio_segments: int | None = None
    asymmetry: float | None = None
    asymmetry_se: float | None = None
    ratio_chi2: float | None = None
    phase_deg: float | None = None
    law: str | None = None
    level_v: float | None = None
    level_se_v: float | None = None
    law_chi2: Mapping[str, float] = field(default_factory=dict)
    every_segments: int | None = None
    every_chi2: Mapping[str, float] = field(default_factory=dict)
    trend: float | None = None
    phase_spread_deg: float | None = None
    law_fits: bool = False
    also: tuple[AlsoIn, ...] = ()

    def text(self) -> str:
        """The finding's sentence, its file first and the other files that show it last."""
        also = "".join(
            f"; also in {a.source} ({a.n_significant} segments" + (f", level {1e3 * a.level_v:.3g} mV)" if a.level_v is not None else ")")
            for a in self.also
        )
        return f"{self.source}: {self._body()}{also}"

    def _body(self) -> str:
        k = self.harmonic
        base = (
            f"the {'2nd' if k == 2 else '3rd'} harmonic of the sweep, referred to the valve command, repeats in all "
            f"{self.n_records} records beyond their spread (p = 10^{self.log10_p:.0f} in the strongest segment) in "
            f"{self.n_significant} of {self.n_tested} segments, {self.band_hz[0]:.3g}-{self.band_hz[1]:.3g} Hz, "
            f"up to {100 * self.peak_ratio:.2g} % of the fundamental ({20 * np.log10(self.peak_ratio):.0f} dB) at {self.peak_hz:.3g} Hz "
            f"where the valve command is {1e3 * self.peak_command_v:.3g} mV; "
            + (f"that is in excess of {self.reference}, measured like the file" if self.reference else "a linear system makes none")
        )
        if k == 2:
            text = base + "; even harmonics dominate: the valve's two directions differ (its orifice law under load, unequal piston areas)"
            if self.mean_ratio is None:
                return text
            rho = self.mean_ratio
            if self.asymmetry is None:
                return text + f"; their mean ratio {100 * rho:+.2g} % is beyond any gain asymmetry's"
            delta, se, chi2 = self.asymmetry, self.asymmetry_se, self.ratio_chi2
            text += (
                f"; their mean ratio {100 * rho:+.2g} % over {self.ratio_segments} segments is a gain {100 * abs(delta):.2g} +- {100 * se:.1g} % "
                f"lower in the {'negative' if delta > 0 else 'positive'} direction (c2/c1 = 2 d / (3 pi (1 - d/2)), real and the same at "
                f"every amplitude; that constant fits with chi2 {chi2:.3g} per degree of freedom"
            )
            if chi2 > MAX_DF_CHI2:
                text += ": far from constant, so the two directions differ by more than a gain (the orifice law's share grows with the command)"
            return text + ")"
        kind, chi2 = self.law, self.law_chi2[self.law]
        rivals = ", ".join(f"{o} {self.law_chi2[o]:.3g}" for o in ODD_KINDS if o != kind)
        if self.every_segments is not None:
            rivals += f"; over all {self.every_segments} tested segments, where it is absent too: {kind} {self.every_chi2[kind]:.3g}, " + ", ".join(
                f"{o} {self.every_chi2[o]:.3g}" for o in ODD_KINDS if o != kind
            )
        text = (
            f"{base}; the 3rd harmonic ({self.phase_deg:+.0f} deg from cos 3phi) says {LAW_WORDS[kind]}: its describing function fits a "
            f"level of {1e3 * self.level_v:.3g} +- {1e3 * self.level_se_v:.2g} mV with chi2 {chi2:.3g} per degree of freedom (the other "
            f"laws: {rivals})"
        )
        if self.trend is not None:
            text += f"; the distortion {'falls' if self.trend < 0 else 'grows'} with the command's amplitude (correlation {self.trend:+.2f})"
        if not self.law_fits:
            text += (
                f"; but no law on the command alone tells it apart (phase spread {self.phase_spread_deg:.0f} deg over the segments): the "
                "nonlinearity depends on the loop's state too (the load pressure through the valve's orifice law, say), and "
                "the kind and level are indicative only"
            )
        elif chi2 > MAX_DF_CHI2:
            second = min(self.law_chi2[o] for o in ODD_KINDS if o != kind)
            where_better = (
                "over every tested segment, where the harmonic is and where it is absent" if chi2 > 0.5 * second else "where the harmonic is"
            )
            text += (
                f"; it fits far better than the others {where_better}, and its chi2 above 1 is the describing function's "
                "own approximation (a pure sine at the valve, where the loop feeds the harmonics back)"
            )
        return text


def amplitude_kind(t: AmplitudeTest) -> str:
    """The law an amplitude dependence points to: a response that grows with the amplitude is a dead band's (or
    friction's), one that shrinks a saturation's; no finite gain change names none."""
    return "amplitude_dependence" if not np.isfinite(t.gain_change_db) else "dead_band" if t.gain_change_db > 0 else "saturation"


def amplitude_text(t: AmplitudeTest) -> str:
    """An amplitude dependence across two files in words."""
    name = CHANNEL_NAMES[t.channel]
    return (
        f"{name} at {t.amplitudes_v[1]:.3g} V differs from that at {t.amplitudes_v[0]:.3g} V by chi2 "
        f"{t.chi2:.4g} on {t.dof:.0f} dof ({p_text(t.log10_p, digits=0)}; {t.n_points} points), "
        f"{t.gain_change_db:+.2f} dB on average (inverse-variance weighted) at the larger amplitude: the response "
        + (
            "grows with amplitude, as a dead band's or friction's (small commands lose more)"
            if t.gain_change_db > 0
            else "shrinks with amplitude, as a saturation's"
        )
    )


@dataclass(frozen=True)
class NonlinearEvidence:
    """A nonlinear finding's evidence as data: its harmonics (:class:`HarmonicEvidence`) and the amplitude test across
    files (:class:`AmplitudeTest`), either or both; ``text`` words them."""

    harmonics: HarmonicEvidence | None = None
    across_files: AmplitudeTest | None = None

    def text(self, kind: str) -> str:
        if self.harmonics is None:
            return amplitude_text(self.across_files)
        text = self.harmonics.text()
        if self.across_files is not None:
            agrees = amplitude_kind(self.across_files) == kind
            text += f"; across files: {amplitude_text(self.across_files)}" + ("" if agrees else f" (the harmonics say {kind})")
        return text


@dataclass(frozen=True)
class NonlinearFinding:
    """A nonlinearity claimed, with what it rests on (``data``; ``evidence`` is its sentence)."""

    kind: str  # dead_band | saturation | hysteresis | asymmetry | amplitude_dependence
    params: dict
    stderr: dict
    data: NonlinearEvidence
    harmonics: tuple = field(default=())
    amplitude: tuple = field(default=())

    @property
    def evidence(self) -> str:
        return self.data.text(self.kind)

    @property
    def law_fits(self) -> bool:
        """A law on the command (its describing function) explains the harmonics: the data can be linearised."""
        return self.data.harmonics is not None and self.data.harmonics.law_fits


# -- describing functions ---------------------------------------------------------------
#: Odd laws whose describing functions are fitted to the 3rd harmonic (the rig's laws, samii.diagnose.rig.valve_law).
ODD_KINDS = ("dead_band", "saturation", "hysteresis")
_N_THETA = 4096


def _periodic_output(kind: str, q: float) -> np.ndarray:
    """One period of ``kind`` at level ``q`` fed ``cos theta`` (steady state)."""
    x = np.cos(2 * np.pi * np.arange(_N_THETA) / _N_THETA)
    if kind == "dead_band":
        return np.sign(x) * np.maximum(np.abs(x) - q, 0.0)
    if kind == "saturation":
        return np.clip(x, -q, q)
    # a play of half-width q, in its periodic state from the top of the wave (output 1 - q)
    y = np.empty_like(x)
    out = 1.0 - q
    for i, v in enumerate(x):
        if v > out + q:
            out = v - q
        elif v < out - q:
            out = v + q
        y[i] = out
    return y


@cache
def _ratio_table(kind: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Levels q (over a unit amplitude), c3/c1 and the describing function's gain c1 at each."""
    q = np.concatenate([[0.0], np.geomspace(1e-4, 0.999, 400)])
    h = np.empty(q.size, complex)
    g = np.empty(q.size, complex)
    for i, qi in enumerate(q):
        c = np.fft.rfft(_periodic_output(kind, float(qi))) / (_N_THETA / 2)
        h[i] = c[3] / c[1] if abs(c[1]) > 1e-12 else np.nan
        g[i] = c[1]
    if not np.isfinite(h[0]):  # a saturation at level 0 is a square wave: its limit, -1/3, is the next level's
        h[0] = h[1]
    return q, h, g


def _from_table(kind: str, level_over_amplitude, column: int) -> tuple[np.ndarray, np.ndarray]:
    """``level / amplitude`` as an array, and column 1 (c3/c1) or 2 (the gain c1) of ``kind``'s table interpolated there
    (levels beyond 0.999 read at 0.999)."""
    if kind not in ODD_KINDS:
        raise ValueError(f"describing functions: kind must be one of {ODD_KINDS}, got {kind!r}")
    x = np.atleast_1d(np.asarray(level_over_amplitude, float))
    table = _ratio_table(kind)
    q, values = table[0], table[column]
    xc = np.clip(x, 0.0, 0.999)
    return x, np.interp(xc, q, values.real) + 1j * np.interp(xc, q, values.imag)


def describing_gain(kind: str, level_over_amplitude) -> np.ndarray:
    """The describing function ``N = c1 / a`` of ``kind`` at ``level / amplitude`` (complex: a play's lags).

    A saturation's is ``N(q)`` for ``q < 1`` and 1 beyond; a dead band's and a play's fall to 0 as ``q`` nears 1
    (the valve no longer moves)."""
    x, out = _from_table(kind, level_over_amplitude, 2)
    if kind == "saturation":
        return np.where(x >= 1.0, 1.0, out)
    return np.where(x >= 0.999, 0.0, out)


def describing_ratio(kind: str, level_over_amplitude) -> np.ndarray:
    """``c3 / c1`` of ``kind`` (dead_band, saturation, hysteresis) fed ``cos theta``, at ``level / amplitude``: the
    complex 3rd and 1st harmonics in the input's phase frame (real for the static laws: + for a dead band, - for a
    saturation; a play's memory turns it), tabulated from the law's FFT on 4096 points over 401 levels and
    interpolated. A saturation not reached gives 0."""
    x, out = _from_table(kind, level_over_amplitude, 1)
    if kind == "saturation":
        out = np.where(x >= 1.0, 0.0, out)
    return out if kind == "hysteresis" else out.real


#: Largest |c2/c1| a gain asymmetry gives (d -> 1 or -> -inf: one direction passes nothing, |cos|'s share 4/(3 pi)).
ASYMMETRY_MAX_RATIO = 4.0 / (3.0 * np.pi)


def asymmetry_ratio(delta):
    """``c2/c1`` of a gain 1 for positive commands and ``1 - delta`` for negative ones, fed ``cos theta``:
    ``u = (1 - delta/2) cos + (delta/2) |cos|``, and ``|cos|``'s cos 2theta term is ``4 / (3 pi)``."""
    delta = np.asarray(delta, float)
    return 2.0 * delta / (3.0 * np.pi * (1.0 - delta / 2.0))


def asymmetry_fraction(rho: float) -> float:
    """The ``delta`` whose :func:`asymmetry_ratio` is ``rho``."""
    return float(3.0 * np.pi * rho / (2.0 + 1.5 * np.pi * rho))


def predicted_ratio(finding, h: HarmonicAnalysis, k: int) -> np.ndarray | None:
    """The finding's law's ``D_k / V_1`` at each segment of ``h`` (its command amplitudes), or None when it has no
    law with a level: 3rd harmonics from an odd law's describing function, 2nd from an asymmetry's fraction."""
    if finding.kind in ODD_KINDS and f"{finding.kind}_v" in finding.params:
        if k != 3:
            return np.zeros(h.freq_hz.size, complex)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.asarray(describing_ratio(finding.kind, finding.params[f"{finding.kind}_v"] / h.command_v), complex)
    if finding.kind == "asymmetry" and "asymmetry_fraction" in finding.params:
        return np.full(h.freq_hz.size, complex(asymmetry_ratio(finding.params["asymmetry_fraction"]) if k == 2 else 0.0))
    return None


@dataclass(frozen=True)
class HarmonicError:
    """The sweep's harmonics against what a model predicts, over the tested segments of the files with a law."""

    rms_ratio: float  # rms of |D_k/V_1 - predicted| over segments and harmonics
    chi2: float  # mean squared residual over its spread, per real residual (1 at the noise)
    n_segments: int

    def to_dict(self) -> dict:
        return {"rms_ratio": self.rms_ratio, "chi2": self.chi2, "n_segments": self.n_segments}


def harmonic_errors(findings: Sequence[NonlinearFinding]) -> tuple[HarmonicError, HarmonicError] | None:
    """The harmonics' error before (a linear model: none) and after (the findings' laws), pooled over every
    file a law was found in, each segment tested for each harmonic; None when no finding has a law with a level.
    The linear model's error is the harmonic a linear model cannot make; the nonlinear effect's is what its law
    leaves of it. An odd law that does not fit (``law_fits`` False: its kind and level are indicative only) is
    not a model of the harmonics, so it has no "after": its describing function at that level predicts
    harmonics wherever the command is small, which the data need not have."""
    by_file: dict[str, tuple[HarmonicAnalysis, list]] = {}
    for f in findings:
        if f.kind in ODD_KINDS and not f.law_fits:
            continue
        for h in f.harmonics:
            if predicted_ratio(f, h, 3) is not None:
                by_file.setdefault(h.source, (h, []))[1].append(f)
    if not by_file:
        return None
    before, after, z_before, z_after = [], [], [], []
    for h, fs in by_file.values():
        for k in h.ratio:
            ok = np.isfinite(h.log10_p[k]) & np.isfinite(h.ratio[k]) & (h.ratio_sd[k] > 0)
            pred = sum(predicted_ratio(f, h, k) for f in fs)
            r, sd = h.ratio[k][ok], h.ratio_sd[k][ok]
            res = r - np.nan_to_num(pred[ok])
            before.append(np.abs(r) ** 2)
            after.append(np.abs(res) ** 2)
            z_before.append(np.abs(r) ** 2 / (2.0 * sd**2))
            z_after.append(np.abs(res) ** 2 / (2.0 * sd**2))
    n = int(sum(x.size for x in before))
    if n == 0:
        return None

    def err(sq, z):
        return HarmonicError(float(np.sqrt(np.mean(np.concatenate(sq)))), float(np.mean(np.concatenate(z))), n)

    return err(before, z_before), err(after, z_after)


def _fit_level(kind: str, a: np.ndarray, rho: np.ndarray, sd: np.ndarray) -> tuple[float, float, float]:
    """Level (V) of ``kind`` whose ``c3/c1`` at the command amplitudes ``a`` fits the complex ratios ``rho`` best
    (weighted, ``sd`` per real part); its standard error from the curvature (scaled by the misfit when above 1); chi2 per
    degree of freedom (2 per segment, less the level)."""
    hi = float(np.max(a)) * (1.0 if kind == "saturation" else 0.999)
    lo = 1e-4 * float(np.median(a))

    def cost(level: float) -> float:
        return float(np.sum(np.abs(rho - describing_ratio(kind, level / a)) ** 2 / sd**2))

    grid = np.geomspace(lo, hi, 80)
    costs = [cost(g) for g in grid]
    j = int(np.argmin(costs))
    res = minimize_scalar(cost, bounds=(grid[max(j - 1, 0)], grid[min(j + 1, grid.size - 1)]), method="bounded", options={"xatol": 1e-6 * grid[j]})
    best = float(res.x)
    step = 1e-3 * best
    curv = (cost(best + step) - 2 * cost(best) + cost(best - step)) / step**2
    chi2 = float(res.fun) / max(2 * rho.size - 1, 1)
    # scaled by the misfit when the describing function (a sine at the valve, the loop's harmonics ignored) fits worse than the noise
    se = float(np.sqrt(2.0 / curv * max(chi2, 1.0))) if curv > 0 else float("inf")
    return best, se, chi2


# -- harmonics within one file ------------------------------------------------------------
def _interp_response(freq_hz: np.ndarray, h: np.ndarray, f: np.ndarray) -> np.ndarray:
    """``h`` at ``f`` (cubic splines in log frequency of log magnitude and unwrapped phase); NaN outside the grid.

    Not piecewise linear: referred through at every FFT bin (:func:`harmonic_analysis`), the kinks of a linear
    interpolation at each grid point are a ripple in frequency with the grid's period, i.e. an echo ``1/spacing``
    later in time; at 100 points per decade and a sweep of 4-8 s per octave that echo lands where the sweep was
    at 2-3 f, where the test looks for harmonics."""

    x = np.log(np.asarray(f, float))
    out = np.full(x.shape, np.nan, complex)
    h = np.asarray(h, complex)
    good = np.isfinite(h) & (h != 0) & np.isfinite(freq_hz) & (np.asarray(freq_hz) > 0)  # a zero or NaN point has no log
    lf, h = np.log(np.asarray(freq_hz, float)[good]), h[good]
    if lf.size < 2:
        return out
    inside = (x >= lf[0]) & (x <= lf[-1])
    if not inside.any():
        return out
    mag = CubicSpline(lf, np.log(np.abs(h)))(x[inside])
    ph = CubicSpline(lf, np.unwrap(np.angle(h)))(x[inside])
    out[inside] = np.exp(mag + 1j * ph)
    return out


def _pool(x: np.ndarray, k: int = POOL) -> tuple[np.ndarray, np.ndarray]:
    """Mean of the finite values over ``k`` neighbouring segments, and how many there were."""
    ok = np.isfinite(x)
    num = moving_sum(np.where(ok, x, 0.0), k)
    den = moving_sum(ok.astype(float), k)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan), den


def _segment_amplitudes(y: dict, phi: np.ndarray, dphi: np.ndarray, edges: np.ndarray, ks=(1,) + HARMONICS) -> dict:
    """Per segment ``[edges[i], edges[i+1])`` and harmonic k: the Hann-in-phi weighted complex amplitude of each signal."""
    out = {name: np.zeros((edges.size - 1, len(ks)), complex) for name in y}
    for i in range(edges.size - 1):
        a, b = edges[i], edges[i + 1]
        p = phi[a:b]
        u = (p - p[0]) / max(p[-1] - p[0], 1e-12)
        w = (1.0 - np.cos(2 * np.pi * u)) * dphi[a:b]
        if not w.sum() > 0.0:  # a segment of one or two samples (a cycle shorter than the sampling resolves): no amplitude
            for name in y:
                out[name][i] = np.nan
            continue
        w = w / w.sum()
        basis = np.exp(-1j * np.outer(ks, p))  # (k, samples)
        for name, sig in y.items():
            out[name][i] = 2.0 * basis @ (w * sig[a:b])
    return out


def _span(dphi: np.ndarray, a: int, b: int) -> float:
    """Ratio of the highest to the lowest instantaneous frequency over a segment's first and last eighths."""
    q = max((b - a) // 8, 1)
    f1, f2 = float(np.mean(dphi[a : a + q])), float(np.mean(dphi[b - q : b]))
    return max(f1, f2) / max(min(f1, f2), 1e-12)


def harmonic_analysis(m, *, alpha: float = ALPHA) -> HarmonicAnalysis | None:
    """Harmonics of the sweep in ``m`` (a :class:`samii.measure.measured.Measured` with its time series), or None
    when it has no time series, fewer than 2 records or no theta/v to refer the distortion with."""
    ts, layout = m.timeseries, m.layout
    if ts is None or layout is None or layout.n_records < 2 or "act" not in m.frf.channels:
        return None
    fs = ts.sample_rate_hz
    n_rec = int(np.floor(layout.record_s * fs))
    starts = [int(round((layout.start_s + j * layout.record_s) * fs)) for j in range(layout.n_records)]
    starts = [s for s in starts if s + n_rec <= ts.t.size]
    if len(starts) < 2:
        return None
    i_first, i_end = starts[0], starts[-1] + n_rec
    frf = m.frf
    routes = [("theta", "act")] + ([("accel", "total")] if ts.accel is not None and "total" in frf.channels else [])
    # the distortion referred to the valve's input, in time: d = IFFT(Y / H - V) over the measured band (module docstring)
    nfft = int(2 ** np.ceil(np.log2(i_end - i_first)))
    fgrid = np.fft.rfftfreq(nfft, 1.0 / fs)
    v_cut = ts.v[i_first:i_end]
    V = np.fft.rfft(v_cut - np.mean(v_cut), nfft)
    sigs = {"v": ts.v}
    drawn: set[str] = set()  # routes whose FRF error is drawn (module docstring)
    rng = np.random.default_rng(0)  # the draws are part of the method: the same file gives the same answer
    f_pos = np.where(fgrid > 0, fgrid, 1.0)

    def referred(Y, h_grid):
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            h = np.where(fgrid > 0, _interp_response(frf.freq_hz, h_grid, f_pos), np.nan)
            D = Y / h - V
        d = np.fft.irfft(np.where(np.isfinite(D), D, 0.0), nfft)[: i_end - i_first]
        return np.concatenate([np.zeros(i_first), d, np.zeros(ts.t.size - i_end)])

    for sig, ch in routes:
        y = getattr(ts, sig)[i_first:i_end]
        Y = np.fft.rfft(y - np.mean(y), nfft)
        h_grid = frf.response(ch)
        sigs["d_" + sig] = referred(Y, h_grid)
        var = m.var.get(ch)
        if var is None:
            continue
        # the FRF's own random error is common to every record: referred through it, it is a distortion that repeats
        # identically in each record, which their spread cannot see; drawn from its variance, it is measured here
        sd = np.sqrt(np.clip(np.where(np.isfinite(var), var, MAX_H_VAR), 0.0, MAX_H_VAR) / 2.0)
        for j in range(H_DRAWS):
            eta = sd * (rng.standard_normal(sd.size) + 1j * rng.standard_normal(sd.size))
            sigs[f"d_{sig}#{j}"] = referred(Y, h_grid * np.exp(eta))
        drawn.add(sig)
    ks = (1,) + HARMONICS
    per_record, per_cycle, cycle_f = [], [], None
    phi0 = None
    edges = None
    for s0 in starts:
        r = ts.r[s0 : s0 + n_rec]
        an = signal.hilbert(r - np.mean(r))
        env = np.abs(an)
        phi = np.unwrap(np.angle(an))
        if phi0 is None:
            valid = np.flatnonzero(env > ENVELOPE * np.percentile(env, ENVELOPE_LEVEL))
            i_lo, i_hi = int(valid[0]), int(valid[-1])
            phi0 = phi
            c_lo = int(np.ceil(phi[i_lo] / (2 * np.pi))) + 1
            c_hi = int(np.floor(phi[i_hi] / (2 * np.pi))) - 1
            cycles = np.arange(c_lo, c_hi + 1, SEGMENT_CYCLES)
            if cycles.size < 3:
                return None
        phi = phi - 2 * np.pi * np.round((phi[i_lo] - phi0[i_lo]) / (2 * np.pi))
        idx = np.searchsorted(np.maximum.accumulate(phi), 2 * np.pi * cycles)
        dphi = np.gradient(phi) * fs
        if edges is None:
            edges, per_phi = idx, dphi
        per_record.append(_segment_amplitudes({k: v[s0 : s0 + n_rec] for k, v in sigs.items()}, phi, dphi, idx, ks))
        one = np.searchsorted(np.maximum.accumulate(phi), 2 * np.pi * np.arange(c_lo, c_hi + 1))
        vr = ts.v[s0 : s0 + n_rec]
        per_cycle.append(np.abs(_segment_amplitudes({"v": vr - np.mean(vr)}, phi, dphi, one, (1,))["v"][:, 0]))
        if cycle_f is None:
            cycle_f = np.array([1.0 / ((one[i + 1] - one[i]) / fs) for i in range(one.size - 1)])
    n = len(per_record)
    seg_f = np.array([(cycles[i + 1] - cycles[i]) / ((edges[i + 1] - edges[i]) / fs) for i in range(edges.size - 1)])
    amp = {name: np.stack([pr[name] for pr in per_record]) for name in sigs}  # (records, segments, k)
    v1 = amp["v"][:, :, 0]
    v1_mean = v1.mean(axis=0)
    v1_var = _pool(np.var(v1, axis=0, ddof=1))[0]
    span = np.array([_span(per_phi, edges[i], edges[i + 1]) for i in range(edges.size - 1)])
    with np.errstate(invalid="ignore", divide="ignore"):
        strong = (np.abs(v1_mean) ** 2 / (v1_var / n) >= MIN_FUNDAMENTAL_SNR) & (span <= MAX_SPAN)
    ratio, ratio_sd, logp, dofs = {}, {}, {}, {}
    top = float(frf.freq_hz[-1])
    tested = {}
    # an encoder's or converter's rounding (a column on a lattice, found with the file's floor) makes harmonics of its
    # own, the same in every record (QUANT_HARMONIC): per route, the bound of the column's harmonic referred to the
    # valve's input, as a variance
    steps = m.floor.quant_steps if getattr(m, "floor", None) is not None else {}
    quant = {}
    for sig, ch in routes:
        q = steps.get(sig)
        if q is None:
            continue
        with np.errstate(invalid="ignore", divide="ignore"):
            a_sig = np.abs(_interp_response(frf.freq_hz, frf.response(ch), seg_f)) * np.abs(v1_mean)
            bound2 = (QUANT_HARMONIC * q) ** 2 * q / np.maximum(a_sig, 0.25 * q)
            quant[sig] = {k: bound2 / np.abs(_interp_response(frf.freq_hz, frf.response(ch), np.minimum(k * seg_f, top))) ** 2 for k in HARMONICS}
    for jk, k in enumerate(HARMONICS, start=1):
        # the routes combined record by record, each weighted by the inverse of its own variance of the mean (its
        # records' pooled spread, its FRF's error referred, its rounding), then tested on the combination's own
        # variance: the routes share v's noise, so their spreads do not add as independent ones would. Weighted by the
        # records' spread alone, a route referred through a response that is noise at k f (theta/v beyond its notch)
        # took half the weight and its FRF's error drowned the other's harmonic: a 150 mV saturation's 3rd harmonic,
        # 13 % of the command at 7.7 Hz and 10 standard deviations on xdd/v alone, was 4.5 in the combination
        def masked(name):  # (records, segments): harmonic k of ``name`` where k f is within the measured band
            return np.where(k * seg_f[None, :] <= top, amp[name][:, :, jk], np.nan)  # noqa: B023 - called within this iteration

        draws = {sig: np.array([masked(f"d_{sig}#{j}") for j in range(H_DRAWS)]) for sig in drawn}  # (draws, records, segments)
        ds, ws = [], []
        for sig, _ in routes:
            d = masked("d_" + sig)
            ds.append(d)
            var_r = _pool(np.var(d, axis=0, ddof=1).real)[0] / n
            if sig in draws:
                var_r = var_r + np.nan_to_num(_pool(np.var(draws[sig].mean(axis=1), axis=0, ddof=1))[0])
            if sig in quant:
                var_r = var_r + np.nan_to_num(quant[sig][k], nan=0.0, posinf=0.0)
            with np.errstate(divide="ignore"):
                ws.append(1.0 / var_r)
        ds, ws = np.array(ds), np.array(ws)
        ok = np.isfinite(ws) & (ws > 0) & np.all(np.isfinite(ds), axis=1)
        w = np.where(ok, ws, 0.0)
        wsum = w.sum(axis=0)

        def combined(parts):  # the routes' (records, segments) amplitudes combined with the data's weights
            with np.errstate(invalid="ignore", divide="ignore"):
                c = np.sum(w[:, None, :] * np.where(ok[:, None, :], parts, 0.0), axis=0) / wsum  # noqa: B023 - called within this iteration
            return np.where(wsum > 0, c, np.nan)  # noqa: B023 - called within this iteration

        comb = combined(ds)
        # the FRF's error referred: the spread of the record mean over the draws (each route drawn on its own)
        h_var = np.zeros(comb.shape[1])
        if len(drawn) == len(routes):
            means = np.array([combined(np.array([draws[sig][j] for sig, _ in routes])).mean(axis=0) for j in range(H_DRAWS)])
            h_var = _pool(np.var(means, axis=0, ddof=1))[0]
        with np.errstate(invalid="ignore", divide="ignore"):
            d_mean = comb.mean(axis=0)
            pooled, count = _pool(np.var(comb, axis=0, ddof=1).real)
            d_var = pooled / n + np.where(np.isfinite(h_var), h_var, 0.0)
            for r_i, (sig, _) in enumerate(routes):  # the rounding's harmonics: the same in every record, not divided by n
                if sig in quant:
                    share = np.where(wsum > 0, w[r_i] / wsum, 0.0)
                    d_var = d_var + np.nan_to_num(share**2 * quant[sig][k], nan=0.0, posinf=0.0)
            frame = np.exp(-1j * k * np.angle(v1_mean))
            ratio[k] = d_mean * frame / np.abs(v1_mean)
            ratio_sd[k] = np.sqrt(d_var / 2.0) / np.abs(v1_mean)  # per real part
            stat = np.abs(d_mean) ** 2 / d_var
            # degrees of freedom of the sum of the two variance estimates (Welch-Satterthwaite). The FRF's variance
            # was itself estimated from the same records' spread: it carries no more information than they do, so
            # its share counts with the records' dof, not with the number of draws (that overstated the dof up to
            # 150 and made p-values of strong segments 10^-45 instead of 10^-21)
            a, b = pooled / n, np.where(np.isfinite(h_var), h_var, 0.0)
            dof_a = 2.0 * (n - 1) * count
            dof = (a + b) ** 2 / ((a * a + b * b) / np.maximum(dof_a, 1e-12))
        test = strong & np.isfinite(stat) & (count > 0) & np.isfinite(dof)
        p = np.full(stat.shape, np.nan)
        p[test] = stats.f.logsf(stat[test], 2, dof[test]) / np.log(10.0)
        logp[k] = p
        dofs[k] = np.where(test, dof, np.nan)
        tested[k] = int(test.sum())
    n_tests = max(sum(tested.values()), 1)
    return HarmonicAnalysis(
        m.source, seg_f, np.abs(v1_mean), ratio, ratio_sd, logp, n, float(np.log10(alpha / n_tests)), cycle_f, np.mean(per_cycle, axis=0), dofs
    )


#: Bounds of the command ratio a model's harmonics are scaled by (:func:`excess_over`): beyond them the
#: proportional law is an extrapolation.
REFERENCE_SCALE = (0.5, 2.0)


def excess_over(h: HarmonicAnalysis, ref: HarmonicAnalysis, *, label: str) -> HarmonicAnalysis:
    """``h``'s harmonics in excess of a model's own (``ref``: the model measured like the file, with
    the DAQ's noise, :func:`harmonic_analysis` on it), tested like ``h``'s: each segment's ratio less
    the model's at its frequency (complex, in the fundamental's frame; interpolated over frequency,
    none where the model's were not measured), the two spreads added, F(2, the data's dof) at the
    data's threshold. A model with a nonlinearity of its own (the simulator's orifice law: a 3rd
    harmonic of ~1.7 % near the hydraulic resonance when its command reaches ~0.28 V) makes harmonics
    a diagnosis against it must not report as missing.

    Where the model's command differs from the data's (a delay the model lacks raises the loop's
    resonance), its ratio is scaled by the commands' ratio, clipped to ``REFERENCE_SCALE``: the
    orifice's distortion is the product of two first-order quantities, spool opening and load
    pressure, so its share of the fundamental grows in proportion to the command (the simulator's
    3rd harmonic at 7 Hz: 0.055/V at 0.19 V, 0.060/V at 0.28 V). The test is one-sided: a segment
    where the model's harmonic is at least the data's is not tested (a model with more distortion
    than the data does not show a nonlinearity the data have)."""
    ratio, sd, logp = {}, {}, {}
    order = np.argsort(ref.freq_hz)
    fr = ref.freq_hz[order]
    cmd_ref = ref.command_v[order]
    for k in h.ratio:
        r_ref = ref.ratio.get(k, np.full(ref.freq_hz.size, np.nan))[order]
        s_ref = ref.ratio_sd.get(k, np.full(ref.freq_hz.size, np.nan))[order]
        ok = np.isfinite(r_ref) & np.isfinite(s_ref) & (cmd_ref > 0)
        if ok.sum() >= 2:
            inside = (h.freq_hz >= fr[ok][0]) & (h.freq_hz <= fr[ok][-1])
            lf = np.log(fr[ok])
            at = np.log(np.where(inside, h.freq_hz, fr[ok][0]))
            with np.errstate(invalid="ignore", divide="ignore"):
                scale = np.clip(h.command_v / np.exp(np.interp(at, lf, np.log(cmd_ref[ok]))), *REFERENCE_SCALE)
            scale = np.where(np.isfinite(scale), scale, 1.0)
            rr = np.where(inside, scale * (np.interp(at, lf, r_ref[ok].real) + 1j * np.interp(at, lf, r_ref[ok].imag)), 0.0)
            ss = np.where(inside, scale * np.interp(at, lf, s_ref[ok]), 0.0)
        else:
            rr, ss = np.zeros(h.freq_hz.size, complex), np.zeros(h.freq_hz.size)
        ratio[k] = h.ratio[k] - rr
        sd[k] = np.sqrt(h.ratio_sd[k] ** 2 + ss**2)
        dof = h.dof.get(k, np.full(h.freq_hz.size, np.nan))
        p = np.full(h.freq_hz.size, np.nan)
        # one-sided: where the model makes at least the data's harmonic, the data hold no nonlinearity it lacks
        test = np.isfinite(h.log10_p[k]) & np.isfinite(dof) & (sd[k] > 0) & (np.abs(h.ratio[k]) > np.abs(rr))
        stat = np.abs(ratio[k][test]) ** 2 / (2.0 * sd[k][test] ** 2)
        p[test] = stats.f.logsf(stat, 2, dof[test]) / np.log(10.0)
        logp[k] = p
    return replace(h, ratio=ratio, ratio_sd=sd, log10_p=logp, reference=label)


#: Where the describing function passes less than this share of the command, its approximation (one sine at the valve;
#: the loop feeds the harmonics back) is poor and the point is left out of the linear fit. On the battery's dead band of
#: 20 mV, 0.1 left theta/v's chi2 at 38 after and a spurious pole/zero at 0.2-0.4 Hz; 0.5 leaves 9 and none there.
MIN_GAIN = 0.5


def linearised(m, finding: NonlinearFinding, h: HarmonicAnalysis | None = None):
    """``m`` with theta/v and xdd/v divided by the finding's describing function at the command amplitude of each
    frequency (the measured ``|V_1|`` of the sweep's cycles, interpolated in log frequency, held beyond them): the
    best linear approximation of a law on the command is the linear plant times ``N(a)``, so what is left is the
    plant, for the linear effects to be tested on. Points where ``|N|`` < ``MIN_GAIN`` are left out (variance 1):
    there the describing function says little of the loop (a play at a command a few times its width). The
    diagnosis leaves them out of the error before too, so that both are on the same points.
    ``h``: the analysis of ``m`` (its command amplitudes; default the finding's first)."""
    h = finding.harmonics[0] if h is None else h
    level = finding.params[f"{finding.kind}_v"]
    f_c, a_c = h.cycle_freq_hz, h.cycle_command_v
    ok = np.isfinite(f_c) & np.isfinite(a_c) & (a_c > 0)
    order = np.argsort(f_c[ok])
    f_c, a_c = f_c[ok][order], a_c[ok][order]
    f = m.frf.freq_hz
    a = np.exp(np.interp(np.log(f), np.log(f_c), np.log(a_c)))
    n = describing_gain(finding.kind, level / a)
    lost = np.abs(n) < MIN_GAIN
    n = np.where(lost, 1.0, n)
    frf = replace(m.frf, **{ch: m.frf.response(ch) / n for ch in ("act", "total") if ch in m.frf.channels})
    # where the law passes less than MIN_GAIN the describing function says little of the loop: those points are
    # left out (variance 1), of the fit and of the error; the error before leaves them out too (diagnosis)
    var = {ch: (None if v is None else np.where(lost, 1.0, v) if ch in ("act", "total") else v) for ch, v in m.var.items()}
    # the describing function keeps the law's fundamental only; the harmonics it neglects come back round the
    # loop into the fundamental at their own size relative to it: the law's |c3/c1| at each point, as a variance
    # (beside the distortion measured, distortion_var, whichever is larger)
    rho2 = np.where(lost, 0.0, np.abs(describing_ratio(finding.kind, level / a)) ** 2)
    gain = np.abs(n)
    how = (
        f"{m.noise_source}; theta/v and xdd/v divided by the {finding.kind.replace('_', ' ')}'s describing function at "
        f"{1e3 * level:.3g} mV (gain {gain.min():.2f}-{gain.max():.2f}; {int(lost.sum())} point(s) where it passes less than "
        f"{MIN_GAIN:g} of the command left out, of the error before too)"
    )
    return replace(m, frf=frf, var=var, noise_source=how, model_var=_model_var_with(m, rho2))


def distortion_var(m, h: HarmonicAnalysis):
    """``m`` with the fit's extra variance (Measured.model_var) on theta/v and xdd/v where its harmonic analysis
    ``h`` found distortion: at each point the sum over harmonics of ``|D_k/V_1|^2`` of the nearest segment (in
    log frequency) whose harmonic is significant and material, else 0. A linear model of nonlinear data fits
    their best linear approximation, and that is uncertain by the distortion it leaves out (in the spirit of
    the "nonlinear variance" of Pintelon and Schoukens' best linear approximation; a heuristic: a sweep's
    distortion is deterministic, and its k-th harmonic lands at k f, not at f, so the size of the distortion
    at f stands for the misfit the linear model may have there): near a lightly damped resonance, where
    the command is largest, a saturation's few per cent on a response measured to 0.1 % otherwise draws
    linear "effects" that make the rest of the band worse (held-out battery rig: theta/v chi2 1.15 -> 2.4)."""
    f = m.frf.freq_hz
    ok = np.isfinite(h.freq_hz) & (h.freq_hz > 0)
    if not ok.any():
        return m
    seg = np.log(h.freq_hz[ok])
    nearest = np.argmin(np.abs(np.log(f)[:, None] - seg[None, :]), axis=1)
    rho2 = np.zeros(f.size)
    for k in h.ratio:
        sig = h.significant(k)[ok]
        r2 = np.where(sig, np.abs(np.nan_to_num(h.ratio[k][ok])) ** 2, 0.0)
        rho2 += r2[nearest]
    return replace(m, model_var=_model_var_with(m, rho2)) if rho2.any() else m


def _model_var_with(m, rho2: np.ndarray) -> dict:
    """``m``'s model variance on theta/v and xdd/v with ``rho2`` beside it, the larger of the two at each point."""
    have = m.model_var or {}
    return {ch: np.maximum(rho2, have[ch]) if ch in have else rho2 for ch in ("act", "total") if ch in m.frf.channels}


# -- amplitude dependence across files -------------------------------------------------------
#: Neighbouring points averaged in the amplitude test's windows.
WINDOW = 9


def amplitude_test(a, b) -> AmplitudeTest | None:
    """theta/v (else xdd/v) of two files compared on the points both measure with a known noise (module docstring);
    None when they share fewer than two windows of such points.

    The normalised difference ``eps = ln(H_hi/H_lo) / sqrt(var_lo + var_hi)`` is averaged over windows of ``WINDOW``
    points (an amplitude dependence is smooth in frequency; the noise is not) and the window means are tested as
    chi-square with 2 dof per window, on the scale of ``eps`` measured from its own roughness
    (``|eps[k+2] - eps[k]|^2 / 2``, which a smooth difference hardly touches). So a noise estimate that is off by
    a factor (a 3-record spread's inverse runs ~20 % high) moves the test by that factor on few degrees of
    freedom, not on hundreds, where it alone made clean files "differ"."""
    (lo, hi) = (a, b) if (a.amplitude_v or 0.0) <= (b.amplitude_v or 0.0) else (b, a)
    shared = [
        c for c in ("act", "total") if c in lo.frf.channels and c in hi.frf.channels and lo.var.get(c) is not None and hi.var.get(c) is not None
    ]
    if not shared:
        return None
    ch = shared[0]  # one channel: theta/v and xdd/v share v's and the records' noise, and would count it twice
    v1, v2 = lo.var[ch], hi.var[ch]
    f = lo.frf.freq_hz
    h2 = _interp_response(hi.frf.freq_hz, hi.frf.response(ch), f)
    v2i = np.interp(f, hi.frf.freq_hz, v2, left=np.nan, right=np.nan)
    ok = np.isfinite(h2) & np.isfinite(v2i) & (v1 <= 0.25) & (v2i <= 0.25)
    n_win = int(ok.sum()) // WINDOW
    if n_win < 2:
        return None
    e = np.log(h2[ok] / lo.frf.response(ch)[ok])
    var = v1[ok] + v2i[ok]
    eps = e / np.sqrt(var)
    scale = float(np.mean(np.abs(eps[2:] - eps[:-2]) ** 2) / 2.0)
    corr = max(lo.corr_length, hi.corr_length, 1.0)
    means = eps[: n_win * WINDOW].reshape(n_win, WINDOW).mean(axis=1)
    # each window mean's variance: scale * corr / WINDOW (neighbours share error over ~corr points)
    stat = float(2.0 * np.sum(np.abs(means) ** 2) * WINDOW / (scale * corr))  # ~ chi2(2 n_win)
    dof = 2.0 * n_win
    w = 1.0 / var
    gain = float(20.0 / np.log(10.0) * np.sum(e.real * w) / np.sum(w))  # inverse-variance weighted
    ew, ww = e[: n_win * WINDOW].reshape(n_win, WINDOW), w[: n_win * WINDOW].reshape(n_win, WINDOW)
    change = float(np.max(np.abs(np.sum(ew * ww, axis=1) / np.sum(ww, axis=1))))
    return AmplitudeTest(
        (lo.source, hi.source),
        (lo.amplitude_v or float("nan"), hi.amplitude_v or float("nan")),
        stat,
        dof,
        _log10_sf(stat, dof),
        gain,
        int(ok.sum()),
        ch,
        change,
    )


def _log10_sf(stat: float, dof: float) -> float:
    """log10 of chi2(dof)'s survival at ``stat``, never -inf (below 1e-300: the Wilson-Hilferty normal tail, floored at -1e4)."""
    lp = float(stats.chi2.logsf(stat, dof)) / np.log(10.0)
    if np.isfinite(lp):
        return lp
    z = ((stat / dof) ** (1.0 / 3.0) - (1.0 - 2.0 / (9.0 * dof))) / np.sqrt(2.0 / (9.0 * dof))
    return max(float(stats.norm.logsf(z)) / np.log(10.0), -1e4)


# -- the finding -------------------------------------------------------------------------------
def _harmonic_kind(h: HarmonicAnalysis) -> tuple[str, dict, dict, HarmonicEvidence]:
    """The kind the harmonics of ``h`` point to, its parameters and standard errors, and what it rests on."""
    sig2, sig3 = h.significant(2), h.significant(3)
    e2 = float(np.sum(np.abs(h.ratio[2][sig2]) ** 2))
    e3 = float(np.sum(np.abs(h.ratio[3][sig3]) ** 2))
    worst_k = max((k for k in (3, 2) if (sig3 if k == 3 else sig2).sum() >= MIN_SEGMENTS), key=lambda k: e3 if k == 3 else e2)
    sel = sig3 if worst_k == 3 else sig2
    r = h.ratio[worst_k][sel]
    f = h.freq_hz[sel]
    a = h.command_v[sel]
    peak = int(np.argmax(np.abs(r)))
    seen = HarmonicEvidence(
        source=h.source, harmonic=worst_k, n_records=h.n_records, n_significant=int(sel.sum()),
        n_tested=int(np.isfinite(h.log10_p[worst_k]).sum()), band_hz=(float(f.min()), float(f.max())), peak_ratio=float(abs(r[peak])),
        peak_hz=float(f[peak]), peak_command_v=float(a[peak]), log10_p=float(np.nanmin(h.log10_p[worst_k][sel])), reference=h.reference or None,
    )  # fmt: skip
    params = {"harmonic": float(worst_k), "max_ratio": float(abs(r[peak])), "at_hz": float(f[peak])}
    stderr = {"max_ratio": float(h.ratio_sd[worst_k][sel][peak])}
    if worst_k == 2:
        tested = np.isfinite(h.log10_p[2]) & np.isfinite(h.ratio[2]) & (h.ratio_sd[2] > 0)
        if tested.sum() < 2:
            return "asymmetry", params, stderr, seen
        w = 1.0 / h.ratio_sd[2][tested] ** 2
        r2 = h.ratio[2][tested]
        rho = float(np.sum(w * r2.real) / np.sum(w))
        seen = replace(seen, mean_ratio=rho, ratio_segments=int(tested.sum()))
        # a gain that differs between the directions is scale-free: its c2/c1 is real and one number at every amplitude
        chi2 = float(np.sum(w * ((r2.real - rho) ** 2 + r2.imag**2)) / max(2 * r2.size - 1, 1))
        if not abs(rho) < ASYMMETRY_MAX_RATIO:
            return "asymmetry", params, stderr, seen
        delta = asymmetry_fraction(rho)
        se = float(abs(delta - asymmetry_fraction(rho + np.sqrt(max(chi2, 1.0) / np.sum(w)))))
        params["asymmetry_fraction"], stderr["asymmetry_fraction"] = delta, se
        params["ratio_chi2"] = chi2  # how well one constant ratio fits: a gain asymmetry's is one number
        return "asymmetry", params, stderr, replace(seen, asymmetry=delta, asymmetry_se=se, ratio_chi2=chi2)
    phase = np.angle(np.sum(r * np.abs(r)))  # amplitude-weighted phase of c3 in the fundamental's frame
    deg = float(np.degrees(phase))
    params["phase_deg"] = deg
    # each odd law's describing function fitted to the 3rd harmonic over the sweep's command amplitudes. The law is
    # named on every tested segment, not only the significant ones: where a law predicts a harmonic the data do not
    # show, that is evidence against it (a 150 mV saturation, significant only at 190-230 mV where its 3rd harmonic is
    # flat at 10 %, fitted there a 50 mV play better; below 180 mV the play's 10 % is absent, the saturation's ~0 is
    # not). Its level is fitted where the harmonic stands clear of the noise, as before: over every segment the
    # describing function's own approximation (a sine at the valve, where the loop feeds the harmonics back) weighs
    # in, and dead bands came out 8 % (a 20 mV one, whose division then left an extra pole/zero pair) to 19 % low.
    every = np.isfinite(h.log10_p[3]) & np.isfinite(h.ratio[3]) & (h.ratio_sd[3] > 0)
    sd = h.ratio_sd[3][sel]
    fits = {k: _fit_level(k, a, r, sd) for k in ODD_KINDS}
    if every.sum() > sel.sum():
        named = {k: _fit_level(k, h.command_v[every], h.ratio[3][every], h.ratio_sd[3][every])[2] for k in ODD_KINDS}
    else:
        named = {k: fits[k][2] for k in ODD_KINDS}
    kind = min(named, key=named.get)
    level, se, chi2 = fits[kind]
    name = f"{kind}_v"
    params[name] = level
    stderr[name] = se
    # the phase's spread over the segments: a law on the command alone keeps it where its describing function says
    spread = float(np.degrees(np.sqrt(-2.0 * np.log(max(abs(np.sum(r / np.abs(r))) / r.size, 1e-12)))))
    params["phase_spread_deg"] = spread
    trend = np.corrcoef(np.log(a), np.log(np.abs(r)))[0, 1] if a.size > 2 else float("nan")
    second = min(fits[k][2] for k in ODD_KINDS if k != kind)
    # the law fits where it explains the significant segments within the describing function's approximation or far
    # better than the others there; or where, over every tested segment, it predicts the harmonic where it stands and
    # its absence where it is absent within that bound, far better than the others: a 150 mV saturation seen at
    # 180-230 mV near the hydraulic resonance (chi2 44 there against a play's 73, where the loop feeds the harmonics
    # back) fits 5.7 over all 32 segments against 61 for the play and the dead band, which predict harmonics at every
    # amplitude. Divided out, its file's errors fell on every channel (xdd/v chi2 75 -> 24, harmonics 24 -> 2.6).
    named_second = min(named[k] for k in ODD_KINDS if k != kind)
    identified = every.sum() > sel.sum() and named[kind] <= MAX_DF_CHI2 and named[kind] < 0.5 * named_second
    law_fits = spread <= 45.0 and (chi2 <= MAX_DF_CHI2 or chi2 <= 0.5 * second or identified)
    seen = replace(
        seen, phase_deg=deg, law=kind, level_v=float(level), level_se_v=float(se), law_chi2={k: float(fits[k][2]) for k in ODD_KINDS},
        every_segments=int(every.sum()) if every.sum() > sel.sum() else None,
        every_chi2={k: float(named[k]) for k in ODD_KINDS} if every.sum() > sel.sum() else {},
        trend=float(trend) if np.isfinite(trend) else None, phase_spread_deg=spread, law_fits=bool(law_fits),
    )  # fmt: skip
    return kind, params, stderr, seen


def find_nonlinear(
    measured: Sequence, *, alpha: float = ALPHA, references: Sequence | None = None, reference_label: str = "the model's own"
) -> tuple[list[NonlinearFinding], list[str], list[HarmonicAnalysis], list[AmplitudeTest]]:
    """Nonlinear findings over the files (one per kind from the harmonics, files merged; the amplitude test merged into
    the first odd-law finding, else one of its own), notes, the harmonic analyses and the amplitude tests.

    ``references``: per file, the model under test measured like it (its own harmonics, or None): the harmonics
    are then tested in excess of the model's (:func:`excess_over`), and a file whose harmonics the model makes
    itself gets a note instead of a finding."""
    findings, notes = [], []
    refs = list(references) if references is not None else [None] * len(measured)
    analyses = []
    for m, ref in zip(measured, refs, strict=True):
        h = harmonic_analysis(m, alpha=alpha)
        if h is None:
            continue
        if ref is not None:
            own = harmonic_analysis(ref, alpha=alpha)
            if own is not None:
                excess = excess_over(h, own, label=reference_label)
                if h.claimed and not excess.claimed:
                    k = max(h.ratio, key=lambda k: h.significant(k).sum())
                    sig = h.significant(k)
                    i = int(np.flatnonzero(sig)[np.argmax(np.abs(h.ratio[k][sig]))])
                    j = int(np.argmin(np.abs(own.freq_hz - h.freq_hz[i])))
                    scale = float(np.clip(h.command_v[i] / own.command_v[j], *REFERENCE_SCALE))
                    notes.append(
                        f"{m.source}: the sweep's harmonics ({'2nd' if k == 2 else '3rd'}, {int(sig.sum())} segments, up to "
                        f"{100 * abs(h.ratio[k][i]):.2g} % at {h.freq_hz[i]:.3g} Hz, command {1e3 * h.command_v[i]:.3g} mV) "
                        f"are {reference_label}: measured like the file it makes {100 * abs(own.ratio[k][j]):.2g} % there "
                        f"at a command of {1e3 * own.command_v[j]:.3g} mV ({100 * scale * abs(own.ratio[k][j]):.2g} % at the "
                        "file's, in proportion), and none beyond its own is significant"
                    )
                h = excess
        analyses.append(h)
    by_kind: dict[str, list] = {}
    for h in sorted((h for h in analyses if h.claimed), key=lambda h: -h.n_significant):
        kind, params, stderr, seen = _harmonic_kind(h)
        by_kind.setdefault(kind, []).append((h, params, stderr, seen))
    for kind, group in by_kind.items():  # one finding per kind, from the file that shows it most
        h, params, stderr, seen = group[0]
        also = tuple(AlsoIn(g[0].source, g[0].n_significant, g[1].get(kind + "_v")) for g in group[1:])
        findings.append(NonlinearFinding(kind, params, stderr, NonlinearEvidence(replace(seen, also=also)), harmonics=tuple(g[0] for g in group)))
    tests = []
    ms = list(measured)
    for i in range(len(ms)):
        for j in range(i + 1, len(ms)):
            t = amplitude_test(ms[i], ms[j])
            if t is not None:
                tests.append(t)
    n_pairs = max(len(tests), 1)
    level = np.log10(alpha / n_pairs)
    differ = [t for t in tests if t.log10_p <= level]
    # practically significant too: a window must change by more than the floor of the two files allows (a clean rig's
    # 0.05 and 0.2 V files differed at p < 1e-3 by -0.0065 dB, a "saturation")

    least = PRACTICAL_FACTOR * np.sqrt(2.0) * REL_FLOOR
    for t in [t for t in differ if not t.max_change > least]:
        differ.remove(t)
        notes.append(
            f"{t.sources[0]} and {t.sources[1]} (amplitudes {t.amplitudes_v[0]:.3g} and {t.amplitudes_v[1]:.3g} V) differ beyond "
            f"their noise (chi2 {t.chi2:.4g} on {t.dof:.0f} dof) but by at most {100 * t.max_change:.2g} % over {WINDOW} points "
            f"({t.gain_change_db:+.3g} dB on average), within {PRACTICAL_FACTOR:g} x the floor of the two files "
            f"({100 * least:.2g} %): not an amplitude dependence these data can vouch for"
        )
    for t in differ:
        a1, a2 = t.amplitudes_v
        same = not (np.isfinite(a1) and np.isfinite(a2) and a2 >= MIN_AMPLITUDE_RATIO * a1)
        if same:
            notes.append(
                f"{t.sources[0]} and {t.sources[1]} (amplitudes {a1:.3g} and {a2:.3g} V) differ beyond their noise "
                f"(chi2 {t.chi2:.4g} on {t.dof:.0f} dof): at (nearly) one amplitude this says the rig changed between "
                "the runs, not that it is nonlinear"
            )
    amp = [t for t in differ if np.isfinite(t.amplitudes_v[0]) and t.amplitudes_v[1] >= MIN_AMPLITUDE_RATIO * t.amplitudes_v[0]]
    if amp:
        t = max(amp, key=lambda t: -t.log10_p)
        kind = amplitude_kind(t)
        found = next((f for f in findings if f.kind in ("dead_band", "saturation", "hysteresis")), None)
        if found is not None:
            findings[findings.index(found)] = replace(found, data=replace(found.data, across_files=t), amplitude=tuple(amp))
        else:
            findings.append(
                NonlinearFinding(
                    kind if not findings else "amplitude_dependence",
                    {"gain_change_db": t.gain_change_db, "amplitude_low_v": t.amplitudes_v[0], "amplitude_high_v": t.amplitudes_v[1]},
                    {},
                    NonlinearEvidence(across_files=t),
                    (),
                    tuple(amp),
                )
            )
    return findings, notes, analyses, tests
