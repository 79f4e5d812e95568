"""When a fit of the battery is right (issue 32, item 1), shared by both draws.

A fit is right when wp, w1, wz and w3 are each within ``REL_TOL`` of the truth or within
``N_SE`` of the fit's own standard errors of it. Where it is not, it may still have said so:
every parameter it missed is named as not determined by the data, or the fit is not sound.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

KEYS = ("wp", "w1", "wz", "w3")
REL_TOL = 0.02
N_SE = 3.0


def judge(res, truth: Mapping[str, float]) -> tuple[bool, dict[str, tuple[float, float, bool]]]:
    """(right, {name: (relative error, error in standard errors, within either)})."""
    errs, ok = {}, True
    for k in KEYS:
        v, t, se = res.params[k], truth[k], res.stderr[k]
        n_se = abs(v - t) / se if np.isfinite(se) and se > 0 else np.inf
        good = bool(abs(v / t - 1) <= REL_TOL or n_se <= N_SE)
        errs[k] = (v / t - 1, n_se, good)
        ok &= good
    return ok, errs


def said(res, errs) -> bool:
    """The fit said not to use what missed: every parameter that missed is one it names as not
    determined by the data (``FitResult.undetermined``), or it is not a sound fit (none of its
    parameters to be used)."""
    return not res.sound or all(k in res.undetermined for k, (_, _, good) in errs.items() if not good)


def row(res, truth: Mapping[str, float], wall_s: float) -> dict:
    """One fit's line of a battery's table and JSON: right or not, said or not, each key's error, the verdict."""
    ok, errs = judge(res, truth)
    return {"ok": ok, "said": not ok and said(res, errs), "errs": errs, "sound": res.sound, "wall_s": wall_s, "cost": res.cost,
            "params_hz": {k: res.params[k] / 2 / np.pi for k in KEYS}, "truth_hz": {k: truth[k] / 2 / np.pi for k in KEYS},
            "concerns": list(res.concerns), "caveats": list(res.caveats), "undetermined": list(res.undetermined)}
