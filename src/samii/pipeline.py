"""The whole pipeline on one model as one library call: :func:`run` returns a typed :class:`Run`.

The stages, each the library call its command makes (so each stage's files are what that command writes):

1. the base modes and the servo-loop poles at the nominal pose (:func:`samii.sim.linearize.modes_report`);
2. ``measure/``: swept sine 0.1-40 Hz, 0.1 V, 3 sign-alternating records, sensor noise seeded by ``seed``
   (:func:`samii.measure.bode_test.run_bode_test`), and ``measure.rrd``, its Rerun recording;
3. ``fit/``: the notebook's 3-mode model fitted to that FRF (:func:`samii.identify.fit_file.fit_frf_file`);
4. ``controllers/damping.json``: acceleration feedback designed on a fit of the same FRF
   (:func:`samii.closedloop.damping.damping_from_frf`);
5. ``closedloop/<controller>_<scenario>/``: the notebook's pole-cancelling compensator (chapter 10) and pole
   placement (chapter 8), as the notebook built them, and the damping controller, each in the step and Loper tests
   in the nonlinear simulator (:func:`samii.closedloop.trial.run_trial`), and ``closedloop.rrd``: the damping
   controller's Loper test beside the servo loop alone;
6. ``diagnose/``: the fit diagnosed against the measured record (:func:`samii.diagnose.files.diagnose_files`);
7. ``summary.json``: the figures of the printed summary (:class:`samii.schema.summary.RunSummary`);
8. ``report.html``: one self-contained page with the figures and tables of all of it (:mod:`samii.report`).

The diagnosis (6) needs the measurement and the fit alone: it runs in a worker process of its own
(:func:`samii.forkmap.fork_later`) while the design (4) and the closed-loop trials (5) run here, each on a core. The
figures and the recording no later stage reads are drawn beside that chain (measurement -> fit -> diagnosis ->
report), not in it: the measurement's Bode figure in a worker of its own while the fit runs, its recording and the
fit's figure here once the diagnosis has started (the stages' ``later``, :class:`samii.outputs.LaterOutput`). The
notebook's controllers, which depend on its numbers alone, are designed in a worker while the measurement runs (the
pole placement's symbolic canonical form takes seconds). The folder is the same as with the stages one after the
other (``SAMII_WORKERS=1``).

The stages hand each other the files a user's chain of commands would (the fit reads ``measure/frf.csv``, not the
estimate in memory), so the numbers are those of the commands run one by one. The folder is written whole or not at
all: the stages write into a staging folder beside it, which replaces ``out`` at the end (an existing ``out`` only
with ``overwrite``, or when it holds a previous run's output). :meth:`Run.load` reads a folder back into the same
types :func:`run` returns; :meth:`Run.save` writes a run to another folder.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property, partial
from pathlib import Path

from samii import notebook as nb
from samii.closedloop.controllers import read_controller, write_controller
from samii.closedloop.damping import damping_from_frf
from samii.closedloop.trial import TrialRequest, resolve_controller, run_trial
from samii.diagnose.files import DiagnoseRequest, diagnose_files
from samii.errors import InputError, mark_outputs_started, raise_if_signalled, uninterrupted
from samii.forkmap import fork_later
from samii.formats import read_frf_csv, read_timeseries_csv
from samii.identify.fit_file import fit_frf_file
from samii.json_output import finite_or_none
from samii.measure.bode_test import BodeTestRequest, run_bode_test
from samii.outputs import LaterOutput, remove_stale_runs, restore_replaced
from samii.progress import SILENT, Progress
from samii.report.page import write_report
from samii.run_summary import CONTROLLERS, RECORDINGS, SCENARIOS
from samii.schema import read_document
from samii.schema.closed_loop import ClosedLoopRecord
from samii.schema.diagnosis import DiagnosisRecord
from samii.schema.measurement import MeasurementRecord
from samii.schema.summary import (
    CLOSED_LOOP_FIELDS,
    DAMPING_FIELDS,
    FIT_FIELDS,
    MARKER,
    BaseMode,
    ClosedLoopSummary,
    DampingSummary,
    DiagnosisSummary,
    FitSummary,
    MeasurementSummary,
    ModesSummary,
    RunSummary,
)
from samii.sim.overrides import parse_overrides
from samii.timeseries import TimeSeries
from samii.viz.figures import pyplot

__all__ = ["run", "Run", "ClosedLoopRun", "N_STAGES"]

#: Stages :func:`run` reports to its progress: modes, measurement, fit, design, the closed-loop runs (the servo loop
#: alone's step and each controller in each scenario), diagnosis, report.
N_STAGES = 4 + 1 + len(CONTROLLERS) * len(SCENARIOS) + 2
_STAGING = ".{name}.samii-run-"


@dataclass(frozen=True)
class ClosedLoopRun:
    """One closed-loop trial as its folder holds it."""

    record: ClosedLoopRecord  #: closedloop/<name>/run.json
    #: closedloop/<name>/timeseries.csv (None: the run diverged in its first step, run.json's "recorded" false)
    trace: TimeSeries | None


@dataclass(frozen=True)
class Run:
    """A run of the pipeline, as its folder holds it: the summary typed, each stage's document as written, each stage's
    result as the type its files are read into (SI units throughout). :meth:`load` checks the documents (the JSON
    files); the stages' results (:attr:`frf`, :attr:`fit`, :attr:`damping`, :attr:`timeseries`) are read from their
    files when first asked for, each file's damage an InputError naming it then."""

    path: Path  #: the folder (a temporary one for a run not saved)
    summary: RunSummary
    measurement_record: MeasurementRecord  #: measure/run.json
    fit_record: Mapping  #: fit/fit.json as written (typed: :attr:`fit`)
    closed_loop: Mapping[str, ClosedLoopRun]  #: "<controller>_<scenario>"
    diagnosis: DiagnosisRecord  #: diagnose/diagnosis.json
    #: What :func:`run` had to say beside the results, in words (a previous output restored, a closed-loop run's note,
    #: report.html not written); not in the folder: a run read back has none
    notes: tuple[str, ...] = field(default=(), compare=False)
    _temporary: object = field(default=None, repr=False, compare=False)  #: keeps a run not saved alive

    @cached_property
    def frf(self):
        """measure/frf.csv, a samii.frequency_response.FrequencyResponse."""

        return read_frf_csv(self.path / "measure" / "frf.csv")

    @cached_property
    def fit(self):
        """fit/fit.json as the baseline a diagnosis takes (samii.diagnose.baseline.SavedFit)."""
        from samii.diagnose.baseline import read_fit_json  # (lazy: imports scipy, only when called)

        return read_fit_json(self.path / "fit" / "fit.json", name="fit/fit.json")

    @cached_property
    def damping(self):
        """controllers/damping.json (samii.closedloop.controllers.SavedController)."""

        return read_controller(self.path / "controllers" / "damping.json")

    @cached_property
    def timeseries(self):
        """measure/timeseries.csv (samii.timeseries.TimeSeries), a quarter-million rows."""

        return read_timeseries_csv(self.path / "measure" / "timeseries.csv")

    @classmethod
    def load(cls, folder) -> Run:
        """The run saved in ``folder``; InputError naming the file and field of anything missing, damaged or written
        by a newer samii (:mod:`samii.schema`)."""

        folder = Path(folder)
        if not folder.is_dir():
            raise InputError(f"{folder}: not a folder (expected a main job's output, samii run --out)")
        summary = RunSummary.from_json(read_document(folder, "summary.json"), folder / "summary.json")
        closed = {}
        for name in summary.closed_loop:
            if "/" in name or name in ("", ".", ".."):
                raise InputError(f"{folder / 'summary.json'}: field 'closed_loop' names a run {name!r}, which is no folder name")
            record = read_document(folder, f"closedloop/{name}/run.json", ClosedLoopRecord)
            trace = folder / "closedloop" / name / "timeseries.csv"
            if not trace.exists() and not record.recorded:
                closed[name] = ClosedLoopRun(record, None)  # a run that diverged in its first step writes run.json alone
                continue
            if not trace.exists():
                raise InputError(f"{trace}: missing, and the run was recorded (its run.json): the folder is not whole; run samii run again")
            closed[name] = ClosedLoopRun(record, read_timeseries_csv(trace))
        return cls(
            path=folder,
            summary=summary,
            measurement_record=read_document(folder, "measure/run.json", MeasurementRecord),
            fit_record=read_document(folder, "fit/fit.json"),
            closed_loop=closed,
            diagnosis=read_document(folder, "diagnose/diagnosis.json", DiagnosisRecord),
        )

    def save(self, folder, *, overwrite: bool = False) -> Run:
        """The run written to ``folder`` (its files as they are, report.html naming the new folder), replacing it
        whole under the rules of :func:`run`'s ``out``; the saved run."""
        out = Path(folder)
        if out.exists() and out.resolve() == self.path.resolve():
            return self
        _check_out(out, overwrite)
        stage_dir = _stage_dir(out)
        try:
            shutil.copytree(self.path, stage_dir, symlinks=True)
            if (stage_dir / "report.html").exists():
                _report(stage_dir, out)
            _replace_whole(stage_dir, out)
        finally:
            if stage_dir.exists():
                shutil.rmtree(stage_dir)
        return Run.load(out)


def _is_previous_run(path: Path) -> bool:
    try:
        return json.loads((path / "summary.json").read_text()).get("written_by") == MARKER
    except (OSError, ValueError, AttributeError):
        return False


def _check_out(out: Path, overwrite: bool) -> None:
    # the folder is replaced whole by a rename: the working folder (or one holding it) and a mount point cannot be
    # (the rename fails after the whole pipeline has run, "Device or resource busy")
    here, target = Path.cwd().resolve(), out.resolve()
    if target == here or target in here.parents:
        raise InputError(
            f"--out {out}: is the working folder{'' if target == here else ' or holds it'}; the main job replaces "
            "--out whole, so give a folder of its own (e.g. --out samii_run)"
        )
    if out.is_dir() and os.path.ismount(out):
        raise InputError(f"--out {out}: is a mount point; the main job replaces --out whole, so give a folder inside it")
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    if out.exists() and any(out.iterdir()) and not overwrite and not _is_previous_run(out):
        raise InputError(f"--out {out}: exists and is not a previous main job's output; pass --overwrite to replace it, or another --out")
    parent = out.absolute().parent
    if not parent.is_dir():
        raise InputError(f"--out {out}: {parent} is {'a file, not a folder' if parent.exists() else 'a folder that does not exist'}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"--out {out}: folder {parent} is not writable")


def _stage_dir(out: Path) -> Path:
    """A fresh staging folder beside ``out`` (what runs killed outright left there removed first)."""

    prefix = _STAGING.format(name=out.name)
    stage_dir = out.absolute().parent / f"{prefix}{os.getpid()}"
    remove_stale_runs(out.absolute().parent, prefix)  # what a killed run (SIGKILL) left
    if stage_dir.exists():
        shutil.rmtree(stage_dir)
    mark_outputs_started(out)
    return stage_dir


def _replace_whole(stage_dir: Path, out: Path) -> None:
    """``stage_dir`` moved into place as ``out``, replacing what was there."""

    raise_if_signalled()  # a signal whose exception a library swallowed (a finaliser's): keep nothing
    # the old folder moved aside and the new one into place by renames a signal waits for: removed first, an
    # interrupted removal left neither (a folder half-deleted); what it replaced goes after, as a killed run's does
    with uninterrupted(done=out):
        old = stage_dir.with_name(stage_dir.name + "-replaced")
        if out.exists():
            os.replace(out, old)
        os.replace(stage_dir, out)
        shutil.rmtree(old, ignore_errors=True)  # (left, a later run's remove_stale_runs takes it)


@contextlib.contextmanager
def _named_stage(name: str):
    """A refusal of the request inside a stage, named by the stage's command."""
    try:
        yield
    except InputError as exc:
        raise InputError(f"stage `samii {name}`: {exc}") from None


def _model_path(model) -> str | None:
    """The model file as the stages record it: absolute (as the folder's files name it, wherever it is moved)."""
    return str(Path(model).absolute()) if model else None


def _override_texts(overrides) -> list[str]:
    """Overrides as ``--set`` gives them (NAME=VALUE texts), from those or from a mapping of names to numbers."""
    if isinstance(overrides, Mapping):
        return [f"{k}={float(v)!r}" for k, v in overrides.items()]
    return [str(o) for o in overrides or ()]


def run(
    out=None,
    *,
    model=None,
    overrides: Sequence[str] | Mapping[str, float] = (),
    seed: int = 0,
    overwrite: bool = False,
    progress: Progress | None = None,
    note: Callable[[str], None] | None = None,
    argv: Sequence[str] = (),
) -> Run:
    """Run the pipeline (module docstring) on ``model`` (an MJCF or parameter file; None: the embedded one) with
    ``overrides`` (``["hydraulic.supply_pressure=8e6"]`` or ``{"hydraulic.supply_pressure": 8e6}``), the
    measurement's sensor noise seeded by ``seed``, into folder ``out`` (None: a temporary folder, kept while the
    returned run is; :meth:`Run.save` writes it elsewhere). ``note`` hears what the run has to say beside its results
    as it happens (the returned run's ``notes`` keep it too). ``argv``: the command line recorded in measure/run.json.
    """

    progress = progress or SILENT
    notes: list[str] = []

    def said(text: str) -> None:
        notes.append(text)
        if note is not None:
            note(text)

    temporary = None
    if out is None:
        temporary = tempfile.TemporaryDirectory(prefix="samii-run-")
        out = Path(temporary.name) / "run"
    out = Path(out)
    texts = _override_texts(overrides)
    if (back := restore_replaced(out, _STAGING.format(name=out.name))) is not None:  # a run killed between its two renames
        said(f"{out} was missing and is back from {back.name}, where a run killed while replacing it had moved it")
    _check_out(out, overwrite)
    stage_dir = _stage_dir(out)
    stage_dir.mkdir()
    progress.expect(N_STAGES)
    started = time.perf_counter()
    try:
        summary = _run_stages(stage_dir, model, texts, seed, progress, said, argv)
        summary = replace(
            summary,
            wall_s=time.perf_counter() - started,
            recordings_mb={n: (stage_dir / n).stat().st_size / 1e6 for n in RECORDINGS if (stage_dir / n).is_file()},
        )
        _write_summary(stage_dir, summary)
        progress.stage("writing report.html")
        try:
            _report(stage_dir, out)
        except Exception as exc:  # noqa: BLE001 - the report is read from the stages' files: a fault in it loses none of them
            summary = replace(summary, report_error=f"{type(exc).__name__}: {exc}")
            said(f"warning: report.html not written ({summary.report_error}); every other output is; samii report {out} tries again")
            _write_summary(stage_dir, summary)
        progress.advance()
        _replace_whole(stage_dir, out)
    finally:
        if stage_dir.exists():
            shutil.rmtree(stage_dir)
    return replace(Run.load(out), notes=tuple(notes), _temporary=temporary)


def _write_summary(d: Path, summary: RunSummary) -> None:
    (d / "summary.json").write_text(json.dumps(summary.to_json(), indent=1, allow_nan=False) + "\n")


def _run_stages(d: Path, model, overrides: list[str], seed: int, progress: Progress, said, argv: Sequence[str]) -> RunSummary:
    parsed = parse_overrides(overrides)  # (a bad --set refused before any worker is forked)
    # the notebook's controllers (chapters 8 and 10, as it built them: its numbers alone, whatever the model) are
    # designed in a worker while the measurement runs here: the pole placement's symbolic canonical form takes seconds
    with fork_later(_notebook_controllers) as notebook_controllers:
        return _stages(d, model, parsed, overrides, seed, progress, said, argv, notebook_controllers)


#: The notebook's controllers the closed-loop trials run, by their ``--controller`` names.
_NOTEBOOK = tuple(spec for _, spec, _ in CONTROLLERS if spec)


def _notebook_controllers() -> dict:
    """The notebook's controllers the closed-loop trials run, designed as ``--controller NAME`` designs them."""
    return {spec: resolve_controller(spec) for spec in _NOTEBOOK}


def _stages(d: Path, model, parsed: dict, overrides: list[str], seed: int, progress: Progress, said, argv, notebook_controllers) -> RunSummary:
    """The stages in turn (module docstring); ``notebook_controllers()`` waits for the notebook's controllers."""
    model_file = _model_path(model)
    progress.stage("modes")
    modes = _modes(model, parsed)
    progress.advance()

    progress.stage("measuring (swept sine, 253 s simulated)")
    with _named_stage("measure"):
        test = run_bode_test(d / "measure", BodeTestRequest(noise=True, seed=seed), model=model_file, overrides=parsed,
                             rerun=d / "measure.rrd", argv=argv, relative_to=d, later=True)  # fmt: skip
    rec = test.record
    sweep = rec.excitation["swept"]
    measurement = MeasurementSummary(
        excitation=sweep["excitation"],
        amplitude_v=sweep["amplitude_v"],
        sample_rate_hz=rec.daq.sample_rate_hz,
        simulated_s=rec.timing.simulated_s,
        sensor_noise=rec.daq.sensor_noise,
    )
    progress.advance()

    # The figures and recordings no later stage reads are drawn beside the stages that wait on each other
    # (measurement -> fit -> diagnosis -> report), not between them: the measurement's Bode figure in a worker of its
    # own while the fit runs here, the recording (rerun's threads stay in this process) and the fit's figure here
    # while the diagnosis runs in its worker.
    pyplot()  # matplotlib imported once, before the workers fork: each would import it again (about 1 s each)
    with fork_later(partial(_write_later, test.later, forks=True)) as measure_drawn:
        progress.stage("fitting the notebook's 3-mode model")
        with _named_stage("fit"):
            fitted = fit_frf_file(d / "measure" / "frf.csv", out=d / "fit", relative_to=d, later=True)
        fit = json.loads((d / "fit" / "fit.json").read_text())  # the summary repeats the file, as written
        fit_summary = FitSummary(params=fit["params"], stderr=fit["stderr"], eq9_4=dict(nb.EQ9_4), **{k: fit.get(k) for k in FIT_FIELDS})
        progress.advance()

        def diagnosed():
            with _named_stage("diagnose"):
                return diagnose_files([d / "measure" / "timeseries.csv"], DiagnoseRequest(baseline=str(d / "fit" / "fit.json")),
                                      out=d / "diagnose", relative_to=d).record  # fmt: skip

        # the diagnosis needs the measurement and the fit alone: it runs in a worker of its own while the damping
        # design and the closed-loop trials run here (each on a core; their folders are apart)
        with fork_later(diagnosed) as diagnosis_record:
            progress.stage("writing measure.rrd and the fit's figure")
            with _named_stage("measure"):
                _write_later(test.later, forks=False)
            with _named_stage("fit"):
                _write_later(fitted.later)
            progress.stage("designing the damping controller")
            damping, design = _design_stage(d, float(rec.model.hydraulic["position_gain"]), _sensor_chain(model_file, parsed))
            progress.advance()
            closed = _closed_loop_stage(d, damping, model_file, parsed, progress, said, notebook_controllers)
            progress.stage("diagnosing the fit against the measured record")
            diag = diagnosis_record()
        with _named_stage("measure"):
            measure_drawn()
    diagnosis = DiagnosisSummary(verdict=diag.verdict, effects=diag.found, error_before=diag.error_before, error_after=diag.error_after)
    progress.advance()
    return RunSummary(
        seed=seed,
        model_file=str(model) if model else "embedded default",
        overrides=tuple(overrides),
        modes=modes,
        measurement=measurement,
        fit=fit_summary,
        damping_design=DampingSummary(**{k: design.get(k) for k in DAMPING_FIELDS}),
        closed_loop=closed,
        diagnosis=diagnosis,
    )


def _write_later(outputs: Sequence[LaterOutput], forks: bool | None = None) -> None:
    """Write the outputs a stage left for later (those that may be written in a forked worker or not, or all)."""
    for o in outputs:
        if forks is None or o.forks == forks:
            o.write()


def _sensor_chain(model_file, overrides: dict):
    """The model's sensors (its ``sensor.*`` options), which the damping design takes into account (None: ideal)."""
    from samii.closedloop.damping import SensorChain  # (lazy: imports mujoco, only when called)
    from samii.sim.model import load_model  # (lazy: imports mujoco, only when called)
    from samii.sim.sensor_dynamics import SensorDynamics  # (lazy: imports mujoco, only when called)

    chain = SensorChain(SensorDynamics.from_model(load_model(model_file, overrides=overrides or None)))
    return None if chain.ideal else chain


def _design_stage(d: Path, kp: float, chain=None) -> tuple[Path, dict]:
    """``controllers/damping.json``, designed on the measured FRF with the servo gain ``kp`` the data were measured
    with (the Bode test's model), through the model's sensors ``chain`` (None: ideal); the file and the design's
    figures."""
    (d / "controllers").mkdir()
    with _named_stage("design"):
        designed = damping_from_frf(read_frf_csv(d / "measure" / "frf.csv"), source="measure/frf.csv", position_gain_v_per_rad=kp,
                                    chain=chain)  # fmt: skip
    damping = d / "controllers" / "damping.json"  # named in the run's files as the folder names it: controllers/damping.json
    write_controller(designed.controller, damping)
    return damping, finite_or_none(designed.to_dict())


def _closed_loop_stage(
    d: Path, damping: Path, model_file, parsed, progress: Progress, said, notebook: Callable[[], Mapping]
) -> dict[str, ClosedLoopSummary]:
    """The closed-loop trials: the servo loop alone's step, each controller in each scenario (``notebook()``: the
    notebook's controllers by name, designed beside the measurement)."""
    closed = {}
    trials = [("servo_loop_alone_step", TrialRequest("unity", "step"))] + [
        (f"{name}_{sc}", TrialRequest(spec or str(damping), sc)) for name, spec, _ in CONTROLLERS for sc in SCENARIOS
    ]
    for name, request in trials:
        progress.stage(f"closed loop: {name}")
        rerun = d / "closedloop.rrd" if name == "damping_loper" else None
        with _named_stage("closedloop"):
            trial = run_trial(request, out=d / "closedloop" / name, model=model_file, overrides=parsed, rerun=rerun, relative_to=d,
                              note=lambda text, name=name: said(f"note: closed loop {name}: {text}"),
                              saved=notebook()[request.controller] if request.controller in _NOTEBOOK else None)  # fmt: skip
        closed[name] = ClosedLoopSummary(**{k: getattr(trial.record, k) for k in CLOSED_LOOP_FIELDS})
        progress.advance()
    return closed


def _report(d: Path, out: Path) -> None:
    """``report.html``, from the folder's own files (``samii report``), naming the folder as it will be called."""

    write_report(Run.load(d), name=out.name)


def _modes(model, overrides: dict) -> ModesSummary:
    from samii.sim.linearize import modes_report  # (lazy: imports mujoco, scipy, only when called)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        rep = modes_report(model, overrides=overrides or None)
    pair = [z for z in rep.coupled_poles if 30 < abs(z.imag) < 80]
    return ModesSummary(
        pose_deg=tuple(float(a) for a in rep.pose_deg),
        base_modes=tuple(BaseMode(float(m.freq_hz), float(m.zeta)) for m in rep.base_modes[:3]),
        servo_pair_1_s=(float(pair[0].real), float(abs(pair[0].imag))) if pair else None,
    )
