"""A closed-loop trial: one controller through one scenario in the nonlinear simulator, written to a folder.

What ``samii closedloop`` does, as a library call: :func:`resolve_controller` turns a controller spec (a built-in
name or a controller file) into the card's controller, :func:`check_fits` holds it against the card's limits,
and :func:`run_trial` runs the scenario (:func:`samii.closedloop.scenario.run_closed_loop`) and writes
``timeseries.csv``, ``run.json`` and the figures into an all-or-nothing folder (and a Rerun recording when asked).
A run that is unstable by design is a result (``stable`` false), not an error. Refusals are
:class:`~samii.errors.InputError` worded with the command's option names.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from samii.errors import InputError
from samii.json_output import dumps
from samii.outputs import OutputFolder, check_output_file, create_parent, shown_path, written_beside
from samii.progress import said
from samii.schema import document, record_of
from samii.schema.closed_loop import ClosedLoopRecord
from samii.sim.overrides import as_overrides

if TYPE_CHECKING:  # (the type only: this module is imported at samii's start-up, that one is not needed there)
    from samii.closedloop.controllers import SavedController

__all__ = ["TrialRequest", "Trial", "run_trial", "resolve_controller", "check_fits", "model_at_rest", "write_rerun", "BUILTIN_CONTROLLERS", "FILES"]

BUILTIN_CONTROLLERS = {
    "unity": "the servo amplifier's position loop alone (1 V/deg), no digital controller",
    "notebook-place": "chapter 8: digital pole placement with observer on eq 1.4, as the notebook built it (whole position loop)",
    "notebook-cancel": "chapter 10: pole-cancelling compensator on eq 9.4, the notebook's gain 0.0666 (whole position loop)",
    "damping": "tuned acceleration feedback designed here from a simulated measurement of the model: measure, fit, design (about 3 s)",
}
#: The data files of a trial's folder (besides the figures, samii.closedloop.plots.FIGURES).
FILES = ("timeseries.csv", "run.json")


@dataclass(frozen=True)
class TrialRequest:
    """The scenario and the controller card's conditions, as ``samii closedloop``'s options say them."""

    controller: str  #: a BUILTIN_CONTROLLERS name or a controller file
    scenario: str  #: "step", "loper" or "release"
    duration_s: float = 10.0
    step_deg: float | None = None  #: None: the scenario's default
    impulse_n_s: float | None = None  #: None: the scenario's default
    delay_samples: float = 0.0  #: the controller's computation delay
    noise: bool = False  #: seeded sensor noise and ADC quantisation on the controller's measurements
    seed: int | None = None  #: of that noise (None: 0)
    #: the card's anti-alias filter: None (none), "auto" (a quarter of the controller's rate) or its corner [Hz]
    antialias: str | float | None = None


@dataclass
class Trial:
    """A trial's result (samii.closedloop.scenario's ClosedLoopResult), its run.json as typed values, and what was
    written, as the run names it."""

    result: object
    record: ClosedLoopRecord
    written: list[str] = field(default_factory=list)


def resolve_controller(spec: str, factory=None, *, say: Callable[[str], None] | None = None):
    """The controller ``spec`` names (None: the unity servo loop alone); ``factory`` builds the plant the "damping"
    controller is designed on, and ``say`` hears that design's stages."""
    from samii.closedloop import controllers as cs  # (lazy: this module is imported at samii's start-up, that one is not needed there)

    if not spec.strip():
        raise InputError(f"--controller: expected {', '.join(BUILTIN_CONTROLLERS)} or a controller file, got an empty string")
    if spec == "damping":
        from samii.closedloop.damping import (  # (lazy: this module is imported at samii's start-up, that one is not needed there)
            damping_from_simulation,
        )

        model = model_at_rest(factory)
        return damping_from_simulation(model, progress=said(say)).controller
    if spec == "unity":
        return None
    if spec == "notebook-place":
        return cs.notebook_place()
    if spec == "notebook-cancel":
        return cs.notebook_cancel()
    if Path(spec).suffix.lower() == ".json" or Path(spec).exists():
        return cs.read_controller(spec)
    raise InputError(f"--controller {spec!r}: expected {', '.join(BUILTIN_CONTROLLERS)} or a controller file (.json)")


def resolve_antialias(antialias: str | float | None, sample_time_s: float, dt: float) -> float | None:
    """The card's anti-alias corner [Hz] ``--antialias`` asks for (None, "auto" or a corner) for a controller sampling
    every ``sample_time_s`` on a model stepping ``dt``: "auto" is the measurement DAQ's rule at the controller's rate
    (a quarter of it); refused, naming the option, at or above half the physics rate."""
    if antialias is None:
        return None
    from samii.closedloop.card import default_antialias_hz  # (lazy: imports mujoco, only when called)

    hz = default_antialias_hz(sample_time_s) if antialias == "auto" else float(antialias)
    if not hz < 0.5 / dt:
        raise InputError(f"--antialias {hz:g}: the corner must lie below half the physics rate ({0.5 / dt:g} Hz)")
    return hz


def check_fits(saved, spec: str, delay_samples: float, dt: float) -> None:
    """The controller against the card's limits and the physics step, naming the file and field or the option."""
    from samii.closedloop.card import CardFitError, check_fit  # (lazy: this module is imported at samii's start-up, that one is not needed there)

    try:
        check_fit(saved.controller, dt, delay_samples)
    except CardFitError as exc:
        if exc.field == "delay_samples":
            raise InputError(f"--delay-samples {delay_samples:g}: {exc}") from None
        where = f"controller file {spec}" if spec not in BUILTIN_CONTROLLERS else f"--controller {spec}"
        raise InputError(f"{where}: {exc}") from None


def _check_request(req: TrialRequest, *, plots: bool, out) -> None:
    if req.step_deg is not None and req.scenario == "release":
        raise InputError("--step-deg: the release scenario holds theta_ref (use --impulse-n-s for its size)")
    if req.impulse_n_s is not None and req.scenario != "release":
        raise InputError("--impulse-n-s: only the release scenario starts with an impulse")
    if req.seed is not None and not req.noise:
        raise InputError("--seed: only meaningful with --noise")
    if not plots and out is None:
        raise InputError("--no-plots: only meaningful with --out")
    if req.scenario == "loper" and req.duration_s < 4.0:
        raise InputError(f"--duration-s {req.duration_s:g}: the loper scenario switches the controller on at t = 2 s and needs at least 4 s")


def model_at_rest(factory):
    """The run's model with its ``home`` keyframe at the static equilibrium the factory found (a
    model changed by ``--set`` or a parameter file is not at rest in its written keyframe)."""

    from samii.sim.plugin import compile_spec  # (lazy: this module is imported at samii's start-up, that one is not needed there)

    spec, qpos, act = factory()
    model = compile_spec(spec)
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home")
    model.key_qpos[key], model.key_act[key] = qpos, act
    return model


def write_rerun(result, tmp, final, factory) -> None:
    """The trial (and its comparison run, if any) as a Rerun recording in ``tmp``; a failure names ``final``."""

    from samii.viz.recording import (  # (lazy: this module is imported at samii's start-up, that one is not needed there)
        RunRecord,
        recording_failed,
        write_recording,
    )

    create_parent(tmp)
    s = result.signals
    model = model_at_rest(factory)
    frame_t = s.frame_t if s.frame_t is not None else np.zeros(0)
    frame_q = s.frame_qpos if s.frame_qpos is not None else np.zeros((0, model.nq))
    runs = [
        RunRecord(
            "closedloop",
            result.timeseries(),
            frame_t,
            frame_q,
            switch_on_s=s.switch_on_s,
            label=f"samii closedloop: controller {result.controller}, scenario {result.scenario.name}",
        )
    ]
    c = result.comparison
    if c is not None and c.frame_t is not None:  # the same scenario under the servo amplifier alone (Figure 11.4 as a recording)
        runs.append(
            RunRecord(
                "servo_loop_alone",
                result.timeseries(comparison=True),
                c.frame_t,
                c.frame_qpos,
                label=f"the comparison: scenario {result.scenario.name} under the servo amplifier alone (no controller)",
            )
        )
    try:
        write_recording(tmp, model, runs, application_id="samii_closedloop")
    except (RuntimeError, OSError) as exc:  # rerun's writer reports file-system failures as RuntimeError
        raise recording_failed(exc, final) from None


def run_trial(
    request: TrialRequest,
    *,
    out=None,
    model=None,
    overrides: Sequence[str] | Mapping[str, float] | None = None,
    plots: bool = True,
    rerun=None,
    rerun_fps: float | None = None,
    overwrite: bool = False,
    say: Callable[[str], None] | None = None,
    note: Callable[[str], None] | None = None,
    relative_to=None,
    saved: SavedController | None = None,
) -> Trial:
    """Run ``request`` on ``model`` (an MJCF or parameter file; None: the embedded one) with ``overrides``; given
    ``out``, write it into that folder (all or nothing, checked before any work), with its figures unless ``plots``
    is false; given ``rerun``, a recording there. ``say`` hears the stages of a "damping" controller's design, ``note``
    what was asked and will not be done (as it is found);
    ``relative_to`` names the written files relative to that folder (the main job's) instead of as given; ``saved``:
    the controller ``request.controller`` names, resolved already (:func:`resolve_controller`'s: the main job resolves
    the notebook's beside its measurement), None: resolved here."""
    from samii.closedloop.plots import FIGURES  # (lazy: this module is imported at samii's start-up, that one is not needed there)
    from samii.closedloop.scenario import (  # (lazy: this module is imported at samii's start-up, that one is not needed there)
        NoiseSpec,
        default_spec_factory,
        run_closed_loop,
        scenario,
    )

    _check_request(request, plots=plots, out=out)
    names = list(FILES) + (list(FIGURES) if plots else [])
    folder = OutputFolder(out, names, overwrite=overwrite) if out is not None else None
    rerun_path = check_output_file(rerun, overwrite=overwrite, option="--rerun", beside=folder) if rerun else None
    if request.controller == "unity" and request.delay_samples:
        raise InputError("--delay-samples: the unity servo loop is analog (no digital controller to delay)")
    if request.controller == "unity" and request.noise:
        raise InputError("--noise: the unity servo loop samples no sensors (its analog loop reads the joint angle directly)")
    if request.controller == "unity" and request.antialias is not None:
        raise InputError("--antialias: the unity servo loop samples no sensors (its analog loop reads the joint angle directly)")

    overrides = as_overrides(overrides)  # (read after the request's own checks)
    factory = default_spec_factory(model, overrides or None)
    if saved is None:
        saved = resolve_controller(request.controller, factory, say=say)
    antialias = None
    if saved is not None:
        spec, _, _ = factory()
        check_fits(saved, request.controller, request.delay_samples, float(spec.option.timestep))
        antialias = resolve_antialias(request.antialias, saved.controller.sample_time_s, float(spec.option.timestep))
    kw = {"duration_s": request.duration_s}
    if request.step_deg is not None:
        kw["step_deg"] = request.step_deg
    if request.impulse_n_s is not None:
        kw["impulse_n_s"] = request.impulse_n_s
    sc = scenario(request.scenario, **kw)
    noise = NoiseSpec(seed=request.seed or 0) if request.noise else None
    frame_steps = None
    if rerun_path:
        from samii.viz.recording import frame_steps_for  # (lazy: this module is imported at samii's start-up, that one is not needed there)

        frame_steps = frame_steps_for(model_at_rest(factory), rerun_fps)
    # the controller's name in the run's files and figures: a built-in's, or the file as the run names it
    label = request.controller if request.controller in BUILTIN_CONTROLLERS else shown_path(request.controller, relative_to)
    result = run_closed_loop(saved, sc, label=label, spec_factory=factory, delay_samples=request.delay_samples, noise=noise,
                             qpos_every=frame_steps, antialias_hz=antialias)  # fmt: skip

    written: list[str] = []
    recorded = result.signals.t.size >= 2  # a run that diverged in its first step has nothing to record or draw
    if not recorded and rerun_path is not None:
        if note is not None:
            note(f"--rerun {rerun_path}: not written, the run diverged in its first step")
        rerun_path = None
    doc = result.run_json()
    doc["model"] = {"file": str(model) if model else "embedded default", "overrides": overrides}
    doc["controller_detail"] = None if saved is None else {
        "name": saved.controller.name, "method": saved.controller.method, "model_units": saved.controller.model_units,
        "servo_loop": "replaced" if saved.replaces_servo else "kept", "provenance": dict(saved.provenance)}  # fmt: skip
    doc["recorded"] = recorded  # (false: the run diverged in its first step; run.json alone is written)
    record = record_of(ClosedLoopRecord, doc, "samii.closedloop.trial.run_trial")
    with written_beside(rerun_path) as rrd_tmp:
        if folder is not None:
            from samii.formats import write_timeseries_csv  # (lazy: this module is imported at samii's start-up, that one is not needed there)

            with folder:
                if recorded:
                    write_timeseries_csv(result.timeseries(), folder.path("timeseries.csv"), overwrite=True)
                else:
                    for name in [n for n in (*FILES, *FIGURES) if n != "run.json"]:  # the verdict alone
                        folder.omit(name)
                folder.path("run.json").write_text(dumps(document(record), indent=1) + "\n")
                if recorded and plots:
                    from samii.closedloop.plots import (  # (lazy: this module is imported at samii's start-up, that one is not needed there)
                        plot_base,
                        plot_linear,
                        plot_theta,
                    )

                    plot_theta(result, folder.path("theta.png"))
                    plot_base(result, folder.path("base_accel.png"))
                    plot_linear(result, folder.path("linear_vs_nonlinear.png"))
                if rrd_tmp is not None:  # inside the folder's transaction: a failed recording leaves no folder behind
                    write_rerun(result, rrd_tmp, rerun_path, factory)
            written = [shown_path(folder.final(n), relative_to) for n in folder.names]
        elif rrd_tmp is not None:
            write_rerun(result, rrd_tmp, rerun_path, factory)
    if rerun_path is not None:
        written.append(shown_path(rerun_path, relative_to))
    return Trial(result=result, record=record, written=written)
