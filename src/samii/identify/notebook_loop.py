"""The notebook's own fitting procedure: fminsearch looped, with its percent-change test.

Chapter 9: "Curve fit set to loop 20 times. Each loop runs the Matlab
optimization for a maximum of 500 iterations. The Krauss convergence criteria
was set to a maximum percent change in any coefficient of 0.01 and an error
function maximum percent change of 0.01. These criteria needed to be met for 5
consecutive loops." fminsearch is Nelder-Mead; scipy's implementation uses the
same initial simplex (5 % of each nonzero coefficient) and the same default
tolerances (TolX = TolFun = 1e-4, absolute) as MATLAB's.

Kept as the baseline of ``benchmarks/fit_speed.py``, and ``percent_change`` as
the comparison criterion every samii fit reports.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["PercentChange", "percent_change", "LoopResult", "nelder_mead_loop"]

#: "maximum percent change in any coefficient of 0.01 and an error function maximum percent change of 0.01" (chapter 9)
NOTEBOOK_TOL_PCT = 0.01


@dataclass(frozen=True)
class PercentChange:
    """The notebook's convergence test between two successive iterates (or loop ends).

    ``cost_at_floor``: the newer cost is at rounding level (an exact fit to exact
    data), where a percent change of the cost means nothing and is not tested.
    """

    max_param_pct: float
    cost_pct: float
    tol_pct: float = NOTEBOOK_TOL_PCT
    cost_at_floor: bool = False

    @property
    def met(self) -> bool:
        return bool(self.max_param_pct < self.tol_pct and (abs(self.cost_pct) < self.tol_pct or self.cost_at_floor))

    def describe(self) -> str:
        verdict = "met" if self.met else "not met"
        floor = ", the cost at rounding level" if self.cost_at_floor else ""
        return f"notebook criterion {verdict} (max |change| of a coefficient {self.max_param_pct:.2g} %, of the cost {self.cost_pct:.2g} %{floor}; limit {self.tol_pct} %)"


def percent_change(
    x_old: np.ndarray, x_new: np.ndarray, cost_old: float, cost_new: float, *, tol_pct: float = NOTEBOOK_TOL_PCT, cost_floor: float = 0.0
) -> PercentChange:
    """100 (new - old) / old for every coefficient (largest magnitude kept) and for the cost.

    A new cost at or below ``cost_floor`` marks an exact fit (see ``PercentChange``).
    """
    x_old, x_new = np.asarray(x_old, float), np.asarray(x_new, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        px = np.where(x_old != 0, 100.0 * (x_new - x_old) / np.abs(x_old), np.where(x_new == x_old, 0.0, np.inf))
        pc = 100.0 * (cost_new - cost_old) / abs(cost_old) if cost_old != 0 else (0.0 if cost_new == cost_old else np.inf)
    return PercentChange(float(np.max(np.abs(px))), float(pc), tol_pct, bool(abs(cost_new) <= cost_floor))


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class LoopResult:
    """Outcome of ``nelder_mead_loop``."""

    x: np.ndarray
    cost: float
    loops: int
    criterion_met: bool
    nfev: int
    last_change: PercentChange | None


def nelder_mead_loop(
    cost: Callable[[np.ndarray], float],
    x0: np.ndarray,
    *,
    loops: int = 20,
    maxiter: int = 500,
    consecutive: int = 5,
    tol_pct: float = NOTEBOOK_TOL_PCT,
) -> LoopResult:
    """Restart Nelder-Mead up to ``loops`` times (``maxiter`` iterations each) until the
    percent-change criterion has held for ``consecutive`` successive loops.
    """
    from scipy.optimize import minimize  # (lazy: imports scipy, only when called)

    x = np.asarray(x0, float)
    c = float(cost(x))
    streak, nfev, change = 0, 0, None
    for k in range(1, loops + 1):
        res = minimize(cost, x, method="Nelder-Mead", options={"maxiter": maxiter, "xatol": 1e-4, "fatol": 1e-4})
        nfev += int(res.nfev)
        change = percent_change(x, res.x, c, float(res.fun), tol_pct=tol_pct)
        x, c = np.asarray(res.x, float), float(res.fun)
        streak = streak + 1 if change.met else 0
        if streak >= consecutive:
            return LoopResult(x, c, k, True, nfev, change)
    return LoopResult(x, c, loops, False, nfev, change)
