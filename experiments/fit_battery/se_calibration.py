"""Are the fit's standard errors honest on simulator rigs? Refit one rig under many noise seeds.

For each rig (``simulator_spread.py``'s draw: ``--seed`` and ``--cases``) the rig is measured as
the main job does under ``--records`` other sensor-noise seeds and fitted from its truth's values
(start given, no perturbed starts: this checks the uncertainty of the minimum, not the search).
Printed per parameter: the truth, the mean and scatter of the fits, the median reported standard
error, their ratio (about 1 for honest standard errors, below 1 for conservative ones) and the
bias in units of the scatter. The README's figures (scatter 0.27-0.84 times the standard errors)
are ``--seed 2 --cases 23 25 12 6`` and ``--seed 4 --cases 8 --records 12`` (out/se_calibration.txt).

Run:  python experiments/fit_battery/se_calibration.py --seed 2 --cases 23 25 [--records 10]
Measurements of the rigs' truths are cached in out/sim_cache/ as simulator_spread.py caches them.
"""

from __future__ import annotations

import argparse

import numpy as np
from criterion import KEYS


def calibrate(case: int, seed: int, records: int) -> list[str]:
    from simulator_spread import measure_case

    from samii.identify import ModelStructure, fit
    from samii.identify.fit import resolve_weighting
    from samii.measure.campaign import measure_swept
    from samii.measure.daq import SensorNoise
    from samii.sim.model import load_model
    from samii.sim.plugin import load_plugin

    load_plugin()
    rec = measure_case(case, seed)
    if "error" in rec:
        return [f"rig {case} of seed {seed}: {rec['error']}"]
    truth = rec["truth"]["params"]
    model = load_model(overrides=rec["overrides"])
    vals, ses = {k: [] for k in KEYS}, {k: [] for k in KEYS}
    for k in range(records):  # other seeds than the battery's own record ([seed, case, 1])
        data = measure_swept(model, noise=SensorNoise(), rng=np.random.default_rng([seed, case, 100 + k])).frf
        res = fit(
            data,
            ModelStructure.notebook_3mode(),
            phase_weight=0.1,
            weighting=resolve_weighting(data, None, "auto"),
            start=truth,
            n_perturbed=0,
            profile=False,
        )  # compared with the standard errors, not the profiles
        for p in KEYS:
            vals[p].append(res.params[p])
            ses[p].append(res.stderr[p])
    lines = []
    for p in KEYS:
        v, se = np.array(vals[p]) / 2 / np.pi, np.median(ses[p]) / 2 / np.pi
        t, sd = truth[p] / 2 / np.pi, float(np.std(v, ddof=1))
        lines.append(
            f"rig {case:3d} {p:>3}: truth {t:7.3f} Hz, fits {v.mean():7.3f} +- {sd:.3f} Hz, median SE {se:.3f} Hz, "
            f"scatter/SE {sd / se:.2f}, bias/scatter {(v.mean() - t) / sd:+.2f}"
        )
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--cases", type=int, nargs="+", default=[23, 25])
    ap.add_argument("--records", type=int, default=10)
    args = ap.parse_args()
    for case in args.cases:
        for line in calibrate(case, args.seed, args.records):
            print(line, flush=True)


if __name__ == "__main__":
    main()
