"""``samii closedloop``: run a controller in the nonlinear simulator through a scenario.

Writes into ``--out`` (optional): ``timeseries.csv`` (DATA_FORMATS.md, with
``theta_ref``, ``r`` and the controller's ``command``), ``run.json``, and the
figures ``theta.png``, ``base_accel.png``, ``linear_vs_nonlinear.png``; with
``--rerun FILE.rrd`` a Rerun recording. A run that is unstable by design is a
result (``"stable": false``, its growth rate and frequency; exit 0), not an
error. Imports nothing heavy at module level.
"""

from __future__ import annotations

import argparse
import sys

from samii.cli_args import add_json, add_model, add_out, add_overwrite, add_rerun, add_set, float_in, seed
from samii.errors import InputError

__all__ = ["add_arguments", "run", "BUILTIN_CONTROLLERS", "resolve_controller", "model_at_rest", "check_fits"]

BUILTIN_CONTROLLERS = {
    "unity": "the servo amplifier's position loop alone (1 V/deg), no digital controller",
    "notebook-place": "chapter 8: digital pole placement with observer on eq 1.4, as the notebook built it (whole position loop)",
    "notebook-cancel": "chapter 10: pole-cancelling compensator on eq 9.4, the notebook's gain 0.0666 (whole position loop)",
    "damping": "tuned acceleration feedback designed here from a simulated measurement of the model: measure, fit, design (about 3 s)",
}
_FILES = ("timeseries.csv", "run.json")
MAX_DURATION_S = 600.0
MAX_STEP_DEG = 30.0
MAX_IMPULSE_N_S = 20.0


def _step_deg(text: str) -> float:
    v = float_in(-MAX_STEP_DEG, MAX_STEP_DEG, unit="deg")(text)
    if v == 0:
        raise argparse.ArgumentTypeError(f"expected a nonzero step in -{MAX_STEP_DEG:g}...{MAX_STEP_DEG:g} deg, got {text!r}")
    return v


_step_deg.__name__ = "step"


#: The card's delay line (samii.closedloop.card.MAX_DELAY_STEPS) and the release scenario's impulse
#: (samii.closedloop.scenario.DEFAULT_IMPULSE_N_S), repeated here so that building the parser stays
#: cheap (those modules load MuJoCo); a test holds them equal.
MAX_DELAY_STEPS = 200
DEFAULT_IMPULSE_N_S = 0.5


def add_arguments(parser: argparse.ArgumentParser) -> None:
    specs = "; ".join(f"{k}: {v}" for k, v in BUILTIN_CONTROLLERS.items())
    parser.add_argument(
        "--controller", required=True, metavar="SPEC", help=f"{specs}; or a controller file written by samii design place|cancel --save"
    )
    parser.add_argument("--scenario", required=True, choices=("step", "loper", "release"),
                        help="step: theta_ref steps by --step-deg at t = 1 s, controller on throughout; loper: the step under "
                        "the servo loop alone, the controller switched on (bumplessly) at t = 2 s, compared with the run never "
                        f"switched (free decay); release: a tip impulse of --impulse-n-s (default {DEFAULT_IMPULSE_N_S:g} N s) "
                        "along the accelerometer at t = 0 sets the base vibrating, theta_ref held")  # fmt: skip
    parser.add_argument(
        "--step-deg",
        type=_step_deg,
        default=None,
        metavar="D",
        help=f"reference step [deg], nonzero, |D| <= {MAX_STEP_DEG:g} (default 5; step and loper only)",
    )
    parser.add_argument(
        "--impulse-n-s",
        type=float_in(0.0, MAX_IMPULSE_N_S, lo_open=True, unit="N s"),
        default=None,
        metavar="P",
        help=f"release: tip impulse [N s], 0 < P <= {MAX_IMPULSE_N_S:g} (default {DEFAULT_IMPULSE_N_S:g}: about 4 m/s² at the base)",
    )
    parser.add_argument(
        "--duration-s",
        type=float_in(3.0, MAX_DURATION_S, unit="s"),
        default=10.0,
        metavar="S",
        help=f"simulated time [s], 3...{MAX_DURATION_S:g} (default 10)",
    )
    parser.add_argument("--delay-samples", type=float_in(0.0, float(MAX_DELAY_STEPS), unit="samples"), default=0.0, metavar="N",
                        help="computation delay of the controller [samples], whole or fractional (default 0; the command is "
                        f"held from the sample on, zero-order hold); at most {MAX_DELAY_STEPS} physics steps")  # fmt: skip
    parser.add_argument("--noise", action="store_true",
                        help="seeded sensor noise and ADC quantisation on the controller's measurements (theta 5e-4 rad rms and "
                        "4096-count/rev encoder steps; acceleration 0.01 m/s² rms and a 16-bit +-10 V ADC at 1 V/g)")  # fmt: skip
    parser.add_argument("--seed", type=seed, default=None, help="seed of the sensor noise (with --noise; default 0)")
    add_model(parser, "MJCF or parameter .json file (default: the embedded SAMII model)")
    add_set(parser, "override a model parameter, e.g. hydraulic.bulk_modulus=1e9 (repeatable; samii params lists them)")
    add_out(parser, "write timeseries.csv, run.json and the figures here")
    parser.add_argument("--no-plots", action="store_true", help="with --out, no figures")
    add_rerun(
        parser,
        "also write a Rerun recording of the run: the beam and arm in 3D with their deflection magnified, the signals grouped by unit, "
        "the base modes' coordinates, the controller's switch-on, and a stored layout",
    )
    add_overwrite(parser, "replace existing output files")
    add_json(parser, "print the result as JSON")


def resolve_controller(spec: str, factory=None, quiet: bool = False):
    from pathlib import Path

    from samii.closedloop import controllers as cs

    if not spec.strip():
        raise InputError(f"--controller: expected {', '.join(BUILTIN_CONTROLLERS)} or a controller file, got an empty string")
    if spec == "damping":
        from samii.closedloop.damping import damping_from_simulation

        model = model_at_rest(factory)

        def say(what: str) -> None:
            if not quiet:
                print(f"  damping controller: {what}", file=sys.stderr)

        return damping_from_simulation(model, progress=say).controller
    if spec == "unity":
        return None
    if spec == "notebook-place":
        return cs.notebook_place()
    if spec == "notebook-cancel":
        return cs.notebook_cancel()
    if Path(spec).suffix.lower() == ".json" or Path(spec).exists():
        return cs.read_controller(spec)
    raise InputError(f"--controller {spec!r}: expected {', '.join(BUILTIN_CONTROLLERS)} or a controller file (.json)")


def _check_options(args) -> None:
    if args.step_deg is not None and args.scenario == "release":
        raise InputError("--step-deg: the release scenario holds theta_ref (use --impulse-n-s for its size)")
    if args.impulse_n_s is not None and args.scenario != "release":
        raise InputError("--impulse-n-s: only the release scenario starts with an impulse")
    if args.seed is not None and not args.noise:
        raise InputError("--seed: only meaningful with --noise")
    if args.no_plots and args.out is None:
        raise InputError("--no-plots: only meaningful with --out")
    if args.scenario == "loper" and args.duration_s < 4.0:
        raise InputError(f"--duration-s {args.duration_s:g}: the loper scenario switches the controller on at t = 2 s and needs at least 4 s")


def _summary(r, out_names: list[str]) -> str:
    lines = [
        f"closed loop: {r.controller}, {r.scenario.name} scenario, {r.scenario.duration_s:g} s"
        + (f", delay {r.delay_samples:g} samples" if r.delay_samples else "")
        + (", sensor noise on" if r.noise else "")
    ]
    lines.append("  stable in the nonlinear simulator" if r.stable else f"  UNSTABLE: {r.instability()}")
    for n in r.notes:
        lines.append(f"  note: {n}")
    th = r.theta
    if th.final_pct is not None:
        f = lambda x, u: "n/a" if x is None else f"{x:.3g}{u}"  # noqa: E731
        if not r.stable:
            lines.append(f"  theta: final value {th.final_pct:.3g} % of the step (rise, overshoot and settle not given: the run is unstable)")
        elif th.final_pct is not None and not th.followed:
            lines.append(
                f"  theta: did not follow the step (its final value is {th.final_pct:.3g} % of the step; rise, overshoot and settle undefined)"
            )
        else:
            lines.append(
                f"  theta: rise {f(th.rise_s, ' s')}, overshoot {f(th.overshoot_pct, ' %')}, settle (2 %) {f(th.settle_s, ' s')}"
                + (f", final value {th.final_pct:.3g} % of the step" if th.final_pct is not None and abs(th.final_pct - 100.0) >= 2.0 else "")
            )
    b = r.base
    f = lambda x, u: "n/a" if x is None else f"{x:.3g}{u}"  # noqa: E731
    if r.signals.t.size < 2:
        lines.append("  base: no samples (the run diverged in its first step)")
    elif not r.stable:
        lines.append(f"  base: peak {f(b.peak_m_s2, ' m/s²')}, residual rms {f(b.residual_rms_m_s2, ' m/s²')} (settle and decay not "
                     "given: the run is unstable)" + (f"; free decay {f(r.free_decay_rate_1_s, ' 1/s')}" if r.free_decay_rate_1_s is not None else ""))  # fmt: skip
    else:
        lines.append(f"  base: peak {f(b.peak_m_s2, ' m/s²')}, residual rms {f(b.residual_rms_m_s2, ' m/s²')}, settle (5 %) "
                     f"{f(b.settle_s, ' s')}, decay {f(b.decay_rate_1_s, ' 1/s')}"
                     + (f" (free decay {f(r.free_decay_rate_1_s, ' 1/s')})" if r.free_decay_rate_1_s is not None else ""))  # fmt: skip
    c = r.comparison_base
    if c is not None:
        lines.append(f"  servo loop alone: peak {f(c.peak_m_s2, ' m/s²')}, residual rms {f(c.residual_rms_m_s2, ' m/s²')}, "
                     f"settle (5 %) {f(c.settle_s, ' s')}")  # fmt: skip
    if r.modes:
        lines.append("  modes of the response: " + ", ".join(f"{m.freq_hz:.3g} Hz (zeta {m.zeta:.3f})" for m in r.modes))
    e = r.rms_error_pct
    lines.append(f"  linear prediction: {'stable' if r.linear_stable else 'marginal' if r.linear_marginal else 'UNSTABLE'}"
                 + (f", rms error theta {f(e['theta'], ' %')}, accel {f(e['accel'], ' %')}" if r.linear is not None else ""))  # fmt: skip
    if out_names:
        from samii.outputs import with_size

        lines.append("  wrote " + ", ".join(with_size(n) for n in out_names))
    return "\n".join(lines)


def check_fits(saved, args, dt: float) -> None:
    """The controller against the card's limits and the physics step, naming the file and field or the option."""
    from samii.closedloop.card import CardFitError, check_fit

    try:
        check_fit(saved.controller, dt, args.delay_samples)
    except CardFitError as exc:
        if exc.field == "delay_samples":
            raise InputError(f"--delay-samples {args.delay_samples:g}: {exc}") from None
        where = f"controller file {args.controller}" if args.controller not in BUILTIN_CONTROLLERS else f"--controller {args.controller}"
        raise InputError(f"{where}: {exc}") from None


def run(args) -> int:
    import os

    _check_options(args)
    from samii.closedloop.plots import FIGURES
    from samii.outputs import OutputFolder, check_output_file

    names = list(_FILES) + ([] if args.no_plots else list(FIGURES))
    folder = OutputFolder(args.out, names, overwrite=args.overwrite) if args.out is not None else None
    rerun_path = check_output_file(args.rerun, overwrite=args.overwrite, option="--rerun", beside=folder) if args.rerun else None
    if args.controller == "unity" and args.delay_samples:
        raise InputError("--delay-samples: the unity servo loop is analog (no digital controller to delay)")
    if args.controller == "unity" and args.noise:
        raise InputError("--noise: the unity servo loop samples no sensors (its analog loop reads the joint angle directly)")

    from samii.closedloop.scenario import NoiseSpec, default_spec_factory, run_closed_loop, scenario
    from samii.sim.cli_modes import parse_overrides

    overrides = parse_overrides(args.set)
    factory = default_spec_factory(args.model, overrides or None)
    saved = resolve_controller(args.controller, factory, quiet=args.json)
    if saved is not None:
        spec, _, _ = factory()
        check_fits(saved, args, float(spec.option.timestep))
    kw = {"duration_s": args.duration_s}
    if args.step_deg is not None:
        kw["step_deg"] = args.step_deg
    if args.impulse_n_s is not None:
        kw["impulse_n_s"] = args.impulse_n_s
    sc = scenario(args.scenario, **kw)
    noise = NoiseSpec(seed=args.seed or 0) if args.noise else None
    frame_steps = None
    if rerun_path:
        from samii.viz.recording import frame_steps_for

        frame_steps = frame_steps_for(model_at_rest(factory), args.rerun_fps)
    result = run_closed_loop(saved, sc, label=args.controller, spec_factory=factory, delay_samples=args.delay_samples, noise=noise,
                             qpos_every=frame_steps)  # fmt: skip

    written: list[str] = []
    recorded = result.signals.t.size >= 2  # a run that diverged in its first step has nothing to record or draw
    if not recorded and rerun_path is not None:
        print(f"samii closedloop: note: --rerun {rerun_path}: not written, the run diverged in its first step", file=sys.stderr)
        rerun_path = None
    rrd_tmp = rerun_path.parent / f".{rerun_path.name}.{os.getpid()}.tmp" if rerun_path else None
    try:
        if folder is not None:
            from samii.formats import write_timeseries_csv
            from samii.json_output import dumps

            with folder:
                if recorded:
                    write_timeseries_csv(result.timeseries(), folder.path("timeseries.csv"), overwrite=True)
                else:
                    for name in [n for n in (*_FILES, *FIGURES) if n != "run.json"]:  # the verdict alone
                        folder.omit(name)
                doc = result.run_json()
                doc["model"] = {"file": args.model or "embedded default", "overrides": overrides}
                doc["controller_detail"] = None if saved is None else {
                    "name": saved.controller.name, "method": saved.controller.method, "model_units": saved.controller.model_units,
                    "servo_loop": "replaced" if saved.replaces_servo else "kept", "provenance": dict(saved.provenance)}  # fmt: skip
                folder.path("run.json").write_text(dumps(doc, indent=1) + "\n")
                if recorded and not args.no_plots:
                    from samii.closedloop.plots import plot_base, plot_linear, plot_theta

                    plot_theta(result, folder.path("theta.png"))
                    plot_base(result, folder.path("base_accel.png"))
                    plot_linear(result, folder.path("linear_vs_nonlinear.png"))
                if rrd_tmp is not None:  # inside the folder's transaction: a failed recording leaves no folder behind
                    _write_rerun(result, rrd_tmp, rerun_path, factory)
            written = [str(folder.final(n)) for n in folder.names]
        elif rrd_tmp is not None:
            _write_rerun(result, rrd_tmp, rerun_path, factory)
        if rrd_tmp is not None:
            os.replace(rrd_tmp, rerun_path)
            written.append(str(rerun_path))
    finally:
        if rrd_tmp is not None and rrd_tmp.exists():
            rrd_tmp.unlink()

    if args.json:
        from samii.json_output import dumps

        print(dumps(result.as_json()))
    else:
        print(_summary(result, written))
    return 0


def model_at_rest(factory):
    """The run's model with its ``home`` keyframe at the static equilibrium the factory found (a
    model changed by ``--set`` or a parameter file is not at rest in its written keyframe)."""
    import mujoco

    from samii.sim.plugin import compile_spec

    spec, qpos, act = factory()
    model = compile_spec(spec)
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home")
    model.key_qpos[key], model.key_act[key] = qpos, act
    return model


def _write_rerun(result, tmp, final, factory) -> None:
    import numpy as np

    from samii.outputs import create_parent
    from samii.viz.recording import RunRecord, recording_failed, write_recording

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


if __name__ == "__main__":  # pragma: no cover
    from samii.cli import main

    sys.exit(main(["closedloop", *sys.argv[1:]]))
