"""Chapter 9 of the notebook: 3-mode s^4 fits for phase weights 0, 0.1, ..., 0.5.

Makes, in ``out/``:

* ``bode_overlay.png``: data and the six fits (the notebook's figures 9.13, 9.14);
* ``model_error.png``: where each fit is wrong, along frequency (model minus the
  stand-in's noise-free response; model minus data when ``--data`` is given);
* ``rms_vs_weight.png``: RMS magnitude and phase error per channel against the weight;
* ``parameters.png``: every parameter against the weight with 95 % intervals,
  next to the notebook's own values (eq 9.3-9.12);
* ``table.md`` and ``results.json``.

The notebook's measured data are not available; by default the data are the
stand-in of ``samii.identify.studies.synthetic_rig_frf`` and every figure says so.
Run ``PYTHONPATH=src python experiments/phase_weight_sweep/run.py [--data FRF.csv]``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from samii import notebook as nb
from samii.identify.cli_studies import study_setup
from samii.identify.cost import FitProblem
from samii.identify.report import fits_markdown, params_markdown
from samii.identify.studies import NOTEBOOK_PHASE_WEIGHTS, phase_weight_sweep, to_notebook_units
from samii.viz.figures import save_figure
from samii.viz.fit_plot import plot_fit_overlay, plot_model_error, plot_panels, plot_parameter_sweep

HERE = Path(__file__).resolve().parent


def main() -> None:
    out, data, clean, note = study_setup(__doc__.splitlines()[0], HERE / "out")
    fits = phase_weight_sweep(data, weights=NOTEBOOK_PHASE_WEIGHTS, rng=np.random.default_rng(0))
    st = fits[0].structure
    label = {r.phase_weight: f"pw {r.phase_weight:g}" for r in fits}

    save_figure(
        plot_fit_overlay(
            data, {label[r.phase_weight]: r for r in fits}, title="Phase-weight sweep, 3-mode s⁴ model (notebook ch. 9, fig. 9.13/9.14)", note=note
        ),
        out / "bode_overlay.png",
    )

    reference = clean if clean is not None else data
    what = "model - noise-free stand-in" if clean is not None else "model - data"
    errors = {}
    for r in fits:
        e = FitProblem(reference, st, phase_weight=r.phase_weight).errors(st.vector(r.params))
        errors[label[r.phase_weight]] = e
    save_figure(
        plot_model_error(reference.freq_hz, errors, title="Where each phase weight puts the error", note=note, what=what), out / "model_error.png"
    )

    pws = [r.phase_weight for r in fits]
    rms = {
        k: {c: [float(np.sqrt(np.mean(errors[label[w]][c][i] ** 2))) for w in pws] for c in fits[0].channels}
        for i, k in enumerate(("RMS magnitude error [dB]", "RMS phase error [deg]"))
    }
    save_figure(
        plot_panels(pws, rms, xlabel="phase weight", title=f"Magnitude traded for phase: RMS of {what}, 0.1-40 Hz", note=note),
        out / "rms_vs_weight.png",
    )

    nbu = [to_notebook_units(r.params) for r in fits]
    nbse = [to_notebook_units(r.stderr) for r in fits]
    ref = {n: [nb.EQ9_FITS[w][n] for w in pws] for n in st.param_names} if all(w in nb.EQ9_FITS for w in pws) else None
    save_figure(
        plot_parameter_sweep(
            pws,
            nbu,
            nbse,
            st.param_names,
            xlabel="phase weight",
            reference=ref,
            reference_label="notebook eq 9.3-9.12 (its own data)",
            units=st.units(theta="deg"),
            title="Parameters against phase weight (notebook units: θ in deg assumed)",
            note=note,
        ),
        out / "parameters.png",
    )

    nb_cols = {f"notebook pw {w:g}": dict(nb.EQ9_FITS[w]) for w in pws if w in nb.EQ9_FITS}
    text = (
        "# Phase-weight sweep (notebook chapter 9)\n\n"
        f"{note}\n\n"
        "Parameters in the notebook's units (theta assumed in degrees: K1 x 180/pi, B x pi/180 from SI); "
        "samii values with 95 % intervals (sandwich covariance).\n\n"
        + fits_markdown({f"samii pw {r.phase_weight:g}": r for r in fits}, convert=to_notebook_units)
        + "\nThe notebook's own fits of its measured data (eq 9.3-9.12), for comparison of trends only:\n\n"
        + params_markdown(nb_cols, st.param_names)
    )
    (out / "table.md").write_text(text)
    (out / "results.json").write_text(json.dumps({"note": note, "fits": [r.to_dict() for r in fits]}, indent=1) + "\n")
    for r in fits:
        print(
            f"pw {r.phase_weight:g}: cost {r.cost:.5g}, converged {r.converged}, RMS act {r.rms_mag_db['act']:.3g} dB / {r.rms_phase_deg['act']:.3g} deg, base {r.rms_mag_db['base']:.3g} dB / {r.rms_phase_deg['base']:.3g} deg, tau {r.params['tau']:.4g}"
        )


if __name__ == "__main__":
    main()
