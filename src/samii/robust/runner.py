"""A robustness study as a library call: :func:`plan_study` checks a :class:`StudyRequest` and prepares it (the
nominal plant, the draws, the controller designed or read once on the nominal plant, the engine), :meth:`Study.run`
runs it and returns a :class:`StudyResult`; :func:`run_study` does both. ``samii robust`` is this call and its
printing.

What makes a study say less than it seems to comes back as :class:`StudyWarning` (a code and its figures, worded by
:attr:`StudyWarning.text`), recorded in ``robust.json``'s ``warnings``. With ``out`` the study writes ``robust.json``
(the summary, the nominal plant's run, every sample), ``samples.csv`` (one line per sample: its parameters and results)
and the figures ``histograms.png`` and ``influence.png``, all or nothing (:class:`samii.outputs.OutputFolder`, checked
before any work).
"""

from __future__ import annotations

import csv
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from samii import forkmap
from samii.closedloop.trial import check_fits, resolve_antialias, resolve_controller
from samii.errors import InputError
from samii.json_output import dumps
from samii.outputs import OutputFolder
from samii.progress import SILENT, Progress
from samii.robust.engine import DEFAULT_CONNECT_TIMEOUT_S, Engine, check_address, configured_scheduler
from samii.robust.plots import FIGURES, plot_histograms, plot_influence
from samii.robust.sampling import DELAY_SAMPLES, Covariance, PlantDraws, draw_plants, parse_spread, read_covariance, sample_seeds
from samii.robust.study import StudySummary, summarise
from samii.robust.task import SampleResult, SampleTask
from samii.schema import document, record_of
from samii.schema.robust import RobustRecord
from samii.sim.overrides import as_overrides

__all__ = ["StudyRequest", "StudyWarning", "Study", "StudyResult", "NoPlantBuilt", "plan_study", "run_study", "FILES", "TINY_SPREAD", "FEW_SAMPLES"]

#: The files a study writes with ``out`` beside its figures (samii.robust.plots.FIGURES).
FILES = ("robust.json", "samples.csv")
#: An absolute spread below this fraction of its nominal value varies nothing (double precision keeps 1e-16; a
#: parameter known to 1e-4 of itself is known better than any rig's).
TINY_SPREAD = 1e-4
#: Fewer plants than this: the 5 % and 95 % percentiles are the smallest and largest drawn (1/0.05 = 20).
FEW_SAMPLES = 20


class NoPlantBuilt(InputError):
    """None of the drawn plants could be built (no static equilibrium near the nominal pose, a mode too stiff for the
    physics step): the spreads are too wide. Raised by :meth:`Study.run` once the plants have been tried."""


@dataclass(frozen=True)
class StudyRequest:
    """What ``samii robust`` is asked (its options, by the same names)."""

    controller: str  #: unity, notebook-cancel, notebook-place, damping, or a controller file
    scenario: str = "step"  #: step, loper or release (samii.closedloop.scenario)
    samples: int = 100
    seed: int = 0  #: of the draws, and of the sensor noise with ``noise``
    spreads: Sequence[str] = ()  #: NAME=P% (relative) or NAME=SIGMA (absolute, in the parameter's unit)
    covariance: str | Path | None = None  #: a calibration.json (samii calibrate): its parameters drawn jointly
    model: str | Path | None = None  #: the nominal plant's parameter file (.json); None: the embedded model
    overrides: Sequence[str] | Mapping[str, float] = ()  #: NAME=VALUE texts or a mapping, on the nominal plant
    delay_samples: float = 0.0  #: the controller's computation delay [samples]
    noise: bool = False  #: sensor noise on the controller's measurements, seeded per sample
    #: the card's anti-alias filter: None (none), "auto" (a quarter of the controller's rate) or its corner [Hz]
    antialias: str | float | None = None
    #: 0: this process; N: N worker processes on this machine; None: Dask's configured scheduler if any, else one process per core
    workers: int | None = None
    scheduler: str | None = None  #: a Dask scheduler's address (tcp://host:8786)
    scheduler_timeout_s: float | None = None  #: how long the scheduler has to answer (None: DEFAULT_CONNECT_TIMEOUT_S)


@dataclass(frozen=True)
class StudyWarning:
    """A reason the study says less than it seems to: ``code`` what, ``values`` its figures; :attr:`text` words it."""

    code: str  #: "covariance_not_converged", "tiny_spread" or "few_samples"
    values: Mapping[str, object] = field(default_factory=dict)

    @property
    def text(self) -> str:
        v = self.values
        if self.code == "covariance_not_converged":
            return (
                f"--covariance {v['file']}: the calibration did not converge (field 'converged' is false): its standard "
                "errors and correlations describe no minimum of its cost; calibrate again"
            )
        if self.code == "tiny_spread":
            sigma, value = v["sigma"], v["nominal"]
            return (
                f"--spread {v['name']}={sigma:g}: an absolute standard deviation of {sigma:g} on a nominal {value:.6g} "
                f"({sigma / abs(value):.2g} of it): the study varies nothing; a relative spread is written with % ({v['name']}={sigma:g}%)"
            )
        if self.code == "few_samples":
            return (
                f"--samples {v['samples']}: the 5 and 95 % percentiles of fewer than {v['few']} plants are the extremes drawn, not the spread's tails"
            )
        raise ValueError(f"StudyWarning: unknown code {self.code!r}")


@dataclass(frozen=True)
class StudyResult:
    """A study's outcome: ``record`` is robust.json's content (without its schema_version) as typed values."""

    request: StudyRequest
    summary: StudySummary
    draws: PlantDraws
    nominal: SampleResult  #: the nominal plant's run
    samples: list[SampleResult]
    warnings: tuple[StudyWarning, ...]
    record: RobustRecord
    written: tuple[Path, ...] = ()  #: the files written (with ``out``)

    @property
    def engine(self) -> str:
        """What ran it, in words."""
        return self.record.engine

    @property
    def wall_s(self) -> float:
        return self.record.wall_s


def _nominal_params(req: StudyRequest) -> tuple[object, Covariance | None, list[StudyWarning]]:
    from samii.sim.model import default_params, params_from_dict, params_with_overrides, read_params_file  # (lazy: imports mujoco, only when called)

    cov, said = None, []
    if req.covariance:
        if req.model:
            raise InputError("--model: with --covariance the nominal plant is the calibration's (its calibrated_params); give one of them")
        cov = read_covariance(req.covariance)
        if cov.converged is False:  # its standard errors are those of a point that is no minimum: said, used as asked
            said.append(StudyWarning("covariance_not_converged", {"file": str(req.covariance)}))
        try:
            params = params_from_dict(cov.nominal, complete=True)
        except ValueError as exc:
            raise InputError(f"--covariance {req.covariance}: field 'calibrated_params': {exc}") from None
    elif req.model:
        if not str(req.model).lower().endswith(".json"):
            raise InputError(f"--model {req.model}: samii robust varies a parameter file's values (.json; samii params lists them), not an MJCF")
        params = read_params_file(req.model)
    else:
        params = default_params()
    overrides = as_overrides(req.overrides)
    if cov is not None and set(overrides) & set(cov.names):
        raise InputError(f"--set {sorted(set(overrides) & set(cov.names))[0]}: also drawn by --covariance; give one of them")
    return (params_with_overrides(params, overrides) if overrides else params), cov, said


def _study_warnings(req: StudyRequest, spreads, nominal: dict) -> list[StudyWarning]:
    """What makes a study say less than it seems to: an absolute spread that is a rounding error of its parameter (the
    '%' forgotten: NAME=20 is 20 in the parameter's unit), percentiles of fewer plants than they need."""
    out = []
    for sp in spreads:
        value = nominal.get(sp.name)
        if sp.absolute is not None and isinstance(value, (int, float)) and value and 0 < sp.absolute < TINY_SPREAD * abs(value):
            out.append(StudyWarning("tiny_spread", {"name": sp.name, "sigma": sp.absolute, "nominal": float(value)}))
    if req.samples < FEW_SAMPLES:
        out.append(StudyWarning("few_samples", {"samples": req.samples, "few": FEW_SAMPLES}))
    return out


def _engine(req: StudyRequest) -> Engine:
    if req.scheduler and req.workers is not None:
        raise InputError("--workers: with --scheduler the cluster's own workers run the study; give one of them")
    # an explicit workers (0 included) wins over Dask's configured scheduler address
    scheduler = req.scheduler or (configured_scheduler() if req.workers is None else None)
    source = "--scheduler" if req.scheduler else "Dask's configured scheduler-address (DASK_SCHEDULER_ADDRESS or ~/.config/dask)"
    if scheduler and check_address(scheduler, source) is None:  # before any work: an address Dask cannot connect to
        raise InputError(
            f"{source} {scheduler}: an in-process address (inproc://) names a scheduler inside one Python "
            "process, never another command's; give the scheduler's tcp://host:port"
        )
    if req.scheduler_timeout_s is not None and not scheduler:  # (it was accepted and did nothing)
        raise InputError("--scheduler-timeout: only with a Dask cluster to wait for (--scheduler, or Dask's configured scheduler-address)")
    timeout = req.scheduler_timeout_s or DEFAULT_CONNECT_TIMEOUT_S
    workers = 0 if scheduler else forkmap.workers() if req.workers is None else req.workers
    return Engine(workers=workers, scheduler=scheduler, connect_timeout_s=timeout, scheduler_source=source)


@dataclass
class Study:
    """A study checked and prepared (:func:`plan_study`), not yet run. As a context manager it holds its engine's
    connection to a user's Dask cluster (connected first, bounded in time: a scheduler that refuses or never answers
    is one InputError); :meth:`run` runs it."""

    request: StudyRequest
    draws: PlantDraws
    tasks: list[SampleTask]  #: the nominal plant's (index -1) first, then the drawn ones
    engine: Engine
    warnings: list[StudyWarning]
    folder: object = None  #: samii.outputs.OutputFolder with ``out``

    def describe(self) -> str:
        r = self.request
        return f"{r.controller}, {r.scenario} test, {r.samples} plants (seed {r.seed}) {self.engine.describe()}"

    def __enter__(self) -> Study:
        if self.engine.scheduler:  # (local workers are forked and ended by the run itself)
            self.engine.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        if self.engine.scheduler:
            self.engine.__exit__(*exc)

    def run(self, progress: Progress | None = None) -> StudyResult:
        """Run every plant (``progress`` hears a unit per plant), reduce, and write the folder if one was given."""
        r = self.request
        started = time.perf_counter()
        results = self.engine.map(self.tasks, progress=progress or SILENT)
        wall = time.perf_counter() - started
        nominal, samples = results[0], results[1:]
        summary = summarise(self.draws, samples)
        if summary.n == 0:
            why = samples[0].note.removeprefix("no plant: ")
            raise NoPlantBuilt(f"none of the {r.samples} drawn plants could be built (the first: {why}); narrow the spreads")
        d = self.draws
        document = {
            "controller": r.controller, "scenario": r.scenario, "seed": r.seed, "n_samples": r.samples,
            "engine": self.engine.describe(), "wall_s": wall, "warnings": [w.text for w in self.warnings],
            "varied": [{"name": n, "nominal": float(v), "source": s} for n, v, s in zip(d.names, d.nominal, d.sources)],
            "nominal_plant": nominal.table_row(),
            "summary": summary.as_json(),
            "samples": [dict(s.table_row(), params=d.overrides(s.index)) for s in samples],
        }  # fmt: skip
        record = record_of(RobustRecord, document, "samii.robust.runner.Study.run")
        result = StudyResult(r, summary, d, nominal, samples, tuple(self.warnings), record)
        if self.folder is not None:
            result = replace(result, written=_write(self.folder, result))
        return result


def plan_study(request: StudyRequest, *, out=None, overwrite: bool = False, say: Callable[[str], None] | None = None) -> Study:
    """``request`` checked and prepared (every refusal an InputError naming the option, before any plant runs): the
    output folder ``out`` (None: nothing written), the nominal plant, the draws (each a plant the model accepts),
    the engine, and the controller designed (``say`` hears a "damping" design's stages) or read, once, on the nominal
    plant and checked against the controller card."""
    from samii.sim.model import dotted, load_model, load_spec, params_with_overrides  # (lazy: imports mujoco, only when called)

    req = request
    if req.controller == "unity" and req.delay_samples:
        raise InputError("--delay-samples: the unity servo loop is analog (no digital controller to delay)")
    if req.controller == "unity" and req.noise:
        raise InputError("--noise: the unity servo loop samples no sensors (its analog loop reads the joint angle directly)")
    if req.controller == "unity" and req.antialias is not None:
        raise InputError("--antialias: the unity servo loop samples no sensors (its analog loop reads the joint angle directly)")
    folder = OutputFolder(out, list(FILES) + list(FIGURES), overwrite=overwrite) if out is not None else None
    spreads = [parse_spread(s) for s in req.spreads]
    if req.controller == "unity" and any(sp.name == DELAY_SAMPLES for sp in spreads):
        raise InputError(f"--spread {DELAY_SAMPLES}: the unity servo loop is analog (no digital controller to delay)")
    params, cov, said = _nominal_params(req)
    nominal = {**dotted(params), DELAY_SAMPLES: float(req.delay_samples)}
    draws = draw_plants(req.samples, req.seed, nominal, spreads, cov)
    said += _study_warnings(req, spreads, nominal)

    def plant(i: int) -> dict[str, float]:
        return {n: v for n, v in draws.overrides(i).items() if n != DELAY_SAMPLES}

    def delay(i: int) -> float:
        return draws.overrides(i).get(DELAY_SAMPLES, float(req.delay_samples))

    for i in range(req.samples):  # every drawn value is one the model accepts, checked before any run
        try:
            params_with_overrides(params, plant(i))
        except InputError as exc:
            raise InputError(f"sample {i}: {exc}: narrow the spread (or give it as an absolute value)") from None
    engine = _engine(req)

    nominal_model = load_model(params=params)
    qpos, act = nominal_model.key_qpos[0].copy(), nominal_model.key_act[0].copy()
    saved = resolve_controller(req.controller, lambda: (load_spec(params=params)[0], qpos, act), say=say)
    aa = None
    if saved is not None:
        check_fits(saved, req.controller, req.delay_samples, float(nominal_model.opt.timestep))
        aa = resolve_antialias(req.antialias, saved.controller.sample_time_s, float(nominal_model.opt.timestep))
        from samii.closedloop.card import CardFitError, check_fit  # (lazy: imports mujoco, only when called)

        for i in range(req.samples):  # and every drawn delay one the card can run
            try:
                check_fit(saved.controller, float(nominal_model.opt.timestep), delay(i))
            except CardFitError as exc:
                raise InputError(f"sample {i}: --spread {DELAY_SAMPLES} drew a delay of {delay(i):.4g} samples, {exc}: narrow the spread") from None
    base = params.as_dict()

    def noise_seed(i: int) -> int | None:
        return sample_seeds(req.seed, i)[1] if req.noise else None

    tasks = [SampleTask(-1, base, {}, saved, req.scenario, req.delay_samples, noise_seed(-1), aa)]
    tasks += [SampleTask(i, base, plant(i), saved, req.scenario, delay(i), noise_seed(i), aa) for i in range(req.samples)]
    return Study(req, draws, tasks, engine, said, folder)


def run_study(request: StudyRequest, *, out=None, overwrite: bool = False, progress: Progress | None = None, say=None) -> StudyResult:
    """:func:`plan_study` and :meth:`Study.run` in one call."""
    with plan_study(request, out=out, overwrite=overwrite, say=say) as study:
        return study.run(progress)


def _write(folder, result: StudyResult) -> tuple[Path, ...]:
    r = result.request
    with folder:
        folder.path("robust.json").write_text(dumps(document(result.record), indent=1) + "\n")
        _write_csv(folder.path("samples.csv"), result.draws, result.samples)
        plot_histograms(result.samples, result.summary, f"{r.controller}, {r.scenario} test, {r.samples} plants", folder.path("histograms.png"))
        plot_influence(result.draws, result.samples, result.summary, folder.path("influence.png"))
    return tuple(folder.written)


def _write_csv(path, draws: PlantDraws, samples: list[SampleResult]) -> None:
    numbers = ["zeta", "mode_hz", "growth_rate_1_s", "base_settle_s", "theta_settle_s", "theta_overshoot_pct"]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["index", *draws.names, "valid", "stable", "linear_stable", *numbers, "note"])
        for s in samples:
            row = s.table_row()
            w.writerow([s.index, *(repr(float(v)) for v in draws.values[s.index]), int(s.valid), int(s.stable), int(s.linear_stable),
                        *("" if row[c] is None else repr(float(row[c])) for c in numbers), s.note])  # fmt: skip
