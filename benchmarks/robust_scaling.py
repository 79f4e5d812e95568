"""How ``samii robust`` scales: samples per second in this process, and on a local Dask cluster of 1 and 2
worker processes, measured in one run on the same tasks.

Goals (issue 13): at least 1.7x the samples per second from 1 to 2 workers, and the engine's overhead
per sample under 10 % of the sample itself (a 10 s closed-loop run: the step test of the notebook's
pole-cancelling compensator on a plant with a bulk modulus and clamp stiffness drawn). The overhead is
the 1-worker cluster's time per sample over the in-process time per sample, less 1. The clusters are
started before the timing (their start-up, a few seconds, is printed apart) and warmed on one batch.

Goal (issue 34, item 1): a sample at most 1.3x the plain stepping of its steps: ``mujoco.rollout`` of the
embedded model from its ``home`` keyframe for the same 10 s (10,000 physics steps, zero command), in
this process, the baseline measured in the same run.

    python benchmarks/robust_scaling.py [--samples 16] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=16, help="samples per timed batch (default 16)")
    ap.add_argument("--repeats", type=int, default=3, help="timed batches per engine; the median is kept (default 3)")
    args = ap.parse_args()

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from _timing import paired_ratio

    from samii.closedloop.controllers import notebook_cancel
    from samii.robust.engine import Engine
    from samii.robust.sampling import draw_plants, parse_spread
    from samii.robust.task import SampleTask
    from samii.sim.model import default_params, dotted

    params = default_params()
    draws = draw_plants(
        args.samples, 0, dotted(params), [parse_spread("hydraulic.bulk_modulus=20%"), parse_spread("beam.clamp_stiffness_Nm_rad=10%")], None
    )
    ctrl = notebook_cancel()
    tasks = [SampleTask(i, params.as_dict(), draws.overrides(i), ctrl, "step") for i in range(args.samples)]
    print(
        f"{args.samples} samples per batch (10 s closed loop each), {args.repeats} batches per engine, {os.cpu_count()} cores, "
        f"Python {sys.version.split()[0]}"
    )

    rates, per_sample, results = {}, {}, {}
    for label, engine in (("in-process", Engine()), ("1 worker", Engine(workers=1)), ("2 workers", Engine(workers=2))):
        t = time.perf_counter()
        with engine:
            startup = time.perf_counter() - t
            engine.map(tasks[: max(2, engine.workers)])  # warm: imports, the plugin, caches
            times = []
            for _ in range(args.repeats):
                t = time.perf_counter()
                results[label] = engine.map(tasks)
                times.append(time.perf_counter() - t)
        med = statistics.median(times)
        rates[label] = args.samples / med
        per_sample[label] = med / args.samples
        print(
            f"  {label:<11} {rates[label]:6.2f} samples/s ({1e3 * per_sample[label]:.0f} ms per sample; batches {', '.join(f'{x:.2f}' for x in times)} s;"
            f" start-up {startup:.1f} s)"
        )

    same = all([r.table_row() for r in results[k]] == [r.table_row() for r in results["in-process"]] for k in results)
    speedup = rates["2 workers"] / rates["1 worker"]
    overhead = per_sample["1 worker"] / per_sample["in-process"] - 1.0
    print(f"2 workers / 1 worker: {speedup:.2f}x (goal >= 1.7x)")
    print(f"engine overhead per sample (1 worker against in-process): {100 * overhead:+.1f} % of a sample (goal < 10 %)")
    print(f"the same table from every engine: {'yes' if same else 'NO'}")
    plain = _plain_stepping(10.0)
    k, pairs = min(4, args.samples), max(args.repeats, 5)
    with Engine() as engine:
        ratio, lo, hi, t_plain, t_samples = paired_ratio(lambda: [plain() for _ in range(k)], lambda: engine.map(tasks[:k]), pairs)
    print(
        f"a sample in this process against plain stepping of its steps ({1e3 * t_plain / k:.0f} ms for 10 s; "
        f"{1e3 * t_samples / k:.0f} ms a sample): {ratio:.2f}x, {lo:.2f}-{hi:.2f} over {pairs} interleaved pairs of {k} (goal <= 1.3x)"
    )


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
