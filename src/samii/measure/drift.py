"""Sensor drift: a slow change of a signal's level from record to record, estimated from the records' means.

A repeated excitation gives the same response in every record (a sweep from rest
to rest, or a periodic one in steady state), so each record of a channel has the
same mean, save for noise. A sensor whose bias drifts (an accelerometer or its
charge amplifier warming up, an encoder's reference slipping) moves the means
from record to record, and within a record the drift is a ramp. A ramp's
spectrum falls as 1/f and is the same in every record of a steady drift: with
records of one sign it biases the low end of the band, where the records' spread
does not see it; a sign-alternating sweep's weights (1/4, -1/2, 1/4) cancel it
from the estimate but not from each record's deviation, and the spread the tests
weigh by grows. On a second, independent rig, 2e-5 rad/s on theta and 1e-3 m/s^2
per s on the accelerometer (1.7 mrad and 0.084 m/s^2 per 84 s record) raised
xdd/theta's variance 2.3e3-fold at 0.1 Hz and changed the diagnosis without a word.

Where the records rest (a sweep from rest to rest, as samii measure makes it),
the drift is read where the arm is still: the operating point at the first
record's start and the last part of every record's closing rest (the sweep's
ringing has died away there), a level per rest; the curve is the least-squares
polynomial through those levels, quadratic from three rests on (a warm-up's
bend), linear through two. Nothing of the response enters: a sign-alternating
sweep's records, whose responses have means of opposite signs, need no care.

Where they do not rest (back-to-back sweeps, a periodic excitation), the records'
means ``m_k`` at their centres ``t_k`` are modelled by least squares::

    m_k = a + mu s_k + b t_k (+ c t_k^2)

``a`` the operating point; ``mu s_k`` the response's own mean, which changes sign
with a record's excitation (``s_k`` = +-1; left out when all records have one
sign); ``b t + c t^2`` the drift, quadratic where the records leave a degree of
freedom for it. The first record, which inherits no tail from a record before
it, is left out.

Either is exact for a linear (or quadratic, where fitted) drift and leaves the
repeated response untouched. A drift that bends faster than a quadratic over the
file keeps part of its bend: on a drawn rig with three 84 s records an
accelerometer warming by 0.1 m/s^2 with a 5 min time constant, beside theta
drifting 2e-5 rad/s, leaves an estimate that errs from the noise-free one as its
stated noise says (chi2 per point 0.95-1.26 on three drawn rigs, as without the drift). Records too few to tell a drift
from the response (one record without rests; two back-to-back of opposite signs)
give none.
"""

from __future__ import annotations

import numpy as np

__all__ = ["record_means", "drift_curve", "drift_from_rests"]


def record_means(x: np.ndarray, starts: np.ndarray, n: int) -> np.ndarray:
    """Mean of ``x`` over each record of ``n`` samples starting at the sample indices ``starts``."""
    x = np.asarray(x, float)
    return np.array([x[s : s + n].mean() for s in np.asarray(starts, int)])


def drift_curve(x: np.ndarray, starts: np.ndarray, n: int, *, signs=None, rests: bool = True) -> np.ndarray | None:
    """The drift of ``x`` at every sample (module docstring), zero at the first record's centre; None where the records
    cannot tell one from the response.

    ``starts`` are the records' first samples, ``n`` their length in samples, ``signs`` each record's excitation sign
    (+1/-1; default all +1), ``rests``: the records start from rest (else the first, which inherits no tail, is left
    out)."""
    starts = np.asarray(starts, int)
    s = np.ones(starts.size) if signs is None else np.asarray(signs, float).ravel()
    if s.size != starts.size:
        raise ValueError(f"{s.size} record signs for {starts.size} records")
    means = record_means(x, starts, n)
    centres = starts + (n - 1) / 2.0
    use = slice(0, None) if rests else slice(1, None)
    m, t, s = means[use], centres[use], s[use]
    scale = float(n)  # time in records, about the first record used: a well-conditioned design
    t0 = t[0] if t.size else 0.0
    base = [np.ones_like(t)] + ([s] if np.unique(s).size > 1 else [])
    if t.size < len(base) + 1:
        return None
    cols = base + [(t - t0) / scale] + ([((t - t0) / scale) ** 2] if t.size >= len(base) + 2 else [])
    coef, *_ = np.linalg.lstsq(np.column_stack(cols), m, rcond=None)
    drift = coef[len(base) :]
    k = (np.arange(np.asarray(x).size, dtype=float) - centres[0]) / scale
    k0 = (t0 - centres[0]) / scale
    curve = sum(c * ((k - k0) ** (p + 1) - (-k0) ** (p + 1)) for p, c in enumerate(drift))
    return np.asarray(curve, float)


def drift_from_rests(x: np.ndarray, windows: np.ndarray) -> np.ndarray | None:
    """The drift of ``x`` at every sample read off its rests (module docstring): ``windows`` (k, 2) sample ranges
    [start, stop) where the arm is at rest, in time order; the least-squares polynomial through their mean levels
    (quadratic from three on, linear through two), zero at the first window's centre. None with fewer than two."""
    x = np.asarray(x, float)
    windows = np.asarray(windows, int).reshape(-1, 2)
    windows = windows[(windows[:, 1] > windows[:, 0]) & (windows[:, 0] >= 0) & (windows[:, 1] <= x.size)]
    if windows.shape[0] < 2:
        return None
    levels = np.array([x[a:b].mean() for a, b in windows])
    centres = (windows[:, 0] + windows[:, 1] - 1) / 2.0
    scale = float(max(centres[-1] - centres[0], 1.0))
    u = (centres - centres[0]) / scale
    degree = 2 if u.size >= 3 else 1
    coef = np.polynomial.polynomial.polyfit(u, levels, degree)
    k = (np.arange(x.size, dtype=float) - centres[0]) / scale
    return np.polynomial.polynomial.polyval(k, coef) - coef[0]
