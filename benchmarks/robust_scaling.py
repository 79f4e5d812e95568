"""How ``samii robust`` scales: a sample against plain stepping, the engines that could run many samples on one
machine, and a 1,000-sample study, measured in one run on the same tasks (the 10 s step test of the notebook's
pole-cancelling compensator on plants with a bulk modulus and clamp stiffness drawn).

Goal (issue 34, item 1): a sample at most 1.3x the plain stepping of its steps: ``mujoco.rollout`` of the
embedded model from its ``home`` keyframe for the same 10 s (10,000 physics steps, zero command), in this process,
measured in interleaved pairs in the same run.

Goal (issue 34, item 2): many plants per core. Measured on the same samples: one after the other in this process;
two threads in this process (``mujoco.rollout`` steps without the GIL; samii does not use this: measured to choose);
N worker processes forked from this one (``samii.forkmap``: samii's engine on one machine); a local Dask cluster of
N worker processes (what samii used on one machine before; a user's cluster is Dask still), its start-up apart. The
same table from each. Then a study of ``--study`` samples (default 1,000) through the library call ``samii robust``
makes, on its default engine: goal at most 45 s of wall time on 2 cores on the machine issue 34 was measured on (the
time here is also printed scaled to it by the plain step, ``_timing.on_issue_machine``).

Goals of issue 13, on the engine samii uses: 2 workers at least 1.7x one, the engine's cost per sample under 10 %.

    python benchmarks/robust_scaling.py [--samples 64] [--repeats 3] [--study 1000]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=64, help="samples per timed batch (default 64)")
    ap.add_argument("--repeats", type=int, default=3, help="timed batches per engine; the median is kept (default 3)")
    ap.add_argument("--study", type=int, default=1000, help="samples of the study run at the end (default 1000; 0: none)")
    args = ap.parse_args()

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from _timing import goal_line, paired_ratio, step_yardstick, yardstick_line

    from samii.closedloop.controllers import notebook_cancel
    from samii.forkmap import workers
    from samii.robust.sampling import draw_plants, parse_spread
    from samii.robust.task import SampleTask
    from samii.sim.model import default_params, dotted

    params = default_params()
    spreads = ["hydraulic.bulk_modulus=20%", "beam.clamp_stiffness_Nm_rad=10%"]
    draws = draw_plants(args.samples, 0, dotted(params), [parse_spread(s) for s in spreads], None)
    tasks = [SampleTask(i, params.as_dict(), draws.overrides(i), notebook_cancel(), "step") for i in range(args.samples)]
    cores = workers()
    print(
        f"{args.samples} samples per batch (10 s closed loop each), {args.repeats} batches per engine, {cores} cores, Python {sys.version.split()[0]}"
    )

    # item 1: a sample against plain stepping of its steps
    from samii.robust.engine import Engine

    plain = _plain_stepping(10.0)
    k, pairs = min(4, args.samples), max(args.repeats, 5)
    ratio, lo, hi, t_plain, t_samples = paired_ratio(lambda: [plain() for _ in range(k)], lambda: Engine().map(tasks[:k]), pairs)
    print(
        f"a sample in this process against plain stepping of its steps ({1e3 * t_plain / k:.0f} ms for 10 s; "
        f"{1e3 * t_samples / k:.0f} ms a sample): {ratio:.2f}x, {lo:.2f}-{hi:.2f} over {pairs} interleaved pairs of {k} (goal <= 1.3x)"
    )

    # item 2: the engines on the same samples
    per_sample, results = {}, {}
    n = max(2, cores)
    engines = [("in this process", _serial), ("2 threads", _threads(2))]
    engines += [(f"{w} forked processes", _forked(w)) for w in sorted({2, n})]
    engines += [(f"Dask local, {w} processes", _dask(w)) for w in sorted({2, n})]
    for label, make in engines:
        t = time.perf_counter()
        with make() as run:
            startup = time.perf_counter() - t
            run(tasks[: max(2, n)])  # warm: imports, the plugin, caches, a cluster's workers
            times = []
            for _ in range(args.repeats):
                t = time.perf_counter()
                results[label] = run(tasks)
                times.append(time.perf_counter() - t)
        per_sample[label] = statistics.median(times) / args.samples
        print(
            f"  {label:<26} {1e3 * per_sample[label]:5.1f} ms a sample, {per_sample['in this process'] / per_sample[label]:4.2f}x this process "
            f"(batches {', '.join(f'{x:.2f}' for x in times)} s; start-up {startup:.2f} s)"
        )
    rows = {label: [r.table_row() for r in res] for label, res in results.items()}
    print(f"the same table from every engine: {'yes' if all(r == rows['in this process'] for r in rows.values()) else 'NO'}")
    gil = 1.0 - t_plain / t_samples  # (the stepping runs without the GIL; the Python around it, the rest of a sample, holds it)
    print(
        f"a sample's Python around its stepping, which holds the GIL: about {100 * gil:.0f} % of it (a sample less the plain "
        f"stepping of its steps): threads in one process cannot pass {1 / gil:.1f}x whatever the cores, processes scale with them"
    )
    two = per_sample["in this process"] / per_sample["2 forked processes"]
    print(f"2 forked processes / this process: {two:.2f}x (goal >= 1.7x); the engine's cost per sample: {100 * (2 / two - 1):+.1f} % (goal < 10 %)")

    if args.study:
        from samii.robust.runner import StudyRequest, run_study

        request = StudyRequest(controller="notebook-cancel", samples=args.study, seed=0, spreads=tuple(spreads))
        t = time.perf_counter()
        result = run_study(request)
        wall = time.perf_counter() - t
        print(
            f"a study of {args.study} samples (samii robust --controller notebook-cancel --samples {args.study} --spread "
            f"{' --spread '.join(spreads)}), {result.record.engine}: {wall:.1f} s wall, {1e3 * wall / args.study:.1f} ms a sample"
        )
        step = step_yardstick()
        print(yardstick_line(step))
        print(goal_line("a study of 1,000 samples" + ("" if args.study == 1000 else f" (from {args.study})"), wall * 1000 / args.study, 45.0, step))


class _Runner:
    """A context whose value runs a list of tasks and returns their results in order."""

    def __init__(self, run, close=lambda: None):
        self.run, self.close = run, close

    def __enter__(self):
        return self.run

    def __exit__(self, *exc):
        self.close()


def _serial():
    from samii.robust.engine import Engine

    return _Runner(Engine(workers=0).map)


def _threads(n: int):
    """``n`` threads in this process, each running whole samples (the rollout releases the GIL while it steps). BLAS
    held to one thread for the whole batch (a sample's own limit, entered and left by two threads at once, would
    restore the other's threads in the middle of its run)."""

    def start():
        from concurrent.futures import ThreadPoolExecutor

        from samii.robust.task import run_sample
        from samii.threads import one_blas_thread

        pool = ThreadPoolExecutor(n)
        limit = one_blas_thread()
        limit.__enter__()

        def close():
            pool.shutdown()
            limit.__exit__(None, None, None)

        return _Runner(lambda tasks: list(pool.map(run_sample, tasks)), close)

    return start


def _forked(n: int):
    def start():
        from samii.robust.engine import Engine

        return _Runner(Engine(workers=n).map)

    return start


def _dask(n: int):
    def start():
        from distributed import LocalCluster

        from samii.robust.engine import Engine

        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                               scheduler_kwargs={"dashboard_address": "127.0.0.1:0"}, silence_logs=50)  # fmt: skip
        engine = Engine(scheduler=cluster.scheduler_address).__enter__()

        def close():
            engine.__exit__()
            cluster.close()

        return _Runner(engine.map, close)

    return start


def _plain_stepping(seconds: float):
    """Steps the embedded model from its ``home`` keyframe for ``seconds`` (zero command) with ``mujoco.rollout``:
    the plain stepping a sample's closed loop does as many steps of."""
    from _timing import plain_rollout

    from samii.sim.model import load_model, make_data
    from samii.sim.plugin import load_plugin

    load_plugin()
    model = load_model()
    return plain_rollout(model, make_data(model), int(round(seconds / model.opt.timestep)))


if __name__ == "__main__":
    main()
