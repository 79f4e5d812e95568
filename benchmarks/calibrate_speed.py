"""samii calibrate: six physical parameters from FRF data, timed in one run.

Goal (issue 8): 6 parameters calibrated in under 30 s on 2 cores. The baseline
measured in the same run is one evaluation of the simulator's FRF (write the MJCF,
compile, static equilibrium, linearise, FRF at the data's points), the unit
every solver iteration is made of (2 n + 1 = 13 of them per Jacobian).

Scenario: the FRF the simulator gives with six knobs off by +-20 % (clamp
stiffness, joint-1 stiffness, Maxwell-arm stiffness, joint-1 damping, oil
volume, leakage), 3-average swept-sine noise (samii.identify.synthetic),
0.3-35 Hz at 100 points per decade; calibrated from the embedded model with
the coherence weighting. Times are medians of ``REPEATS`` runs.

Run::

    python benchmarks/calibrate_speed.py
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small dense problems: threads only add contention

import statistics
import time

import numpy as np

from samii.calibrate import MODE_KNOBS, calibrate
from samii.calibrate.simulator import SimulatorFRF, parameter_value
from samii.identify.synthetic import SweptSineNoise, synthesize
from samii.measure.frf import log_frequency_grid
from samii.sim.model import default_params

SIX = MODE_KNOBS
REPEATS = 3
GOAL_S = 30.0


def main() -> None:
    base = default_params()
    sim = SimulatorFRF(base, SIX)
    x0 = np.array([parameter_value(base, n) for n in SIX])
    truth = x0 * np.array([1.2, 0.8, 1.2, 0.8, 1.2, 0.8])
    f = log_frequency_grid(0.3, 35.0, 100)
    exact = sim.frf(truth, f)
    data = synthesize(f, {"act": exact.act, "base": exact.base}, noise=SweptSineNoise(), rng=np.random.default_rng(1))

    evals = []
    for k in range(20):
        x = x0 * (1 + 1e-3 * (k + 1))  # a fresh point each time (no cache hit)
        t = time.perf_counter()
        SimulatorFRF(base, SIX).frf(x, f)
        evals.append(time.perf_counter() - t)
    t_eval = statistics.median(evals)

    times, results = [], []
    for _ in range(REPEATS):
        t = time.perf_counter()
        res = calibrate(data, SIX, weighting="coherence")
        times.append(time.perf_counter() - t)
        results.append(res)
    t_cal = statistics.median(times)
    res = results[-1]
    err = max(abs(res.values[n] / v - 1) for n, v in zip(SIX, truth))
    print(f"one simulator FRF evaluation ({f.size} points): {1e3 * t_eval:.1f} ms (median of {len(evals)})")
    print(
        f"calibrate, 6 parameters from 20 % off: {t_cal:.2f} s (median of {REPEATS}); {res.nfev} iterations; = {t_cal / t_eval:.0f} evaluations' time"
    )
    print(f"largest parameter error against the truth: {100 * err:.2f} % (noisy data); converged {res.converged}")
    print(f"goal < {GOAL_S:g} s: {'met' if t_cal < GOAL_S else 'NOT met'} ({t_cal / GOAL_S:.2f} of the budget)")


if __name__ == "__main__":
    main()
