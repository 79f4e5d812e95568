"""What a fit leaves behind: JSON of every fit and overlay Bode plots, in one folder.

Nothing already there is overwritten unless asked (DATA_FORMATS.md, "Bad input").
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable, Mapping, Sequence

from samii.frequency_response import FrequencyResponse
from samii.identify.fit import FitResult

__all__ = ["CLI_KEYS", "summary_dict", "fit_filename", "write_fit_outputs", "params_markdown", "quality_rows", "fits_markdown"]

#: Keys of ``samii fit --json`` (issue 5); then phase weight, weighting, band, channels,
#: parameters not fitted (null in ``params``), the lack-of-fit report and the warnings.
CLI_KEYS = ("params", "stderr", "cost", "rms_mag_db", "rms_phase_deg", "converged", "message")


def summary_dict(result: FitResult) -> dict:
    """The ``--json`` object of one fit."""
    d = result.to_dict()
    out = {k: d[k] for k in CLI_KEYS}
    for k in ("sound", "concerns", "phase_weight", "weighting", "band_hz", "channels", "not_fitted", "lack_of_fit", "warnings"):
        out[k] = d[k]
    return out


def fit_filename(result: FitResult, many: bool) -> str:
    return f"fit_pw{result.phase_weight:g}.json" if many else "fit.json"


def write_fit_outputs(data: FrequencyResponse, results: Sequence[FitResult], out_dir, *, overwrite: bool = False, note: str | None = None) -> list[Path]:
    """Write ``fit.json`` (or ``fit_pw<W>.json`` per weight), ``bode_fit.png`` and, for a sweep, ``parameters.png``.

    Raises
    ------
    FileExistsError
        If a file to be written exists and ``overwrite`` is False.
    """
    out = Path(out_dir)
    many = len(results) > 1
    targets = [out / fit_filename(r, many) for r in results] + [out / "bode_fit.png"] + ([out / "parameters.png"] if many else [])
    if not overwrite:
        existing = [str(p) for p in targets if p.exists()]
        if existing:
            raise FileExistsError(f"would overwrite {', '.join(existing)}; choose another --out or pass --overwrite")
    out.mkdir(parents=True, exist_ok=True)
    for r, path in zip(results, targets):
        path.write_text(json.dumps(r.to_dict(), indent=2) + "\n")
    from samii.viz.fit_plot import plot_fit_overlay, plot_parameter_sweep, save_figure

    band = results[0].band_hz
    full = (data.freq_hz[0], data.freq_hz[-1])
    models = {(f"fit, phase weight {r.phase_weight:g}" if many else "fit"): r for r in results}
    st = results[0].structure
    title = f"samii fit: {st.describe()}"
    fig = plot_fit_overlay(data, models, channels=results[0].channels, band_hz=None if band == full else band, title=title, note=note or data.metadata.get("source"))
    save_figure(fig, out / "bode_fit.png")
    if many:
        fig = plot_parameter_sweep(
            [r.phase_weight for r in results],
            [r.params for r in results],
            [r.stderr for r in results],
            st.param_names,
            xlabel="phase weight",
            units=st.units(),
            title="fitted parameters against phase weight (95 % intervals)",
            note=note,
        )
        save_figure(fig, out / "parameters.png")
    return targets


def params_markdown(columns: Mapping[str, Mapping[str, float]], names: Sequence[str], *, stderr: Mapping[str, Mapping[str, float]] | None = None, extra_rows: Mapping[str, Mapping[str, str]] | None = None) -> str:
    """A markdown table: one row per parameter, one column per fit; ``value ± 1.96 stderr`` where given."""
    labels = list(columns)
    lines = ["| parameter | " + " | ".join(labels) + " |", "|---|" + "---|" * len(labels)]
    for n in names:
        cells = []
        for lab in labels:
            v = columns[lab].get(n)
            se = (stderr or {}).get(lab, {}).get(n)
            if v is None:
                cells.append("")
            elif se is not None:
                cells.append(f"{v:.5g} ± {1.96 * se:.2g}")
            else:
                cells.append(f"{v:.5g}")
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    for row, vals in (extra_rows or {}).items():
        lines.append(f"| {row} | " + " | ".join(vals.get(lab, "") for lab in labels) + " |")
    return "\n".join(lines) + "\n"


def quality_rows(fits: Mapping[str, FitResult]) -> dict[str, dict[str, str]]:
    """Extra table rows for ``params_markdown``: cost, convergence and RMS errors of each labelled fit."""
    rows = {"cost": {k: f"{r.cost:.5g}" for k, r in fits.items()}, "converged": {k: str(r.converged) for k, r in fits.items()}}
    channels = next(iter(fits.values())).channels
    for c in channels:
        rows[f"RMS {c} [dB / deg]"] = {k: f"{r.rms_mag_db[c]:.3g} / {r.rms_phase_deg[c]:.3g}" for k, r in fits.items()}
    rows["lack of fit (bands where residuals > 5x random error)"] = {k: _lof_cell(r) for k, r in fits.items()}
    return rows


def _lof_cell(result: FitResult) -> str:
    lof = result.lack_of_fit
    if lof is None:
        return ""
    if not lof.found:
        return "none"
    return lof.summary()


def fits_markdown(fits: Mapping[str, FitResult], *, convert: Callable[[Mapping[str, float]], Mapping[str, float]] = dict) -> str:
    """``params_markdown`` of labelled fits (values and standard errors through ``convert``) with their quality rows."""
    names = next(iter(fits.values())).structure.param_names
    cols = {k: convert(r.params) for k, r in fits.items()}
    ses = {k: convert(r.stderr) for k, r in fits.items()}
    return params_markdown(cols, names, stderr=ses, extra_rows=quality_rows(fits))
