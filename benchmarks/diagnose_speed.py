"""samii diagnose on a 6-minute 1 kHz time series (three sweeps), timed in one run, on both test rigs.

Goal (issue 31, item 5): every diagnosis of a 6-minute 1 kHz time series of three
sweeps at most 30 s on 2 cores, the median at most 10 s over both rigs' cases (issue
11's was 20 s a file, most of it reading the file). The baseline measured in the
same run is reading the file alone (``samii.measure.measured.load``: parse the CSV,
find the records from r, estimate the FRFs and their noise).

The same six cases on each rig: clean data, one effect in each category that costs
the selection most, a combination, and a valve nonlinearity.

* ``effect``: ``samii.diagnose.rig.EffectRig``, the notebook's eq 9.1/9.2 at eq
  9.4's parameters x (1 +- 15 %) under the position loop, exact in the frequency
  domain, the DAQ's default noise; the sweep is 0.1-40 Hz, 0.1 V, three records of
  120 s (``SweptSine`` with 8 s per octave); no metadata (the records are found from r).
* ``second``: the independent second rig of the diagnosis battery
  (``experiments/diagnose_battery/second_rig.py``: a digital position loop simulated
  in time, a 16-bit encoder, its own swept sine), its nuisance set N01: 1 kHz, three
  up-sweeps of 120 s back to back, 0.1 V.

Each file is written as a time-series CSV, then ``samii diagnose FILE --out DIR``
runs in this process, as a user runs it (figures written).

Run::

    python benchmarks/diagnose_speed.py [--rig effect|second|both] [--cases NAME ...]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from samii.diagnose.rig import EffectRig
from samii.formats import write_timeseries_csv
from samii.measure.excitation import SweptSine
from samii.measure.measured import load

FS = 1000.0
GOAL_MAX_S = 30.0
GOAL_MEDIAN_S = 10.0
#: (name, EffectRig keywords): clean data, one effect in each category that costs the selection most, a combination
#: and a valve nonlinearity
CASES = [
    ("clean", {}),
    ("command delay 4 ms", {"command_delay_s": 0.004}),
    ("base mode 15 Hz", {"base_mode": (15.0, 0.02, 0.02)}),
    ("accel LP1 30 Hz", {"accel_lowpass_hz": 30.0}),
    ("delay 4 ms + LP1 30 Hz", {"command_delay_s": 0.004, "accel_lowpass_hz": 30.0}),
    ("dead band 20 mV", {"valve_nonlinearity": ("dead_band", 0.02)}),
]


def sweep() -> SweptSine:
    """Three down-sweeps 0.1-40 Hz of 120 s each (6 minutes in all)."""
    sw = SweptSine(amplitude_v=0.1, repetitions=3, seconds_per_octave=8.0, cycles_per_octave=4.0)
    return sw


#: The second rig's cases (its run_second_rig.py's keywords, FT its residue scale): the same six
SECOND_CASES = [
    ("clean", {}),
    ("command delay 4 ms", {"command_delay_s": 0.004}),
    ("base mode 15 Hz", {"base_mode": (15.0, 0.02, 0.02 * 0.3048)}),
    ("accel LP1 30 Hz", {"accel_lowpass_hz": 30.0}),
    ("delay 4 ms + LP1 30 Hz", {"command_delay_s": 0.004, "accel_lowpass_hz": 30.0}),
    ("dead band 20 mV", {"valve_nonlinearity": ("dead_band", 0.02)}),
]


#: The second rig and its battery's cases (not a package: imported from their folder)
BATTERY = Path(__file__).resolve().parents[1] / "experiments" / "diagnose_battery"


def write_second_case(folder: Path, name: str, effects: dict, seed: int) -> Path:
    """A second-rig file (experiments/diagnose_battery/run_second_rig.py's nuisance set N01) of ``effects``."""
    if str(BATTERY) not in sys.path:
        sys.path.insert(0, str(BATTERY))
    from run_second_rig import NUISANCES, simulate_case
    from second_rig import write_csv

    _, fs, sweep, daq = NUISANCES[0]
    case = {"name": name, "fs": fs, "sweep": sweep, "daq": daq, "effects": effects, "seed": 5000 + seed}
    data, text, _, _ = simulate_case(case)
    path = folder / ("second_" + name.replace(" ", "_").replace("+", "and") + ".csv")
    write_csv(path, data, {"sample_rate_hz": f"{fs:g}", "excitation": text})
    return path


def write_case(folder: Path, name: str, effects: dict, seed: int) -> Path:
    rng = np.random.default_rng(seed)
    rig = EffectRig.drawn(rng, spread=0.15, **effects)  # drawn again while the position loop is unstable
    sw = sweep()
    r = sw.signal(np.arange(int(round(sw.duration_s * FS))) / FS)
    ts = rig.simulate(r, sample_rate_hz=FS, rng=rng, metadata={})
    path = folder / (name.replace(" ", "_").replace("+", "and") + ".csv")
    write_timeseries_csv(ts, path)
    return path


def time_case(path: Path, out: Path, options: tuple[str, ...] = ()) -> dict:
    """``samii diagnose PATH --out OUT [options]`` run in this process, its output silenced: reading the file alone
    and the whole command timed [s], and the effects found (exit if it fails)."""
    from samii.cli import main

    t0 = time.perf_counter()
    load(path)
    read_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    with open(os.devnull, "w") as null:
        stdout, sys.stdout = sys.stdout, null
        try:
            rc = main(["diagnose", str(path), *options, "--out", str(out), "--no-progress", "--overwrite"])
        finally:
            sys.stdout = stdout
    total_s = time.perf_counter() - t0
    if rc != 0:
        raise SystemExit(f"samii diagnose {path} {' '.join(options)} exited {rc}")
    import json

    d = json.loads((out / "diagnosis.json").read_text())
    return {"read_s": read_s, "total_s": total_s, "found": [f"{e['category']}/{e['kind']}" for e in d["effects"]]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", help="case names (default: all)")
    ap.add_argument("--seed", type=int, default=4)
    ap.add_argument("--rig", choices=("effect", "second", "both"), default="both")
    args = ap.parse_args()
    rigs = [r for r in ("effect", "second") if args.rig in (r, "both")]
    print(f"6-minute files at {FS:g} Hz, 3 records; goal: at most {GOAL_MAX_S:g} s a file, median at most {GOAL_MEDIAN_S:g} s")
    print(f"{'rig':<7} {'case':<26} {'read [s]':>9} {'total [s]':>10} {'total/read':>11}  found")
    totals = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for rig in rigs:
            write, cases = (write_case, CASES) if rig == "effect" else (write_second_case, SECOND_CASES)
            for name, effects in cases:
                if args.cases and name not in args.cases:
                    continue
                path = write(folder, name, effects, args.seed)
                r = time_case(path, folder / "out")
                totals.append(r["total_s"])
                print(
                    f"{rig:<7} {name:<26} {r['read_s']:9.2f} {r['total_s']:10.2f} {r['total_s'] / r['read_s']:11.1f}  {', '.join(r['found']) or '-'}",
                    flush=True,
                )
    print(f"median {np.median(totals):.1f} s (goal {GOAL_MEDIAN_S:g} s), max {np.max(totals):.1f} s (goal {GOAL_MAX_S:g} s) over {len(totals)} files")


if __name__ == "__main__":
    main()
