"""Chapter 4 of the notebook: s^2 against s^4 numerator of xdd/theta, 3 modes, phase weight 0.1.

The notebook found the comparison "somewhat inconclusive" on 0.1-40 Hz data: both
fit, the s^4 model follows the lack of roll-off from 20 to 40 Hz a little
better, and "Bode data would need to be taken over a wider range" to decide.
This script makes

* ``out/bode_overlay.png``: both fits on theta/v, xdd/theta and xdd/v (figures
  4.1-4.3), the models drawn to 100 Hz beyond the data to show where they part;
* ``out/bandwidth.png``: how far the data must reach before the two are told
  apart: both models fitted to stand-in data ending at 20 ... 100 Hz, their
  cost and base-channel RMS error against the band edge;
* ``out/table.md`` and ``out/results.json``.

The notebook's measured data are not available; by default the data are the
stand-in of ``samii.identify.studies.synthetic_rig_frf`` (an s^4 system by
construction, so the bandwidth study says how much band a 3-average swept
sine needs to confirm s^4, not which model the rig follows). Run
``PYTHONPATH=src python experiments/s2_vs_s4/run.py [--data FRF.csv]``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from samii.identify.cli_studies import study_setup
from samii.identify.report import fits_markdown
from samii.identify.studies import STANDIN_SEED, s2_vs_s4, synthetic_rig_frf, to_notebook_units
from samii.viz.fit_plot import plot_fit_overlay, plot_panels, save_figure

HERE = Path(__file__).resolve().parent
PW = 0.1  # chapter 4 used phase weight 0.1
BAND_EDGES_HZ = (20.0, 30.0, 40.0, 60.0, 100.0)
POINTS_PER_DECADE = 154  # the stand-in's density: 400 points over 0.1-40 Hz


def main() -> None:
    out, data, clean, note = study_setup(__doc__.splitlines()[0], HERE / "out")
    fits = s2_vs_s4(data, phase_weight=PW, rng=np.random.default_rng(0))
    channels = tuple(c for c in ("act", "base", "total") if c in data.channels)
    save_figure(
        plot_fit_overlay(
            data,
            {f"{k} fit": r for k, r in fits.items()},
            channels=channels,
            model_span_hz=(data.freq_hz[0], 100.0),
            title="s² vs s⁴ numerator, 3 modes, phase weight 0.1 (notebook ch. 4, fig. 4.1-4.3); models drawn to 100 Hz",
            note=note,
        ),
        out / "bode_overlay.png",
    )

    summary = {"note": note, "fits": {k: r.to_dict() for k, r in fits.items()}}
    if clean is not None:
        rows = []
        for f_max in BAND_EDGES_HZ:
            f = np.geomspace(0.1, f_max, int(round(POINTS_PER_DECADE * np.log10(f_max / 0.1))))
            d = synthetic_rig_frf(f, rng=np.random.default_rng(STANDIN_SEED))
            r = s2_vs_s4(d, phase_weight=PW, rng=np.random.default_rng(0))
            rows.append(
                {
                    "f_max_hz": f_max,
                    **{f"cost_{k}": v.cost for k, v in r.items()},
                    **{f"rms_base_db_{k}": v.rms_mag_db["base"] for k, v in r.items()},
                    **{f"rms_base_deg_{k}": v.rms_phase_deg["base"] for k, v in r.items()},
                }
            )
        summary["bandwidth"] = rows
        edges = [r["f_max_hz"] for r in rows]
        panels = {
            "cost s² / cost s⁴": {"ratio": [r["cost_s2"] / r["cost_s4"] for r in rows]},
            "RMS base error [dB]": {k: [r[f"rms_base_db_{k}"] for r in rows] for k in ("s2", "s4")},
            "RMS base error [deg]": {k: [r[f"rms_base_deg_{k}"] for r in rows] for k in ("s2", "s4")},
        }
        save_figure(
            plot_panels(
                edges,
                panels,
                xlabel="upper edge of the swept sine [Hz]",
                logx=True,
                title="How much band tells s² from s⁴ (fits to stand-in data 0.1 Hz - edge; errors against the data)",
                note=note,
            ),
            out / "bandwidth.png",
        )

    text = (
        "# s^2 vs s^4 numerator (notebook chapter 4)\n\n"
        f"{note}\n\n"
        "3 modes, w2 = wz, phase weight 0.1, fitted to theta/v and xdd/theta. Parameters in the notebook's units (theta assumed in degrees; "
        "the s^2 model's B carry an extra s^2, so its B are not comparable with the s^4 ones); 95 % intervals.\n\n"
        + fits_markdown({f"{k} fit": r for k, r in fits.items()}, convert=to_notebook_units)
    )
    if "bandwidth" in summary:
        text += "\nBand needed (stand-in data 0.1 Hz to the edge, same density and noise):\n\n| edge [Hz] | cost s2 | cost s4 | ratio | RMS base s2 [dB / deg] | RMS base s4 [dB / deg] |\n|---|---|---|---|---|---|\n"
        for r in summary["bandwidth"]:
            text += f"| {r['f_max_hz']:g} | {r['cost_s2']:.5g} | {r['cost_s4']:.5g} | {r['cost_s2'] / r['cost_s4']:.3g} | {r['rms_base_db_s2']:.3g} / {r['rms_base_deg_s2']:.3g} | {r['rms_base_db_s4']:.3g} / {r['rms_base_deg_s4']:.3g} |\n"
    for k, r in fits.items():
        text += f"\n{k} warnings: " + ("; ".join(r.warnings) or "none") + "\n"
    (out / "table.md").write_text(text)
    (out / "results.json").write_text(json.dumps(summary, indent=1) + "\n")
    for k, r in fits.items():
        print(f"{k}: cost {r.cost:.5g}, converged {r.converged}, RMS base {r.rms_mag_db['base']:.3g} dB / {r.rms_phase_deg['base']:.3g} deg")
    for r in summary.get("bandwidth", []):
        print(f"edge {r['f_max_hz']:g} Hz: cost s2 / s4 = {r['cost_s2']:.5g} / {r['cost_s4']:.5g}")


if __name__ == "__main__":
    main()
