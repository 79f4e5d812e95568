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

from samii.cli_args import add_antialias, add_json, add_model, add_out, add_overwrite, add_rerun, add_seed, add_set, float_in
from samii.closedloop.trial import BUILTIN_CONTROLLERS

__all__ = ["add_arguments", "run", "MAX_DELAY_STEPS"]

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
    add_seed(parser, "seed of the sensor noise (with --noise; default 0)", default=None)
    add_antialias(parser)
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


def _summary(r, out_names: list[str]) -> str:
    lines = [
        f"closed loop: {r.controller}, {r.scenario.name} scenario, {r.scenario.duration_s:g} s"
        + (f", delay {r.delay_samples:g} samples" if r.delay_samples else "")
        + (", sensor noise on" if r.noise else "")
    ]
    if r.sensors:
        from samii.sim.sensor_dynamics import SensorDynamics  # (lazy: imports mujoco, only when called)

        lines.append(f"  the controller reads through the sensors: {SensorDynamics(**r.sensors).text()}")
    if r.antialias_hz is not None:
        lines.append(f"  the controller's data acquisition filters theta and accel at {r.antialias_hz:.4g} Hz (8th-order Butterworth)")
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


def run(args) -> int:
    from samii.closedloop.trial import TrialRequest, run_trial

    request = TrialRequest(
        controller=args.controller,
        scenario=args.scenario,
        duration_s=args.duration_s,
        step_deg=args.step_deg,
        impulse_n_s=args.impulse_n_s,
        delay_samples=args.delay_samples,
        noise=args.noise,
        seed=args.seed,
        antialias=args.antialias,
    )

    def say(what: str) -> None:  # the stages of a "damping" controller's design
        if not args.json:
            print(f"  damping controller: {what}", file=sys.stderr)

    trial = run_trial(request, out=args.out, model=args.model, overrides=args.set, plots=not args.no_plots, rerun=args.rerun,
                      rerun_fps=args.rerun_fps, overwrite=args.overwrite, say=say,
                      note=lambda text: print(f"samii closedloop: note: {text}", file=sys.stderr))  # fmt: skip
    if args.json:
        from samii.json_output import dumps

        print(dumps(trial.result.as_json()))  # what the run found (run.json's first part, samii.schema.closed_loop.ClosedLoopFigures)
    else:
        print(_summary(trial.result, trial.written))
    return 0


if __name__ == "__main__":  # pragma: no cover
    from samii.cli import main

    sys.exit(main(["closedloop", *sys.argv[1:]]))
