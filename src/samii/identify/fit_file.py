"""A frequency-response file fitted and written to a folder: what ``samii fit FRF`` does, as a library call.

:func:`read_frf_file` reads an FRF CSV or a rig-era .mat and refuses what cannot be fitted, naming the file, line
and column; :func:`fit_frf_file` fits the notebook's models to it at one or more phase weights
(:func:`samii.identify.fit.fit`) and writes ``fit.json``, its plots and tables into an all-or-nothing folder
(:func:`samii.identify.report.write_fit_outputs`). Refusals are :class:`~samii.errors.InputError` worded with the
command's option names.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from samii.errors import InputError, input_error_of
from samii.formats import DataFormatError, csv_header, is_mat_file, read_frf_csv, read_mat_bode
from samii.frequency_response import FrequencyResponse
from samii.identify.cost import frequency_out_of_range
from samii.identify.fit import check_not_noise, fit
from samii.identify.report import fit_figures, fit_output_names, write_fit_outputs
from samii.identify.structures import ModelStructure
from samii.outputs import LaterOutput, OutputFolder, shown_path, write_whole
from samii.progress import SILENT, Progress, part

__all__ = ["FitRequest", "FitFile", "read_frf_file", "fit_frf_file"]


@dataclass(frozen=True)
class FitRequest:
    """How to fit, as ``samii fit``'s options say it (defaults: the notebook's eq 9.4 fit)."""

    n_modes: int = 3
    numerator: str = "s4"
    phase_weights: tuple[float, ...] = (0.1,)  #: one fit each
    band_hz: tuple[float, float] | None = None  #: None: the whole file
    weighting: str = "auto"
    start: str = "both"
    averages: int | None = None  #: behind the coherence (None: the file's frf_records, else 3)
    profiles: str = "auto"  #: "auto", "on" or "off"
    mat_freq_name: str | None = None
    mat_freq_unit: str = "hz"


@dataclass
class FitFile:
    """A file's fits: one :class:`~samii.identify.fit.FitResult` per phase weight, and the data fitted."""

    data: FrequencyResponse
    structure: object  #: samii.identify.structures.ModelStructure
    results: list
    written: list[str] = field(default_factory=list)  #: the files written, as the run names them
    #: the figures, left for the caller to write (``later``; named in ``written`` all the same); empty: in the folder
    later: tuple[LaterOutput, ...] = ()


def _csv_line_of_row(path: Path, row: int) -> int | None:
    """1-based file line of data row ``row`` (0-based) of a CSV read by ``read_frf_csv``."""
    seen_header = False
    k = -1
    with open(path, encoding="utf-8", errors="replace", newline=None) as fh:
        for number, line in enumerate(fh, start=1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            if not seen_header:
                seen_header = True
                continue
            k += 1
            if k == row:
                return number
    return None


def read_frf_file(path, *, mat_freq_name: str | None = None, mat_freq_unit: str = "hz") -> FrequencyResponse:
    """The file as a FrequencyResponse; InputError naming the file for anything a user can fix."""

    path = Path(path)
    mat = is_mat_file(path)
    if mat:
        try:
            data = read_mat_bode(path, freq_name=mat_freq_name, freq_unit=mat_freq_unit)
        except DataFormatError as exc:  # the library names its arguments: name the options
            text = str(exc)
            if text.endswith("pass freq_name="):
                text = text[: -len("freq_name=")] + "--mat-freq-name NAME"
            elif "freq_unit" in text:
                text += " (samii fit: --mat-freq-unit rad/s)"
            raise InputError(text) from None
    else:
        given = [o for o, v in (("--mat-freq-name", mat_freq_name is not None), ("--mat-freq-unit", mat_freq_unit != "hz")) if v]
        if given:
            raise InputError(f"{' and '.join(given)}: only for a .mat file; {path} is read as an FRF CSV")
        try:
            data = read_frf_csv(path)
        except DataFormatError:
            header = csv_header(path)
            if "t" in header and "freq_hz" not in header:
                shown = ", ".join(header[:6]) + (", ..." if len(header) > 6 else "")
                raise InputError(
                    f"{path}: this is a time series (columns {shown}), not a frequency response; samii fit expects an FRF: "
                    "a CSV with freq_hz and <channel>_mag/<channel>_phase_deg columns (DATA_FORMATS.md, as samii measure "
                    "writes frf.csv) or a rig-era .mat"
                ) from None
            raise
    bad = frequency_out_of_range(data.freq_hz)
    if bad is not None:
        k, reason = bad
        if mat:
            where = f"{path}, variable {data.metadata.get('freq_vector', '?')!r}, element {k + 1}"
        else:
            line = _csv_line_of_row(path, k)
            where = f"{path}, line {line}, column 'freq_hz'" if line is not None else f"{path}, data row {k + 1}"
        raise InputError(f"{where}: {reason}")
    return data


def fit_frf_file(
    path,
    request: FitRequest = FitRequest(),
    *,
    out=None,
    overwrite: bool = False,
    progress: Progress | None = None,
    relative_to=None,
    later: bool = False,
) -> FitFile:
    """Fit the FRF file ``path`` as ``request`` asks and, given ``out``, write the fits into that folder (all or
    nothing; checked before any work). ``relative_to``: the folder whose files name ``path`` relative to it (the
    main job's) rather than as given. ``later``: the figures are not drawn here but left in the result's ``later``
    (:class:`samii.outputs.LaterOutput`), for the caller to draw after the folder is committed (the main job draws
    them beside the next stages' work)."""

    name = shown_path(path, relative_to)
    folder = OutputFolder(out, fit_output_names(list(request.phase_weights)), overwrite=overwrite) if out is not None else None
    progress = progress or SILENT
    progress.stage("reading")
    data = read_frf_file(path, mat_freq_name=request.mat_freq_name, mat_freq_unit=request.mat_freq_unit)
    structure = ModelStructure(n_modes=request.n_modes, numerator=request.numerator)
    if request.weighting == "coherence":
        lacking = [c for c in data.channels if data.coherence(c) is None]
        if lacking:
            raise InputError(f"{name}: --weighting coherence needs coherence, but channel(s) {', '.join(lacking)} have no *_coh column")
    band = tuple(request.band_hz) if request.band_hz else None
    if band is not None and not np.any((data.freq_hz >= band[0]) & (data.freq_hz <= band[1])):
        raise InputError(
            f"{name}: --band-hz {band[0]:g} {band[1]:g}: no frequency point in the band (the data span {data.freq_hz[0]:g}-{data.freq_hz[-1]:g} Hz)"
        )
    rng = np.random.default_rng(0)
    progress.expect(len(request.phase_weights))  # a fit per phase weight, each one unit
    try:  # noise: refused before any work, as calibrate and diagnose refuse it (a fit of it converged to "a sound fit")
        check_not_noise(data, structure, band_hz=band)
    except ValueError as exc:
        raise input_error_of(name, exc) from None
    results = []
    for w in request.phase_weights:
        try:
            results.append(
                fit(
                    data,
                    structure,
                    phase_weight=w,
                    band_hz=band,
                    weighting=request.weighting,
                    start=request.start or "both",
                    rng=rng,
                    n_averages=request.averages,
                    progress=part(progress, 1),
                    profile={"auto": "auto", "on": True, "off": False}[request.profiles],
                )
            )
        except np.linalg.LinAlgError:
            raise  # numerical trouble: a defect, reported as an internal error
        except (ValueError, KeyError) as exc:  # the data cannot be fitted as asked (InputError included)
            raise input_error_of(name, exc) from None
    written: list[str] = []
    left: list[LaterOutput] = []
    if folder is not None:
        progress.stage("writing plots")
        figures = fit_figures(data, results, note=f"data: {name}") if later else []
        with folder:
            write_fit_outputs(data, results, folder, note=f"data: {name}", figures=not later)
            for figure, _ in figures:
                folder.omit(figure)  # (an earlier run's is removed at the commit: the caller writes this run's)
        written = [shown_path(p, relative_to) for p in folder.written]
        for figure, draw in figures:
            left.append(LaterOutput(folder.final(figure), partial(write_whole, folder.final(figure), draw), forks=True))
            written.append(shown_path(folder.final(figure), relative_to))
    return FitFile(data=data, structure=structure, results=results, written=written, later=tuple(left))
