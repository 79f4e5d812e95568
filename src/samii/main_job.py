"""The main job: the whole pipeline on one model, into one output folder, with a short summary.

``samii`` with no arguments runs it on the embedded default model into ``./samii_run``;
``samii run [--out DIR] [--model XML] [--set NAME=VALUE ...] [--seed S]`` on a user's model.
The stages are samii's own commands, run in this process with the same options a user would give
them, so each stage's files are what that command writes:

1. ``modes``: the base modes and the servo-loop poles at the nominal pose (printed);
2. ``measure/``: swept sine 0.1-40 Hz, 0.1 V, 3 sign-alternating records, sensor noise seeded
   by ``--seed`` (``samii measure --noise``), and ``measure.rrd``, its Rerun recording;
3. ``fit/``: the notebook's 3-mode model fitted to that FRF (``samii fit``);
4. ``controllers/damping.json``: acceleration feedback designed on a fit of the same FRF
   (``samii design damping --frf``);
5. ``closedloop/<controller>_<scenario>/``: the notebook's pole-cancelling compensator (chapter 10)
   and pole placement (chapter 8), as the notebook built them, and the damping controller, each in
   the step and Loper tests in the nonlinear simulator (``samii closedloop``), and
   ``closedloop.rrd``: the damping controller's Loper test beside the servo loop alone;
6. ``diagnose/``: the fit diagnosed against the measured record (``samii diagnose --baseline
   fit/fit.json``);
7. ``summary.json``: the figures of the printed summary.

The folder is written whole or not at all: the stages write into a staging folder beside it,
which replaces ``--out`` at the end (an existing ``--out`` only with ``--overwrite``, or when it
holds a previous main job's output).

8. ``report.html``: one self-contained page with the figures and tables of all of it (``samii report``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from samii.cli_args import add_model, add_no_progress, add_out, add_overwrite, add_set
from samii.errors import InputError
from samii.run_summary import CONTROLLERS, MARKER, SCENARIOS, summary_lines

__all__ = ["add_arguments", "run", "run_main_job", "run_pipeline", "PipelineResult", "DEFAULT_OUT"]

#: Where ``samii`` with no arguments writes.
DEFAULT_OUT = "samii_run"


@dataclass
class PipelineResult:
    out: Path
    summary: dict
    lines: list[str] = field(default_factory=list)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from samii.cli_args import seed as seed_type

    add_out(parser, f"output folder (default ./{DEFAULT_OUT}); replaced whole at the end", default=DEFAULT_OUT)
    add_model(parser, "MJCF model (default: the embedded one)")
    add_set(parser, "override a model parameter (samii params lists them); repeatable")
    parser.add_argument(
        "--seed", type=seed_type, default=0, help="seed of the measurement's sensor noise (default 0): the same seed gives the same outputs"
    )
    add_overwrite(parser, "replace --out if it exists (a previous main job's output is replaced anyway)")
    add_no_progress(parser)


def run(args: argparse.Namespace) -> int:
    result = run_pipeline(args.out, model=args.model, overrides=args.set, seed=args.seed, overwrite=args.overwrite, progress=not args.no_progress)
    print("\n".join(result.lines))
    return 0


def run_main_job() -> int:
    """``samii`` with no arguments: the pipeline on the embedded model into ``./samii_run``."""
    return run(argparse.Namespace(out=DEFAULT_OUT, model=None, set=[], seed=0, overwrite=False, no_progress=False))


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


class _Progress:
    def __init__(self, enabled: bool, total: int):
        from tqdm import tqdm

        self.bar = tqdm(
            total=total,
            desc="samii",
            unit="stage",
            leave=False,
            file=sys.stderr,
            dynamic_ncols=True,
            disable=None if enabled else True,
            bar_format="{desc}: {n}/{total} stages {elapsed} {postfix}",
        )

    def start(self, what: str) -> None:
        self.bar.set_postfix_str(what)

    def done(self) -> None:
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()


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


def _closed_loop(d: Path, name: str, request, model, overrides: dict, rerun) -> dict:
    """One closed-loop trial written to ``closedloop/NAME``: the result's figures the summary takes."""
    from samii.closedloop.trial import run_trial
    from samii.json_output import finite_or_none

    with _named_stage("closedloop"):
        trial = run_trial(request, out=d / "closedloop" / name, model=model, overrides=overrides, rerun=rerun, relative_to=d)
    res = finite_or_none(trial.result.as_json())
    return {k: res.get(k) for k in ("stable", "unstable_mode_hz", "growth_rate_1_s", "instability", "theta", "base")}


def run_pipeline(out, *, model=None, overrides=(), seed: int = 0, overwrite: bool = False, progress: bool = True) -> PipelineResult:
    """Run the pipeline (module docstring) into ``out`` and return the summary."""
    out = Path(out)
    from samii.outputs import remove_stale_runs, restore_replaced

    if (back := restore_replaced(out, f".{out.name}.samii-run-")) is not None:  # a run killed between its two renames
        print(f"samii run: {out} was missing and is back from {back.name}, where a run killed while replacing it had moved it", file=sys.stderr)
    _check_out(out, overwrite)
    from samii.errors import mark_outputs_started

    stage_dir = out.absolute().parent / f".{out.name}.samii-run-{os.getpid()}"
    remove_stale_runs(out.absolute().parent, f".{out.name}.samii-run-")  # what a killed run (SIGKILL) left
    if stage_dir.exists():
        shutil.rmtree(stage_dir)
    mark_outputs_started(out)
    stage_dir.mkdir()
    bar = _Progress(progress, 6 + len(CONTROLLERS) * len(SCENARIOS))
    started = time.perf_counter()
    try:
        summary = _run_stages(stage_dir, model, list(overrides or ()), seed, bar)
        summary["wall_s"] = time.perf_counter() - started
        summary["recordings_mb"] = {n: (stage_dir / n).stat().st_size / 1e6 for n in ("measure.rrd", "closedloop.rrd") if (stage_dir / n).is_file()}
        (stage_dir / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=False) + "\n")
        bar.start("writing report.html")
        try:
            _report(stage_dir, out)
        except Exception as exc:  # noqa: BLE001 - the report is read from the stages' files: a fault in it loses none of them
            summary["report_error"] = f"{type(exc).__name__}: {exc}"
            print(
                f"samii run: warning: report.html not written ({summary['report_error']}); every other output is; samii report {out} tries again",
                file=sys.stderr,
            )
            (stage_dir / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=False) + "\n")
        bar.done()
        from samii.errors import raise_if_signalled

        raise_if_signalled()  # a signal whose exception a library swallowed (a finaliser's): keep nothing
        from samii.errors import uninterrupted

        # the old folder moved aside and the new one into place by renames a signal waits for: removed first, an
        # interrupted removal left neither (a folder half-deleted); what it replaced goes after, as a killed run's does
        with uninterrupted(done=out):
            old = stage_dir.with_name(stage_dir.name + "-replaced")
            if out.exists():
                os.replace(out, old)
            os.replace(stage_dir, out)
            shutil.rmtree(old, ignore_errors=True)  # (left, a later run's remove_stale_runs takes it)
    finally:
        bar.close()
        if stage_dir.exists():
            shutil.rmtree(stage_dir)
    return PipelineResult(out, summary, summary_lines(summary, out))


def _run_stages(d: Path, model, overrides: list[str], seed: int, bar: _Progress) -> dict:
    from samii import notebook as nb
    from samii.json_output import finite_or_none

    s: dict = {"written_by": MARKER, "seed": seed, "model": {"file": str(model) if model else "embedded default", "overrides": overrides}}

    bar.start("modes")
    s["modes"] = _modes(model, overrides)
    bar.done()

    bar.start("measuring (swept sine, 253 s simulated)")
    from samii.measure.bode_test import BodeTestRequest, run_bode_test
    from samii.sim.cli_modes import parse_overrides

    with _named_stage("measure"):
        test = run_bode_test(d / "measure", BodeTestRequest(noise=True, seed=seed), model=_model_path(model),
                             overrides=parse_overrides(overrides), rerun=d / "measure.rrd", argv=sys.argv[1:], relative_to=d)  # fmt: skip
    run = test.summary
    sweep = run["excitation"]["swept"]
    s["measurement"] = {
        "excitation": sweep["excitation"],
        "amplitude_v": sweep["amplitude_v"],
        "sample_rate_hz": run["daq"]["sample_rate_hz"],
        "simulated_s": run["timing"]["simulated_s"],
        "sensor_noise": run["daq"]["sensor_noise"],
    }
    bar.done()

    bar.start("fitting the notebook's 3-mode model")
    from samii.identify.fit_file import fit_frf_file

    with _named_stage("fit"):
        fit_frf_file(d / "measure" / "frf.csv", out=d / "fit", relative_to=d)
    fit = json.loads((d / "fit" / "fit.json").read_text())
    p, se = fit["params"], fit["stderr"]
    s["fit"] = {
        "params": p,
        "stderr": se,
        "eq9_4": dict(nb.EQ9_4),
        **{k: fit.get(k) for k in ("sound", "verdict", "concerns", "caveats", "undetermined", "lack_of_fit", "rms_mag_db", "rms_phase_deg")},
    }
    bar.done()

    bar.start("designing the damping controller")
    (d / "controllers").mkdir()
    from samii.sim.cli_modes import parse_overrides
    from samii.sim.model import load_model
    from samii.sim.plugin import hydraulic_params

    kp = hydraulic_params(load_model(model, overrides=parse_overrides(overrides) or None)).position_gain  # what the data were measured with
    from samii.closedloop.controllers import write_controller
    from samii.closedloop.damping import damping_from_frf
    from samii.formats import read_frf_csv

    with _named_stage("design"):
        designed = damping_from_frf(read_frf_csv(d / "measure" / "frf.csv"), source="measure/frf.csv", position_gain_v_per_rad=float(kp))
    write_controller(designed.controller, d / "controllers" / "damping.json")
    design = finite_or_none(designed.to_dict())
    s["damping_design"] = {k: design.get(k) for k in ("gain_v_per_m_s2", "gain_limit_v_per_m_s2", "gain_margin_db", "filter_hz", "rolloff_hz")}
    bar.done()

    from samii.closedloop.trial import TrialRequest

    s["closed_loop"] = {}
    runs = [("servo_loop_alone", "unity", "step")] + [
        (name, spec or str(d / "controllers" / "damping.json"), sc) for name, spec, _ in CONTROLLERS for sc in SCENARIOS
    ]
    for name, spec, sc in runs:
        bar.start(f"closed loop: {name}, {sc}")
        rerun = d / "closedloop.rrd" if (name, sc) == ("damping", "loper") else None
        s["closed_loop"][f"{name}_{sc}"] = _closed_loop(
            d, f"{name}_{sc}", TrialRequest(spec, sc), _model_path(model), parse_overrides(overrides), rerun
        )
        bar.done()

    bar.start("diagnosing the fit against the measured record")
    from samii.diagnose.files import DiagnoseRequest, diagnose_files

    with _named_stage("diagnose"):
        done = diagnose_files(
            [d / "measure" / "timeseries.csv"], DiagnoseRequest(baseline=str(d / "fit" / "fit.json")), out=d / "diagnose", relative_to=d
        )
    diag = finite_or_none(done.diagnosis.to_dict())
    s["diagnosis"] = {
        "verdict": diag.get("verdict"),
        "effects": [e for e in diag.get("effects", []) if not e.get("expected")],
        "error_before": diag.get("error_before"),
        "error_after": diag.get("error_after"),
    }
    bar.done()
    return s


def _report(d: Path, out: Path) -> None:
    """``report.html``, from the folder's own files (``samii report``), naming the folder as it will be called."""
    from samii.report.content import read_run_folder
    from samii.report.page import write_report

    run = read_run_folder(d)
    run.display_name = out.name
    write_report(run)


def _modes(model, overrides) -> dict:
    import warnings

    from samii.sim.cli_modes import parse_overrides
    from samii.sim.linearize import modes_report

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        rep = modes_report(model, overrides=parse_overrides(overrides) or None)
    pair = [z for z in rep.coupled_poles if 30 < abs(z.imag) < 80]
    return {
        "pose_deg": [float(a) for a in rep.pose_deg],
        "base_modes": [{"freq_hz": float(m.freq_hz), "zeta": float(m.zeta)} for m in rep.base_modes[:3]],
        "servo_pair_1_s": [float(pair[0].real), float(abs(pair[0].imag))] if pair else None,
    }
