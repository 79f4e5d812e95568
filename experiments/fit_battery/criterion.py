"""When a fit of the battery is right (issue 32, item 1), shared by both draws.

A fit is right when wp, w1, wz and w3 are each within ``REL_TOL`` of the truth or within
``N_SE`` standard errors of it: inside the fit's own profile interval at that level
(``FitResult.profiles``: lopsided where the cost is, unbounded on a side the data do not
bound), or ``N_SE`` standard errors either side where a parameter was not profiled. Where it
is not, it may still have said so: every parameter it missed is named as not determined by the
data, or the fit is not sound.
"""

from __future__ import annotations

from collections.abc import Mapping
from math import erf

import numpy as np

KEYS = ("wp", "w1", "wz", "w3")
REL_TOL = 0.02
N_SE = 3.0


#: The level of an N_SE interval, erf(N_SE / sqrt(2)).
LEVEL = float(erf(N_SE / np.sqrt(2)))


def within_interval(res, k: str, t: float, level: float = LEVEL) -> bool:
    """``t`` inside ``res``'s interval of ``k`` at ``level`` (``FitResult.interval``: its profile's where
    profiled, a side the data do not bound taken as unbounded; a parameter with no finite standard error
    and no profile holds nothing)."""
    if k not in res.profiles and not (np.isfinite(res.stderr[k]) and res.stderr[k] > 0):
        return False
    lo, hi = res.interval(k, level)
    blo, bhi = res.profiles[k].bounded(level) if k in res.profiles else (True, True)
    return bool((t >= lo or not blo) and (t <= hi or not bhi))


def judge(res, truth: Mapping[str, float]) -> tuple[bool, dict[str, tuple[float, float, bool]]]:
    """(right, {name: (relative error, error in standard errors, within either)})."""
    errs, ok = {}, True
    for k in KEYS:
        v, t, se = res.params[k], truth[k], res.stderr[k]
        n_se = abs(v - t) / se if np.isfinite(se) and se > 0 else np.inf
        good = bool(abs(v / t - 1) <= REL_TOL or within_interval(res, k, t))
        errs[k] = (v / t - 1, n_se, good)
        ok &= good
    return ok, errs


def said(res, errs) -> bool:
    """The fit said not to use what missed: every parameter that missed is one it names as not
    determined by the data (``FitResult.undetermined``), or it is not a sound fit (none of its
    parameters to be used)."""
    return not res.sound or all(k in res.undetermined for k, (_, _, good) in errs.items() if not good)


def row(res, truth: Mapping[str, float], wall_s: float) -> dict:
    """One fit's line of a battery's table and JSON: right or not, said or not, each key's error, the verdict,
    and whether its 95 % interval holds the truth (``covered_95``: the interval's calibration on rigs it was
    not built on; about 95 % of them should)."""
    ok, errs = judge(res, truth)
    covered = {k: within_interval(res, k, truth[k], 0.95) for k in KEYS}
    # the stricter reading, for comparison: within REL_TOL or N_SE local standard errors (value +- N_SE SE)
    local = all(abs(e) <= REL_TOL or n <= N_SE for e, n, _ in errs.values())
    return {
        "ok": ok,
        "ok_local": bool(local),
        "said": not ok and said(res, errs),
        "errs": errs,
        "sound": res.sound,
        "wall_s": wall_s,
        "cost": res.cost,
        "params_hz": {k: res.params[k] / 2 / np.pi for k in KEYS},
        "truth_hz": {k: truth[k] / 2 / np.pi for k in KEYS},
        "covered_95": covered,
        "concerns": [c.text for c in res.concerns],
        "caveats": [c.text for c in res.caveats],
        "undetermined": list(res.undetermined),
    }


def coverage_line(rows: list[dict]) -> str:
    """How often the 95 % intervals held the truth, per parameter, over the rows of sound fits."""
    sound = [r for r in rows if r["sound"]]
    cells = [f"{k} {sum(r['covered_95'][k] for r in sound)}/{len(sound)}" for k in KEYS]
    return f"95 % intervals holding the truth (sound fits): {', '.join(cells)}"
