"""Does `samii fit` find the physical minimum on simulator measurements of rigs it was not built on?

Each case draws the simulator's physical parameters (clamp stiffness, joint-1
stiffness, beam length, oil volume, bulk modulus, position gain) log-uniformly
around the embedded model, measures it as the main job does (swept sine
0.1-40 Hz, 3 repetitions, 0.1 V, sensor noise of ``SensorNoise()``, its own
seed) and fits the notebook's 3-mode s^4 model as `samii fit` does by default
(coherence weighting, phase weight 0.1, both starts + 2 perturbed).

The truth is the minimum of the same cost (the data's points and coherence
weights) on the noise-free linearised FRF of that rig, started at the
linearisation's physical values: base modes with joint 2 held (w1, w2 = wz,
w3) and the servo loop's pair (wp), every lightly damped coupled pair between
2 and 25 Hz tried as wp and the lowest cost kept. A fit is in the right
minimum when wp, w1, wz and w3 are each within 2 % of the truth or within 3
standard errors of it (the issue's criterion; mode 3 often sits where the
0.1 V sweep's data are noise). A rig whose servo loop is unstable (`samii measure` refuses it:
it oscillates on its own) is reported and skipped.

Run:  python experiments/fit_battery/simulator_spread.py [--cases 40] [--seed 0] [--jobs 2]
Measurements are cached in out/sim_cache/ (delete it to re-measure).
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from criterion import KEYS, N_SE, REL_TOL, coverage_line, row

OUT = Path(__file__).resolve().parent / "out"
#: (name, low factor, high factor) of each spread parameter, drawn log-uniformly
SPREAD = (
    ("beam.clamp_stiffness_Nm_rad", 0.5, 2.0),
    ("arm.joint1_stiffness_Nm_rad", 0.6, 1.6),
    ("beam.length_m", 0.85, 1.15),
    ("hydraulic.total_volume", 0.6, 1.6),
    ("hydraulic.bulk_modulus", 0.7, 1.4),
    ("hydraulic.position_gain", 0.7, 1.4),
)


def draw(case: int, seed: int) -> dict[str, float]:
    rng = np.random.default_rng([seed, case])
    return {name: float(np.exp(rng.uniform(np.log(lo), np.log(hi)))) for name, lo, hi in SPREAD}


def _overrides(factors: dict[str, float]) -> dict[str, float]:
    from samii.sim.model import default_params

    p = default_params()
    out = {}
    for name, f in factors.items():
        group, field = name.split(".")
        out[name] = getattr(getattr(p, group), field) * f
    return out


def truth(model, overrides, data) -> dict:
    """The structure's minimum on the noise-free linearised FRF at the data's points and weights, in the physical basin."""
    from samii.frequency_response import FrequencyResponse
    from samii.identify import ModelStructure, fit
    from samii.measure.campaign import linearised_frf
    from samii.sim.linearize import modes_report

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        rep = modes_report(overrides=overrides)
    modes = [2 * np.pi * m.freq_hz for m in rep.base_modes[:3]]
    zetas = [m.zeta for m in rep.base_modes[:3]]
    lin = linearised_frf(model, data.freq_hz)
    frf = FrequencyResponse(
        data.freq_hz,
        act=lin.act,
        base=lin.base,
        total=lin.total,
        act_coh=data.act_coh,
        base_coh=data.base_coh,
        total_coh=data.total_coh,
        metadata=dict(data.metadata),
    )
    st = ModelStructure.notebook_3mode()
    pairs = [p for p in rep.coupled_poles if p.imag > 2 * np.pi * 2 and p.imag < 2 * np.pi * 25 and -p.real / abs(p) < 0.5]
    best = None
    for p in pairs:
        wp = float(abs(p))
        # K1 and the B's are placeholders (a given start's gains are read off the data, starts.snap_to_peaks); tau = 3 wp
        # as auto_start (eq 9.4: 2.9); dampings floored so that no start is a razor-sharp mode
        start = dict(
            K1=0.4,
            wp=wp,
            zp=max(-p.real / wp, 0.05),
            wz=modes[1],
            zz=max(zetas[1], 0.01),
            tau=3 * wp,
            w1=modes[0],
            z1=max(zetas[0], 0.01),
            w3=modes[2],
            z3=max(zetas[2], 0.01),
            B1=-0.02,
            B2=0.02,
            B3=0.003,
        )
        res = fit(frf, st, phase_weight=0.1, weighting="coherence", start=start, n_perturbed=0, profile=False)  # the minimum only
        if best is None or res.cost < best.cost:
            best = res
    return {"params": dict(best.params), "base_modes_hz": [w / 2 / np.pi for w in modes], "cost": best.cost}


def measure_case(case: int, seed: int, cache: Path = OUT / "sim_cache") -> dict:
    """Draw rig ``case`` of ``seed``, measure it and find its truth; its FRF and record cached in ``cache``."""
    from samii.formats import write_frf_csv
    from samii.measure.campaign import measure_swept
    from samii.measure.daq import SensorNoise
    from samii.sim.linearize import modes_report
    from samii.sim.model import load_model
    from samii.sim.plugin import load_plugin

    load_plugin()
    cache.mkdir(parents=True, exist_ok=True)
    path = cache / f"seed{seed}_case{case:03d}.csv"
    meta_path = path.with_suffix(".json")
    if meta_path.exists():
        return json.loads(meta_path.read_text())
    factors = draw(case, seed)
    ov = _overrides(factors)
    rec = {"case": case, "factors": factors, "overrides": ov, "frf": str(path)}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            poles = modes_report(overrides=ov, max_freq_hz=200.0).coupled_poles
        if poles.real.max() > 0:  # `samii measure` refuses such a rig (exit 3): it oscillates on its own
            worst = poles[np.argmax(poles.real)]
            raise RuntimeError(f"servo loop unstable: pole at {worst.real:.3g} {worst.imag:+.3g}j 1/s")
        model = load_model(overrides=ov)
        m = measure_swept(model, noise=SensorNoise(), rng=np.random.default_rng([seed, case, 1]))
        write_frf_csv(m.frf, path, overwrite=True)
        rec["truth"] = truth(model, ov, m.frf)
    except RuntimeError as exc:  # an unstable rig is a finding, not a fit case
        rec["error"] = f"{type(exc).__name__}: {exc}"
    meta_path.write_text(json.dumps(rec, indent=1) + "\n")
    return rec


def fit_case(rec: dict) -> dict:
    from samii.formats import read_frf_csv
    from samii.identify import ModelStructure, fit
    from samii.identify.fit import resolve_weighting

    data = read_frf_csv(rec["frf"])
    t0 = time.perf_counter()
    res = fit(data, ModelStructure.notebook_3mode(), phase_weight=0.1, weighting=resolve_weighting(data, None, "auto"))
    wall = time.perf_counter() - t0
    return {"case": rec["case"], **row(res, rec["truth"]["params"], wall), "starts": res.starts}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    with ProcessPoolExecutor(args.jobs) as ex:
        recs = list(ex.map(measure_case, range(args.cases), [args.seed] * args.cases))
        good = [r for r in recs if "error" not in r]
        rows = list(ex.map(fit_case, good))
    for r in recs:
        if "error" in r:
            print(f"case {r['case']:3d}: not measured ({r['error'][:100]})")
    n_ok = sum(r["ok"] for r in rows)
    n_said = sum(r["said"] for r in rows)
    print(f"{'case':>4} {'right':>5} {'sound':>5}  " + "  ".join(f"{k + ' fit/true Hz':>16}" for k in KEYS) + "   wall")
    for r in rows:
        cells = [f"{r['params_hz'][k]:6.2f}/{r['truth_hz'][k]:6.2f}{'' if r['errs'][k][2] else '*':1}" for k in KEYS]
        verdict = "yes" if r["ok"] else ("said" if r["said"] else "NO")
        print(f"{r['case']:4d} {verdict:>5} {'yes' if r['sound'] else 'no':>5}  " + "  ".join(f"{c:>16}" for c in cells) + f"  {r['wall_s']:5.1f} s")
    print(
        f"\n(* missed: not within {REL_TOL:.0%} of the truth or {N_SE:g} standard errors (the fit's profile interval at that level); 'said': every miss named as not determined by the data, or the fit not sound)"
    )
    print(
        f"right minimum in {n_ok} of {len(rows)} measured rigs, {n_said} more where the fit said which parameter it cannot tell, "
        f"{len(rows) - n_ok - n_said} wrong without saying so ({len(recs) - len(rows)} rigs not measurable); "
        f"sound {sum(r['sound'] for r in rows)}; fit wall median {np.median([r['wall_s'] for r in rows]):.1f} s"
    )
    print(
        f"within {REL_TOL:.0%} or {N_SE:g} local standard errors (value +- {N_SE:g} SE, not the profile): {sum(r['ok_local'] for r in rows)} of {len(rows)}"
    )
    print(coverage_line(rows))
    (OUT / f"simulator_spread_seed{args.seed}.json").write_text(json.dumps(rows, indent=1, default=float) + "\n")


if __name__ == "__main__":
    main()
