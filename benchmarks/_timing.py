"""Timing shared by the benchmark scripts (imported as ``_timing``: a script's folder is on ``sys.path``)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable


def _times(fn: Callable[[], object], repeats: int, *, warm_up: bool = False) -> list[float]:
    """Wall times [s] of ``repeats`` calls of ``fn`` (after one untimed call with ``warm_up``)."""
    if warm_up:
        fn()
    times = []
    for _ in range(max(1, repeats)):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return times


def median_time(fn: Callable[[], object], repeats: int, *, warm_up: bool = False) -> float:
    """Median wall time [s] of ``repeats`` calls of ``fn`` (after one untimed call with ``warm_up``)."""
    return statistics.median(_times(fn, repeats, warm_up=warm_up))


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


#: One plain step of the embedded model (``mujoco.rollout``, one thread) on the machine issue 34 was measured on [s]:
#: its robust sample's 10,000 steps of plain stepping took 54 ms. The goals in seconds (the main job's 12 s, the
#: suite's 6 minutes) were set on that machine; :func:`step_yardstick` says how this one compares.
#:
#: The ratio holds for samii's Python as well, not only for MuJoCo's C step (stop 75, a machine stepping at 3.85 us,
#: 1.40x the issue's): on that machine the code the issue was measured on (163091e, the commit before its first change)
#: ran a robust sample in 174 ms against the issue's 236 ms (1.36x; ``benchmarks/robust_scaling.py`` of that commit, in
#: process), and its test command in 6.9 minutes against the "about 10 minutes" its README gave (1.45x).
ISSUE_34_STEP_S = 5.4e-6


def step_yardstick(steps: int = 10_000, repeats: int = 9) -> float:
    """Seconds per plain step of the embedded model on this machine (``mujoco.rollout`` from its home state, zero
    command, as many steps as issue 34's reference; the fastest of ``repeats`` after a warm-up, which a busy spell
    of the machine does not move): its speed beside a benchmark's seconds, so that figures measured on different
    machines can be set side by side (it measures MuJoCo's C step, not the Python around it)."""
    from samii.sim.model import load_model, make_data
    from samii.sim.plugin import load_plugin

    load_plugin()
    model = load_model()
    return min(_times(plain_rollout(model, make_data(model), steps), repeats, warm_up=True)) / steps


def yardstick_line(step_s: float) -> str:
    """The machine's speed in words: its plain step against ISSUE_34_STEP_S."""
    return (
        f"this machine: a plain step of the embedded model takes {step_s * 1e6:.2f} us "
        f"(issue 34's machine: {ISSUE_34_STEP_S * 1e6:.1f} us; this one {ISSUE_34_STEP_S / step_s:.2f}x as fast at stepping)"
    )


def on_issue_machine(seconds: float, step_s: float) -> float:
    """``seconds`` measured on this machine, scaled to issue 34's by the plain step (ISSUE_34_STEP_S): what a goal set
    in seconds there is judged by."""
    return seconds * ISSUE_34_STEP_S / step_s


def goal_line(what: str, seconds: float, goal_s: float, step_s: float) -> str:
    """``what`` against its goal of ``goal_s`` seconds on issue 34's machine: here, and scaled there."""
    there = on_issue_machine(seconds, step_s)
    return (
        f"{what}: {seconds:.1f} s here, {there:.1f} s scaled to issue 34's machine by the plain step; "
        f"goal at most {goal_s:.0f} s there: {'met' if there <= goal_s else 'NOT met'}"
    )
