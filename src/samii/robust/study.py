"""A robustness study's statistics: from the samples' results to what a person reads.

* the probability of instability with its exact (Clopper-Pearson) 95 % interval;
* percentiles (5, 50, 95) of the closed-loop damping (the least-damped mode's damping ratio,
  negative for a growing mode) and of the base's settling time (stable samples);
* the worst samples with their parameters (unstable first, by growth rate, then by damping);
* each varied parameter's influence: Spearman's rank correlation with the closed-loop damping over
  every sample (an unstable one enters with its negative damping), ranked by its magnitude.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from samii.robust.sampling import PlantDraws
from samii.robust.task import SampleResult

__all__ = ["StudySummary", "summarise", "PERCENTILES"]

PERCENTILES = (5, 50, 95)
N_WORST = 5


@dataclass(frozen=True)
class StudySummary:
    n: int  #: plants run (the valid ones)
    n_invalid: int  #: plants drawn that could not be built (no static equilibrium, a mode too stiff for the step): not in n
    n_unstable: int
    p_unstable: float
    p_unstable_ci95: tuple[float, float]
    zeta_percentiles: dict[int, float] | None
    settle_percentiles: dict[int, float] | None
    n_zeta: int  #: samples whose damping could be measured
    worst: list[dict]
    influence: list[dict]  #: [{"name", "spearman", "p_value"}], strongest first

    def as_json(self) -> dict:
        return {"n_samples": self.n, "n_invalid": self.n_invalid, "n_unstable": self.n_unstable, "p_unstable": self.p_unstable, "p_unstable_ci95": list(self.p_unstable_ci95),
                "zeta_percentiles": {str(k): v for k, v in (self.zeta_percentiles or {}).items()} or None, "n_zeta": self.n_zeta,
                "base_settle_s_percentiles": {str(k): v for k, v in (self.settle_percentiles or {}).items()} or None,
                "worst": self.worst, "influence": self.influence}  # fmt: skip


def _pct(x: list[float]) -> dict[int, float] | None:
    return {p: float(np.percentile(x, p)) for p in PERCENTILES} if x else None


def summarise(draws: PlantDraws, results: list[SampleResult]) -> StudySummary:
    from scipy import stats  # (lazy: imports scipy, only when called)

    invalid = [r for r in results if not r.valid]
    results = [r for r in results if r.valid]
    n = len(results)
    unstable = [r for r in results if not r.stable]
    k = len(unstable)
    ci = stats.binomtest(k, n).proportion_ci(confidence_level=0.95, method="exact") if n else None
    zeta = [r.zeta for r in results if r.zeta is not None]
    settle = [r.base_settle_s for r in results if r.stable and r.base_settle_s is not None]

    def badness(r: SampleResult) -> tuple:
        if not r.stable:
            return (0, -(r.growth_rate_1_s if r.growth_rate_1_s is not None else math.inf))
        return (1, r.zeta if r.zeta is not None else math.inf)

    worst = []
    for r in sorted(results, key=badness)[:N_WORST]:
        row = r.table_row()
        row["params"] = draws.overrides(r.index)
        row["params_rel_pct"] = {
            nm: 100.0 * (v / nom - 1.0) if nom else None for nm, v, nom in zip(draws.names, draws.values[r.index], draws.nominal)
        }
        worst.append(row)

    influence = []
    have = [r for r in results if r.zeta is not None]
    if len(have) >= 5:
        z = np.array([r.zeta for r in have])
        for j, name in enumerate(draws.names):
            x = draws.values[[r.index for r in have], j]
            if np.ptp(x) == 0 or np.ptp(z) == 0:
                rho, p = 0.0, 1.0
            else:
                res = stats.spearmanr(x, z)
                rho, p = float(res.statistic), float(res.pvalue)
            influence.append({"name": name, "spearman": rho, "p_value": p})
        influence.sort(key=lambda d: -abs(d["spearman"]))
    return StudySummary(n, len(invalid), k, k / n if n else math.nan, (float(ci.low), float(ci.high)) if ci else (math.nan, math.nan), _pct(zeta), _pct(settle),
                        len(zeta), worst, influence)  # fmt: skip
