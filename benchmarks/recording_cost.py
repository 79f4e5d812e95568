"""What ``--rerun`` adds to a run: the default swept-sine measurement and a closed-loop Loper test,
each with and without its recording, in one process (median over repeats).

Usage::

    python benchmarks/recording_cost.py [--repeats 5]

Each run is timed alone and recorded in interleaved pairs (a slow spell of the machine weighs on
both); the overhead is the median of the pairs' ratios, with their range. Printed per run: the run alone (what the command does without ``--rerun``: simulation, DAQ,
``timeseries.csv``), the run keeping its animation frames, the recording written
(:func:`samii.viz.recording.write_recording`), and the overhead (frames kept + recording) as a
fraction of the run alone (warm: rerun imported; the import, once per command, is printed\nseparately). Goal (issue 12): under 30 %.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import warnings
from pathlib import Path

from _timing import paired_ratio

from samii.measure.campaign import measure
from samii.measure.excitation import SweptSine
from samii.sim.model import load_model
from samii.viz.recording import RunRecord, frame_steps_for, write_recording


def measurement(repeats: int, folder: Path) -> None:
    model = load_model()
    sweep = SweptSine()
    steps = frame_steps_for(model)

    def plain():
        measure(model, sweep, timeseries_path=folder / "ts.csv", overwrite=True)

    def recorded():
        res = measure(model, sweep, timeseries_path=folder / "ts.csv", overwrite=True, frame_steps=steps)
        run = RunRecord("swept", res.timeseries, res.run.frame_t_s, res.run.frame_qpos, sweep_hz=sweep.frequency_hz(res.timeseries.t))
        write_recording(folder / "m.rrd", model, [run], application_id="bench")

    ratio, lo, hi, base, rec = paired_ratio(plain, recorded, repeats)
    size = (folder / "m.rrd").stat().st_size / 1e6
    print(
        f"samii measure (default swept sine, {sweep.duration_s:.0f} s simulated, {1 / (steps * model.opt.timestep):.0f} frames/s): "
        f"run {base:.2f} s, with recording {rec:.2f} s: overhead {_pct(ratio, lo, hi)} (goal < 30 %), file {size:.0f} MB"
    )


def closed_loop(repeats: int, folder: Path) -> None:
    from samii.closedloop.scenario import default_spec_factory, run_closed_loop, scenario
    from samii.closedloop.trial import resolve_controller, write_rerun
    from samii.sim.plugin import compile_spec

    factory = default_spec_factory(None, None)
    saved = resolve_controller("damping", factory)
    sc = scenario("loper", duration_s=10.0)
    steps = frame_steps_for(compile_spec(factory()[0]))

    def plain():
        run_closed_loop(saved, sc, label="damping", spec_factory=factory)

    def recorded():
        result = run_closed_loop(saved, sc, label="damping", spec_factory=factory, qpos_every=steps)
        write_rerun(result, folder / "c.rrd", folder / "c.rrd", factory)

    ratio, lo, hi, base, rec = paired_ratio(plain, recorded, repeats)
    print(f"samii closedloop (damping, Loper test, 10 s): run {base:.2f} s, with recording {rec:.2f} s: overhead {_pct(ratio, lo, hi)} (goal < 30 %)")


def _pct(ratio: float, lo: float, hi: float) -> str:
    return f"{100 * (ratio - 1):.1f} % (pairs {100 * (lo - 1):.0f}-{100 * (hi - 1):.0f} %)"


def import_cost() -> float:
    """Wall time [s] of ``import rerun, rerun.blueprint`` in a fresh interpreter, less the interpreter's start."""
    import subprocess
    import sys
    import time

    def run(code: str) -> float:
        t = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], check=True)
        return time.perf_counter() - t

    return min(run("import rerun, rerun.blueprint") for _ in range(3)) - min(run("pass") for _ in range(3))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(f"{os.cpu_count()} cores; median over {args.repeats} interleaved pairs (run alone, run recorded)")
    with warnings.catch_warnings(), tempfile.TemporaryDirectory() as tmp:
        warnings.simplefilter("ignore", RuntimeWarning)
        measurement(args.repeats, Path(tmp))
        closed_loop(args.repeats, Path(tmp))
    print(f"once per command with --rerun: importing rerun {import_cost():.2f} s (not in the figures above)")


if __name__ == "__main__":
    main()
