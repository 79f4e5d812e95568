"""Timing shared by the benchmark scripts (imported as ``_timing``: a script's folder is on ``sys.path``)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable


def median_time(fn: Callable[[], object], repeats: int, *, warm_up: bool = False) -> float:
    """Median wall time [s] of ``repeats`` calls of ``fn`` (after one untimed call with ``warm_up``)."""
    if warm_up:
        fn()
    times = []
    for _ in range(max(1, repeats)):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def paired_ratio(base: Callable[[], object], other: Callable[[], object], repeats: int) -> tuple[float, float, float, float, float]:
    """``other``'s wall time over ``base``'s, measured in interleaved pairs (after one untimed call of
    each) so that a slow spell of the machine weighs on both: (median ratio, lowest, highest,
    median time of base [s], median time of other [s])."""
    base()
    other()
    ratios, tb, to = [], [], []
    for _ in range(max(1, repeats)):
        t = time.perf_counter()
        base()
        a = time.perf_counter() - t
        t = time.perf_counter()
        other()
        b = time.perf_counter() - t
        ratios.append(b / a)
        tb.append(a)
        to.append(b)
    return statistics.median(ratios), min(ratios), max(ratios), statistics.median(tb), statistics.median(to)


def plain_rollout(model, data, n_steps: int) -> Callable[[], object]:
    """A function that steps ``model`` ``n_steps`` times from ``data``'s present state (zero command) with one
    ``mujoco.rollout`` call: plain ``mj_step``, the baseline the closed-loop benchmarks divide by."""
    import mujoco
    import numpy as np
    from mujoco import rollout

    full = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(model, full))
    mujoco.mj_getState(model, data, state, full)
    ctrl = np.zeros((1, int(n_steps), model.nu))
    return lambda: rollout.rollout(model, data, state[None, :], ctrl)
