"""Mains hum: spectral lines at 50 or 60 Hz and their harmonics, found in a recorded signal and subtracted.

A rig's signals pick up the mains (ground loops, a transformer beside the
accelerometer's amplifier). A line is outside the sweep's band, but the
FRF estimator takes each record whole with a rectangular window (a transient
from rest to rest: exact for the response, samii.measure.frf), and a
stationary line leaks through that window's sidelobes to every frequency,
falling only as 1/(f_line - f). When the record lasts a whole number of mains
periods (120 s sweeps and 20 s of rest: 7000 cycles of 50 Hz) the line's phase
is the same in every record, its leakage repeats, and the records' spread
cannot see it: on a second, independent rig a 0.01 m/s² hum at 50 Hz put xdd/theta
100x off at 0.4 Hz (where the acceleration of a 0.05 V sweep is tiny) with a
stated error of 13 %.

Each candidate line (50 and 60 Hz and their harmonics below the Nyquist
frequency) is located on the whole signal's spectrum within ``SEARCH_HZ``
of its nominal frequency (mains drifts by up to 0.1 %), claimed when its power
stands ``MIN_PROMINENCE`` above the median of its neighbourhood (a sweep's
spectrum is smooth there; a line is not) while the excitation has no line there,
and subtracted as one sinusoid of constant amplitude and phase fitted by least
squares at that frequency. A subtraction that does not take at least 90 % of the
line's power away (the mains drifted during the file: one sinusoid cannot follow
it) is undone and said. A column on a lattice (an encoder, a converter) is left
as it is: it picked up no hum after its rounding, and subtracting one would
lose its lattice (samii.measure.floor)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft

__all__ = ["Line", "find_lines", "remove_lines", "MAINS_HZ"]

#: Mains frequencies whose lines (and harmonics) are looked for.
MAINS_HZ = (50.0, 60.0)
#: Harmonics of each mains frequency looked for.
HARMONICS = 5
#: A line is looked for within this of its nominal frequency [Hz] (mains is held to +-0.2 % in most grids).
SEARCH_HZ = 0.25
#: Neighbourhood [Hz] whose median power a line must stand above, and the factor (power, 30 dB).
NEIGHBOURHOOD_HZ = 2.0
MIN_PROMINENCE = 1e3


@dataclass(frozen=True)
class Line:
    """One spectral line found in a signal: its frequency [Hz] and amplitude (the signal's unit); ``removed``: the
    subtraction took at least 90 % of its power away."""

    freq_hz: float
    amplitude: float
    removed: bool = True


def _prominent(spec: np.ndarray, f: np.ndarray, i: int, n_s: float) -> bool:
    df = f[1]
    ring = (np.abs(f - f[i]) <= NEIGHBOURHOOD_HZ) & (np.abs(f - f[i]) > 10 * max(df, 1.0 / n_s))
    return bool(ring.any() and spec[i] >= MIN_PROMINENCE * np.median(spec[ring]))


def find_lines(x: np.ndarray, fs: float, excitation: np.ndarray | None = None) -> list[Line]:
    """The mains lines of ``x`` (module docstring), each with its frequency refined on the whole signal's spectrum;
    none where ``excitation`` (r) has a line of its own."""
    x = np.asarray(x, float)
    n = x.size
    if n < 16:
        return []
    nfft = scipy.fft.next_fast_len(2 * n, real=True)
    spec = np.abs(scipy.fft.rfft(x - x.mean(), nfft)) ** 2
    f = np.fft.rfftfreq(nfft, 1.0 / fs)
    spec_r = None
    if excitation is not None:
        e = np.asarray(excitation, float)
        spec_r = np.abs(scipy.fft.rfft(e - e.mean(), nfft)) ** 2
    df = f[1]
    out = []
    for base in MAINS_HZ:
        for k in range(1, HARMONICS + 1):
            nominal = k * base
            if nominal + NEIGHBOURHOOD_HZ >= 0.5 * fs:
                break
            near = np.abs(f - nominal) <= SEARCH_HZ
            if not near.any():
                continue
            i = int(np.flatnonzero(near)[np.argmax(spec[near])])
            if not _prominent(spec, f, i, n / fs):
                continue
            if spec_r is not None and _prominent(spec_r, f, int(np.flatnonzero(near)[np.argmax(spec_r[near])]), n / fs):
                continue  # the excitation's own line
            # refine between bins (parabola through the log power of the peak and its neighbours)
            a, b, c = np.log(spec[max(i - 1, 0)] + 1e-300), np.log(spec[i] + 1e-300), np.log(spec[min(i + 1, spec.size - 1)] + 1e-300)
            shift = 0.5 * (a - c) / (a - 2 * b + c) if (a - 2 * b + c) < 0 else 0.0
            freq = float(f[i] + np.clip(shift, -0.5, 0.5) * df)
            amp = _fit(x, fs, freq)[1]
            out.append(Line(freq, amp))
    return out


def _fit(x: np.ndarray, fs: float, freq_hz: float) -> tuple[np.ndarray, float]:
    """The least-squares sinusoid of ``x`` at ``freq_hz`` (with a constant), and its amplitude."""
    t = np.arange(x.size) / fs
    w = 2.0 * np.pi * freq_hz
    basis = np.stack([np.cos(w * t), np.sin(w * t), np.ones_like(t)], axis=1)
    coef, *_ = np.linalg.lstsq(basis, x, rcond=None)
    return basis[:, :2] @ coef[:2], float(np.hypot(coef[0], coef[1]))


def remove_lines(x: np.ndarray, fs: float, excitation: np.ndarray | None = None) -> tuple[np.ndarray, list[Line]]:
    """``x`` with its mains lines subtracted, and the lines (``removed`` False where one sinusoid could not take it
    away: that one is left in)."""
    lines = find_lines(x, fs, excitation)
    y = np.asarray(x, float).copy()
    nfft = scipy.fft.next_fast_len(2 * y.size, real=True)
    f = np.fft.rfftfreq(nfft, 1.0 / fs)
    out = []
    for line in lines:
        fitted, _ = _fit(y, fs, line.freq_hz)
        # what is left at the line, over a tenth of its power: the mains drifted (judged on the spectrum's peak)
        near = np.abs(f - line.freq_hz) <= SEARCH_HZ
        before_pk = np.max(np.abs(scipy.fft.rfft(y - y.mean(), nfft)[near]))
        after_pk = np.max(np.abs(scipy.fft.rfft(y - fitted - (y - fitted).mean(), nfft)[near]))
        if after_pk**2 <= 0.1 * before_pk**2:
            y = y - fitted
            out.append(line)
        else:
            out.append(Line(line.freq_hz, line.amplitude, removed=False))
    return y, out
