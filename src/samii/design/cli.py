"""``samii design``: control design on the notebook's models (a thin layer over :mod:`samii.design`).

Subcommands::

    samii design seed-report [--json] [--no-progress]
    samii design rlocus [--out DIR] [--json] [--no-plots] [--force] [--n-gains N] [--no-progress]
    samii design canonical [--modes 2|3] [--outputs accel|modal] [--out DIR] [--force] [--json]
    samii design place [--sample-time-s T] [--zeta Z] [--observer placement|kalman] [--json] [--save FILE.json]
    samii design cancel [--loop theta|accel] [--gain K] [--sample-time-s T] [--json] [--save FILE.json]

Errors a user can fix are :class:`samii.errors.InputError` (exit 2, one line
naming the option); numeric options are checked at parse time
(:mod:`samii.cli_args`); ``--out`` folders are all-or-nothing
(:class:`samii.outputs.OutputFolder`, checked before any work). JSON output
is strict: non-finite numbers are written as ``null``.

Only numpy and light samii modules (cli_args, errors, design.rlocus_study's constant) are imported at module level (the CLI
builds its parser cheaply).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from samii.cli_args import (
    add_antialias,
    add_json,
    add_model,
    add_no_progress,
    add_out,
    add_overwrite,
    add_seed,
    add_set,
    finite_float,
    float_in,
    int_in,
    nonempty_path,
    positive_float,
)
from samii.design.rlocus_study import PLOT_MAX_GAINS  # (a light module: python-control is imported when the study runs)
from samii.errors import InputError

__all__ = ["add_arguments", "run", "N_GAINS_RANGE", "MAX_ABS_CANCEL_GAIN", "PLOT_MAX_GAINS"]

#: ``rlocus --n-gains`` bounds: the log-spaced tracking grid spans 8 decades (1e-5 to 1e3 times the
#: crossing gains), so 100 points is about 12 per decade; run time grows linearly (about 10 s at 3000).
N_GAINS_RANGE = (100, 100_000)

#: ``cancel --sample-time-s`` bound [s]: 10 samples per period of the fastest root of the compensator
#: (the cancelled third-mode pair of eq 10.2, |s| = 156.8 rad/s): 2 pi / 156.8 / 10 = 4.0 ms.
MAX_CANCEL_SAMPLE_TIME_S = 4e-3

#: ``cancel --gain`` magnitude bound: the chosen gain is 0.072; beyond 1e12 the closed-loop matrix
#: overflows the double range the eigenvalue solver needs.
MAX_ABS_CANCEL_GAIN = 1e12


def _cancel_gain(text: str) -> float:
    v = finite_float(text)
    if v == 0.0:
        raise argparse.ArgumentTypeError(f"expected a nonzero gain (K = 0 opens the loop), got {text!r}")
    if abs(v) > MAX_ABS_CANCEL_GAIN:
        raise argparse.ArgumentTypeError(f"expected a gain with |K| <= {MAX_ABS_CANCEL_GAIN:g}, got {text!r}")
    return v


_cancel_gain.__name__ = "gain"


#: Noise standard deviations accepted [model units]: their squares (the covariances) must stay well
#: inside double precision and their ratios within what the Riccati solver resolves (at 1e-4 and 1e4
#: together it warns of an ill-conditioned matrix; at 1e-6 and 1e6 it fails).
NOISE_STD_RANGE = (1e-3, 1e3)
_noise_std = float_in(*NOISE_STD_RANGE, lo_open=False)


def _add_out(p: argparse.ArgumentParser, what: str) -> None:
    add_out(p, f"folder for {what} (created if needed; all files appear together on success)")
    add_overwrite(p, "replace existing files in --out")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    # the action parsers are of the command line's own class (samii.cli): errors in one line
    sub = parser.add_subparsers(dest="design_command", metavar="ACTION", required=True)

    p = sub.add_parser("seed-report", help="recompute eq 8.1-8.3 and 10.1-10.9 and the gain, beside the notebook's values",
                       description="Recompute the notebook's design tables (eq 8.1-8.3 from eq 1.4, eq 10.1-10.9 and the "
                       "chapter-10 gain from eq 9.4) and print each beside the notebook's value. Takes about 5 s.")  # fmt: skip
    add_json(p, "print machine-readable results")
    add_no_progress(p)

    lo, hi = N_GAINS_RANGE
    p = sub.add_parser("rlocus", help="mass-damping root-locus study (chapters 2-3): stable K_a intervals and best damping",
                       description="Mass-damping acceleration-feedback study on 4 models x 7 loop variants: exact stable K_a "
                       "intervals, best damping per base mode, verdicts. About 10 s at the default --n-gains, 30-60 s with "
                       "the 28 figures; a progress bar on stderr shows how far it is.")  # fmt: skip
    _add_out(p, "summary.json, summary.md and one PNG per model and variant")
    add_json(p, "print the summary as JSON (non-finite values as null)")
    p.add_argument("--no-plots", action="store_true", help="with --out, write only the tables")
    p.add_argument("--n-gains", type=int_in(lo, hi), default=3000, metavar="N",
                   help=f"gains per sign on the log-spaced grid along which the root-locus branches are tracked "
                   f"(8 decades around the stability limits), {lo} to {hi}; default 3000 (about 10 s; time grows "
                   f"linearly); the figures draw min(N, {PLOT_MAX_GAINS})")  # fmt: skip
    add_no_progress(p)

    p = sub.add_parser("canonical", help="controllable canonical form (chapters 5-7), checked against the transfer functions")
    p.add_argument("--modes", type=int, choices=(2, 3), default=2, help="base modes: 2 (eq 1.4) or 3 (eq 9.4)")
    p.add_argument("--outputs", choices=("accel", "modal"), default="accel", help="one accelerometer or modal feedback")
    _add_out(p, "the LaTeX file ccf_<modes>mode_<outputs>.tex")
    add_json(p, "print the check as JSON")

    p = sub.add_parser(
        "place",
        help="digital pole placement with observer (chapter 8) on the eq 1.4 model",
        description="Chapter-8 digital pole placement on the eq 1.4 model (notebook units: theta in degrees, "
        "the acceleration in ft/s², v in volts), with an observer at twice the controller poles or a steady-state "
        "Kalman filter. Every closed-loop pole outside the unit circle is flagged UNSTABLE.",
    )
    p.add_argument("--sample-time-s", type=positive_float, default=1e-3, metavar="T",
                   help="controller sample time [s] (default 0.001). It must give at least 10 samples per period 2 pi/|s| "
                   "of the fastest pole the design involves (plant, controller and observer poles): on eq 1.4 T <= 1.849 ms "
                   "with the placement observer (its real pole at 339.6 rad/s), T <= 3.333 ms with kalman (the plant's "
                   "188.5 rad/s pole). Very short T crowds every z = exp(sT) at 1: a design whose poles miss their targets "
                   "by more than 0.01 %% is refused (about T < 1e-7 s)")  # fmt: skip
    p.add_argument("--zeta", type=float_in(0.0, 1.0, lo_open=True, hi_open=True), default=1 / np.sqrt(2), metavar="Z",
                   help="damping ratio of the moved poles, 0 < Z < 1 (1 would make each pair a double real pole, which "
                   "single-input placement cannot place); default 1/sqrt(2), which reproduces eq 8.3 (see seed-report)")  # fmt: skip
    p.add_argument("--observer", choices=("placement", "kalman"), default="placement",
                   help="placement: observer poles at twice the controller poles (continuous), z = exp(2 s T) (default); "
                   "kalman: steady-state Kalman filter, needs the three --*-noise-std options")  # fmt: skip
    p.add_argument(
        "--input-noise-std",
        type=_noise_std,
        default=None,
        metavar="V",
        help="kalman: standard deviation of the process noise entering with the valve command, per sample [V]",
    )
    p.add_argument(
        "--theta-noise-std",
        type=_noise_std,
        default=None,
        metavar="STD",
        help="kalman: standard deviation of the theta measurement noise [deg, the notebook's unit]",
    )
    p.add_argument("--accel-noise-std", type=_noise_std, default=None, metavar="STD",
                   help="kalman: standard deviation of the base-acceleration measurement noise [ft/s², the notebook's "
                   "unit: samii.closedloop.controllers]")  # fmt: skip
    add_json(p, "print the design as JSON")
    _add_save(p)

    p = sub.add_parser(
        "cancel",
        help="pole-cancelling compensator (chapter 10) on the eq 9.4 model",
        description="Chapter-10 pole-cancelling compensator on the eq 9.4 model. Every closed-loop pole with Re s >= 0 is flagged UNSTABLE.",
    )
    p.add_argument("--loop", choices=("theta", "accel"), default="theta", help="the loop the compensator closes (see samii.design.cancel)")
    p.add_argument("--gain", type=_cancel_gain, default=None, metavar="K",
                   help=f"use this loop gain K (1 + K L = 0; nonzero, |K| <= {MAX_ABS_CANCEL_GAIN:g}) instead of the "
                   "rule: the smallest K at which the slowest moving closed-loop pair reaches zeta 0.7 (0.0721)")  # fmt: skip
    p.add_argument("--sample-time-s", type=float_in(0.0, MAX_CANCEL_SAMPLE_TIME_S, lo_open=True, unit="s"), default=1e-3, metavar="T",
                   help=f"sample time of the runnable controller (--save) [s], 0 < T <= {MAX_CANCEL_SAMPLE_TIME_S:g} (default 0.001): "
                   "10 samples per period of the fastest root, the cancelled third mode at 156.8 rad/s")  # fmt: skip
    add_json(p, "print the design as JSON (non-finite values as null)")
    _add_save(p)

    p = sub.add_parser(
        "damping",
        help="a controller that damps the base: tuned acceleration feedback designed on a fit of Bode data",
        description="Fit the notebook's 3-mode model to Bode data (--frf, as samii measure writes frf.csv; without it the "
        "embedded model is measured first: swept sine with sensor noise, about 3 s) and design acceleration feedback through "
        "a second-order low-pass tuned to base mode 1, added to the servo amplifier's command, its gain 6 dB below the "
        "fitted model's stability limit (samii.closedloop.damping).",
    )  # fmt: skip
    p.add_argument(
        "--frf", metavar="FRF.csv", type=nonempty_path, help="measured frequency response (DATA_FORMATS.md; act and base or total channels)"
    )
    p.add_argument(
        "--sample-time-s",
        type=float_in(0.0, 1e-2, lo_open=True, unit="s"),
        default=1e-3,
        metavar="T",
        help="controller sample time [s], 0 < T <= 0.01 (default 0.001: 1 kHz; 0.01: 100 Hz; a controller faster than the physics step runs on a model with a shorter one: samii closedloop --set timestep_s=0.0002 for 5 kHz)",
    )
    p.add_argument(
        "--delay-samples",
        type=int_in(0, 10),
        default=1,
        metavar="N",
        help="computation delay the design allows for [whole samples], 0-10 (default 1)",
    )
    p.add_argument(
        "--gain-margin-db",
        type=float_in(1.0, 40.0, unit="dB"),
        default=6.0,
        metavar="DB",
        help="gain margin on the fitted model [dB], 1-40 (default 6)",
    )
    p.add_argument(
        "--position-gain",
        type=float_in(0.0, 1e4, lo_open=True, unit="V/rad"),
        default=None,
        metavar="KP",
        help="the servo amplifier's position gain [V/rad] the data were measured with (default: the embedded model's, 57.3 = 1 V/deg)",
    )
    add_seed(p, "without --frf: seed of the simulated measurement's sensor noise (default 0)")
    add_model(p, "without --frf: the model measured (MJCF or parameter .json; default the embedded one); with it, the rig's sensors "
                 "(its sensor.* options): the design takes them into account (the data were measured through them, the controller reads through them)")  # fmt: skip
    add_set(p, "override a model parameter (repeatable): sensor.* states the rig's sensor chain, e.g. sensor.accel_lowpass_hz=30")
    p.add_argument("--sensors-from", metavar="DIAGNOSIS.json", type=nonempty_path, default=None,
                   help="the rig's sensor chain as a diagnosis found it (diagnosis.json of samii diagnose; against the simulator, "
                        "the values it carried), on top of --model; --set wins over it")  # fmt: skip
    add_antialias(p)
    add_json(p, "print the design as JSON")
    _add_save(p)


def _add_save(p: argparse.ArgumentParser) -> None:
    p.add_argument("--save", metavar="FILE.json", type=nonempty_path,
                   help="write the runnable controller (matrices, sample time, inputs, units, provenance) for samii closedloop "
                   "--controller FILE.json; the file must not exist unless --force/--overwrite")  # fmt: skip
    add_overwrite(p, "with --save, replace an existing file")


# ---- output helpers ----


def _dumps(obj) -> str:
    """Strict JSON (no NaN/Infinity tokens): :func:`samii.json_output.dumps`."""
    from samii.json_output import dumps

    return dumps(obj, indent=1)


def _fmt_complex(z: complex, width: int = 10, digits: int = 4) -> str:
    if not np.isfinite(z):
        return "infinity"
    return f"{z.real:{width}.{digits}f} {z.imag:+{width}.{digits}f}j"


def _progress(total: int | None, what: str, disabled: bool):
    from samii.cli_progress import Bar

    return Bar(f"samii design {what}", unit="step", total=total, disable=disabled)


def _out_folder(args, names: list[str]):
    """The all-or-nothing ``--out`` folder, checked now, before any work (``None`` without ``--out``)."""
    from samii.outputs import OutputFolder

    if args.out is None:
        if args.overwrite:
            raise InputError("--force/--overwrite: only meaningful with --out")
        return None
    return OutputFolder(args.out, names, overwrite=args.overwrite, overwrite_option="--force")


# ---- actions ----


def run_seed_report(args) -> int:
    from samii.design.seed_report import seed_report

    with _progress(None, "seed-report", args.no_progress) as bar:
        report = seed_report(progress=bar)
    if args.json:
        print(_dumps(report.as_json()))
    else:
        print(report.text())
    return 0


def run_rlocus(args) -> int:
    if args.no_plots and args.out is None:
        raise InputError("--no-plots: only meaningful with --out (without --out no figures are drawn)")
    from samii.design.rlocus_study import rlocus_outputs, run_rlocus_study

    plots = args.out is not None and not args.no_plots
    folder = _out_folder(args, rlocus_outputs(plots))
    with _progress(None, "rlocus", args.no_progress) as bar:
        study = run_rlocus_study(n_gains=args.n_gains, out=folder, plots=plots, progress=bar)
    if args.json:
        print(_dumps(study.rows()))
    else:
        print(study.table)
        if folder is not None:
            print(f"wrote {len(study.written)} files to {folder.root}")
    return 0


def run_canonical(args) -> int:
    name = f"ccf_{args.modes}mode_{args.outputs}.tex"
    folder = _out_folder(args, [name])
    from samii import notebook as nb
    from samii.design import canonical as cc

    form = cc.derive_canonical_form(args.modes, args.outputs)
    p = nb.EQ1_4_OPTIMIZED if args.modes == 2 else nb.EQ9_4
    check = cc.compare_with_tf(form, p)
    if folder is not None:
        with folder:
            folder.path(name).write_text(form.latex())
    model = "eq 1.4" if args.modes == 2 else "eq 9.4"
    if args.json:
        print(_dumps({"outputs": list(form.outputs), "model": model, "check": check}))
        return 0
    print(f"controllable canonical form, {args.modes} base modes, outputs {', '.join(form.outputs)}, input v; checked at {model}")
    print(f"  poles of A vs transfer functions: max relative difference {float(check['poles']['rel']):.2e}")
    for out_name in form.outputs:
        c = check[out_name]
        print(
            f"  {out_name}/v: frequency response {float(c['freq_response_rel']):.2e}, numerator N_ss D - N D_ss "
            f"{float(c['numerator_rel']):.2e} (relative), zeros at the origin {int(c['origin_zeros_ss'])} (state space) / "
            f"{int(c['origin_zeros_tf'])} (transfer function)"
        )
    if folder is not None:
        print(f"wrote {folder.final(name)}")
    return 0


_NOISE_OPTIONS = (("input_noise_std", "--input-noise-std"), ("theta_noise_std", "--theta-noise-std"), ("accel_noise_std", "--accel-noise-std"))


def _check_place_options(args) -> None:
    given = [opt for attr, opt in _NOISE_OPTIONS if getattr(args, attr) is not None]
    if args.observer == "kalman":
        missing = [opt for attr, opt in _NOISE_OPTIONS if getattr(args, attr) is None]
        if missing:
            names = " and ".join([", ".join(missing[:-1]), missing[-1]] if len(missing) > 1 else missing)
            raise InputError(
                f"--observer kalman: missing {names} (all three noise standard deviations are needed: --input-noise-std "
                f"[V per sample], --theta-noise-std [deg], --accel-noise-std [ft/s²] (the notebook's units)"
            )
    elif given:
        raise InputError(f"{', '.join(given)}: only used with --observer kalman (the placement observer takes no noise model)")


def _save_target(args):
    """The ``--save`` file, checked before any work (None without ``--save``)."""
    from samii.outputs import check_output_file

    if args.save is None:
        if args.overwrite:
            raise InputError("--force/--overwrite: only meaningful with --save")
        return None
    return check_output_file(args.save, overwrite=args.overwrite, option="--save")


def _save(saved, path, args, out: dict) -> None:
    from samii.closedloop.controllers import write_controller
    from samii.outputs import create_parent

    write_controller(saved, create_parent(path))
    out["saved"] = str(path)
    args.saved_controller = str(path)  # the text report names it last (run)


def run_place(args) -> int:
    _check_place_options(args)
    save = _save_target(args)
    from samii.design.notebook_designs import place_on_eq1_4

    placed = place_on_eq1_4(sample_time_s=args.sample_time_s, zeta=args.zeta, observer=args.observer, input_noise_std=args.input_noise_std,
                            theta_noise_std=args.theta_noise_std, accel_noise_std=args.accel_noise_std)  # fmt: skip
    d, out = placed.design, placed.to_dict()
    if save is not None:
        _save(placed.saved_controller(), save, args, out)
    if args.json:
        print(_dumps(out))
        return 0

    def flag(z: complex) -> str:
        return "  UNSTABLE (|z| >= 1)" if not abs(z) < 1 else ""

    cl, bad = d.closed_loop_poles_z, d.unstable_poles_z
    print(f"pole placement on eq 1.4 (notebook units), T = {d.sample_time_s:g} s, zeta = {d.zeta:.5g}, observer: {d.observer}")
    for s, z in zip(d.poles_s, d.poles_z):
        print(f"  controller pole s = {_fmt_complex(s)}  ->  z = {z.real:.6f} {z.imag:+.6f}j{flag(z)}")
    for z in d.observer_poles_z:
        print(f"  observer pole z = {z.real:.6f} {z.imag:+.6f}j{flag(z)}")
    print(f"  K = {np.array2string(d.K.ravel(), precision=4)}\n  N = {d.N:.6g}")
    if placed.stable:
        print(f"  closed loop: stable, all {cl.size} poles inside the unit circle (largest |z| = {np.max(np.abs(cl)):.6f})")
    else:
        print(f"  closed loop: UNSTABLE, {bad.size} of {cl.size} poles on or outside the unit circle: "
              + ", ".join(f"{z.real:.6f} {z.imag:+.6f}j" for z in bad))  # fmt: skip
    return 0


def run_cancel(args) -> int:
    from samii.design.notebook_designs import cancel_on_eq9_4

    save = _save_target(args)
    cancelled = cancel_on_eq9_4(loop=args.loop, gain=args.gain, sample_time_s=args.sample_time_s)
    d, out = cancelled.design, cancelled.to_dict()
    if save is not None:
        _save(cancelled.saved_controller(), save, args, out)
    if args.json:
        print(_dumps(out))
        return 0
    cl, bad = d.closed_loop, d.unstable_poles
    print(f"pole-cancelling compensator on eq 9.4, {d.loop} loop, K = {d.gain:.5g}")
    print(f"  numerator   {np.array2string(np.asarray(out['num']), precision=4)}")
    print(f"  denominator {np.array2string(np.asarray(out['den']), precision=4)}")
    for z in sorted(cl, key=abs):
        if z.imag >= 0:
            zeta = -z.real / abs(z) if np.isfinite(z) and abs(z) > 0 else float("nan")
            mark = "  UNSTABLE (Re s >= 0)" if not z.real < 0 else ""
            print(f"  closed-loop pole {_fmt_complex(z)}  zeta {zeta:.3f}{mark}")
    if not cancelled.stable:
        print(f"  closed loop: UNSTABLE, {bad.size} of {cl.size} poles with Re s >= 0 (largest real part {np.max(bad.real):.5g} 1/s); "
              "no DC gain or reference scaling applies")  # fmt: skip
        return 0
    print(f"  closed loop: stable, all {cl.size} poles in the left half plane (largest real part {np.max(cl.real):.4g} 1/s)")
    if d.loop == "theta":
        print(
            f"  theta/theta_ref DC gain of the loop as drawn {out['dc_gain_as_drawn']:.3f}; the runnable controller scales "
            f"theta_ref by {d.reference_gain:.4g} (unit DC gain) unless told not to"
        )
    return 0


def run_damping(args) -> int:
    save = _save_target(args)
    from samii.closedloop import damping as dm
    from samii.closedloop.trial import resolve_antialias
    from samii.sim.model import load_model
    from samii.sim.overrides import as_overrides
    from samii.sim.plugin import hydraulic_params
    from samii.sim.sensor_dynamics import SensorDynamics

    found = dm.sensors_from_diagnosis(args.sensors_from) if args.sensors_from else {}
    overrides = {**found, **as_overrides(args.set)}  # (what --set says outright wins over what the diagnosis found)
    model = load_model(args.model, overrides=overrides or None)  # the model measured, or the rig's sensors with --frf
    antialias = resolve_antialias(args.antialias, args.sample_time_s, float(model.opt.timestep))
    if args.frf is not None:
        from samii.formats import read_frf_csv

        data = read_frf_csv(args.frf)
        kp = args.position_gain if args.position_gain is not None else hydraulic_params(model).position_gain
        chain = dm.SensorChain(SensorDynamics.from_model(model), antialias)
        d = dm.damping_from_frf(data, source=str(args.frf), position_gain_v_per_rad=kp, sample_time_s=args.sample_time_s,
                                delay_samples=args.delay_samples, gain_margin_db=args.gain_margin_db, chain=chain)  # fmt: skip
    else:
        if args.position_gain is not None:
            raise InputError("--position-gain: only with --frf (the simulated measurement uses the model's own gain)")
        from samii.progress import said

        def say(what: str) -> None:
            if not args.json:
                print(f"  {what}", file=sys.stderr)

        d = dm.damping_from_simulation(model, seed=args.seed, sample_time_s=args.sample_time_s, delay_samples=args.delay_samples,
                                       progress=said(say), gain_margin_db=args.gain_margin_db, antialias_hz=antialias)  # fmt: skip
    out = d.to_dict()
    if save is not None:
        _save(d.controller, save, args, out)
    if args.json:
        print(_dumps(out))
        return 0
    roll = f", rolled off beyond {d.rolloff_hz:.4g} Hz" if d.rolloff_hz else ""
    print(f"tuned acceleration feedback on the fitted 3-mode model: v_added = -k F(s) xdd, F a 2nd-order low-pass at {d.filter_hz:.4g} Hz "
          f"(zeta {d.filter_zeta:.3g}){roll}")  # fmt: skip
    if d.chain is not None:
        print(f"  through the sensor chain (divided out of the data before the fit, in the loop designed on): {d.chain.text()}")
    print(f"  k = {d.gain_v_per_m_s2:.4g} V/(m/s²): {d.gain_margin_db:.3g} dB below the fitted model's stability limit {d.gain_limit_v_per_m_s2:.4g}")
    for r in d.mode_table():
        print(f"  mode {r['freq_hz']:6.3g} Hz: zeta {r['zeta_open']:.3f} -> {r['zeta_closed']:.3f} (at {r['freq_hz_closed']:.3g} Hz)")
    if d.max_sensitivity_above_band is not None:
        lo, hi = d.sensitivity_band_hz
        print(f"  on the measured data above the fit band ({lo:.3g}-{hi:.3g} Hz): largest |S| = {d.max_sensitivity_above_band:.3f}"
              + (" (the loop amplifies what the fit does not describe there)" if d.max_sensitivity_above_band > 1.1 else ""))  # fmt: skip
    return 0


_RUN = {
    "seed-report": run_seed_report,
    "rlocus": run_rlocus,
    "canonical": run_canonical,
    "place": run_place,
    "cancel": run_cancel,
    "damping": run_damping,
}


def run(args) -> int:
    code = _RUN[args.design_command](args)
    saved = getattr(args, "saved_controller", None)
    if saved and not args.json:
        print(f"  controller written to {saved} (run it: samii closedloop --controller {saved} --scenario step)")
    return code


if __name__ == "__main__":  # pragma: no cover
    from samii.cli import main

    sys.exit(main(["design", *sys.argv[1:]]))
