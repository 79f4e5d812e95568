"""What a fit leaves behind: JSON of every fit and overlay Bode plots, in one folder.

The folder is written all or nothing (``samii.outputs.OutputFolder``): nothing
already there is overwritten unless asked (DATA_FORMATS.md, "Bad input"), and a
failure part-way (a full disk) leaves no file behind.

JSON is strict (RFC 8259): a number that is not defined (a parameter not fitted,
the infinite standard error of a parameter the data do not determine) is
``null``, never ``NaN`` or ``Infinity`` (``json_text``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from samii import notebook as nb
from samii.frequency_response import FrequencyResponse
from samii.identify.fit import FitResult
from samii.identify.structures import ModelStructure
from samii.json_output import dumps
from samii.outputs import OutputFolder
from samii.schema import versioned
from samii.viz.figures import save_figure
from samii.viz.fit_plot import plot_fit_overlay, plot_parameter_sweep

__all__ = [
    "CLI_KEYS",
    "summary_dict",
    "json_text",
    "fit_filename",
    "fit_output_names",
    "write_fit_outputs",
    "fit_figures",
    "notebook_reference",
    "params_markdown",
    "quality_rows",
    "fits_markdown",
]

#: Keys of ``samii fit --json`` (issue 5); then phase weight, weighting, band, channels,
#: parameters not fitted (null in ``params``), the lack-of-fit report and the warnings.
#: ``stderr`` is null for a parameter not fitted and for one the data do not determine
#: (its standard error is infinite; a warning names it).
CLI_KEYS = ("params", "stderr", "cost", "rms_mag_db", "rms_phase_deg", "converged", "message")


def summary_dict(result: FitResult) -> dict:
    """The ``--json`` object of one fit."""
    d = result.to_dict()
    out = {k: d[k] for k in CLI_KEYS}
    for k in (
        "sound",
        "verdict",
        "concerns",
        "caveats",
        "findings",
        "undetermined",
        "profile_intervals",
        "phase_weight",
        "weighting",
        "band_hz",
        "channels",
        "not_fitted",
        "lack_of_fit",
        "warnings",
    ):
        out[k] = d[k]
    return out


def verdict_of(d: Mapping) -> str:
    """``FitResult.verdict`` from a fit's ``to_dict()`` (or the main job's summary of it); a fit.json
    written before verdicts has only ``sound``."""
    return d.get("verdict") or ("sound" if d.get("sound") else "not sound")


def verdict_text(d: Mapping) -> str:
    """A fit's verdict in one phrase, from its ``to_dict()`` (or the main job's summary of it): a
    failure, whose parameters should not be used, told apart from a sound fit with caveats."""
    verdict = verdict_of(d)
    if verdict == "not sound":
        n = len(d.get("concerns") or [])
        why = f"{n} reason{'s' if n > 1 else ''} given" if n else "the solver stopped before a minimum"
        return f"NOT A SOUND FIT, its parameters should not be used ({why})"
    if verdict == "sound":
        return "a sound fit"
    said = []
    if d.get("undetermined"):
        said.append(f"the data do not determine {', '.join(d['undetermined'])}")
    bands = ((d.get("lack_of_fit") or {}).get("bands")) or []
    if bands:
        where = ", ".join(f"{b['channel']} {b['f_lo_hz']:.2g}-{b['f_hi_hz']:.2g} Hz" for b in bands[:2])
        said.append(f"the structure misses the data in {where}" + (f" and {len(bands) - 2} more band(s)" if len(bands) > 2 else ""))
    return "a sound fit, with caveats" + (f" ({'; '.join(said)})" if said else "")


def json_text(obj) -> str:
    """Strict JSON (indented): non-finite numbers become null (``samii.json_output``)."""

    return dumps(obj, indent=2)


def fit_filename(result_or_weight: FitResult | float, many: bool) -> str:
    """``fit.json``, or ``fit_pw<W>.json`` in a sweep of phase weights."""
    w = result_or_weight.phase_weight if isinstance(result_or_weight, FitResult) else float(result_or_weight)
    return f"fit_pw{w:g}.json" if many else "fit.json"


def fit_output_names(phase_weights: Sequence[float]) -> list[str]:
    """The files ``write_fit_outputs`` writes for fits at these phase weights (known before fitting)."""
    many = len(phase_weights) > 1
    return [fit_filename(w, many) for w in phase_weights] + ["bode_fit.png"] + (["parameters.png"] if many else [])


def notebook_reference(results: Sequence[FitResult]) -> dict[str, list[float]] | None:
    """The notebook's eq 9.3-9.12 values at the results' phase weights, for the 3-mode s^4 model of eq 9.1/9.2.

    Frequencies, dampings and tau only: K1 and B_k depend on the notebook's
    unstated unit of theta. NaN at a phase weight the notebook did not fit;
    None when no result has the notebook's structure and one of its weights.
    """

    st = results[0].structure
    if st != ModelStructure.notebook_3mode() or not any(r.phase_weight in nb.EQ9_FITS for r in results):
        return None
    names = [n for n in st.param_names if n[0] in "wz" or n == "tau"]
    return {n: [nb.EQ9_FITS[r.phase_weight][n] if r.phase_weight in nb.EQ9_FITS else np.nan for r in results] for n in names}


def write_fit_outputs(
    data: FrequencyResponse, results: Sequence[FitResult], out, *, overwrite: bool = False, note: str | None = None, figures: bool = True
) -> list[Path]:
    """Write ``fit.json`` (or ``fit_pw<W>.json`` per weight), ``bode_fit.png`` and, for a sweep, ``parameters.png``
    (``figures`` False: the JSON alone; the caller draws :func:`fit_figures`).

    ``out`` is a folder path, or a ``samii.outputs.OutputFolder`` already
    entered (``samii fit`` makes it before fitting, so that a bad ``--out``
    fails at once); with a path the folder is made here. Either way the files
    appear together or not at all. Returns where they are (or will be, once the
    caller's folder commits).

    Raises
    ------
    samii.errors.InputError
        ``out`` is not a usable folder, or holds one of the files and ``overwrite`` is False.
    """

    names = fit_output_names([r.phase_weight for r in results])
    if not figures:
        names = [n for n in names if not n.endswith(".png")]
    if isinstance(out, OutputFolder):
        _write(out, data, results, note, figures)
        return [out.final(n) for n in names]
    folder = OutputFolder(out, names, overwrite=overwrite)
    with folder:
        _write(folder, data, results, note, figures)
    return list(folder.written)


def _write(folder, data: FrequencyResponse, results: Sequence[FitResult], note: str | None, figures: bool = True) -> None:
    many = len(results) > 1
    for r in results:
        folder.path(fit_filename(r, many)).write_text(json_text(versioned(r.to_dict())) + "\n")
    if figures:
        for name, draw in fit_figures(data, results, note):
            draw(folder.path(name))


def fit_figures(data: FrequencyResponse, results: Sequence[FitResult], note: str | None = None) -> list[tuple[str, Callable[[Path], None]]]:
    """The figures of :func:`write_fit_outputs`, as ``(file name, function that draws it to a path)``: ``bode_fit.png``
    and, for a sweep of phase weights, ``parameters.png``."""

    many = len(results) > 1
    band = results[0].band_hz
    full = (data.freq_hz[0], data.freq_hz[-1])
    st = results[0].structure

    def overlay(path) -> None:
        models = {(f"fit, phase weight {r.phase_weight:g}" if many else "fit"): r for r in results}
        fig = plot_fit_overlay(data, models, channels=results[0].channels, band_hz=None if band == full else band,
                               title=f"samii fit: {st.describe()}", note=note or data.metadata.get("source"))  # fmt: skip
        save_figure(fig, path)

    def sweep(path) -> None:
        fig = plot_parameter_sweep(
            [r.phase_weight for r in results],
            [r.params for r in results],
            [r.stderr for r in results],
            st.param_names,
            xlabel="phase weight",
            reference=notebook_reference(results),
            reference_label="notebook eq 9.3-9.12 (its own data)",
            units=st.units(),
            title="fitted parameters against phase weight (95 % intervals)",
            note=note,
        )
        save_figure(fig, path)

    return [("bode_fit.png", overlay)] + ([("parameters.png", sweep)] if many else [])


def params_markdown(
    columns: Mapping[str, Mapping[str, float]],
    names: Sequence[str],
    *,
    stderr: Mapping[str, Mapping[str, float]] | None = None,
    extra_rows: Mapping[str, Mapping[str, str]] | None = None,
) -> str:
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
        if lof.nothing_tested:
            return "not tested (no coherent point)"
        return "not tested (too few points)" if lof.too_few_points else "none"
    return lof.summary()


def fits_markdown(fits: Mapping[str, FitResult], *, convert: Callable[[Mapping[str, float]], Mapping[str, float]] = dict) -> str:
    """``params_markdown`` of labelled fits (values and standard errors through ``convert``) with their quality rows."""
    names = next(iter(fits.values())).structure.param_names
    cols = {k: convert(r.params) for k, r in fits.items()}
    ses = {k: convert(r.stderr) for k, r in fits.items()}
    return params_markdown(cols, names, stderr=ses, extra_rows=quality_rows(fits))
