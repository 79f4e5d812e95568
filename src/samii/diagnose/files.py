"""Measured files diagnosed and the diagnosis written to a folder: what ``samii diagnose DATA`` does, as a library call.

:func:`diagnose_files` checks the request (the files, the baseline, a simulator's parameter file), reads each file
(:func:`samii.measure.measured.load`), diagnoses them (:func:`samii.diagnose.diagnosis.diagnose`) and writes
``diagnosis.json`` and its figures into an all-or-nothing folder (and, against the simulator, a Rerun recording when
asked). Refusals are :class:`~samii.errors.InputError` worded with the command's option names.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from samii.errors import InputError, input_error_of
from samii.json_output import dumps
from samii.outputs import OutputFolder, check_output_file, create_parent, shown_path, written_beside
from samii.progress import SILENT, Progress
from samii.schema import document
from samii.schema.diagnosis import DiagnosisRecord

__all__ = ["DiagnoseRequest", "DiagnosedFiles", "diagnose_files", "OUTPUTS", "SIM_OUTPUTS", "MAX_FILES"]

OUTPUTS = ("diagnosis.json", "residuals.png", "bode.png", "harmonics.png")
#: Written with --baseline sim: the figure, and the simulator the diagnosis ends with (calibrated, the effects found
#: carried) as a parameter file every command's ``--model`` takes (a closed loop on the rig as diagnosed).
SIM_OUTPUTS = ("simulator.png", "simulator_params.json")
#: Most files one diagnosis takes (each adds the baseline's 13 parameters to the joint fit).
MAX_FILES = 8


@dataclass(frozen=True)
class DiagnoseRequest:
    """How to read the files and what to diagnose them against, as ``samii diagnose``'s options say it."""

    baseline: str = "notebook"  #: "notebook", "sim" or a saved fit's path (fit.json)
    model: str | None = None  #: with baseline "sim": the simulator's parameter file to start from
    band_hz: tuple[float, float] | None = None
    record_s: float | None = None
    mat_freq_name: str | None = None
    mat_freq_unit: str = "hz"


@dataclass
class DiagnosedFiles:
    """The diagnosis (samii.diagnose.diagnosis.Diagnosis), diagnosis.json as typed values, and the files written, as
    the run names them."""

    diagnosis: object
    record: DiagnosisRecord
    written: list[str] = field(default_factory=list)


def simulator_params_text(report) -> str:
    """The simulator a diagnosis against it ends with (``report``, a samii.diagnose.simulator.SimulatorReport: its
    calibration after the effects were carried) as a parameter file's text (``load_model`` and ``--model`` read it)."""
    carried = ", ".join(report.carried) or "none"
    changes = ", ".join(f"{n} = {v:.6g}" for n, v in report.changes.items()) or "none"
    note = (
        f"written by samii diagnose --baseline sim: the simulator calibrated to {report.after.source} with the effects "
        f"found carried into it (carried: {carried}; changed from the first calibration: {changes})"
    )
    return json.dumps({"note": note, "params": report.after.params.as_dict()}, indent=2, allow_nan=False) + "\n"


def _baseline(req: DiagnoseRequest, relative_to):
    """The baseline and the simulator's parameters ``req`` names, checked before any work."""
    sim_params = None
    if req.model is not None:
        if req.baseline != "sim":
            raise InputError(f"--model {req.model}: the simulator to start from is used with --baseline sim only")
        if not str(req.model).lower().endswith(".json"):
            raise InputError(
                f"--model {req.model}: expected a parameter file (.json, as samii calibrate --out writes), "
                "the simulator's calibration moves its parameters"
            )
        from samii.sim.model import read_params_file  # (lazy: this module is imported at samii's start-up, that one is not needed there)

        try:
            sim_params = read_params_file(req.model)
        except (OSError, ValueError) as exc:
            raise InputError(f"--model {req.model}: {exc}") from None
    if req.baseline in ("sim", "notebook"):
        return req.baseline, sim_params
    p = Path(req.baseline)
    if not p.is_file():
        raise InputError(
            f"--baseline {req.baseline}: expected notebook or a saved fit (fit.json from samii fit --out); "
            f"{'it is a folder' if p.is_dir() else 'no such file'}"
        )
    from samii.diagnose.baseline import read_fit_json  # (lazy: this module is imported at samii's start-up, that one is not needed there)

    return read_fit_json(p, name=shown_path(p, relative_to)), sim_params  # bad input before any work


def _write_rerun(d, tmp, path, fps) -> None:
    """The simulator against the data as a Rerun recording in ``tmp``, the temporary name of ``path`` (which a failure
    names)."""
    from samii.diagnose.recording import (  # (lazy: this module is imported at samii's start-up, that one is not needed there)
        write_diagnosis_recording,
    )
    from samii.viz.recording import recording_failed  # (lazy: this module is imported at samii's start-up, that one is not needed there)

    try:
        write_diagnosis_recording(create_parent(tmp), d, fps=fps)
    except (RuntimeError, OSError) as exc:  # rerun's writer reports file-system failures as RuntimeError
        raise recording_failed(exc, path) from None


def diagnose_files(
    data: Sequence,
    request: DiagnoseRequest = DiagnoseRequest(),
    *,
    out=None,
    rerun=None,
    rerun_fps: float | None = None,
    overwrite: bool = False,
    progress: Progress | None = None,
    relative_to=None,
) -> DiagnosedFiles:
    """Diagnose the measured files ``data`` of one rig as ``request`` asks; given ``out``, write the diagnosis into
    that folder (all or nothing, checked before any work), and given ``rerun`` (baseline "sim" only) a recording.

    ``progress`` (samii.progress.Progress): told each stage, advanced by every candidate tried.
    ``relative_to`` names the files relative to that folder (the main job's) instead of as given."""
    from samii.diagnose.diagnosis import diagnose  # (lazy: this module is imported at samii's start-up, that one is not needed there)
    from samii.measure.measured import load  # (lazy: this module is imported at samii's start-up, that one is not needed there)

    data = [str(d) for d in data]
    if len(data) > MAX_FILES:
        raise InputError(f"DATA: {len(data)} files given, at most {MAX_FILES} accepted")
    baseline, sim_params = _baseline(request, relative_to)
    seen: dict[str, str] = {}
    for d in data:  # the same file under two spellings (clean.csv, ./clean.csv, a link) counts once
        key = os.path.realpath(d)
        if key in seen:
            same = f"{d}" if seen[key] == d else f"{seen[key]} and {d}"
            raise InputError(f"DATA: {same} given more than once (the same file); its data would count twice")
        seen[key] = d
    folder = None
    if out is not None:
        folder = OutputFolder(out, OUTPUTS + (SIM_OUTPUTS if baseline == "sim" else ()), overwrite=overwrite)
    rerun_path = None
    if rerun is not None:
        if baseline != "sim":
            raise InputError(f"--rerun {rerun}: the recording shows the simulator against the data; use it with --baseline sim")

        rerun_path = check_output_file(rerun, overwrite=overwrite, option="--rerun", beside=folder)
    elif rerun_fps is not None:
        raise InputError("--rerun-fps: sets the frame rate of a recording; give --rerun FILE.rrd too")

    progress = progress or SILENT
    with written_beside(rerun_path) as rrd_tmp:
        progress.stage("reading")
        band = tuple(request.band_hz) if request.band_hz else None
        measured = []
        for path in data:
            try:
                measured.append(load(path, band_hz=band, record_s=request.record_s, mat_freq_name=request.mat_freq_name,
                                     mat_freq_unit=request.mat_freq_unit, name=None if relative_to is None else shown_path(path, relative_to)))  # fmt: skip
            except ValueError as exc:
                from samii.formats import DataFormatError  # (lazy: this module is imported at samii's start-up, that one is not needed there)

                if isinstance(exc, DataFormatError):
                    raise
                raise input_error_of(path, exc) from None
        progress.stage("fitting the baseline")
        try:
            d = diagnose(measured, baseline=baseline, progress=progress, simulator_params=sim_params)
        except ValueError as exc:
            if isinstance(exc, np.linalg.LinAlgError):
                raise
            text = str(exc)
            names = [str(m.source) for m in measured]
            raise InputError(text if any(text.startswith(n) for n in names) else f"{', '.join(names)}: {text}") from None
        record = d.record()
        if folder is not None:
            progress.stage("writing")
            from samii.diagnose.plots import (  # (lazy: this module is imported at samii's start-up, that one is not needed there)
                bode_figure,
                harmonic_figure,
                residual_figure,
                simulator_figure,
            )
            from samii.forkmap import fork_map  # (lazy: this module is imported at samii's start-up, that one is not needed there)
            from samii.formats import write_text  # (lazy: this module is imported at samii's start-up, that one is not needed there)

            with folder:
                write_text(folder.path("diagnosis.json"), dumps(document(record), indent=2) + "\n")
                if d.simulator is not None:
                    write_text(folder.path("simulator_params.json"), simulator_params_text(d.simulator))
                figures = [(residual_figure, "residuals.png"), (bode_figure, "bode.png"), (harmonic_figure, "harmonics.png")]
                if d.simulator is not None:
                    figures.append((simulator_figure, "simulator.png"))

                def draw(job) -> None:
                    job[0](d, folder.path(job[1]))

                fork_map(draw, figures)  # drawn at once on the machine's cores (samii.forkmap)
                if rerun_path is not None:  # inside the folder's transaction: a failed recording leaves no folder behind
                    progress.stage("recording")
                    _write_rerun(d, rrd_tmp, rerun_path, rerun_fps)
        elif rrd_tmp is not None:
            progress.stage("recording")
            _write_rerun(d, rrd_tmp, rerun_path, rerun_fps)
    written = [shown_path(p, relative_to) for p in (folder.written if folder is not None else [])]
    written += [shown_path(rerun_path, relative_to)] if rerun_path is not None else []
    return DiagnosedFiles(diagnosis=d, record=record, written=written)
