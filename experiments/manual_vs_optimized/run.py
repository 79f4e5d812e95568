"""Chapter 1 of the notebook: the hand-tuned 2-mode model (eq 1.3) against an optimised one.

The notebook optimised the 2-mode s^4 model (eq 1.1, 1.2) over 1-12 Hz with
phase weight 0 (magnitude only) and got eq 1.4. Here the same fit is run three
ways on the same data, from the same start (eq 1.3's frequencies and dampings,
gains read off the data):

* samii (bounded least squares, analytic Jacobian);
* the notebook's own procedure (Nelder-Mead looped 20 x 500 with its 0.01 % test);

and both are compared with eq 1.3 and eq 1.4 themselves (converted to SI, theta
assumed in degrees). Makes ``out/bode_overlay.png`` (the notebook's figures
1.5, 1.6), ``out/model_error.png``, ``out/table.md`` and ``out/results.json``.

The notebook's measured data are not available; by default the data are the
stand-in of ``samii.identify.studies.synthetic_rig_frf`` and every figure says so.
Run ``PYTHONPATH=src python experiments/manual_vs_optimized/run.py [--data FRF.csv]``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from samii import notebook as nb
from samii.identify.cli_studies import study_setup
from samii.identify.cost import FitProblem
from samii.identify.notebook_loop import nelder_mead_loop
from samii.identify.report import params_markdown
from samii.identify.starts import solve_gains
from samii.identify.structures import ModelStructure
from samii.identify.studies import manual_vs_optimized, to_notebook_units
from samii.viz.fit_plot import plot_fit_overlay, plot_model_error, save_figure

HERE = Path(__file__).resolve().parent
BAND = nb.EQ1_4_FIT_RANGE_HZ


def main() -> None:
    out, data, clean, note = study_setup(__doc__.splitlines()[0], HERE / "out")
    st = ModelStructure.notebook_2mode()
    t = time.perf_counter()
    study = manual_vs_optimized(data, band_hz=BAND, rng=np.random.default_rng(0))
    t_samii = time.perf_counter() - t
    res = study.samii
    problem = FitProblem(data, st, phase_weight=0.0, band_hz=BAND)
    x0 = solve_gains(problem, st.vector(study.manual))  # the same start samii's "given" start begins from
    t = time.perf_counter()
    loop = nelder_mead_loop(problem.cost, x0)
    t_nm = time.perf_counter() - t
    nm_params = st.params(loop.x)

    models = {
        "manual, eq 1.3": (st, study.manual),
        "notebook optimised, eq 1.4": (st, study.notebook_optimized),
        "notebook procedure (Nelder-Mead loop) on these data": (st, nm_params),
        "samii fit on these data": res,
    }
    save_figure(
        plot_fit_overlay(data, models, band_hz=BAND, title="Manual vs optimised 2-mode fit (notebook ch. 1, fig. 1.5/1.6)", note=note),
        out / "bode_overlay.png",
    )
    reference = clean if clean is not None else data
    what = "model - noise-free stand-in" if clean is not None else "model - data"
    ref_problem = FitProblem(reference, st, phase_weight=0.0)
    errors = {k: ref_problem.errors(st.vector(m.params if hasattr(m, "params") else m[1])) for k, m in models.items()}
    save_figure(plot_model_error(reference.freq_hz, errors, band_hz=BAND, title="2-mode models", note=note, what=what), out / "model_error.png")

    cost = {
        "manual eq 1.3": study.cost_manual,
        "notebook eq 1.4": study.cost_notebook_optimized,
        "notebook procedure": loop.cost,
        "samii": res.cost,
    }
    cols = {
        "manual eq 1.3": to_notebook_units(study.manual),
        "notebook eq 1.4": to_notebook_units(study.notebook_optimized),
        "notebook procedure": to_notebook_units(nm_params),
        "samii": to_notebook_units(res.params),
    }
    extra = {
        "cost (1-12 Hz, pw 0)": {k: f"{v:.5g}" for k, v in cost.items()},
        "wall time [s]": {
            "notebook procedure": f"{t_nm:.3g} ({loop.loops} loops, criterion {'met' if loop.criterion_met else 'not met'})",
            "samii": f"{t_samii:.3g} (converged {res.converged})",
        },
    }
    rms = {}
    for k, p in zip(cost, [study.manual, study.notebook_optimized, nm_params, res.params]):
        e = problem.errors(st.vector(p))
        rms[k] = " / ".join(f"{float(np.sqrt(np.mean(e[c][0] ** 2))):.3g}" for c in ("act", "base"))
    extra["RMS in band, act / base [dB]"] = rms
    text = (
        "# Manual vs optimised 2-mode fit (notebook chapter 1)\n\n"
        f"{note}\n\n"
        "2-mode s^4 model of eq 1.1/1.2 (gains B_k w_k^2), phase weight 0, band 1-12 Hz. Parameters in the notebook's units "
        "(theta assumed in degrees); samii with 95 % intervals. eq 1.3 and eq 1.4 were fitted to the notebook's measured data, "
        "so their costs here say how well they describe the stand-in, not how good they were.\n\n"
        + params_markdown(cols, st.param_names, stderr={"samii": to_notebook_units(res.stderr)}, extra_rows=extra)
        + "\nsamii warnings: "
        + ("; ".join(res.warnings) or "none")
        + "\n"
    )
    (out / "table.md").write_text(text)
    (out / "results.json").write_text(
        json.dumps(
            {
                "note": note,
                "cost": cost,
                "time_s": {"notebook_procedure": t_nm, "samii": t_samii},
                "samii": res.to_dict(),
                "notebook_procedure": {"params": nm_params, "loops": loop.loops, "criterion_met": loop.criterion_met},
            },
            indent=1,
        )
        + "\n"
    )
    for k, v in cost.items():
        print(f"{k:>20}: cost {v:.5g}")
    print(f"time: notebook procedure {t_nm:.3g} s, samii {t_samii:.3g} s")


if __name__ == "__main__":
    main()
