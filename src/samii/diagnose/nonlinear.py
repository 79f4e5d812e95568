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
variance. ``D_k`` is tested against its record-to-record spread (pooled over
``POOL`` neighbouring segments): ``|mean D_k|^2 / (var/n)`` is F(2, dof)
under linearity; a segment is significant at ``ALPHA`` / (segments x
harmonics) (Bonferroni) and *material* when ``|D_k| / |V_1|`` is at least
``MATERIAL`` (1 %, -40 dB: below that no linear model's fit is affected
beyond what a rig's own small nonlinearities, the orifice law's among them,
leave everywhere). Nonlinearity is claimed from at least ``MIN_SEGMENTS``
such segments.

The kind, from the phase and the trend of the 3rd harmonic. For a static odd
nonlinearity fed ``a cos theta`` the output's 3rd harmonic is in phase with
``cos 3 theta`` for a dead band (``a - clip``: the centre of the wave removed)
and in antiphase for a saturation (its peaks clipped); a nonlinearity with
memory (friction, backlash, hysteresis) moves it off both. Even harmonics
dominant: the two directions differ (the valve's orifice under load, unequal
piston areas). A dead band's or a saturation's level follows from the
describing functions: ``c3/c1`` as a function of ``d/a`` (or ``L/a``), computed
here from the static law, fitted to the segments' ``c3/c1`` and command
amplitudes ``a = |V_1|`` by weighted least squares.

Across files: amplitude dependence
----------------------------------
Two files of one rig at different excitation amplitudes measure the same
frequency response if the rig is linear. For each pair whose amplitudes differ
by at least ``MIN_AMPLITUDE_RATIO``, the difference of their theta/v (and
xdd/v) log responses on the common points, normalised by the sum of their
variances, is tested as chi-square (degrees of freedom divided by the noise's
correlation length) at ``ALPHA`` / pairs. The direction names the kind: the
response grows with amplitude for a dead band (or friction: small commands lose
more) and shrinks for a saturation. Files at the same amplitude that differ say
the rig changed between the runs, not that it is nonlinear (a note, not an
effect).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy import signal, stats
from scipy.optimize import minimize_scalar

__all__ = ["HarmonicAnalysis", "AmplitudeTest", "NonlinearFinding", "harmonic_analysis", "amplitude_test", "find_nonlinear",
           "describing_ratio", "PARAM_UNITS", "ALPHA", "MATERIAL", "SEGMENT_CYCLES", "MIN_SEGMENTS", "MIN_AMPLITUDE_RATIO"]

ALPHA = 1e-3
#: Units of a nonlinear finding's parameters (for printing).
PARAM_UNITS = {"harmonic": "1", "max_ratio": "1", "at_hz": "Hz", "phase_deg": "deg", "phase_spread_deg": "deg", "dead_band_v": "V",
               "saturation_v": "V", "gain_change_db": "dB", "amplitude_low_v": "V", "amplitude_high_v": "V"}
#: Smallest distortion, relative to the fundamental of the valve command, claimed as a nonlinearity.
MATERIAL = 0.01
#: Whole cycles of the sweep per segment (>= 2: with one cycle, Hann leaks the fundamental into k = 2).
SEGMENT_CYCLES = 4
#: Significant and material segments needed to claim a nonlinearity.
MIN_SEGMENTS = 2
#: Neighbouring segments whose spreads are pooled.
POOL = 9
HARMONICS = (2, 3)
#: Files whose amplitudes differ by less than this factor are compared as repeats, not as an amplitude test.
MIN_AMPLITUDE_RATIO = 1.25
#: Only where the sweep's envelope is at least this fraction of its peak (not in its fades or rests).
ENVELOPE = 0.9
#: A segment whose frequency changes by more than this factor is not tested (the slowest part of a sweep).
MAX_SPAN = 2.0
#: A segment's fundamental must stand this far above its spread (|mean|^2 / var of the mean) to be referred to.
MIN_FUNDAMENTAL_SNR = 100.0


@dataclass(frozen=True)
class HarmonicAnalysis:
    """One time series' harmonics of the sweep, per segment (module docstring)."""

    source: str
    freq_hz: np.ndarray  # fundamental of each segment
    command_v: np.ndarray  # |V_1|, the valve command's amplitude
    ratio: dict  # k -> complex D_k e^{-ik arg V_1} / |V_1| (the distortion in the fundamental's phase frame)
    ratio_sd: dict  # k -> standard deviation of |ratio| from the spread
    log10_p: dict  # k -> log10 p of each segment under linearity (NaN where not testable)
    n_records: int
    threshold_log10_p: float

    def significant(self, k: int) -> np.ndarray:
        p = self.log10_p[k]
        with np.errstate(invalid="ignore"):
            return np.isfinite(p) & (p <= self.threshold_log10_p) & (np.abs(self.ratio[k]) >= MATERIAL)

    @property
    def n_significant(self) -> int:
        return int(sum(self.significant(k).sum() for k in self.ratio))


@dataclass(frozen=True)
class AmplitudeTest:
    """Two files at different (or equal) amplitudes compared on their common points."""

    sources: tuple[str, str]
    amplitudes_v: tuple[float, float]
    chi2: float
    dof: float
    log10_p: float
    gain_change_db: float  # mean of 20 log10 |H_large / H_small| over the common points of theta/v
    n_points: int

    @property
    def significant(self) -> bool:
        return self.log10_p <= np.log10(ALPHA)


@dataclass(frozen=True)
class NonlinearFinding:
    """A nonlinearity claimed, with what it rests on."""

    kind: str  # dead_band | saturation | hysteresis | asymmetry | amplitude_dependence
    params: dict
    stderr: dict
    evidence: str
    harmonics: tuple = field(default=())
    amplitude: tuple = field(default=())


# -- describing functions ---------------------------------------------------------------
def _law(kind: str, x: np.ndarray, level: float) -> np.ndarray:
    if kind == "dead_band":
        return np.sign(x) * np.maximum(np.abs(x) - level, 0.0)
    return np.clip(x, -level, level)


def describing_ratio(kind: str, level_over_amplitude: np.ndarray) -> np.ndarray:
    """``c3 / c1`` of ``kind`` (dead_band, saturation) fed ``cos theta``, at ``level / amplitude`` (the harmonics'
    cosine coefficients, from the static law's FFT on 4096 points)."""
    x = np.atleast_1d(np.asarray(level_over_amplitude, float))
    th = 2 * np.pi * np.arange(4096) / 4096
    out = np.empty(x.size)
    for i, q in enumerate(x):
        y = _law(kind, np.cos(th), float(q))
        c = np.fft.rfft(y) / 2048
        out[i] = c[3].real / c[1].real if abs(c[1]) > 1e-12 else np.nan
    return out


def _fit_level(kind: str, a: np.ndarray, rho: np.ndarray, sd: np.ndarray) -> tuple[float, float, float]:
    """Level (V) of ``kind`` whose ``c3/c1`` at the command amplitudes ``a`` fits ``rho`` best (weighted); its
    standard error from the curvature (scaled by the misfit when above 1); chi2 per degree of freedom."""
    hi = 0.999 * float(np.max(a)) if kind == "dead_band" else float(np.max(a))
    lo = 1e-4 * float(np.median(a))

    def cost(level: float) -> float:
        h = describing_ratio(kind, np.clip(level / a, 0.0, 1.0 if kind == "saturation" else 0.999))
        if kind == "saturation":
            h = np.where(level >= a, 0.0, h)
        return float(np.sum(((rho - h) / sd) ** 2))

    grid = np.geomspace(lo, hi, 60)
    costs = [cost(g) for g in grid]
    j = int(np.argmin(costs))
    res = minimize_scalar(cost, bounds=(grid[max(j - 1, 0)], grid[min(j + 1, grid.size - 1)]), method="bounded",
                          options={"xatol": 1e-6 * grid[j]})
    best = float(res.x)
    step = 1e-3 * best
    curv = (cost(best + step) - 2 * cost(best) + cost(best - step)) / step**2
    chi2 = float(res.fun) / max(rho.size - 1, 1)
    # scaled by the misfit when the describing function (a sine at the valve, the loop's harmonics ignored) fits worse than the noise
    se = float(np.sqrt(2.0 / curv * max(chi2, 1.0))) if curv > 0 else float("inf")
    return best, se, chi2


# -- harmonics within one file ------------------------------------------------------------
def _interp_response(freq_hz: np.ndarray, h: np.ndarray, f: np.ndarray) -> np.ndarray:
    """``h`` at ``f`` (log-frequency interpolation of log magnitude and unwrapped phase); NaN outside the grid."""
    lf = np.log(freq_hz)
    mag = np.interp(np.log(f), lf, np.log(np.abs(h)), left=np.nan, right=np.nan)
    ph = np.interp(np.log(f), lf, np.unwrap(np.angle(h)), left=np.nan, right=np.nan)
    return np.exp(mag + 1j * ph)


def _pool(x: np.ndarray, k: int = POOL) -> np.ndarray:
    ok = np.isfinite(x)
    num = np.convolve(np.where(ok, x, 0.0), np.ones(k), mode="same")
    den = np.convolve(ok.astype(float), np.ones(k), mode="same")
    with np.errstate(invalid="ignore", divide="ignore"):
        return num / den


def _segment_amplitudes(y: dict, phi: np.ndarray, dphi: np.ndarray, edges: np.ndarray, ks=(1,) + HARMONICS) -> dict:
    """Per segment ``[edges[i], edges[i+1])`` and harmonic k: the Hann-in-phi weighted complex amplitude of each signal."""
    out = {name: np.zeros((edges.size - 1, len(ks)), complex) for name in y}
    for i in range(edges.size - 1):
        a, b = edges[i], edges[i + 1]
        p = phi[a:b]
        u = (p - p[0]) / max(p[-1] - p[0], 1e-12)
        w = (1.0 - np.cos(2 * np.pi * u)) * dphi[a:b]
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
    """Harmonics of the sweep in ``m`` (a :class:`samii.diagnose.measured.Measured` with its time series), or None
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
    for sig, ch in routes:
        y = getattr(ts, sig)[i_first:i_end]
        with np.errstate(invalid="ignore", divide="ignore"):
            h = np.where(fgrid > 0, _interp_response(frf.freq_hz, frf.response(ch), np.where(fgrid > 0, fgrid, 1.0)), np.nan)
            D = np.fft.rfft(y - np.mean(y), nfft) / h - V
        d = np.fft.irfft(np.where(np.isfinite(D), D, 0.0), nfft)[: i_end - i_first]
        sigs["d_" + sig] = np.concatenate([np.zeros(i_first), d, np.zeros(ts.t.size - i_end)])
    ks = (1,) + HARMONICS
    per_record = []
    phi0 = None
    edges = None
    for s0 in starts:
        r = ts.r[s0 : s0 + n_rec]
        an = signal.hilbert(r - np.mean(r))
        env = np.abs(an)
        phi = np.unwrap(np.angle(an))
        if phi0 is None:
            valid = np.flatnonzero(env > ENVELOPE * env.max())
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
    n = len(per_record)
    seg_f = np.array([(cycles[i + 1] - cycles[i]) / ((edges[i + 1] - edges[i]) / fs) for i in range(edges.size - 1)])
    amp = {name: np.stack([pr[name] for pr in per_record]) for name in sigs}  # (records, segments, k)
    v1 = amp["v"][:, :, 0]
    v1_mean = v1.mean(axis=0)
    v1_var = _pool(np.var(v1, axis=0, ddof=1))
    span = np.array([_span(per_phi, edges[i], edges[i + 1]) for i in range(edges.size - 1)])
    strong = (np.abs(v1_mean) ** 2 / (v1_var / n) >= MIN_FUNDAMENTAL_SNR) & (span <= MAX_SPAN)
    ratio, ratio_sd, logp = {}, {}, {}
    dof = 2.0 * (n - 1) * POOL
    n_tests = max(int(strong.sum()) * len(HARMONICS), 1)
    for j, k in enumerate(HARMONICS, start=1):
        est, var_est = [], []
        top = float(frf.freq_hz[-1])
        for sig, _ in routes:
            d = np.where(k * seg_f[None, :] <= top, amp["d_" + sig][:, :, j], np.nan)  # (records, segments)
            est.append(d.mean(axis=0))
            var_est.append(_pool(np.var(d, axis=0, ddof=1).real) / n)
        est, var_est = np.array(est), np.array(var_est)
        ok = np.isfinite(est) & np.isfinite(var_est) & (var_est > 0)
        w = np.where(ok, 1.0 / np.where(ok, var_est, 1.0), 0.0)
        wsum = w.sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            d_mean = np.where(wsum > 0, np.sum(w * np.where(ok, est, 0.0), axis=0) / np.where(wsum > 0, wsum, 1.0), np.nan)
            d_var = np.where(wsum > 0, 1.0 / wsum, np.nan)
            frame = np.exp(-1j * k * np.angle(v1_mean))
            ratio[k] = d_mean * frame / np.abs(v1_mean)
            ratio_sd[k] = np.sqrt(d_var / 2.0) / np.abs(v1_mean)  # per real part
            stat = np.abs(d_mean) ** 2 / d_var
        p = np.full(stat.shape, np.nan)
        test = strong & np.isfinite(stat)
        p[test] = stats.f.logsf(stat[test], 2, dof) / np.log(10.0)
        logp[k] = p
    return HarmonicAnalysis(m.source, seg_f, np.abs(v1_mean), ratio, ratio_sd, logp, n,
                            float(np.log10(alpha / n_tests)))


# -- amplitude dependence across files -------------------------------------------------------
def amplitude_test(a, b) -> AmplitudeTest | None:
    """theta/v and xdd/v of two files compared on the points both measure with a known noise (module docstring);
    None when they share no such points."""
    (lo, hi) = (a, b) if (a.amplitude_v or 0.0) <= (b.amplitude_v or 0.0) else (b, a)
    chi2, npts, corr, gains = 0.0, 0, max(lo.corr_length, hi.corr_length, 1.0), []
    for ch in ("act", "total"):
        if ch not in lo.frf.channels or ch not in hi.frf.channels:
            continue
        v1, v2 = lo.var.get(ch), hi.var.get(ch)
        if v1 is None or v2 is None:
            continue
        f = lo.frf.freq_hz
        h2 = _interp_response(hi.frf.freq_hz, hi.frf.response(ch), f)
        v2i = np.interp(f, hi.frf.freq_hz, v2, left=np.nan, right=np.nan)
        ok = np.isfinite(h2) & np.isfinite(v2i) & (v1 <= 0.25) & (v2i <= 0.25)
        if not ok.any():
            continue
        e = np.log(h2[ok] / lo.frf.response(ch)[ok])
        chi2 += float(np.sum(np.abs(e) ** 2 / ((v1[ok] + v2i[ok]) / 2.0)))
        npts += int(ok.sum())
        if ch == "act":
            gains = 20.0 / np.log(10.0) * e.real
    if npts == 0:
        return None
    dof = 2.0 * npts / corr
    stat = chi2 / corr
    return AmplitudeTest((lo.source, hi.source), (lo.amplitude_v or float("nan"), hi.amplitude_v or float("nan")), stat, dof,
                         _log10_sf(stat, dof), float(np.mean(gains)) if len(gains) else float("nan"), npts)


def _log10_sf(stat: float, dof: float) -> float:
    """log10 of chi2(dof)'s survival at ``stat``, never -inf (below 1e-300: the Wilson-Hilferty normal tail, floored at -1e4)."""
    lp = float(stats.chi2.logsf(stat, dof)) / np.log(10.0)
    if np.isfinite(lp):
        return lp
    z = ((stat / dof) ** (1.0 / 3.0) - (1.0 - 2.0 / (9.0 * dof))) / np.sqrt(2.0 / (9.0 * dof))
    return max(float(stats.norm.logsf(z)) / np.log(10.0), -1e4)


def _p_text(log10_p: float) -> str:
    return "p < 1e-300" if log10_p <= -300 else f"p = 10^{log10_p:.0f}"


# -- the finding -------------------------------------------------------------------------------
def _harmonic_kind(h: HarmonicAnalysis) -> tuple[str, dict, dict, str]:
    sig2, sig3 = h.significant(2), h.significant(3)
    e2 = float(np.sum(np.abs(h.ratio[2][sig2]) ** 2))
    e3 = float(np.sum(np.abs(h.ratio[3][sig3]) ** 2))
    worst_k = 3 if e3 >= e2 else 2
    sel = sig3 if worst_k == 3 else sig2
    r = h.ratio[worst_k][sel]
    f = h.freq_hz[sel]
    a = h.command_v[sel]
    peak = int(np.argmax(np.abs(r)))
    where = (f"{sel.sum()} of {np.isfinite(h.log10_p[worst_k]).sum()} segments, {f.min():.3g}-{f.max():.3g} Hz, "
             f"up to {100 * abs(r[peak]):.2g} % of the fundamental ({20 * np.log10(abs(r[peak])):.0f} dB) at {f[peak]:.3g} Hz "
             f"where the valve command is {1e3 * a[peak]:.3g} mV")
    best_p = float(np.nanmin(h.log10_p[worst_k][sel]))
    base = (f"the {'2nd' if worst_k == 2 else '3rd'} harmonic of the sweep, referred to the valve command, repeats in all "
            f"{h.n_records} records beyond their spread (p = 10^{best_p:.0f} in the strongest segment) in {where}; "
            "a linear system makes none")
    params = {"harmonic": float(worst_k), "max_ratio": float(abs(r[peak])), "at_hz": float(f[peak])}
    stderr = {"max_ratio": float(h.ratio_sd[worst_k][sel][peak])}
    if worst_k == 2:
        return "asymmetry", params, stderr, base + ("; even harmonics dominate: the valve's two directions differ (its orifice "
                                                    "law under load, unequal piston areas)")
    phase = np.angle(np.sum(r * np.abs(r)))  # amplitude-weighted phase of c3 in the fundamental's frame
    deg = float(np.degrees(phase))
    params["phase_deg"] = deg
    if abs(deg) <= 60.0 or abs(deg) >= 120.0:
        kind = "dead_band" if abs(deg) <= 60.0 else "saturation"
        rho = r.real * (1.0 if kind == "dead_band" else 1.0)
        sd = h.ratio_sd[3][sel]
        level, se, chi2 = _fit_level(kind, a, rho, sd)
        name = "dead_band_v" if kind == "dead_band" else "saturation_v"
        params[name] = level
        stderr[name] = se
        what = ("in phase with cos 3phi: the centre of the wave is missing, a dead band (spool overlap; Coulomb friction "
                "that holds the joint at small commands looks alike)" if kind == "dead_band" else
                "in antiphase with cos 3phi: the peaks are flattened, a saturation (spool travel, flow limit)")
        # the phase's spread over the segments: a static law on the command keeps it at 0 or 180 deg everywhere
        spread = float(np.degrees(np.sqrt(-2.0 * np.log(max(abs(np.sum(r / np.abs(r))) / r.size, 1e-12)))))
        trend = np.corrcoef(np.log(a), np.log(np.abs(r)))[0, 1] if a.size > 2 else float("nan")
        text = (f"{base}; the 3rd harmonic is {what} ({deg:+.0f} deg); its describing function fits a level of "
                f"{1e3 * level:.3g} +- {1e3 * se:.2g} mV (chi2 {chi2:.2g} per degree of freedom)")
        if np.isfinite(trend):
            text += f"; the distortion {'falls' if trend < 0 else 'grows'} with the command's amplitude (correlation {trend:+.2f})"
        params["phase_spread_deg"] = spread
        if spread > 45.0 or chi2 > 10.0:
            text += (f"; but its phase spreads over {spread:.0f} deg across the band and the static law fits it poorly: the "
                     "nonlinearity depends on the loop's state, not on the command alone (the load pressure through the valve's "
                     "orifice law, say), and the level is indicative only")
        return kind, params, stderr, text
    return "hysteresis", params, stderr, (f"{base}; the 3rd harmonic is {deg:+.0f} deg off cos 3phi: neither a dead band nor a "
                                          "saturation (both in phase or antiphase) but a nonlinearity with memory: friction, "
                                          "backlash, hysteresis")


def find_nonlinear(measured: Sequence, *, alpha: float = ALPHA) -> tuple[list[NonlinearFinding], list[str], list[HarmonicAnalysis], list[AmplitudeTest]]:
    """Nonlinear findings over the files (at most one per file from harmonics, one from amplitude dependence) and notes."""
    findings, notes = [], []
    analyses = [h for h in (harmonic_analysis(m, alpha=alpha) for m in measured) if h is not None]
    for h in analyses:
        if h.n_significant >= MIN_SEGMENTS:
            kind, params, stderr, text = _harmonic_kind(h)
            findings.append(NonlinearFinding(kind, params, stderr, f"{h.source}: {text}", harmonics=(h,)))
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
    for t in differ:
        a1, a2 = t.amplitudes_v
        same = not (np.isfinite(a1) and np.isfinite(a2) and a2 >= MIN_AMPLITUDE_RATIO * a1)
        if same:
            notes.append(f"{t.sources[0]} and {t.sources[1]} (amplitudes {a1:.3g} and {a2:.3g} V) differ beyond their noise "
                         f"(chi2 {t.chi2:.4g} on {t.dof:.0f} dof): at (nearly) one amplitude this says the rig changed between "
                         "the runs, not that it is nonlinear")
    amp = [t for t in differ if np.isfinite(t.amplitudes_v[0]) and t.amplitudes_v[1] >= MIN_AMPLITUDE_RATIO * t.amplitudes_v[0]]
    if amp:
        t = max(amp, key=lambda t: -t.log10_p)
        grows = t.gain_change_db > 0
        kind = "dead_band" if grows else "saturation"
        text = (f"theta/v and xdd/v at {t.amplitudes_v[1]:.3g} V differ from those at {t.amplitudes_v[0]:.3g} V by chi2 "
                f"{t.chi2:.4g} on {t.dof:.0f} dof ({_p_text(t.log10_p)}; {t.n_points} points), theta/v "
                f"{t.gain_change_db:+.2f} dB on average at the larger amplitude: the response "
                + ("grows with amplitude, as a dead band's or friction's (small commands lose more)" if grows else
                   "shrinks with amplitude, as a saturation's"))
        found = next((f for f in findings if f.kind in ("dead_band", "saturation", "hysteresis")), None)
        if found is not None:
            agrees = found.kind == kind
            findings[findings.index(found)] = NonlinearFinding(
                found.kind, found.params, found.stderr,
                found.evidence + f"; across files: {text}" + ("" if agrees else f" (the harmonics say {found.kind})"),
                found.harmonics, tuple(amp))
        else:
            findings.append(NonlinearFinding(kind if not findings else "amplitude_dependence",
                                             {"gain_change_db": t.gain_change_db, "amplitude_low_v": t.amplitudes_v[0],
                                              "amplitude_high_v": t.amplitudes_v[1]}, {}, text, (), tuple(amp)))
    return findings, notes, analyses, tests
