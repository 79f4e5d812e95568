"""The simulator-baseline diagnosis of tests/test_diagnose_sim.py on a sweep that starts at another frequency
(issue 34, item 4: shorter records where the physics allows).

Each case is the simulator's own swept-sine measurement (0.1 V, three sign-alternating sweeps down to ``--start-hz``,
up from 40 Hz, seeded sensor noise) with one effect option the diagnosis is not told about, diagnosed against the
simulator (``diagnose(..., baseline="sim")``). Per case and seed it writes one JSON line to ``out/results.jsonl``: the
effects found beyond the expected ones, what was carried into the simulator, the simulator's error per channel
before and after (chi2 per residual, rms deg), and the wall time of the measurement and the diagnosis; and prints a
line each. The tests' asserts are stated in that module; this script only measures.

Run ``python experiments/sim_baseline_band/run.py --start-hz 0.3 --seeds 3 4 5 6 26 31 [--cases delay lowpass ...]``
(about 10 s of wall time per case and seed on 2 cores at 0.3 Hz, 15 s at 0.1 Hz).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from samii.diagnose.diagnosis import diagnose
from samii.measure.campaign import measure_swept
from samii.measure.daq import SensorNoise
from samii.measure.excitation import SweptSine
from samii.measure.measured import load
from samii.sim.model import load_model

#: The cases of tests/test_diagnose_sim.py: the option each adds to the embedded model.
CASES = {
    "clean": {},
    "delay": {"hydraulic.command_delay": 0.004},
    "lowpass": {"sensor.accel_lowpass_hz": 20.0},
    "tip_body": {"beam.tip_body_mass_kg": 0.5, "beam.tip_body_freq_hz": 15.0, "beam.tip_body_damping_ratio": 0.02},
    "slow_spool": {"hydraulic.valve_time_constant": 0.00897},
}


def one(case: str, start_hz: float, seed: int, folder: Path) -> dict:
    """Measure ``case`` from ``start_hz`` with ``seed``'s noise and diagnose it against the simulator."""
    path = folder / f"{case}_{start_hz:g}_{seed}.csv"
    over = CASES[case]
    t0 = time.perf_counter()
    measure_swept(load_model(overrides=over) if over else load_model(), SweptSine(start_hz=start_hz), noise=SensorNoise(),
                  rng=np.random.default_rng(seed), timeseries_path=path)  # fmt: skip
    t1 = time.perf_counter()
    d = diagnose([load(path)], baseline="sim")
    t2 = time.perf_counter()
    s = d.simulator
    return {
        "case": case,
        "start_hz": start_hz,
        "seed": seed,
        "measure_s": round(t1 - t0, 2),
        "diagnose_s": round(t2 - t1, 2),
        "verdict": d.verdict,
        "found": [{"kind": f"{e.category}/{e.kind}", "params": e.params} for e in d.effects if not e.expected],
        "carried": list(s.carried),
        "changes": dict(s.changes),
        "before": {k: {"chi2": v.chi2, "rms_deg": v.rms_deg} for k, v in s.error_before.items()},
        "after": {k: {"chi2": v.chi2, "rms_deg": v.rms_deg} for k, v in s.error_after.items()},
    }


def _values(params: dict) -> str:
    return ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in params.items())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--start-hz", type=float, default=0.3, help="the sweep's lowest frequency [Hz] (default 0.3)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[3, 4, 5, 6, 26, 31])
    ap.add_argument("--cases", nargs="+", choices=sorted(CASES), default=list(CASES))
    args = ap.parse_args()
    out = Path(__file__).resolve().parent / "out"
    out.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp, open(out / "results.jsonl", "a") as f:
        for case in args.cases:
            for seed in args.seeds:
                r = one(case, args.start_hz, seed, Path(tmp))
                f.write(json.dumps(r) + "\n")
                f.flush()
                found = "; ".join(f"{e['kind']} {_values(e['params'])}" for e in r["found"]) or "nothing"
                xv = f"xdd/v chi2 {r['before']['total']['chi2']:.3g} -> {r['after']['total']['chi2']:.3g}"
                print(f"{case:<10} {args.start_hz:g} Hz seed {seed:<3} {r['diagnose_s']:5.1f} s  found {found}; carried {r['carried']}; {xv}")


if __name__ == "__main__":
    main()
