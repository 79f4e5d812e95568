"""samii's Bode fit against the notebook's procedure, in one run.

The notebook (chapter 9) minimised its cost with fminsearch (Nelder-Mead),
"looped 20 times, each loop ... a maximum of 500 iterations", stopping when
every coefficient and the cost changed by less than 0.01 % for 5 consecutive
loops. ``samii.identify.notebook_loop.nelder_mead_loop`` does exactly that
with scipy's Nelder-Mead (same initial simplex and tolerances as MATLAB's).

Both minimise the same cost (``FitProblem.cost``: dB^2 + (pw deg)^2 over
theta/v and xdd/theta) from the same start; printed: wall time of each, the
ratio, and the final cost of each. Goal (issue 5): samii >= 100x faster at
equal or lower cost.

Scenarios (3-mode s^4 model, phase weight 0.1, 400 log-spaced points 0.1-40 Hz):

* ``eq9_4_noisy``: data synthesised from eq 9.4 with 3-average swept-sine
  noise; start: every parameter 30 % off (seeded signs).
* ``rig_notebook_start``: the studies' stand-in rig data (eq 9.4 plus
  unmodelled effects and noise); start: the notebook start (eq 9.4
  frequencies and dampings, gains read off the data).

BLAS is limited to one thread before numpy loads: on these small dense
problems threads only add contention (the machine is shared), and both
methods run under the same setting. samii's time is the median of repeats;
Nelder-Mead's one run (it is deterministic). Run::

    PYTHONPATH=src python benchmarks/fit_speed.py
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import time  # noqa: E402

import numpy as np  # noqa: E402

from samii import notebook as nb  # noqa: E402
from samii.identify import FitProblem, ModelStructure, SweptSineNoise, fit, synthesize  # noqa: E402
from samii.identify.notebook_loop import nelder_mead_loop  # noqa: E402
from samii.identify.starts import notebook_start  # noqa: E402
from samii.identify.studies import synthetic_rig_frf  # noqa: E402

F_HZ = np.geomspace(0.1, 40.0, 400)
PW = 0.1  # the notebook's chosen weight (eq 9.4)
REPEATS = 5


def scenarios():
    st = ModelStructure.notebook_3mode()
    data = synthesize(F_HZ, {c: st.response(nb.EQ9_4, F_HZ, c) for c in ("act", "base")}, noise=SweptSineNoise(), rng=np.random.default_rng(2003))
    rng = np.random.default_rng(1)
    off = {k: nb.EQ9_4[k] * (1 + 0.3 * rng.choice([-1.0, 1.0])) for k in st.param_names}
    yield "eq9_4_noisy", data, st, off
    rig = synthetic_rig_frf(F_HZ, rng=np.random.default_rng(2003))
    yield "rig_notebook_start", rig, st, notebook_start(FitProblem(rig, st, phase_weight=PW))


def main() -> None:
    print(f"{'scenario':<20} {'NM loop [s]':>11} {'NM cost':>12} {'loops':>5} {'crit':>5} {'samii [s]':>10} {'samii cost':>12} {'ratio':>7} {'cost ok':>7}")
    for name, data, st, start in scenarios():
        problem = FitProblem(data, st, phase_weight=PW)
        x0 = st.vector(start)
        t = time.perf_counter()
        nm = nelder_mead_loop(problem.cost, x0)
        t_nm = time.perf_counter() - t
        fit(data, st, phase_weight=PW, start=start, n_perturbed=0)  # warm-up (imports)
        times = []
        for _ in range(REPEATS):
            t = time.perf_counter()
            res = fit(data, st, phase_weight=PW, start=start, n_perturbed=0)
            times.append(time.perf_counter() - t)
        t_s = float(np.median(times))
        ok = res.cost <= nm.cost * (1 + 1e-9)
        print(f"{name:<20} {t_nm:11.3f} {nm.cost:12.6g} {nm.loops:5d} {'met' if nm.criterion_met else 'no':>5} {t_s:10.4f} {res.cost:12.6g} {t_nm / t_s:7.0f} {'yes' if ok else 'NO':>7}")
        t = time.perf_counter()
        full = fit(data, st, phase_weight=PW)
        print(f"{'':<20} (samii default: notebook + auto + 2 perturbed starts: {time.perf_counter() - t:.3f} s, cost {full.cost:.6g})")


if __name__ == "__main__":
    main()
