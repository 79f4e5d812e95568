"""Sensor drift: a slow change of the level a signal rests at, from record to record, read off the records' rests.

A repeated excitation from rest to rest (samii measure's sweeps) brings the arm
back to the same rest after every record, so each rest of a channel has the same
level, save for noise. A sensor whose bias drifts (an accelerometer or its charge
amplifier warming up, an encoder's reference slipping) moves that level from
rest to rest, and within a record the drift is a ramp. A ramp's spectrum falls
as 1/f and is the same in every record of a steady drift: with records of one
sign it biases the low end of the band, where the records' spread does not see
it; a sign-alternating sweep's weights (1/4, -1/2, 1/4) cancel it from the
estimate but not from each record's deviation, and the spread the tests weigh by
grows. On a second, independent rig, 2e-5 rad/s on theta and 1e-3 m/s^2 per s
on the accelerometer (1.7 mrad and 0.084 m/s^2 per 84 s record) raised
xdd/theta's variance 2.3e3-fold at 0.1 Hz and changed the diagnosis without a word.

The drift is read where the arm is still: the operating point at the first
record's start and the last part of every record's closing rest (the sweep's
ringing has died away there), one level per rest, and the curve through them is
a not-a-knot cubic spline (a line through two levels, the parabola through
three), continued past the ends by its end pieces. Nothing of the response
enters, so records of either sign need no care. On the second rig's files
(samii's experiments/diagnose_battery) a ramp of 0.02 m/s^2 and a 0.005 Hz sine
drift of 0.02 m/s^2 are taken out to within 0.1 of the noise's variance; a
quadratic through the same levels left the sine's 48x. Records that do not rest
(back-to-back sweeps, a periodic excitation) give none: their means hold the
response's own mean (of either sign) and the first record lacks the tail the
others inherit, and a drift read off them turned a clean file's xdd/theta from
0.05 to 7 times its noise's variance there.
"""

from __future__ import annotations

import numpy as np
from scipy import stats
from scipy.interpolate import CubicSpline

__all__ = ["drift_from_rests"]


#: Levels that differ by less than this fraction of the signal's swing give no drift: a 16-bit converter's count over
#: that swing. (A noise-free simulation's rests differ by the sweep's last ringing, 1e-8 m/s^2 of a 1 m/s^2 swing,
#: which moved its weak xdd/theta at 0.1 Hz by 2 standard errors of its floor.)
RESOLUTION = 2.0**-16


def drift_from_rests(x: np.ndarray, windows: np.ndarray, *, alpha: float = 1e-3) -> np.ndarray | None:
    """The drift of ``x`` at every sample read off its rests (module docstring): ``windows`` (k, 2) sample ranges
    [start, stop) where the arm is at rest, in time order; the curve through their mean levels, zero at the first
    window's centre. None with fewer than two, or where the levels agree to within their noise at ``alpha`` (the
    scatter of each rest's quarter means: chi-square over the levels' spread about their mean): a curve through
    levels that differ by noise alone would add that noise to every record."""
    x = np.asarray(x, float)
    windows = np.asarray(windows, int).reshape(-1, 2)
    windows = windows[(windows[:, 1] > windows[:, 0]) & (windows[:, 0] >= 0) & (windows[:, 1] <= x.size)]
    if windows.shape[0] < 2:
        return None
    levels = np.array([x[a:b].mean() for a, b in windows])
    if np.ptp(levels) <= RESOLUTION * np.ptp(x):
        return None  # less than a 16-bit converter's count across the signal's swing: no rig could measure it
    # the noise of a level: the scatter of each rest's quarters (what varies within a rest, slow noise included)
    quarters = [np.array([q.mean() for q in np.array_split(x[a:b], 4)]) for a, b in windows if b - a >= 8]
    if not quarters:
        return None
    se2 = float(np.mean([np.var(q, ddof=1) for q in quarters])) / 4.0
    spread = float(np.sum((levels - levels.mean()) ** 2))
    if se2 > 0 and spread <= se2 * stats.chi2.isf(alpha, levels.size - 1):
        return None  # the rests agree to within their noise: no drift the data show
    centres = (windows[:, 0] + windows[:, 1] - 1) / 2.0
    scale = float(max(centres[-1] - centres[0], 1.0))
    u = (centres - centres[0]) / scale
    k = (np.arange(x.size, dtype=float) - centres[0]) / scale
    if u.size == 2:
        return (levels[1] - levels[0]) * k
    return CubicSpline(u, levels, bc_type="not-a-knot", extrapolate=True)(k) - levels[0]
