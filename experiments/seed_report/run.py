"""Recompute the notebook's design figures and export the chapter 5-8 and 10 artefacts.

Writes into ``out/`` next to this file:

* ``seed_report.txt`` / ``seed_report.json``: ``samii design seed-report`` (eq 8.1-8.3, 10.1-10.9, gain);
* ``ccf_{2,3}mode_{accel,modal}.tex``: the symbolic canonical forms (chapters 5 and 7);
* ``canonical_check.json``: state space vs transfer functions (poles, numerator polynomials, frequency response);
* ``placement_poles.png``: chapter 8 pole sets, continuous and digital (T = 1 ms);
* ``cancel_locus.png``: chapter 10 root locus up to our gain and the notebook's.

Run: ``python experiments/seed_report/run.py`` (about 15 s).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from samii import notebook as nb
from samii.design import cancel, canonical, placement
from samii.design.seed_report import ZETA_EQ8_3, seed_report
from samii.viz.cancel_design_plot import plot_cancel_locus
from samii.viz.placement_design_plot import plot_pole_sets

OUT = Path(__file__).resolve().parent / "out"
SAMPLE_TIME_S = 1e-3  # the closed-loop issue runs controllers at 1 kHz; the notebook does not print its T


def main() -> None:
    OUT.mkdir(exist_ok=True)
    report = seed_report()
    (OUT / "seed_report.txt").write_text(report.text())
    (OUT / "seed_report.json").write_text(json.dumps(report.as_json(), indent=1))

    checks = {}
    for n_modes, p in ((2, nb.EQ1_4_OPTIMIZED), (3, nb.EQ9_4)):
        for outputs in ("accel", "modal"):
            form = canonical.derive_canonical_form(n_modes, outputs)
            (OUT / f"ccf_{n_modes}mode_{outputs}.tex").write_text(form.latex())
            checks[f"{n_modes}mode_{outputs}"] = canonical.compare_with_tf(form, p)
    (OUT / "canonical_check.json").write_text(json.dumps(checks, indent=1))

    model = canonical.numeric_statespace(canonical.derive_canonical_form(2, "accel"), nb.EQ1_4_OPTIMIZED)
    design = placement.design_placement(model, sample_time_s=SAMPLE_TIME_S, zeta=ZETA_EQ8_3)
    plot_pole_sets(design, path=OUT / "placement_poles.png")

    cd = cancel.design_pole_cancel(nb.EQ9_4, loop="theta")
    plot_cancel_locus(cd, notebook_gain=nb.EQ10_GAIN, path=OUT / "cancel_locus.png")

    print(report.text())
    for what in ("freq_response_rel", "numerator_rel"):
        worst = {k: max(v[o][what] for o in v if o != "poles") for k, v in checks.items()}
        print(f"canonical forms vs transfer functions, worst {what}:", {k: f"{x:.1e}" for k, x in worst.items()})
    print(
        f"theta loop DC gain at K = {cd.gain:.4g} as drawn: {1 / cd.reference_gain:.3f}; "
        f"the runnable controller scales theta_ref by {cd.reference_gain:.4g} by default (unit DC gain)"
    )
    print(f"wrote {OUT}")


if __name__ == "__main__":
    np.set_printoptions(precision=5)
    main()
