"""``samii diagnose --baseline sim`` on the simulator's own data with effect options it is not told
about (issue 11, items 5 and 6): what is found, what is carried into the simulator, and the
simulator's error against the data before and after.

Every case is ``samii measure --noise`` on the embedded model with one or two of the simulator's
effect options set (the valve's command delay, dead band or saturation in the hydraulic plugin;
the sensors' dynamics in the DAQ; a body on a compliant mount at the beam's end): 0.1 V, three sign-alternating sweeps 0.1-40 Hz, 1 kHz, the
DAQ's default sensor noise, its own seed. The diagnosis starts from the embedded model (the truth
without the option), so the calibration has to find its knobs again and the effect has to be
found, carried and recalibrated. Written to ``out/``:

* ``simulator.json``: per case what was injected, what was found (values after the carry's
  recalibration), the simulator's changes, its error before and after, the time;
* ``simulator.md``: the goals beside what the cases give, and every case in one line.

Run ``python experiments/diagnose_battery/run_simulator.py [--jobs 2] [--quick] [--only TEXT ...]`` (about a minute
a case; two at a time on two cores).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from run import TOLERANCE, effect_text, match_injected  # noqa: E402  (the main battery's tolerances, issue 11's goals)

#: An injected extra mode's truth: the frequency of the mode the body adds, from the model with it.
TIP_BODY_TRUTH = "the tip body's mode"


def _body(mass_kg: float, freq_hz: float, zeta: float) -> dict:
    return {"beam.tip_body_mass_kg": mass_kg, "beam.tip_body_freq_hz": freq_hz, "beam.tip_body_damping_ratio": zeta}


def _truth(injected: list, overrides: dict) -> list:
    """``injected`` with a tip body's truth computed: the base mode it adds (joint 2 held)."""
    from samii.diagnose.simulator import body_effect_values
    from samii.sim.model import default_params, params_with_overrides

    out = []
    for cat, kind, truth in injected:
        if truth == TIP_BODY_TRUTH:
            values, _ = body_effect_values(params_with_overrides(default_params(), overrides), {})
            truth = {"freq_hz": values["freq_hz"]}
        out.append((cat, kind, truth))
    return out


# (name, --set overrides, injected [(category, kind, {param: true value})], seed)
CASES = [
    ("clean, seed 3", {}, [], 3),
    ("clean, seed 5", {}, [], 5),
    ("command delay 2 ms", {"hydraulic.command_delay": 0.002}, [("delay", "command", {"delay_s": 0.002})], 11),
    ("command delay 4 ms", {"hydraulic.command_delay": 0.004}, [("delay", "command", {"delay_s": 0.004})], 12),
    ("theta delay 2 ms", {"sensor.theta_delay_s": 0.002}, [("delay", "theta_sensor", {"delay_s": 0.002})], 13),
    ("accel delay 3 ms", {"sensor.accel_delay_s": 0.003}, [("delay", "accel_sensor", {"delay_s": 0.003})], 14),
    ("accel LP1 20 Hz", {"sensor.accel_lowpass_hz": 20.0}, [("sensor", "accel_lowpass", {"corner_hz": 20.0})], 15),
    ("accel LP2 60 Hz", {"sensor.accel_antialias_hz": 60.0}, [("sensor", "accel_lowpass2", {"corner_hz": 60.0})], 16),
    ("accel HP 0.3 Hz", {"sensor.accel_highpass_hz": 0.3}, [("sensor", "accel_highpass", {"corner_hz": 0.3})], 17),
    ("accel gain 1.2", {"sensor.accel_gain": 1.2}, [("sensor", "accel_gain", {"gain": 1.2})], 18),
    ("dead band 20 mV", {"hydraulic.valve_dead_band": 0.02}, [("nonlinear", "dead_band", {"dead_band_v": 0.02})], 19),
    ("saturation 60 mV", {"hydraulic.valve_saturation": 0.06}, [("nonlinear", "saturation", {"saturation_v": 0.06})], 20),
    (
        "delay 4 ms + HP 0.3 Hz",
        {"hydraulic.command_delay": 0.004, "sensor.accel_highpass_hz": 0.3},
        [("delay", "command", {"delay_s": 0.004}), ("sensor", "accel_highpass", {"corner_hz": 0.3})],
        21,
    ),
    # a body on a compliant mount at the beam's end: the truth is the base mode it adds (joint 2
    # held), a little off the mount's own frequency (TIP_BODY_TRUTH: computed from the model)
    ("tip body 0.5 kg, 15 Hz", _body(0.5, 15.0, 0.02), [("extra_mode", "base_mode", TIP_BODY_TRUTH)], 22),
    ("tip body 0.3 kg, 35 Hz", _body(0.3, 35.0, 0.03), [("extra_mode", "base_mode", TIP_BODY_TRUTH)], 23),
    ("tip body 1 kg, 5 Hz", _body(1.0, 5.0, 0.02), [("extra_mode", "base_mode", TIP_BODY_TRUTH)], 24),
    (
        "delay 4 ms + tip body 0.5 kg, 15 Hz",
        {"hydraulic.command_delay": 0.004, **_body(0.5, 15.0, 0.02)},
        [("delay", "command", {"delay_s": 0.004}), ("extra_mode", "base_mode", TIP_BODY_TRUTH)],
        25,
    ),
    # the valve's spool (a first-order lag, 4.48 ms) twice as slow and twice as fast: against the simulator a real
    # pole/zero pair, (1 + s tau0)/(1 + s tau), carried as the spool's time constant
    ("spool 2x slower (8.97 ms)", {"hydraulic.valve_time_constant": 0.00897}, [("actuator", "pole_zero", {"spool_time_constant_s": 0.00897})], 26),
    ("spool 2x faster (2.24 ms)", {"hydraulic.valve_time_constant": 0.00224}, [("actuator", "pole_zero", {"spool_time_constant_s": 0.00224})], 27),
    # the valve's negative direction 10 % weaker (hydraulic.valve_asymmetry): found from the sweep's 2nd harmonic
    ("asymmetry 10 %", {"hydraulic.valve_asymmetry": 0.1}, [("nonlinear", "asymmetry", {"asymmetry_fraction": 0.1})], 28),
]
#: Tolerances beyond the main battery's: a gain error and the spool's time constant (the issue states none; judged
#: like a corner).
EXTRA_TOLERANCE = {("sensor", "gain"): ("rel", 0.15), ("actuator", "spool_time_constant_s"): ("rel", 0.15)}


def run_case(name: str, overrides: dict, injected: list, seed: int) -> dict:
    from samii.diagnose.diagnosis import diagnose
    from samii.measure.campaign import measure_swept
    from samii.measure.daq import SensorNoise
    from samii.measure.measured import from_timeseries
    from samii.sim.model import load_model

    meas = measure_swept(load_model(overrides=overrides) if overrides else load_model(), noise=SensorNoise(), rng=np.random.default_rng(seed))
    files = [from_timeseries(meas.timeseries, source=name)]
    t0 = time.perf_counter()
    d = diagnose(files, baseline="sim")
    elapsed = time.perf_counter() - t0
    rows, unmatched = match_injected([e for e in d.effects if not e.expected], _truth(injected, overrides), {**TOLERANCE, **EXTRA_TOLERANCE})
    s = d.simulator
    return {
        "name": name,
        "overrides": overrides,
        "seed": seed,
        "injected": rows,
        "extra": [{"category": e.category, "kind": e.kind, "params": e.params} for e in unmatched],
        "verdict": d.verdict,
        "error_before": {k: v.to_dict() for k, v in d.error_before.items()},
        "error_after": {k: v.to_dict() for k, v in d.error_after.items()},
        "simulator": None
        if s is None
        else {
            "carried": list(s.carried),
            "changes": dict(s.changes),
            "not_carried": list(s.not_carried),
            "dropped": list(s.dropped),
            "not_lowering": list(s.not_lowering),
            "worse": s.worse,
            "cannot_represent": [m.text() for m in s.misfit_after],
            "error_before": {k: v.to_dict() for k, v in s.error_before.items()},
            "error_after": {k: v.to_dict() for k, v in s.error_after.items()},
        },
        "time_s": elapsed,
    }


def _summary(results: list[dict]) -> str:
    inj = [row for r in results for row in r["injected"]]
    right_cat = sum(row["found_category"] == row["category"] for row in inj)
    right_kind = sum(row["found_kind"] == row["kind"] for row in inj)
    named = sum(bool(row.get("named_alternative")) for row in inj)
    clean = [r for r in results if not r["injected"]]
    false_clean = sum(1 for r in clean if r["verdict"] != "none" or r["extra"])
    effect_cases = [r for r in results if r["injected"]]
    extra = sum(len(r["extra"]) for r in effect_cases)
    judged = [row for row in inj if row["within_tolerance"] is not None]
    within = sum(bool(row["within_tolerance"]) for row in judged)

    def sim_better(r):
        s = r["simulator"]
        return s is not None and s["carried"] and all(s["error_after"][c]["chi2"] < s["error_before"][c]["chi2"] for c in ("act", "total"))

    better = sum(sim_better(r) for r in effect_cases)
    times = [r["time_s"] for r in results]
    return "\n".join(
        [
            "| goal (issue 11) | --baseline sim on the simulator's data |",
            "|---|---|",
            f"| >= 90 % of effects classified right | category {right_cat}/{len(inj)}, kind {right_kind}/{len(inj)} (and {named} found as another "
            "kind whose evidence names the injected one as fitting almost as well) |",
            f"| 0 false alarms on clean data | {false_clean} of {len(clean)} clean cases |",
            f"| delays 0.5 ms, sensor corners 15 % (gain 15 %, nonlinear levels 15 %) | {within}/{len(judged)} |",
            f"| the simulator's error drops (chi2 of theta/v and xdd/v, re-measured, after carrying) | {better}/{len(effect_cases)} |",
            f"| (not a goal) effects found beyond those injected | {extra} in {len(effect_cases)} effect cases |",
            f"| (issue 31) carries that did not lower the simulator's error (not carried) | "
            f"{sum(len((r['simulator'] or {}).get('not_lowering', [])) for r in results)} |",
            f"| (issue 31) cases whose carry made a channel's rms dB, rms deg or chi2 worse (said in the verdict) | "
            f"{sum(bool((r['simulator'] or {}).get('worse')) for r in results)} of {len(results)} |",
            f"| (issue 31) cases where the simulator, with the carry, cannot represent a band of the data | "
            f"{sum(bool((r['simulator'] or {}).get('cannot_represent')) for r in results)} of {len(results)} |",
            f"| (speed) diagnosis time per case | median {np.median(times):.0f} s, max {np.max(times):.0f} s |",
        ]
    )


def _line(r: dict) -> str:
    found = "; ".join(effect_text(row) for row in r["injected"]) or "-"
    extra = "; ".join(f"{e['category']}/{e['kind']}" for e in r["extra"]) or "-"
    s = r["simulator"]
    sim = " / ".join(f"{s['error_before'][c]['chi2']:.3g} -> {s['error_after'][c]['chi2']:.3g}" for c in ("act", "total")) if s else "-"
    carried = (
        ", ".join(
            f"{k} = {v:.4g}"
            for k, v in (s or {}).get("changes", {}).items()
            if k.startswith("beam.tip_body") or not k.startswith(("beam.", "arm.", "hydraulic.total", "hydraulic.leak"))
        )
        or "-"
    )
    return f"| {r['name']} | {r['verdict']} | {found} | {extra} | {carried} | {sim} | {r['time_s']:.0f} |"


def _one_blas_thread() -> None:
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one clean case and the 4 ms delay")
    ap.add_argument("--jobs", type=int, default=2, help="cases run at once (default 2: two cores)")
    ap.add_argument("--out", type=Path, default=HERE / "out")
    ap.add_argument("--only", action="append", default=[], metavar="TEXT", help="only cases whose name contains TEXT (repeatable)")
    args = ap.parse_args()
    plan = [CASES[0], CASES[3]] if args.quick else CASES
    if args.only:
        plan = [c for c in plan if any(t in c[0] for t in args.only)]
        if not plan:
            sys.exit("no case matches")
    # one BLAS thread per case when cases run side by side: with two each on two cores, the small SVDs of the fits
    # slowed some 10x (stop 20: a 6.7 s diagnosis took 57-113 s beside another)
    with ProcessPoolExecutor(max_workers=max(1, args.jobs), initializer=_one_blas_thread if args.jobs > 1 else None) as pool:
        futures = [pool.submit(run_case, *case) for case in plan]
        results = []
        for f in futures:
            r = f.result()
            results.append(r)
            print(_line(r), flush=True)
    summary = _summary(results)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "simulator.json").write_text(json.dumps({"cases": results}, indent=2) + "\n")
    table = [
        "# --baseline sim on the simulator's own data (generated by run_simulator.py)",
        "",
        summary,
        "",
        "## Cases",
        "",
        "| case | verdict | injected: found, parameter errors | found beyond the injected | carried (simulator value) | "
        "simulator chi2 theta/v / xdd/v before -> after | time [s] |",
        "|---|---|---|---|---|---|---|",
    ] + [_line(r) for r in results]
    (args.out / "simulator.md").write_text("\n".join(table) + "\n")
    print(summary)


if __name__ == "__main__":
    main()
