"""Profile intervals: how far a fitted parameter can move before the data object.

A standard error comes from the cost's curvature at the minimum; it describes the
parameter well only while the cost is quadratic in it over the interval it gives.
A mode where the data are near their noise (the simulator's mode 3 under a 0.1 V
sweep) or an actuator zero beside a shallow second dip is not: the cost is
flat, lopsided or has a second dip within a few standard errors, and the
normal interval ``value +- z SE`` misses the truth far more often than it says.
The profile answers the question directly. The parameter is held at values
stepped away from the estimate, every other parameter re-solved at each (the
solver continued from the neighbouring value), and the cost's rise is read as
a signed profile t statistic (Bates & Watts, *Nonlinear regression analysis
and its applications*, Wiley 1988, sec. 6.1; Venzon & Moolgavkar, Appl. Stat.
37(1) 1988):

    tau(v) = sign(v - v_hat) sqrt((S(v) - S_hat) / sigma2)

``sigma2`` is the cost's rise per squared standard error in the quadratic
limit, ``SE^2 / [(J'J)^-1]_kk`` (``samii.identify.fit`` computes it from the
same sandwich covariance as the standard errors, so that tau equals
``(v - v_hat) / SE`` where the cost is quadratic; with exact weights it is the
textbook ``s^2``). The interval at a level is where ``|tau|`` stays below the
normal quantile of that level, as ``FitResult.interval``'s normal one; it can
be lopsided, and where the scan reached the end of its range (half or twice
the estimate, a neighbouring mode, a bound) without the cost rising that far,
the interval is open on that side: the data do not bound the parameter there.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["Profile", "profile_scan", "interval_text", "TAU_STOP", "RANGE_FACTOR"]

#: A side of a scan stops once |tau| has passed this on two successive values (two, so that one value
#: the solver failed on does not end it): intervals up to this many standard errors are read off, and a
#: second dip of the cost behind a hump lower than this is found; one behind a higher hump is not
#: looked for (finding other minima is the starts' work: ``fit``'s mode scan and perturbed starts).
TAU_STOP = 5.0
#: A scan spans at most this factor either side of the estimate (a mode frequency, wp, a zero).
RANGE_FACTOR = 2.0
#: Steps in ln(value): the first half the relative standard error, each next one aimed at a change of
#: TAU_STEP in |tau| (at most doubling or halving), within these bounds.
STEP_MIN, STEP_MAX = 1e-5, 0.08
#: The quadratic check that comes first: where |tau| at each of PROBE_SE standard errors either side of
#: the estimate is that many within QUADRATIC_TOL (relative), the cost is quadratic over every interval
#: up to the last and those values are the profile (four solves, not a scan). Two distances, so that a
#: second dip of the cost behind a hump within them is seen (one at 4 alone passed a dip 7 SE out).
PROBE_SE = (3.0, 6.0)
QUADRATIC_TOL = 0.1
TAU_STEP = 1.0


@dataclass(frozen=True, eq=False)
class Profile:
    """The profile of one parameter: the values held, the cost's rise at each as a signed t statistic.

    ``values`` ascending, the estimate among them (``tau`` 0); ``tau`` is NaN where the solver
    found no finite answer. ``lowest`` is the lowest cost the
    scan found relative to the estimate's, in units of ``sigma2`` (0 when the estimate is the
    lowest; a negative value means the fit's minimum is not the lowest along this parameter),
    found at ``lowest_at``. A side of a scan ends where ``|tau|`` has passed ``TAU_STOP`` or at the
    end of its range (``profile_scan``), so an interval reaching ``values[0]`` or ``values[-1]`` is
    open there: the data do not bound the parameter on that side within the range.
    """

    name: str
    value: float
    values: np.ndarray
    tau: np.ndarray
    lowest: float
    lowest_at: float

    def __post_init__(self) -> None:
        for a in ("values", "tau"):
            v = np.array(getattr(self, a), float)
            v.setflags(write=False)
            object.__setattr__(self, a, v)

    def interval(self, level: float = 0.95) -> tuple[float, float]:
        """``(lo, hi)``: the outermost values where ``|tau|`` is within the normal quantile of ``level``,
        each end interpolated linearly to where ``|tau|`` crosses it; an open side ends at
        the scan's end (``bounded`` says which sides are)."""
        from scipy.stats import norm  # (lazy: imports scipy, only when called)

        z = float(norm.ppf(0.5 + level / 2))
        t = np.abs(np.where(np.isfinite(self.tau), self.tau, np.inf))
        inside = np.flatnonzero(t <= z)
        i, j = int(inside[0]), int(inside[-1])
        return self._cross(i, i - 1, z), self._cross(j, j + 1, z)

    def bounded(self, level: float = 0.95) -> tuple[bool, bool]:
        """Whether the data bound the interval of ``level`` below and above (False: it reaches the scan's end)."""
        lo, hi = self.interval(level)
        t = np.abs(self.tau)
        return bool(lo > self.values[0] or t[0] > TAU_STOP), bool(hi < self.values[-1] or t[-1] > TAU_STOP)

    def _cross(self, inside: int, outside: int, z: float) -> float:
        if not 0 <= outside < self.values.size:
            return float(self.values[inside])
        ta, tb = abs(self.tau[inside]), abs(self.tau[outside])
        va, vb = self.values[inside], self.values[outside]
        if not np.isfinite(tb):
            return float(va)  # a failed value outside: the interval ends at the last value that was solved
        return float(va + (vb - va) * (z - ta) / (tb - ta))  # tau is linear in the value where the cost is quadratic

    def to_dict(self, levels: tuple[float, ...] = (0.95,)) -> dict:
        out: dict = {"value": float(self.value)}
        for lv in levels:
            lo, hi = self.interval(lv)
            blo, bhi = self.bounded(lv)
            out[f"{100 * lv:g}%"] = {"low": lo, "high": hi, "bounded_low": blo, "bounded_high": bhi}
        out["lowest_tau2"] = float(self.lowest)
        return out


def interval_text(low: float | None, high: float | None, fmt: str = ".4g") -> str:
    """An interval as shown to a user: "lo–hi", "≥ lo" or "≤ hi" where a side is open (None: the data
    do not bound it there), "not bounded" where both are."""
    if low is not None and high is not None:
        return f"{low:{fmt}}–{high:{fmt}}"
    if low is None and high is None:
        return "not bounded"
    return f"≥ {low:{fmt}}" if low is not None else f"≤ {high:{fmt}}"


def profile_scan(
    name: str,
    x_hat: np.ndarray,
    index: int,
    cost_hat: float,
    sigma2: float,
    stderr: float,
    solve: Callable[[np.ndarray], tuple[np.ndarray, float]],
    limits: Callable[[np.ndarray], tuple[float, float]],
) -> Profile:
    """Profile parameter ``index`` (positive) of the minimum ``x_hat``.

    ``solve(x0) -> (x, cost)`` re-solves every other parameter with ``x0[index]`` held;
    ``limits(x) -> (lo, hi)`` the open range the held value may take beside a solution ``x``
    (its neighbouring modes, the solver's bounds). Where the standard error is finite and
    below a sixth of the value, the cost is first solved ``PROBE_SE`` standard errors either side:
    where ``|tau|`` is that many there within ``QUADRATIC_TOL`` the cost is quadratic and those
    are the profile (a second dip of the cost beyond them is not looked for: finding other minima is
    the starts' work). Otherwise each side is scanned, continued from the last solution
    out to ``RANGE_FACTOR`` or the limits: in steps of ln(value) of ``clip(SE / 2 / value,
    STEP_MIN, STEP_MAX)`` first, each next aimed at a rise of ``TAU_STEP`` in ``|tau|``; once
    ``|tau|`` has passed ``TAU_STOP`` twice running, the side ends there.
    """
    v_hat = float(x_hat[index])
    rel = stderr / v_hat if np.isfinite(stderr) and stderr > 0 else STEP_MAX
    h = float(np.clip(rel / 2, STEP_MIN, STEP_MAX))
    points = [(v_hat, 0.0)]
    lowest, lowest_at = 0.0, v_hat
    if rel < 1 / max(PROBE_SE):  # first the quadratic check: the cost PROBE_SE standard errors either side
        lo, hi = limits(x_hat)
        probes = [(d, n, v_hat + d * n * stderr) for d in (-1, 1) for n in PROBE_SE]
        if all(lo < v < hi for *_, v in probes):
            taus, x_prev = [], x_hat
            for d, n, v in probes:  # each side outward, continued from the nearer probe
                x0 = np.array(x_hat if n == PROBE_SE[0] else x_prev, float)
                x0[index] = v
                x_prev, c = solve(x0)
                t2 = (c - cost_hat) / sigma2
                taus.append(d * np.sqrt(max(t2, 0.0)) if np.isfinite(t2) else np.nan)
            points += [(v, t) for (*_, v), t in zip(probes, taus)]
            if all(abs(t / (d * n) - 1) <= QUADRATIC_TOL for (d, n, _), t in zip(probes, taus)):
                points.sort()
                vals, tau = (np.array(c, float) for c in zip(*points))
                return Profile(name, v_hat, vals, tau, lowest=0.0, lowest_at=v_hat)
    for d in (-1, 1):
        x_prev, v, above, step, t_prev = np.array(x_hat, float), v_hat, 0, h, 0.0
        end = v_hat * RANGE_FACTOR**d
        while above < 2:
            lo, hi = limits(x_prev)
            edge = min(end, hi * (1 - 1e-6)) if d > 0 else max(end, lo * (1 + 1e-6))
            if d * (edge - v) <= 0:  # the last value was the range's end
                break
            v_next = v * np.exp(d * step)
            v_next = edge if d * (v_next - edge) > 0 else v_next  # the last step lands on the end
            x0 = x_prev.copy()
            x0[index] = v_next
            x_new, c = solve(x0)
            t2 = (c - cost_hat) / sigma2 if np.isfinite(c) else np.nan
            points.append((v_next, d * np.sqrt(max(t2, 0.0)) if np.isfinite(t2) else np.nan))
            v = v_next
            above = above + 1 if not np.isfinite(t2) or t2 > TAU_STOP**2 else 0
            if np.isfinite(t2):
                x_prev = x_new
                if t2 < lowest:
                    lowest, lowest_at = t2, v_next
                # the next step aims at a change of TAU_STEP in |tau| (signed below the estimate's cost, so that a
                # lower dip is stepped through as finely as a rise), changing by at most a factor 2
                t = np.sign(t2) * np.sqrt(abs(t2))
                step = float(np.clip(step * TAU_STEP / max(abs(t - t_prev), 1e-3), step / 2, 2 * step))
                step, t_prev = float(np.clip(step, STEP_MIN, STEP_MAX)), t
    points.sort()
    vals, tau = (np.array(c, float) for c in zip(*points))
    return Profile(name, v_hat, vals, tau, lowest=float(lowest), lowest_at=float(lowest_at))
