"""A time series' closed-loop FRF with the random error of every point, from the spread between its records.

Each record ``k`` gives its own ratio ``H_k = Y_k / X_k`` (the excitation cancels); the estimate is the weighted ratio
of summed cross-spectra, ``sum_k c_k H_k`` with ``c_k`` each record's share of the denominator, whose relative error
has variance ``sum_k |c_k|^2 a_k s^2`` (``a_k`` each record's share of the noise, ``|R|^2/|R_k|^2``: 1 for repeats).
With deviations ``d_k = H_k/H - 1``, ``E sum_k |d_k|^2 = s^2 (sum a_k - 2 Re sum c_k a_k + n sum_k |c_k|^2 a_k)``
gives ``s^2`` (for repeats with equal weights the familiar ``n - 1``; a sign-alternating sweep weighs its 3 records
1/4, 1/2, 1/4, and the earlier ``sum |c_k|^2 |d_k|^2 n/(n-1)`` was 19 % short for it). The noise varies slowly with
frequency, so this is pooled over every FFT bin around the point (those nearer it than its neighbours on the output
grid, at least ``POOL`` where the grid is every bin, one-sided at the band's ends): at 40 Hz some 140 bins. The
relative error goes as the noise over the excitation's power, so the pool is of the error times ``|R|^2`` (``r`` is
known exactly), divided back at the point: the sweep's spectrum falls steeply at its ends. Checked by Monte Carlo (60
noise draws of one rig): the stated variance is the observed one to a few % from 0.5 to 40 Hz. The same deviations on
the output grid give the correlation between neighbouring points (``corr_length``, the number of points one
independent error spans), which the significance tests need: an FFT grid zero-padded 2x puts correlated bins next to
each other.

The estimate itself is :func:`samii.measure.frf.estimate_frf`'s; this module adds its variance (``E|H_est/H - 1|^2``
of the complex relative error: log magnitude and phase each have half of it), which a diagnosis weighs residuals
against (:mod:`samii.measure.measured`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import scipy.fft

from samii.frequency_response import FrequencyResponse
from samii.measure.frf import CHANNEL_PAIRS, estimate_frf, record_weights, split_records
from samii.measure.records import RecordLayout
from samii.timeseries import TimeSeries

__all__ = ["POOL", "MAX_VAR", "pool_mean", "moving_sum", "corr_length", "cut_to_records", "spectra_at", "timeseries_frf"]

#: Points whose relative random error exceeds this variance (each of log magnitude and phase std
#: sqrt(0.1/2) = 0.22: 1.9 dB, 13 deg) carry no usable information: there the estimate is dominated by
#: noise and its spread says nothing about its error. Why not more: where the response is pure noise, the
#: spread of 3 records gives 1/var ~ F(2, 4), below 0.25 at one point in 9 (below 0.1 at one in 36); pooled
#: over 9 correlated neighbours, islands of pure noise still passed 0.25 (xdd/v at 0.30 Hz, 50x the
#: response, stated sigma 0.5: a base "mode" at p = 10^-22.7 on a clean rig). Points between 0.1 and 0.25
#: weigh 1/400 of a typical point's: little is lost.
MAX_VAR = 0.1

#: Neighbouring points the record-to-record variance is pooled over (odd).
POOL = 9


def pool_mean(x: np.ndarray, k: int = POOL) -> np.ndarray:
    """Moving mean over ``k`` points, the window shrinking at the ends."""
    return moving_sum(x, k) / moving_sum(np.ones_like(x), k)


def moving_sum(x: np.ndarray, k: int) -> np.ndarray:
    """Sum over the ``k`` points centred on each point of ``x``, fewer at the ends: ``np.convolve(x, ones(k),
    "same")``, which returns ``k`` values, not ``x.size``, when ``x`` is shorter than ``k``."""
    start = (k - 1) // 2
    return np.convolve(x, np.ones(k))[start : start + np.size(x)]


def corr_length(dev: np.ndarray) -> float:
    """Points one independent error spans, from the deviations ``dev`` (records, points) normalised to unit variance."""
    total = float(np.sum(np.abs(dev) ** 2))
    if total <= 0:
        return 1.0
    length = 1.0
    for lag in range(1, 20):
        rho = float(np.real(np.sum(dev[:, lag:] * np.conj(dev[:, :-lag])))) / total
        if rho < 0.05:
            break
        length += 2.0 * rho
    return length


def _window_means(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Mean of the finite values of ``x[lo[j]:hi[j]]`` for every j; inf where there are none (a point without
    a noise estimate is dropped, not weighed as exact). Slices, not running sums: one huge bin would take the
    precision of every later window with it."""
    out = np.full(lo.size, np.inf)
    for j, (a, b) in enumerate(zip(lo, hi)):
        seg = x[a:b]
        seg = seg[np.isfinite(seg)]
        if seg.size:
            out[j] = seg.mean()
    return out


def _bin_windows(bins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each output bin, the FFT bins (half-open range) its noise is pooled over: those nearer it than its
    neighbouring output bins, at least ``POOL`` of them, within the first and last output bins."""
    b = np.asarray(bins, int)
    mid = (b[:-1] + b[1:] + 1) // 2
    lo = np.concatenate([[b[0]], mid])
    hi = np.concatenate([mid, [b[-1] + 1]])
    half = POOL // 2
    lo = np.minimum(lo, b - half)
    hi = np.maximum(hi, b + half + 1)
    lo, hi = np.maximum(lo, b[0]), np.minimum(hi, b[-1] + 1)
    return lo - b[0], hi - b[0]


def cut_to_records(ts: TimeSeries, layout: RecordLayout) -> TimeSeries:
    """The part of ``ts`` that ``layout``'s records cover (t, v, theta, accel, r), from the first record's start."""
    fs = ts.sample_rate_hz
    i0 = int(round(layout.start_s * fs))
    n = int(round((layout.n_records - 1) * layout.record_s * fs)) + int(np.floor(layout.record_s * fs))
    cols = {k: v[i0 : i0 + n] for k, v in ts.columns().items() if k in ("t", "v", "theta", "accel", "r")}
    return TimeSeries(**cols, metadata=ts.metadata)


def spectra_at(ts: TimeSeries, layout: RecordLayout, freq_hz: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Each record's spectrum of r, v, theta and accel at ``freq_hz`` (the FFT bins of a :func:`timeseries_frf` grid of
    the same layout), as (signal -> (records, points), r's records in time)."""
    fs = ts.sample_rate_hz
    records, _ = split_records(cut_to_records(ts, layout), record_s=layout.record_s, baseline_s=layout.baseline_s)
    n_fft = scipy.fft.next_fast_len(2 * records["r"].shape[1], real=True)
    bins = np.round(np.asarray(freq_hz) * n_fft / fs).astype(int)
    return {k: scipy.fft.rfft(x, n=n_fft, axis=-1)[:, bins] for k, x in records.items()}, records["r"]


def timeseries_frf(
    ts: TimeSeries, layout: RecordLayout, *, band_hz: tuple[float, float]
) -> tuple[FrequencyResponse, dict[str, np.ndarray | None], float, str]:
    """Closed-loop FRF of ``ts`` cut as ``layout`` says (:func:`estimate_frf`), with the record-to-record variance of every point.

    The variance of a point is pooled over every FFT bin around it (module docstring): the output grid keeps one
    bin in ~100 at 40 Hz (100 points a decade on bins of 1/(2 T)), and the bins between carry the same noise; pooled
    over only the output points the variance had ~36 degrees of freedom, and 1/var as a weight scattered by
    +-25 % over stretches of ~10 points, enough for a "mode" in a clean ẍ/v between 30 and 40 Hz.

    Returns (frf, var per channel, corr_length, how the noise was estimated).
    """
    fs = ts.sample_rate_hz
    cut = cut_to_records(ts, layout)
    frf = estimate_frf(cut, record_s=layout.record_s, baseline_s=layout.baseline_s, band_hz=band_hz)
    frf = replace(frf, metadata={**frf.metadata, "frf_layout": f"records from t = {layout.start_s:.6g} s; {layout.how}"})
    records, n_records = split_records(cut, record_s=layout.record_s, baseline_s=layout.baseline_s)
    if n_records < 2:
        return frf, dict.fromkeys(CHANNEL_PAIRS), 1.0, "unknown (one record: no spread, no coherence)"
    w = record_weights(records["r"])[0][:, None]
    # every FFT bin of the band: the FRF's grid is a subset of them (record_spectra, zero-padded 2x)
    n_fft = scipy.fft.next_fast_len(2 * records["r"].shape[1], real=True)
    bins = np.round(frf.freq_hz * n_fft / fs).astype(int)
    if not np.allclose(bins * fs / n_fft, frf.freq_hz, rtol=1e-9, atol=1e-12):
        raise RuntimeError("the FRF's frequencies are not the FFT bins the noise is estimated on")  # record_spectra changed
    full = {k: scipy.fft.rfft(x, n=n_fft, axis=-1)[:, bins[0] : bins[-1] + 1] for k, x in records.items()}
    lo, hi = _bin_windows(bins)
    at = bins - bins[0]
    R = full["r"]
    # the relative error goes as the noise over the excitation's power, which falls steeply at the sweep's ends and
    # ripples within its band: the pool takes the error times |R|^2 (noise-free: r is known exactly) and divides it back
    r2 = np.maximum(np.mean(np.abs(R) ** 2, axis=0), 1e-300)
    var, devs = {}, []
    # each record's share of the noise: its ratio Y_k/X_k errs as 1/|X_k|^2, and X_k goes as R_k (1 for repeats)
    a = np.clip(r2 / np.maximum(np.abs(R) ** 2, 1e-300), 1e-6, 1e6)
    for ch, (num, den) in CHANNEL_PAIRS.items():
        share = w * np.conj(R) * full[den]
        total = np.sum(share, axis=0)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            c = share / total  # each record's share of the estimate's denominator
            h = np.sum(w * np.conj(R) * full[num], axis=0) / total  # the estimate at every bin
            d = full[num] / full[den] / h - 1.0
            # the estimate is sum_k c_k H_k, each record's relative error of variance a_k s^2: its own variance is
            # sum |c_k|^2 a_k s^2, and E sum_k |d_k|^2 = s^2 (sum a_k - 2 Re sum c_k a_k + n sum |c_k|^2 a_k) (sum c_k = 1).
            # For repeats (a_k = 1) that is n - 2 + n sum|c_k|^2; unequal weights (a sign-alternating sweep's 1/4, 1/2,
            # 1/4) made the earlier sum_k |c_k|^2 |d_k|^2 n/(n-1) 19 % short: 13/64 * 3/2 of s^2 against 3/8.
            ca = np.sum(np.abs(c) ** 2 * a, axis=0)
            spread = ca * np.sum(np.abs(d) ** 2, axis=0) / (np.sum(a, axis=0) - 2.0 * np.sum(c.real * a, axis=0) + n_records * ca)
        spread[~np.isfinite(spread)] = np.nan  # no estimate there (a zero spectrum): left out of the pool
        var[ch] = np.maximum(_window_means(spread * r2, lo, hi) / r2[at], 1e-30)
        if ch != "total":
            # (a point without an estimate, a zero spectrum of a signal rounded to a constant, counts as no deviation:
            # nan_to_num made it 1.8e308, whose square overflowed with a numpy warning to the user)
            dg = np.where(np.isfinite(d[:, at]), d[:, at], 0.0)
            with np.errstate(over="ignore"):
                devs.append(dg / np.sqrt(np.maximum(pool_mean(np.mean(np.abs(dg) ** 2, axis=0)), 1e-30)))
    how = (
        f"record-to-record spread of {n_records} records, pooled over the FFT bins around each point "
        f"(at least {POOL}; weighted by the excitation's power)"
    )
    return frf, var, corr_length(np.vstack(devs)), how
