"""The notebook's mass-damping root-locus study (chapters 2 and 3), answered with numbers.

Models (see ``samii.design.rootlocus.default_models``):

* ``eq1.3_s4``: chapter 2's model (its quoted poles/zeros are eq 1.3's);
* ``eq1.3_s2equiv``: chapter 3's s^2 model is not printed; the s^2 model with
  each mode's residue matched at its resonance (``s2_params_matching_s4``);
* ``eq1.3_s2fit``: a second stand-in, an s^2 model fitted by ``samii.identify``
  to the eq 1.3 model's own frequency response over 1-12 Hz, magnitude only
  (chapter 1's band and cost); written to ``out/s2fit_params.json``;
* ``eq1.4_s4`` and ``eq9.4_s4``: the optimised 2-mode fit and the 3-mode fit,
  to check that the verdicts do not hinge on the fit.

Writes into ``out/``: ``summary.md`` (table), ``summary.json`` (everything),
and ``rlocus_<model>_<variant>.png`` (K_a > 0 and < 0, full and zoomed) for the
chapter 2/3 models. Run: ``python experiments/rootlocus_study/run.py`` (about 50 s); findings in README.md.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from samii import notebook as nb
from samii.design import rootlocus as rl
from samii.viz.rootlocus_plot import plot_variant

OUT = Path(__file__).resolve().parent / "out"
PLOT_MODELS = ("eq1.3_s4", "eq1.3_s2equiv")
FIT_BAND_HZ = (1.0, 12.0)  # eq 1.4's band (chapter 1)


def s2_fit_to_eq1_3() -> tuple[dict[str, float], dict]:
    """Fit the 2-mode s^2 structure to the eq 1.3 model's response (noise-free, 200 points, 1-12 Hz, phase weight 0)."""
    from samii.identify import ModelStructure, fit, synthesize

    s4 = ModelStructure.notebook_2mode()
    s2 = ModelStructure(n_modes=2, numerator="s2", tie_mode2=True, w2_factors=True)
    f = np.geomspace(*FIT_BAND_HZ, 200)
    data = synthesize(f, {c: s4.response(nb.EQ1_3_MANUAL, f, c) for c in ("act", "base")}, noise=None)
    res = fit(data, s2, phase_weight=0.0, start=rl.s2_params_matching_s4(nb.EQ1_3_MANUAL), rng=np.random.default_rng(0))
    info = {
        "source": "samii.identify.fit of the 2-mode s^2 structure to the eq 1.3 (s^4) model's theta/v and xdd/theta, 1-12 Hz, phase weight 0",
        "params": dict(res.params),
        "cost": float(res.cost),
        "converged": bool(getattr(res, "converged", True)),
    }
    return dict(res.params), info


def verdicts(summaries) -> str:
    """One line per variant: does 'no K_a of either sign beats no acceleration feedback' hold, on each model."""
    by_variant: dict[str, list] = {}
    for s in summaries:
        by_variant.setdefault(s.variant.name, []).append(s)
    lines = [
        "",
        "Verdict per variant (holds = no stable K_a of either sign raises the least damping of the base modes the feedback",
        f"can move by {100 * (rl.SIGNIFICANT_GAIN - 1):.0f} % without making another pole less damped than the least-damped one",
        "without feedback). Excluded: " + rl.EXCLUSION_REASON + ".",
        "",
    ]
    for name, group in by_variant.items():
        cells = []
        for s in group:
            verdict = "holds" if not s.beats_no_feedback else "does not hold"
            excl = f", mode {', '.join(map(str, s.excluded_modes))} excluded" if s.excluded_modes else ""
            cells.append(f"{s.model}: {verdict} ({s.best_ratio:.2f}x{excl})")
        lines.append(f"- {name}: " + "; ".join(cells))
    return "\n".join(lines) + "\n"


def main() -> None:
    OUT.mkdir(exist_ok=True)
    models = rl.default_models()
    try:
        p_fit, info = s2_fit_to_eq1_3()
        models = {**dict(list(models.items())[:2]), "eq1.3_s2fit": (p_fit, "s2"), **dict(list(models.items())[2:])}
        (OUT / "s2fit_params.json").write_text(json.dumps(info, indent=1))
    except ImportError as exc:  # identification not installed: the study stands without this cross-check
        print(f"skipping the s^2 fit: {exc}")
    summaries, loops = [], []
    for label, (p, num) in models.items():
        for v in rl.NOTEBOOK_VARIANTS:
            loop = rl.mass_damping_loop(p, numerator=num, variant=v, model=label)
            loops.append(loop)
            summaries.append(rl.summarize(loop))
    table = rl.summary_table(summaries) + verdicts(summaries)
    (OUT / "summary.md").write_text(table)
    (OUT / "summary.json").write_text(json.dumps([s.as_dict() for s in summaries], indent=1))
    for loop, s in zip(loops, summaries):
        if loop.model in PLOT_MODELS:
            plot_variant(loop, s, path=OUT / f"rlocus_{loop.model}_{loop.variant.name}.png")
    print(table)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
