"""Cost of the default ``samii measure`` campaign against plain stepping of the same model.

Usage::

    python benchmarks/measure_cost.py [--repeats 3] [--method swept|stepped]

Times, in one process after a warm-up (median over repeats):

* ``stepping``: one ``mujoco.rollout`` of the campaign's valve command from the
  ``home`` keyframe: the cost of ``mj_step`` alone on the same model (the limit);
* ``measure``: :func:`samii.measure.campaign.measure` as ``samii measure`` runs it:
  simulation in chunks, the DAQ (anti-alias filter, sampling) and
  ``timeseries.csv`` streamed to disk while the next chunk steps on the other core,
  then the FRF estimate;
* ``write_frf``: ``frf.csv``;
* ``figure``: ``bode.png`` with the linearised simulator overlaid (not part of the goal).

Printed: each stage's wall time, the campaign (measure + write_frf)
against stepping, and real-time factors (simulated time / wall time). Goals
(issue 3): >= 100x real time; campaign within 1.3x of stepping. The streaming
needs a second core: on one core the CSV formatting (~1 s for the default
328 s record) adds to the simulation instead of hiding behind it.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
import warnings
from pathlib import Path

import mujoco
import numpy as np
from mujoco import rollout

from samii.formats import write_frf_csv
from samii.measure.campaign import linearised_frf, measure
from samii.measure.excitation import SteppedSine, SweptSine
from samii.sim.model import load_model, make_data


def one_campaign(model, excitation, folder: Path) -> dict[str, float]:
    dt = model.opt.timestep
    n = int(round(excitation.duration_s / dt))
    ctrl = excitation.signal(np.arange(n) * dt)
    data = make_data(model)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, state, spec)
    out = {}
    t = time.perf_counter()
    rollout.rollout(model, data, state[None, :], ctrl[None, :, None])
    out["stepping"] = time.perf_counter() - t

    t = time.perf_counter()
    frf = measure(model, excitation, timeseries_path=folder / "timeseries.csv", overwrite=True).frf
    out["measure"] = time.perf_counter() - t
    t = time.perf_counter()
    write_frf_csv(frf, folder / "frf.csv", overwrite=True)
    out["write_frf"] = time.perf_counter() - t
    t = time.perf_counter()
    from samii.viz.bode_plot import bode_plot

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ref = linearised_frf(model, np.geomspace(0.1, 40.0, 400))
    bode_plot(frf, reference=ref, path=folder / "bode.png")
    out["figure"] = time.perf_counter() - t
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--method", choices=("swept", "stepped"), default="swept")
    args = parser.parse_args()
    model = load_model()
    excitation = SweptSine() if args.method == "swept" else SteppedSine()
    with tempfile.TemporaryDirectory() as tmp:
        one_campaign(model, SweptSine(repetitions=1, tail_s=1.0, start_hz=5.0), Path(tmp))  # warm-up
        runs = [one_campaign(model, excitation, Path(tmp)) for _ in range(args.repeats)]
    med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    sim_s = excitation.duration_s
    campaign = med["measure"] + med["write_frf"]
    print(
        f"default {args.method}-sine campaign: {sim_s:.1f} s simulated, timestep {model.opt.timestep:g} s, "
        f"median of {args.repeats}, {os.cpu_count()} cores"
    )
    for k, v in med.items():
        print(f"  {k:9s} {v:7.3f} s   {v / med['stepping']:6.3f} x stepping")
    print(
        f"campaign (measure+write_frf): {campaign:.3f} s = {campaign / med['stepping']:.2f} x stepping "
        f"(goal <= 1.3), {sim_s / campaign:.0f}x real time (goal >= 100)"
    )
    print(
        f"with the figure: {campaign + med['figure']:.3f} s = {(campaign + med['figure']) / med['stepping']:.2f} x stepping, "
        f"{sim_s / (campaign + med['figure']):.0f}x real time"
    )
    print(f"stepping alone: {sim_s / med['stepping']:.0f}x real time")


if __name__ == "__main__":
    main()
