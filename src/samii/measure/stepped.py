"""Stepped-sine (fixed-sine) estimation: steady-state correlation at one frequency per dwell.

In each dwell's measurement window (after the transient has been discarded, a
whole number of periods long) every signal is correlated with cos and sin of the
dwell frequency. The correlation is written as a least-squares fit of
``a cos(wt) + b sin(wt) + c``: over whole periods it equals the classical
correlation (2/T) integral y e^{-jwt} dt, with ``c`` removing the operating
point, and it stays exact when the window is a fraction of a sample off a
whole number of periods. The complex amplitude is ``Y = a - j b``.

At a single frequency the instrument-variable estimate reduces to the ratio of
complex amplitudes (the excitation's amplitude cancels): act = Theta/V,
base = A/Theta, total = A/V, so the estimate is correct in closed loop.

Coherence of a signal in a window is that of a spectral estimate at the dwell
frequency with the window's resolution, so that it reads like the swept sine's
(:mod:`samii.measure.frf`) on the same plot: with N samples and residual
variance s^2 (what the sine does not explain, taken as white), the least-squares
amplitude has error power E|dY|^2 = var(a) + var(b) = 4 s^2 / N, and
``coherence = |Y|^2 / (|Y|^2 + 4 s^2 / N)``. Noise lowers it as it lowers the
estimate's accuracy; harmonics and slow leftovers count as white noise (a
conservative reading). A channel's coherence is the product of its numerator's
and denominator's, as for the swept sine.
"""

from __future__ import annotations

import numpy as np

from samii.frequency_response import FrequencyResponse
from samii.measure.timeseries import TimeSeries

__all__ = ["estimate_stepped", "sine_amplitude"]

_SIGNALS = ("v", "theta", "accel")


def sine_amplitude(y: np.ndarray, t_s: np.ndarray, freq_hz: float) -> tuple[complex, float]:
    """Complex amplitude ``Y`` (y ~ Re(Y e^{j 2 pi f t}) + c) and its coherence (module docstring)."""
    w = 2.0 * np.pi * freq_hz
    basis = np.column_stack([np.cos(w * t_s), np.sin(w * t_s), np.ones_like(t_s)])
    (a, b, c), *_ = np.linalg.lstsq(basis, y, rcond=None)
    n = y.size
    resid = y - basis @ np.array([a, b, c])
    s2 = float(resid @ resid) / max(n - 3, 1)  # residual variance, 3 parameters fitted
    power = a * a + b * b  # |Y|^2
    coherence = power / (power + 4.0 * s2 / n) if power > 0 else 0.0
    return complex(a, -b), float(coherence)


def estimate_stepped(ts: TimeSeries, *, freqs_hz, windows_s) -> FrequencyResponse:
    """FRF (act, base, total) with coherence at the dwell frequencies of a stepped-sine run.

    Parameters
    ----------
    ts : TimeSeries
        DAQ signals v, theta, accel of the whole run (``r`` not needed).
    freqs_hz : sequence of float
        Dwell frequencies [Hz], distinct.
    windows_s : array (n, 2)
        Measurement window (start, stop) of each dwell in the time of ``ts.t``
        [s] (``SteppedSine.windows_s``), each a whole number of periods.

    Returns
    -------
    FrequencyResponse
        Points sorted by frequency; metadata states the method and windows.
    """
    freqs = np.asarray(freqs_hz, float).ravel()
    windows = np.asarray(windows_s, float).reshape(-1, 2)
    if freqs.size != windows.shape[0]:
        raise ValueError(f"{freqs.size} frequencies but {windows.shape[0]} windows")
    if np.any(freqs <= 0) or np.unique(freqs).size != freqs.size:
        raise ValueError(f"freqs_hz must be positive and distinct, got {freqs}")
    if np.any(freqs >= ts.sample_rate_hz / 2):
        raise ValueError(f"freqs_hz must lie below the Nyquist frequency {ts.sample_rate_hz / 2:g} Hz")
    amp = {k: np.empty(freqs.size, complex) for k in _SIGNALS}
    coh = {k: np.empty(freqs.size) for k in _SIGNALS}
    for i, (f, (start, stop)) in enumerate(zip(freqs, windows)):
        keep = (ts.t >= start - 1e-9) & (ts.t < stop - 1e-9)
        if start < ts.t[0] - 1e-9 or stop > ts.t[-1] + ts.dt_s + 1e-9:
            raise ValueError(f"window {i} ({start:.6g}-{stop:.6g} s at {f:g} Hz) lies outside the data ({ts.t[0]:.6g}-{ts.t[-1]:.6g} s)")
        if np.count_nonzero(keep) < 8:
            raise ValueError(f"window {i} ({start:.6g}-{stop:.6g} s at {f:g} Hz) holds fewer than 8 samples")
        t = ts.t[keep]
        for k in _SIGNALS:
            amp[k][i], coh[k][i] = sine_amplitude(getattr(ts, k)[keep], t, f)
    order = np.argsort(freqs)
    pairs = {"act": ("theta", "v"), "base": ("accel", "theta"), "total": ("accel", "v")}
    kw = {}
    for ch, (num, den) in pairs.items():
        kw[ch] = (amp[num] / amp[den])[order]
        kw[f"{ch}_coh"] = (coh[num] * coh[den])[order]
    meta = dict(ts.metadata)
    meta.update(
        {
            "frf_estimator": "stepped sine: least-squares sine fit (correlation with cos, sin and a constant) per dwell; act=Theta/V base=A/Theta total=A/V",
            "frf_window": "rectangular, whole periods after settling: " + "; ".join(f"{f:g} Hz {a:.6g}-{b:.6g} s" for f, (a, b) in zip(freqs[order], windows[order])),
            "frf_coherence": "|Y|^2/(|Y|^2 + 4 s^2/N) per signal (s^2: residual variance of the sine fit, N samples: the spectral coherence at the window's resolution); channel = product of numerator's and denominator's",
        }
    )
    return FrequencyResponse(freqs[order], metadata=meta, **kw)
