"""samii diagnose --baseline sim on 6-minute 1 kHz time series of the simulator itself, timed in one run.

Goal (issue 31, item 4): at most 60 s on a 6-minute file on 2 cores. The baseline measured in the
same run is one simulated measurement like the file (``samii.diagnose.simulator.measurement_like``:
the embedded model measured with the file's sweep, its repetitions capped at 2, no noise), the unit a
``--baseline sim`` diagnosis is made of: the simulator's own harmonics, each correction of a
calibration, each re-measurement before and after carrying, each carried effect taken out again.
The printed ratio is the diagnosis in such measurements.

Cases (the simulator's options a user would not tell it; experiments/diagnose_battery/run_simulator.py
has the same kinds at 253 s): clean data; a 4 ms command delay (one round of carrying); the delay
with a 0.5 kg body at 15 Hz on the beam's end (a second round: the body carried alone and
recalibrated, the first selection again); the valve's spool twice as slow (a second round as the
spool's time constant). Each file: ``samii measure --noise --averages 4 --tail-s 26`` (four
sign-alternating sweeps 0.1-40 Hz of 90.2 s, 360.8 s in all), then ``samii diagnose FILE
--baseline sim --out DIR`` in this process, as a user runs it (figures written).

Run::

    python benchmarks/diagnose_sim_speed.py [--cases NAME ...]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from diagnose_speed import time_case  # (this folder is on sys.path when a script in it runs)

GOAL_S = 60.0
#: (name, --set overrides, noise seed)
CASES = [
    ("clean", {}, 3),
    ("command delay 4 ms", {"hydraulic.command_delay": 0.004}, 12),
    (
        "delay 4 ms + body 0.5 kg 15 Hz",
        {"hydraulic.command_delay": 0.004, "beam.tip_body_mass_kg": 0.5, "beam.tip_body_freq_hz": 15.0, "beam.tip_body_damping_ratio": 0.02},
        25,
    ),
    ("spool 2x slower", {"hydraulic.valve_time_constant": 0.00897}, 26),
]


def write_case(folder: Path, overrides: dict, seed: int) -> Path:
    """The simulator with ``overrides`` measured as ``samii measure --noise --averages 4 --tail-s 26`` writes it."""
    from samii.formats import write_timeseries_csv
    from samii.measure.campaign import measure_swept
    from samii.measure.daq import SensorNoise
    from samii.measure.excitation import SweptSine
    from samii.sim.model import load_model

    sweep = SweptSine(repetitions=4, tail_s=26.0)
    meas = measure_swept(load_model(overrides=overrides) if overrides else load_model(), sweep, noise=SensorNoise(), rng=np.random.default_rng(seed))
    path = folder / f"sim_{seed}.csv"
    write_timeseries_csv(meas.timeseries, path)
    return path


def one_measurement_s(path: Path) -> tuple[float, float]:
    """(file length [s], wall time [s] of one simulated measurement like it, the embedded model)."""
    from samii.diagnose.simulator import measurement_like
    from samii.measure.measured import load
    from samii.sim.model import default_params

    m = load(path)
    t0 = time.perf_counter()
    measurement_like(default_params(), m)
    return float(m.timeseries.t[-1] - m.timeseries.t[0]), time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", help="case names (default: all)")
    args = ap.parse_args()
    print(f"samii diagnose --baseline sim on 6-minute simulator files at 1 kHz; goal: at most {GOAL_S:g} s a file")
    print(f"{'case':<32} {'file [s]':>8} {'one meas. [s]':>13} {'total [s]':>10} {'total/meas.':>12}  found")
    totals = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for name, overrides, seed in CASES:
            if args.cases and name not in args.cases:
                continue
            path = write_case(folder, overrides, seed)
            length, unit = one_measurement_s(path)
            r = time_case(path, folder / "out", ("--baseline", "sim"))
            totals.append(r["total_s"])
            print(
                f"{name:<32} {length:8.1f} {unit:13.2f} {r['total_s']:10.1f} {r['total_s'] / unit:12.1f}  {', '.join(r['found']) or '-'}", flush=True
            )
    print(f"max {np.max(totals):.1f} s, median {np.median(totals):.1f} s (goal: every file at most {GOAL_S:g} s) over {len(totals)} files")


if __name__ == "__main__":
    main()
