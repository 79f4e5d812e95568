"""The diagnosis on data with effects it is not told about: the confusion table (issue 11, item 6).

Every case is a 3-sweep swept sine (0.1-40 Hz, samii measure's default layout) through
``samii.diagnose.rig.EffectRig``, an independent linear rig: the notebook's eq 9.1/9.2 with
its parameters drawn within +-15 % of eq 9.4 (so the baseline is never the rig's exact
model), the position loop Kp = 180/pi V/rad, the DAQ's default white noise, sampled at
1 kHz, written as a time-series CSV with no metadata (the records are found from r) and
diagnosed with ``samii.diagnose.diagnosis.diagnose`` against the notebook baseline.

Cases: clean controls at three amplitudes and several noise seeds, each single effect of
the library at rig-like values, and combinations. Written to ``out/``:

* ``results.json``: per case what was injected, what was found, parameter errors, the
  error before and after, the time;
* ``table.md``: the confusion table (category found against category injected), the
  goals of issue 11 beside what the battery gives, and every case in one line.

Run ``python experiments/diagnose_battery/run.py [--quick]`` (1-19 s a case, about 2.5 minutes in all).
``--seed-offset N --long --out DIR`` runs the same cases on other rigs and noise, with 6-minute files:
a check on cases the battery was not tuned on (out_seed300_long/, out_seed300/).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from samii.diagnose.diagnosis import diagnose
from samii.diagnose.rig import EffectRig
from samii.measure.excitation import SweptSine
from samii.measure.measured import from_timeseries

HERE = Path(__file__).resolve().parent
FS = 1000.0
#: Spread of the rig's parameters around eq 9.4 (uniform, each parameter its own draw).
SPREAD = 0.15

# (name, EffectRig keywords, injected [(category, kind, {param: true value})])
SINGLE = [
    ("command delay 2 ms", {"command_delay_s": 0.002}, [("delay", "command", {"delay_s": 0.002})]),
    ("command delay 4 ms", {"command_delay_s": 0.004}, [("delay", "command", {"delay_s": 0.004})]),
    ("command delay 8 ms", {"command_delay_s": 0.008}, [("delay", "command", {"delay_s": 0.008})]),
    ("theta delay 3 ms", {"theta_delay_s": 0.003}, [("delay", "theta_sensor", {"delay_s": 0.003})]),
    ("accel delay 3 ms", {"accel_delay_s": 0.003}, [("delay", "accel_sensor", {"delay_s": 0.003})]),
    ("base mode 15 Hz", {"base_mode": (15.0, 0.02, 0.02)}, [("extra_mode", "base_mode", {"freq_hz": 15.0})]),
    ("base mode 6 Hz", {"base_mode": (6.0, 0.02, -0.01)}, [("extra_mode", "base_mode", {"freq_hz": 6.0})]),
    ("base mode 35 Hz", {"base_mode": (35.0, 0.02, 0.02)}, [("extra_mode", "base_mode", {"freq_hz": 35.0})]),
    ("act mode 15/14 Hz", {"act_mode": (15.0, 0.02, 14.0, 0.02)}, [("extra_mode", "act_mode", {"freq_hz": 15.0, "zero_freq_hz": 14.0})]),
    ("accel LP1 30 Hz", {"accel_lowpass_hz": 30.0}, [("sensor", "accel_lowpass", {"corner_hz": 30.0})]),
    ("accel LP2 60 Hz", {"accel_lowpass_hz": 60.0, "accel_lowpass_order": 2}, [("sensor", "accel_lowpass2", {"corner_hz": 60.0})]),
    ("accel HP 0.3 Hz", {"accel_highpass_hz": 0.3}, [("sensor", "accel_highpass", {"corner_hz": 0.3})]),
    ("accel HP 1 Hz", {"accel_highpass_hz": 1.0}, [("sensor", "accel_highpass", {"corner_hz": 1.0})]),
    ("valve 50 Hz", {"valve_hz": 50.0, "valve_zeta": 0.7}, [("actuator", "valve", {"freq_hz": 50.0})]),
    ("valve 80 Hz", {"valve_hz": 80.0, "valve_zeta": 0.5}, [("actuator", "valve", {"freq_hz": 80.0})]),
]
COMBOS = [
    (
        "delay 4 ms + HP 0.3 Hz",
        {"command_delay_s": 0.004, "accel_highpass_hz": 0.3},
        [("delay", "command", {"delay_s": 0.004}), ("sensor", "accel_highpass", {"corner_hz": 0.3})],
    ),
    (
        "delay 4 ms + LP1 30 Hz",
        {"command_delay_s": 0.004, "accel_lowpass_hz": 30.0},
        [("delay", "command", {"delay_s": 0.004}), ("sensor", "accel_lowpass", {"corner_hz": 30.0})],
    ),
    (
        "base mode 15 Hz + accel delay 3 ms",
        {"base_mode": (15.0, 0.02, 0.02), "accel_delay_s": 0.003},
        [("extra_mode", "base_mode", {"freq_hz": 15.0}), ("delay", "accel_sensor", {"delay_s": 0.003})],
    ),
]
#: Added later than the others (after them in the plan, so the others keep their seeds): a leaky actuator integrator,
#: alone (gravity's pull making it a right-half-plane pole, as in samii's simulator; leakage against a restoring load)
#: and beside the accelerometer's AC coupling, the other low-frequency effect.
LATER = [
    ("leak +0.2 1/s", {"leak_per_s": 0.2}, [("actuator", "leak", {"pole_per_s": 0.2})]),
    ("leak -0.5 1/s", {"leak_per_s": -0.5}, [("actuator", "leak", {"pole_per_s": -0.5})]),
    (
        "leak +0.2 1/s + HP 0.3 Hz",
        {"leak_per_s": 0.2, "accel_highpass_hz": 0.3},
        [("actuator", "leak", {"pole_per_s": 0.2}), ("sensor", "accel_highpass", {"corner_hz": 0.3})],
    ),
]
#: A valve nonlinearity (time-domain loop, samii.diagnose.rig.EffectRig.valve_nonlinearity); files at the amplitudes given.
NONLINEAR = [
    ("dead band 5 mV", {"valve_nonlinearity": ("dead_band", 0.005)}, [("nonlinear", "dead_band", {"dead_band_v": 0.005})], (0.1,)),
    ("dead band 20 mV", {"valve_nonlinearity": ("dead_band", 0.02)}, [("nonlinear", "dead_band", {"dead_band_v": 0.02})], (0.1,)),
    ("saturation 80 mV", {"valve_nonlinearity": ("saturation", 0.08)}, [("nonlinear", "saturation", {"saturation_v": 0.08})], (0.1,)),
    ("saturation 150 mV", {"valve_nonlinearity": ("saturation", 0.15)}, [("nonlinear", "saturation", {"saturation_v": 0.15})], (0.1,)),
    ("hysteresis 5 mV", {"valve_nonlinearity": ("hysteresis", 0.005)}, [("nonlinear", "hysteresis", {"hysteresis_v": 0.005})], (0.1,)),
    ("hysteresis 20 mV", {"valve_nonlinearity": ("hysteresis", 0.02)}, [("nonlinear", "hysteresis", {"hysteresis_v": 0.02})], (0.1,)),
    ("asymmetry 10 %", {"valve_nonlinearity": ("asymmetry", 0.1)}, [("nonlinear", "asymmetry", {"asymmetry_fraction": 0.1})], (0.1,)),
    (
        "dead band 5 mV, files at 0.05 and 0.3 V",
        {"valve_nonlinearity": ("dead_band", 0.005)},
        [("nonlinear", "dead_band", {"dead_band_v": 0.005})],
        (0.05, 0.3),
    ),
    (
        "saturation 0.4 V, files at 0.1 and 0.3 V",
        {"valve_nonlinearity": ("saturation", 0.4)},
        [("nonlinear", "saturation", {"saturation_v": 0.4})],
        (0.1, 0.3),
    ),
]
#: Clean controls through the same paths: the time-domain loop (a saturation no command reaches) and two amplitudes.
CLEAN_PATHS = [
    ("clean, time-domain loop, seed 9", {"valve_nonlinearity": ("saturation", 100.0)}, [], (0.1,)),
    ("clean, files at 0.05 and 0.3 V", {}, [], (0.05, 0.3)),
]
CLEAN = [(f"clean {a:g} V seed {s}", a, s) for a, seeds in ((0.05, (1, 2)), (0.1, (3, 4, 5, 6)), (0.3, (7, 8))) for s in seeds]
#: Issue 11's goals: delay within 0.5 ms, extra-mode frequencies within 2 %, sensor corners within 15 %; the
#: issue states none for the actuator, whose valve corner is judged like a sensor's (15 %), nor for a nonlinearity's
#: level (judged alike).
TOLERANCE = {
    ("delay", "delay_s"): ("abs", 5e-4),
    ("extra_mode", "freq_hz"): ("rel", 0.02),
    ("extra_mode", "zero_freq_hz"): ("rel", 0.02),
    ("sensor", "corner_hz"): ("rel", 0.15),
    ("actuator", "freq_hz"): ("rel", 0.15),
    ("actuator", "pole_per_s"): ("rel", 0.15),
    ("nonlinear", "dead_band_v"): ("rel", 0.15),
    ("nonlinear", "saturation_v"): ("rel", 0.15),
    ("nonlinear", "hysteresis_v"): ("rel", 0.15),
    ("nonlinear", "asymmetry_fraction"): ("rel", 0.15),
}


#: --long: three 120 s sweeps (6 minutes in all, issue 11 item 7's file) instead of samii measure's 84 s
LONG_SWEEP = {"seconds_per_octave": 8.0, "cycles_per_octave": 4.0}
_SWEEP_KW: dict = {}


def _sweep(amplitude_v: float) -> np.ndarray:
    sw = SweptSine(repetitions=3, amplitude_v=amplitude_v, **_SWEEP_KW)
    return sw.signal(np.arange(int(round(sw.duration_s * FS))) / FS)


def match_injected(found: list, injected: list, tolerance: dict = TOLERANCE, modelled_hold_s: float = 0.0) -> tuple[list[dict], list]:
    """Each injected (category, kind, truth) matched to a found effect (the same kind, else the same
    category), its parameters' errors and whether they are within ``tolerance``; and the found
    effects no injection matched. ``modelled_hold_s``: the command's hold the diagnosis's baseline carries
    (samii.diagnose.sampling); the EffectRig's command is analogue, so a command delay found beyond it is judged
    with it (hold + found against the injected: the data hold the sum, and a delay as long as the hold cannot be
    told from it)."""
    rows, unmatched = [], list(found)
    for cat, kind, truth in injected:
        alt = f"{cat}/{kind} in its place fits almost as well"
        match = (
            next((e for e in unmatched if e.category == cat and e.kind == kind), None)
            or next((e for e in unmatched if e.category == cat), None)
            or next((e for e in unmatched if alt in e.evidence), None)
        )
        if match is not None:
            unmatched.remove(match)
        errors = {}
        if match is not None and match.kind == kind:
            for p, v in truth.items():
                if p in match.params:  # (an amplitude-only nonlinear finding has no level)
                    how, _ = tolerance[(cat, p)]
                    found_v = match.params[p] + (modelled_hold_s if (cat, kind, p) == ("delay", "command", "delay_s") else 0.0)
                    errors[p] = found_v - v if how == "abs" else found_v / v - 1.0
        # nothing to judge when no parameter was injected or none found
        within = all(abs(e) <= tolerance[(cat, p)][1] for p, e in errors.items()) if errors else None
        # found as another kind whose evidence names the injected one as fitting almost as well: the data cannot tell them apart
        named = match is not None and match.kind != kind and alt in match.evidence
        rows.append(
            {
                "category": cat,
                "kind": kind,
                "truth": truth,
                "found_category": None if match is None else match.category,
                "found_kind": None if match is None else match.kind,
                "found_params": None if match is None else match.params,
                "errors": errors,
                "within_tolerance": within,
                "named_alternative": named,
            }
        )
    return rows, unmatched


#: A saturation the command never reaches is not in the data: its rig is drawn again (like an unstable one) until
#: the command's peak in some file passes the level by this factor. Seed 905 (--seed-offset 700): the drawn rig's
#: resonance kept the 0.1 V sweep's command to 117 mV, under a 150 mV saturation; "missed" there was right.
ACTIVE = 1.1
MAX_DRAWS = 50


def _law_reached(effects: dict, series: list) -> float | None:
    """The commands' peak over a saturation's level (None without one): a saturation acts only above it."""
    law = effects.get("valve_nonlinearity")
    if law is None or law[0] != "saturation":
        return None
    return max(float(np.max(np.abs(ts.v))) for ts in series) / law[1]


def run_case(name: str, effects: dict, injected: list, *, amplitude_v: float | tuple, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    amps = tuple(amplitude_v) if isinstance(amplitude_v, (tuple, list)) else (amplitude_v,)
    for draw in range(1, MAX_DRAWS + 1):  # noqa: B007 - the count of draws is read after the loop
        rig = EffectRig.drawn(rng, spread=SPREAD, **effects)
        series = [rig.simulate(_sweep(a), sample_rate_hz=FS, rng=rng) for a in amps]
        reached = _law_reached(effects, series)
        if reached is None or reached >= ACTIVE or not injected:  # (a clean control's law is meant not to act)
            break
    else:
        raise RuntimeError(f"{name}: no rig in {MAX_DRAWS} draws whose command reaches its saturation")
    files = [from_timeseries(ts, source=f"{name} @ {a:g} V") for ts, a in zip(series, amps)]
    t0 = time.perf_counter()
    d = diagnose(files)
    elapsed = time.perf_counter() - t0
    hold = d.after.baseline.hold_s[0] if d.after.baseline.hold_s else 0.0
    rows, unmatched = match_injected([e for e in d.effects if not e.expected], injected, modelled_hold_s=hold)
    return {
        "modelled_hold_s": hold,
        "name": name,
        "amplitude_v": list(amps),
        "seed": seed,
        "injected": rows,
        "extra": [{"category": e.category, "kind": e.kind, "params": e.params} for e in unmatched],
        "expected": [{"kind": e.kind, "params": e.params} for e in d.effects if e.expected],
        "verdict": d.verdict,
        "unexplained": [b.to_dict() for b in d.unexplained],
        "refused": [{"round": x["round"], "effect": x["effect"], "class": x["class"]} for x in d.refused],
        "error_before": {k: v.to_dict() for k, v in d.error_before.items()},
        "error_after": {k: v.to_dict() for k, v in d.error_after.items()},
        "harmonic_error": None if d.harmonic_error is None else {"before": d.harmonic_error[0].to_dict(), "after": d.harmonic_error[1].to_dict()},
        "time_s": elapsed,
        "rig_draws": draw,
        "command_peak_over_level": reached,
    }


def _confusion(results: list[dict]) -> str:
    cats = ["delay", "extra_mode", "sensor", "actuator", "nonlinear"]
    cols = cats + ["missed"]
    counts = {c: dict.fromkeys(cols, 0) for c in cats + ["(none)"]}
    for r in results:
        for row in r["injected"]:
            counts[row["category"]][row["found_category"] or "missed"] += 1
        for e in r["extra"]:
            counts["(none)"][e["category"]] += 1
    lines = ["| injected \\ found | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for c in cats + ["(none)"]:
        lines.append(f"| {c} | " + " | ".join(str(counts[c][k]) if not (c == "(none)" and k == "missed") else "" for k in cols) + " |")
    return "\n".join(lines)


def _refused_text(results: list[dict]) -> str:
    """The candidates refused over the battery, by class (samii.diagnose.evidence.REFUSALS)."""
    from collections import Counter

    counts = Counter(x["class"] for r in results for x in r.get("refused", []))
    cases = sum(1 for r in results if r.get("refused"))
    return f"{sum(counts.values())} in {cases} cases: " + ", ".join(f"{c} {n}" for c, n in counts.most_common())


def _summary(results: list[dict]) -> tuple[str, dict]:
    inj = [row for r in results for row in r["injected"]]
    right_cat = sum(row["found_category"] == row["category"] for row in inj)
    right_kind = sum(row["found_kind"] == row["kind"] for row in inj)
    named = sum(bool(row.get("named_alternative")) for row in inj)
    clean = [r for r in results if not r["injected"]]
    false_clean = sum(1 for r in clean if r["verdict"] != "none" or r["extra"])
    extra = sum(len(r["extra"]) for r in results if r["injected"])
    tol = [row for row in inj if row["within_tolerance"] is not None]
    within = sum(bool(row["within_tolerance"]) for row in tol)
    # with a nonlinearity whose law fits, the error after is the linear model's on the data divided by its describing function
    improved = [r for r in results if r["injected"]]

    def better(r):
        """No channel's chi2 above before, and their sum lower; with a nonlinear law, its harmonics' chi2 counts
        (a law is explained by the harmonics it predicts: an asymmetric gain's describing function is a plain
        gain the baseline holds, so theta/v and xdd/v cannot move)."""
        pairs = [(r["error_before"][c]["chi2"], r["error_after"][c]["chi2"]) for c in ("act", "total")]
        if r.get("harmonic_error"):
            pairs.append((r["harmonic_error"]["before"]["chi2"], r["harmonic_error"]["after"]["chi2"]))
        return all(a <= b for b, a in pairs) and sum(a for _, a in pairs) < sum(b for b, _ in pairs)

    n_better = sum(better(r) for r in improved)
    times = [r["time_s"] for r in results]
    stats = {
        "effects_injected": len(inj),
        "category_right": right_cat,
        "kind_right": right_kind,
        "named_alternative": named,
        "clean_cases": len(clean),
        "clean_false_alarms": false_clean,
        "extra_effects_in_effect_cases": extra,
        "parameters_within_tolerance": within,
        "parameters_judged": len(tol),
        "error_after_below_before": n_better,
        "effect_cases": len(improved),
        "time_s_median": float(np.median(times)),
        "time_s_max": float(np.max(times)),
    }
    text = "\n".join(
        [
            "| goal (issue 11) | battery |",
            "|---|---|",
            f"| >= 90 % of effects classified right | category {right_cat}/{len(inj)} ({100 * right_cat / len(inj):.0f} %), kind {right_kind}/{len(inj)}"
            f" (and {named} found as another kind whose evidence names the injected one as fitting almost as well) |",
            f"| 0 false alarms on clean data | {false_clean} of {len(clean)} clean cases |",
            f"| delays 0.5 ms, mode frequencies 2 %, sensor corners 15 % | {within}/{len(tol)} effects found with the right kind within tolerance |",
            f"| error after below before in every case with an effect | {n_better}/{len(improved)} (chi2 of theta/v and xdd/v, neither "
            "above before and their sum below; with a nonlinear law found, its harmonics' chi2 counts too, and theta/v and xdd/v are "
            "after its describing function is divided out where it fits) |",
            f"| (not a goal) effects found beyond those injected | {extra} in {len(improved)} effect cases |",
            f"| candidates that passed the F-test, refused (the data do not show them) | {_refused_text(results)} |",
            f"| (speed) diagnosis time per case | median {stats['time_s_median']:.1f} s, max {stats['time_s_max']:.1f} s |",
        ]
    )
    return text, stats


def effect_text(row: dict) -> str:
    """One injected effect of a case: what it was found as, and its parameters' errors."""
    if row["found_kind"] is None:
        return f"{row['kind']}: MISSED"
    errs = ", ".join(f"{p} {1e3 * e:+.2f} ms" if p == "delay_s" else f"{p} {100 * e:+.1f} %" for p, e in row["errors"].items())
    ok = (
        ""
        if row["found_kind"] == row["kind"]
        else f" (as {row['found_kind']}{', named as fitting almost as well' if row.get('named_alternative') else ''})"
    )
    return f"{row['kind']}{ok} {errs}".rstrip()


def _line(r: dict) -> str:
    found = "; ".join(effect_text(row) for row in r["injected"]) or "-"
    extra = "; ".join(f"{e['category']}/{e['kind']} " + ", ".join(f"{k} {v:.4g}" for k, v in e["params"].items()) for e in r["extra"]) or "-"
    eb, ea = r["error_before"], r["error_after"]
    err = " / ".join(f"{eb[c]['chi2']:.3g} -> {ea[c]['chi2']:.3g}" for c in ("act", "total"))
    he = r.get("harmonic_error")
    harm = "-" if not he else f"{he['before']['chi2']:.3g} -> {he['after']['chi2']:.3g}"
    return f"| {r['name']} | {r['verdict']} | {found} | {extra} | {err} | {harm} | {r['time_s']:.1f} |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one clean case, three single effects, one combination")
    ap.add_argument("--out", type=Path, default=HERE / "out")
    ap.add_argument("--nonlinear-only", action="store_true", help="only the nonlinear cases and their clean controls (results merged into out/)")
    ap.add_argument("--table-only", action="store_true", help="rewrite table.md from out/results.json (tolerances re-applied), no runs")
    ap.add_argument(
        "--seed-offset",
        type=int,
        default=0,
        help="added to every case's seed: other rigs and noise, the same effects (a check on cases the battery was not tuned on)",
    )
    ap.add_argument("--long", action="store_true", help="three 120 s sweeps per file (a 6-minute file) instead of 84 s ones")
    args = ap.parse_args()
    if args.long:
        _SWEEP_KW.update(LONG_SWEEP)
    if args.table_only:
        results = json.loads((args.out / "results.json").read_text())["cases"]
        for r in results:
            for row in r["injected"]:
                if row["errors"]:
                    row["within_tolerance"] = all(abs(e) <= TOLERANCE[(row["category"], p)][1] for p, e in row["errors"].items())
        _write(args.out, results)
        return
    plan = [(n, {}, [], a, s) for n, a, s in CLEAN]
    plan += [(n, kw, inj, 0.1, 100 + i) for i, (n, kw, inj) in enumerate(SINGLE + COMBOS + LATER)]
    plan += [(n, kw, inj, amps, 200 + i) for i, (n, kw, inj, amps) in enumerate(CLEAN_PATHS + NONLINEAR)]
    if args.quick:
        plan = plan[2:3] + plan[len(CLEAN) : len(CLEAN) + 3] + plan[-len(NONLINEAR) - 2 : -len(NONLINEAR)] + plan[-len(NONLINEAR) :][:3]
    elif args.nonlinear_only:
        plan = plan[-len(NONLINEAR) - len(CLEAN_PATHS) :]
    results = []
    for name, kw, inj, amp, seed in plan:
        r = run_case(name, kw, inj, amplitude_v=amp, seed=seed + args.seed_offset)
        results.append(r)
        print(_line(r), flush=True)
    if args.nonlinear_only and (args.out / "results.json").exists():
        mine = {r["name"] for r in results}
        results = [r for r in json.loads((args.out / "results.json").read_text())["cases"] if r["name"] not in mine] + results
    _write(args.out, results)


def _write(out: Path, results: list[dict]) -> None:
    summary, stats = _summary(results)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps({"stats": stats, "cases": results}, indent=2) + "\n")
    table = [
        "# Diagnosis battery (generated by run.py)",
        "",
        summary,
        "",
        "## Confusion table (category found against injected; '(none)' counts effects found where none was injected, clean cases included)",
        "",
        _confusion(results),
        "",
        "## Cases",
        "",
        "| case | verdict | injected: found, parameter errors | found beyond the injected | chi2 theta/v / xdd/v before -> after | chi2 of the harmonics before -> after | time [s] |",
        "|---|---|---|---|---|---|---|",
    ] + [_line(r) for r in results]
    (out / "table.md").write_text("\n".join(table) + "\n")
    print(summary)
    print(_confusion(results))


if __name__ == "__main__":
    main()
