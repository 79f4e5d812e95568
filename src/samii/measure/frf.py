"""Frequency-response estimation from swept-sine records, correct in closed loop.

Joint 2 runs under its position loop, so the valve command ``v`` is not the
excitation: it carries the feedback of theta and of whatever disturbs theta.
Dividing output by input spectra (H1, S_vy/S_vv) would then be biased. The
excitation ``r`` is uncorrelated with everything except through the loop, so it
serves as the instrument::

    act   = theta/v   = S_r,theta / S_r,v
    base  = xdd/theta = S_r,accel / S_r,theta
    total = xdd/v     = S_r,accel / S_r,v

Spectra. Each repetition of the sweep is one record from rest to rest (the
excitation fades in and out inside the record and the response decays in the
rest that follows), so the records are transients and are taken whole, with a
rectangular window: for a linear system the Fourier transform of the output of
a full transient record is exactly H times that of its input, at every
frequency, without leakage. Transforms are evaluated on a zero-padded FFT grid
(the output frequencies are the FFT bins nearest a logarithmic grid) or, when
frequencies are given, by a direct Fourier sum at exactly those frequencies.
Each record's operating point (the mean over the rest before its sweep) is
subtracted first. Cross-spectra are summed over the records (the averages).

Sign-alternating records. When the records repeat one excitation with signs
s_k = +-1 (``SweptSine.alternate_sign``), the sum is weighted, ``w_k = 1/(2 n+)``
for positive and ``1/(2 n-)`` for negative records (the smallest-variance
weights with sum w_k s_k = 0): the linear response keeps its sign in R*Y, an
even-order distortion changes it, so it cancels from the estimate. For 3
records (+, -, +) the weights are 1/4, 1/2, 1/4. Otherwise records weigh alike.

Coherence. For the instrument-variable estimate the relevant coherence is that
between the excitation and each signal, ``g_ry = |sum R* Y|^2 / (sum |R|^2 sum |Y|^2)``
over the records (weighted as above). It measures how much of ``y`` at that
frequency follows the excitation linearly: sensor noise and other disturbances
lower it, and so does an even-order distortion when the records alternate in
sign; a distortion repeated identically in every record does not. A
channel's coherence is the product of those of its numerator and denominator,
because the relative variance of a ratio is the sum of those of its two
cross-spectra, ``(1 - g) / g`` each, to first order. With a single record the
coherence is 1 by construction and is not reported.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft

from samii.frequency_response import FrequencyResponse
from samii.timeseries import TimeSeries

__all__ = ["estimate_frf", "record_spectra", "RecordSpectra", "CHANNEL_PAIRS", "split_records", "record_weights", "fourier_at", "log_frequency_grid"]

# Output grid density: 100 points per decade puts >= 2 points inside the
# half-power band of the lightest-damped base mode (2 zeta = 6 % wide, mode 1, eq 9.4).
_POINTS_PER_DECADE = 100
# Excitation level, relative to its mean over all frequencies, below which a
# frequency counts as not excited (-40 dB).
_MIN_EXCITATION = 1e-4

_SIGNALS = ("r", "v", "theta", "accel")
#: Channel -> (numerator, denominator) signals of its instrument-variable estimate.
CHANNEL_PAIRS = {"act": ("theta", "v"), "base": ("accel", "theta"), "total": ("accel", "v")}


def log_frequency_grid(lo_hz: float, hi_hz: float, points_per_decade: float) -> np.ndarray:
    """Logarithmically spaced frequencies from ``lo_hz`` to ``hi_hz`` inclusive."""
    n = int(np.ceil(np.log10(hi_hz / lo_hz) * points_per_decade)) + 1
    return np.geomspace(lo_hz, hi_hz, n)


def split_records(ts: TimeSeries, *, record_s: float, baseline_s: float) -> tuple[dict[str, np.ndarray], int]:
    """Cut ``ts`` into consecutive records of ``record_s`` and remove each record's operating point.

    Returns
    -------
    records : dict
        Signal name (r, v, theta, accel) -> array (n_records, samples per record).
    n_records : int
    """
    if ts.r is None:
        raise ValueError("the closed-loop estimate needs the excitation signal r (column 'r') as instrument")
    fs = ts.sample_rate_hz
    if not (record_s > 0 and np.isfinite(record_s)):
        raise ValueError(f"record_s must be positive, got {record_s!r}")
    n_rec = int(np.floor(record_s * fs + 1e-6))
    n_records = int(np.floor((len(ts) + 0.5) / (record_s * fs) + 1e-9)) + 1
    while n_records > 0 and int(round((n_records - 1) * record_s * fs)) + n_rec > len(ts):
        n_records -= 1  # the last record must fit whole (records start at whole samples, k * record_s rounded)
    if n_records < 1 or n_rec < 2:
        raise ValueError(f"the time series ({len(ts) / fs:.6g} s) is shorter than one record of {record_s:.6g} s")
    n_base = int(round(baseline_s * fs))
    if not (0 <= n_base < n_rec):
        raise ValueError(f"baseline_s must lie in 0...record_s, got {baseline_s!r}")
    starts = np.round(np.arange(n_records) * record_s * fs).astype(int)
    records = {}
    for name in _SIGNALS:
        x = getattr(ts, name)
        rec = np.stack([x[s : s + n_rec] for s in starts])
        if n_base:
            rec = rec - rec[:, :n_base].mean(axis=1, keepdims=True)
        records[name] = rec
    return records, n_records


def record_weights(r_records: np.ndarray, signs=None) -> tuple[np.ndarray, str]:
    """Weights of the records in the averaged cross-spectra, and how they were chosen.

    With both signs present the weights cancel even-order distortion (module
    docstring); otherwise all weigh 1/N. ``signs`` (+1/-1 per record, e.g.
    ``SweptSine.record_signs``) states them; without it they are read off the
    data: records whose excitation correlates with the first one's at
    |rho| > 0.9 count as it repeated with the sign of rho. (Records are cut at
    whole samples, so a repeat can be shifted by up to half a sample: |rho| is
    then below 1 by ~(pi f_max / fs)^2 / 2, 0.8 % for a sweep to 40 Hz at 1 kHz.)
    """
    n = r_records.shape[0]
    uniform = np.full(n, 1.0 / n)
    if n < 2:
        return uniform, "one record"
    if signs is not None:
        signs = np.asarray(signs, float).ravel()
        if signs.size != n or not np.all(np.isin(signs, (-1.0, 1.0))):
            raise ValueError(f"record signs must be {n} values of +1 or -1, got {signs.tolist()}")
        how = "stated"
    else:
        norms = np.linalg.norm(r_records, axis=1)
        if np.any(norms == 0):
            return uniform, "uniform"
        corr = r_records @ r_records[0] / (norms * norms[0])
        if np.any(np.abs(corr) < 0.9):
            return uniform, "uniform (records are not one excitation repeated)"
        signs = np.sign(corr)
        how = "read off the excitation"
    n_pos, n_neg = int(np.sum(signs > 0)), int(np.sum(signs < 0))
    if n_neg == 0 or n_pos == 0:
        return uniform, "uniform (records repeat one excitation with one sign)"
    w = np.where(signs > 0, 0.5 / n_pos, 0.5 / n_neg)
    pattern = "".join("+" if x > 0 else "-" for x in signs)
    return w, f"signs {pattern} ({how}), weights {', '.join(f'{x:.4g}' for x in w)}: even-order distortion cancels"


def fourier_at(x: np.ndarray, freqs_hz: np.ndarray, sample_rate_hz: float) -> np.ndarray:
    """Fourier sum ``sum_n x[..., n] exp(-2j pi f n / fs)`` at arbitrary frequencies (last axis of x)."""
    x = np.asarray(x, float)
    n = np.arange(x.shape[-1]) / sample_rate_hz
    out = np.empty(x.shape[:-1] + (len(freqs_hz),), complex)
    for i0 in range(0, len(freqs_hz), 16):  # 16 frequencies at a time bounds the memory
        f = np.asarray(freqs_hz[i0 : i0 + 16], float)
        out[..., i0 : i0 + len(f)] = x @ np.exp(-2j * np.pi * np.outer(n, f))
    return out


@dataclass(frozen=True, eq=False)
class RecordSpectra:
    """Per-record spectra of one time series.

    Attributes
    ----------
    spectra : dict
        Signal (r, v, theta, accel) -> complex array (n_records, n_freqs).
    freq_hz : array
        Output frequencies [Hz].
    grid : str
        How the frequencies were chosen.
    r_records : array (n_records, samples per record)
        The excitation's records in time (their signs and energy weigh the records).
    """

    spectra: dict
    freq_hz: np.ndarray
    grid: str
    r_records: np.ndarray

    @property
    def n_records(self) -> int:
        return int(self.r_records.shape[0])


def record_spectra(
    ts: TimeSeries,
    *,
    record_s: float,
    baseline_s: float,
    band_hz: tuple[float, float] = (0.1, 40.0),
    freqs_hz=None,
    points_per_decade: float = _POINTS_PER_DECADE,
    pad_factor: int = 2,
) -> RecordSpectra:
    """Spectra of every record of r, v, theta, accel at the output frequencies (see :func:`estimate_frf`)."""
    records, n_records = split_records(ts, record_s=record_s, baseline_s=baseline_s)
    fs = ts.sample_rate_hz
    n_rec = records["r"].shape[1]
    if freqs_hz is None:
        lo, hi = map(float, band_hz)
        if not (0 < lo < hi < fs / 2):
            raise ValueError(f"band_hz must satisfy 0 < lo < hi < {fs / 2:g} Hz (Nyquist), got {band_hz}")
        n_fft = scipy.fft.next_fast_len(int(pad_factor) * n_rec, real=True)
        bins = np.unique(np.round(log_frequency_grid(lo, hi, points_per_decade) * n_fft / fs).astype(int))
        bins = bins[(bins >= np.ceil(lo * n_fft / fs - 1e-9)) & (bins <= np.floor(hi * n_fft / fs + 1e-9))]
        freqs = bins * fs / n_fft
        spectra = {k: scipy.fft.rfft(x, n=n_fft, axis=-1)[:, bins] for k, x in records.items()}
        grid = f"FFT bins (zero-padded to {n_fft} samples, {fs / n_fft:.4g} Hz) nearest a {points_per_decade:g}-per-decade log grid"
    else:
        freqs = np.asarray(freqs_hz, float)
        order = np.argsort(freqs)
        if np.any(np.diff(freqs[order]) <= 0) or freqs[order][0] <= 0 or freqs[order][-1] >= fs / 2:
            raise ValueError(f"freqs_hz must be distinct, positive and below {fs / 2:g} Hz (Nyquist)")
        freqs = freqs[order]
        spectra = {k: fourier_at(x, freqs, fs) for k, x in records.items()}
        grid = "direct Fourier sums at the requested frequencies"
    return RecordSpectra(spectra, freqs, grid, records["r"])


def estimate_frf(
    ts: TimeSeries,
    *,
    record_s: float,
    baseline_s: float,
    band_hz: tuple[float, float] = (0.1, 40.0),
    freqs_hz=None,
    points_per_decade: float = _POINTS_PER_DECADE,
    pad_factor: int = 2,
    record_signs=None,
) -> FrequencyResponse:
    """Closed-loop FRF (act, base, total) with coherence from repeated rest-to-rest sweep records.

    Parameters
    ----------
    ts : TimeSeries
        DAQ signals with the excitation ``r``; starts at the first record.
    record_s : float
        Length of one repetition [s] (``SweptSine.record_s``). Whole records only
        are used.
    baseline_s : float
        Rest at the start of every record whose mean is the operating point
        subtracted from that record (``SweptSine.lead_s``); 0 subtracts nothing.
    band_hz : (float, float)
        Frequency band of the output; must be excited by ``r``.
    freqs_hz : array, optional
        Evaluate exactly at these frequencies instead (overrides ``band_hz``).
    points_per_decade : float
        Density of the logarithmic output grid.
    pad_factor : int
        FFT length is at least this many record lengths (finer grid at low frequency).
    record_signs : sequence of +1/-1, optional
        Sign of the excitation in each record (``SweptSine.record_signs``); by
        default read off the data (:func:`record_weights`).

    Returns
    -------
    FrequencyResponse
        Channels act, base, total; coherence per channel (with >= 2 records);
        metadata states the estimator, records, window and averaging.

    Raises
    ------
    ValueError
        No ``r`` column, data shorter than one record, or a frequency where ``r``
        has no energy (more than 40 dB below its mean spectral level).
    """
    rs = record_spectra(
        ts, record_s=record_s, baseline_s=baseline_s, band_hz=band_hz, freqs_hz=freqs_hz, points_per_decade=points_per_decade, pad_factor=pad_factor
    )
    fs = ts.sample_rate_hz
    spectra, freqs, grid, n_records, n_rec = rs.spectra, rs.freq_hz, rs.grid, rs.n_records, rs.r_records.shape[1]
    w, weighting = record_weights(rs.r_records, record_signs)
    w = w[:, None]
    R = spectra["r"]
    s_rr = np.sum(w * np.abs(R) ** 2, axis=0)
    # Parseval: the mean of |R(f)|^2 over all frequencies is sum r^2. A sweep puts
    # |R(f)|^2 >~ sum r^2 inside its band (0.1-40 Hz: from 1x at 40 Hz to 3000x at 0.1 Hz).
    weak = s_rr < _MIN_EXCITATION * np.sum(w * rs.r_records**2)
    if np.any(weak):
        raise ValueError(
            f"the excitation r has no energy at {np.round(freqs[weak][:5], 4).tolist()} Hz (more than 40 dB below "
            "its mean spectral level); estimate only inside the excited band"
        )
    cross = {k: np.sum(w * np.conj(R) * spectra[k], axis=0) for k in ("v", "theta", "accel")}
    coh = {}
    if n_records >= 2:
        for k in ("v", "theta", "accel"):
            s_yy = np.sum(w * np.abs(spectra[k]) ** 2, axis=0)
            with np.errstate(invalid="ignore", divide="ignore"):
                g = np.abs(cross[k]) ** 2 / (s_rr * s_yy)
            coh[k] = np.clip(np.nan_to_num(g, nan=0.0), 0.0, 1.0)  # y == 0 exactly: no coherent signal
    kw = {}
    for ch, (num, den) in CHANNEL_PAIRS.items():
        kw[ch] = cross[num] / cross[den]
        if coh:
            kw[f"{ch}_coh"] = coh[num] * coh[den]
    meta = dict(ts.metadata)
    meta.update(
        {
            "frf_estimator": "instrument variable, excitation r: act=S_r,theta/S_r,v base=S_r,accel/S_r,theta total=S_r,accel/S_r,v",
            "frf_records": f"{n_records} records of {n_rec / fs:.6g} s (one per sweep repetition), cross-spectra summed over records",
            "frf_record_weights": weighting,
            "frf_window": f"rectangular over each whole rest-to-rest record; operating point = mean of the first {baseline_s:g} s of each record, subtracted",
            "frf_grid": grid,
            "frf_coherence": "g_ry=|sum w R*Y|^2/(sum w|R|^2 sum w|Y|^2) over records; channel = g_r,num * g_r,den"
            if coh
            else "not estimated (one record)",
        }
    )
    return FrequencyResponse(freqs, metadata=meta, **kw)
