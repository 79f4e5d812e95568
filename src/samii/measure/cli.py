"""``samii measure``: the rig's swept- or stepped-sine Bode test, run in the simulator.

Writes into ``--out`` (default ``measure_out``): ``timeseries.csv`` and
``frf.csv`` (DATA_FORMATS.md), ``bode.png``, ``run.json``; with ``--method
both`` also ``timeseries_stepped.csv`` and ``frf_stepped.csv``; with ``--rerun
FILE.rrd`` a Rerun recording. Imports nothing heavy at module level.
"""

from __future__ import annotations

import argparse
import sys

from samii.cli_args import (
    add_band,
    add_json,
    add_model,
    add_no_progress,
    add_out,
    add_overwrite,
    add_rerun,
    add_set,
    float_in,
    int_in,
    positive_float,
    seed,
)
from samii.errors import InputError, SimulationUnstable
from samii.json_output import dumps

__all__ = ["add_arguments", "run"]

_OUTPUTS = {
    "swept": ("timeseries.csv", "frf.csv"),
    "stepped": ("timeseries.csv", "frf.csv"),
    "both": ("timeseries.csv", "frf.csv", "timeseries_stepped.csv", "frf_stepped.csv"),
}
_METHOD_LABEL = {"swept": "swept sine", "stepped": "stepped sine", "both": "swept and stepped sine"}


#: Longest run accepted [s of simulated time]: an hour (3.6 M physics steps, about 0.5 GB of
#: signals in memory); the default swept sine is 253 s, the default stepped sine about 600 s.
MAX_SIMULATED_S = 3600.0
#: Physics steps a measurement takes at most: 3600 s at 36 microseconds, about 10 minutes at the plugin's ~5
#: microseconds a step. The excitation is computed at the physics rate (8 bytes a step): a timestep_s of 1e-7 made a
#: 253 s run grow to 23 GB before the kernel killed it.
MAX_PHYSICS_STEPS = 1e8
#: Valve command range [V] of the servo amplifier (the plugin clamps v to it).
VALVE_RANGE_V = 10.0
#: Smallest excitation accepted [V]: 3 steps of a 16-bit DAQ over +-10 V (0.3 mV each); below it a
#: rig's measurement is quantisation noise (the simulator's would be round-off).
MIN_AMPLITUDE_V = 1e-3
#: Deviation from the linearised simulator [dB] above which the summary warns that the measurement is
#: not small-signal (at the default 0.1 V it is 0.6 dB; at 1 V, 4.3 dB; at 3 V, 9 dB): for a swept sine the
#: sustained deviation of a band (``max_deviation``'s ``sustained_db``), for a stepped sine any point's.
LINEARITY_WARN_DB = 2.0
#: Fraction of the run the valve command may sit on a rail before the run is reported unstable.
RAIL_FRACTION = 0.01


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_out(parser, "output folder (default measure_out)", default="measure_out")
    parser.add_argument(
        "--method",
        choices=("swept", "stepped", "both"),
        default="swept",
        help="swept sine 0.1-40 Hz (default), stepped sine at --freqs-hz, or both (stepped points overlaid)",
    )
    parser.add_argument(
        "--freqs-hz",
        type=positive_float,
        nargs="+",
        metavar="F",
        help="stepped-sine frequencies [Hz], distinct, below the DAQ's anti-alias cutoff (default 17 points over 0.5-35 Hz, "
        "the base resonances 1.75, 9.9 and 25 Hz among them)",
    )
    parser.add_argument(
        "--amplitude-v",
        type=float_in(MIN_AMPLITUDE_V, VALVE_RANGE_V, unit="V"),
        default=None,
        metavar="V",
        help="excitation amplitude added to the valve command, 0.001-10 V (default 0.1 V)",
    )
    parser.add_argument(
        "--averages",
        type=int_in(1, 100),
        default=3,
        metavar="N",
        help="swept-sine repetitions averaged, 1-100 (default 3, as on the rig; coherence needs at least 2)",
    )
    parser.add_argument(
        "--tail-s",
        type=positive_float,
        default=None,
        metavar="S",
        help="rest after each sweep, for the response to decay (default 20 s: 6.5 time constants of the embedded model's base mode 1)",
    )
    add_band(parser, "swept-sine band (default 0.1 40)", default=(0.1, 40.0))
    parser.add_argument(
        "--sample-rate-hz", type=positive_float, default=1000.0, metavar="HZ", help="DAQ sampling rate (default 1000; must divide the physics rate)"
    )
    parser.add_argument("--noise", action="store_true", help="add sensor noise (typical lab levels, see samii.measure.daq.SensorNoise)")
    parser.add_argument("--seed", type=seed, default=0, help="seed of the sensor-noise generator, an integer >= 0 (default 0)")
    add_model(parser, "MJCF file (default: the embedded SAMII model)")
    add_set(parser, "override a model parameter, e.g. hydraulic.supply_pressure=2.1e7 (repeatable)")
    add_rerun(
        parser,
        "also write a Rerun recording: the beam and arm in 3D with their deflection magnified, the signals grouped by unit, the base modes' coordinates, and a stored layout (with --method both, both runs; the file must not exist unless --overwrite)",
        fps_help="animation frames per second in the recording, every frame kept (default: 4 per period of base mode 3, at least 100, thinned where the sweep is slow: samii.viz.thinning)",
    )
    add_overwrite(parser, "replace existing output files")
    add_no_progress(parser)
    add_json(parser, "print the run summary as JSON")


def _versions() -> dict[str, str]:
    from importlib import metadata

    out = {}
    for name in ("samii", "numpy", "scipy", "mujoco", "matplotlib", "rerun-sdk", "control"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def _excitations(args):
    """The excitations ``args`` ask for, checked; raises InputError naming the option."""
    from samii.measure.excitation import SteppedSine, SweptSine

    lo, hi = args.band_hz
    if args.freqs_hz is not None and args.method == "swept":
        raise InputError("--freqs-hz sets the stepped-sine dwells: use it with --method stepped or both")
    if args.freqs_hz is not None and len(set(args.freqs_hz)) != len(args.freqs_hz):
        dup = sorted({f for f in args.freqs_hz if args.freqs_hz.count(f) > 1})
        raise InputError(f"--freqs-hz: {', '.join(f'{f:g}' for f in dup)} Hz given more than once; expected distinct frequencies")
    amp = {} if args.amplitude_v is None else {"amplitude_v": args.amplitude_v}
    try:
        sweep = SweptSine(start_hz=lo, stop_hz=hi, repetitions=args.averages, **({} if args.tail_s is None else {"tail_s": args.tail_s}), **amp)
        stepped = SteppedSine(**({} if args.freqs_hz is None else {"freqs_hz": tuple(args.freqs_hz)}), **amp)
    except ValueError as exc:
        raise InputError(str(exc)) from None
    plan = [("swept", sweep)] if args.method in ("swept", "both") else []
    if args.method in ("stepped", "both"):
        plan.append(("stepped", stepped))
    top = max(hi if kind == "swept" else max(e.freqs_hz) for kind, e in plan)
    from samii.measure.daq import antialias_cutoff_hz

    cutoff = antialias_cutoff_hz(args.sample_rate_hz)
    if top > cutoff:
        option = "--band-hz" if args.method != "stepped" and hi > cutoff else "--freqs-hz"
        raise InputError(
            f"{option}: {top:g} Hz lies above the DAQ's anti-alias cutoff {cutoff:g} Hz at --sample-rate-hz "
            f"{args.sample_rate_hz:g} (a quarter of it); lower the frequency or raise the sample rate"
        )
    total = sum(e.duration_s for _, e in plan)
    if total > MAX_SIMULATED_S:
        raise InputError(
            f"the run would simulate {total:.4g} s, more than the {MAX_SIMULATED_S:g} s accepted "
            "(check --tail-s, --averages, --band-hz and --freqs-hz: a dwell lasts at least 4 periods)"
        )
    return sweep, stepped, plan


def _check_loop_stable(model) -> None:
    """Refuse a model whose servo loop is unstable at the nominal pose: it would oscillate on its own, not measure."""
    import numpy as np

    from samii.sim.linearize import UNSTABLE_RATE_1_S, poles_per_s

    s = poles_per_s(model)
    bad = s[s.real > UNSTABLE_RATE_1_S]
    if bad.size:
        worst = bad[np.argmax(bad.real)]
        how = (
            f"it would oscillate on its own at {abs(worst.imag) / (2 * np.pi):.3g} Hz"
            if abs(worst.imag) > 1e-6
            else "it would drift away from the pose on its own (a real pole: e.g. a beam buckling under its load)"
        )
        raise SimulationUnstable(
            f"the model under its servo loop is unstable at the nominal pose before any excitation: pole at {worst.real:.3g} "
            f"{worst.imag:+.3g}j 1/s, growing {worst.real:.3g} 1/s; {how}, not measure (check the overridden parameters, "
            "e.g. hydraulic.position_gain, beam.length_m)"
        )


def _check_rails(ts, kind: str) -> None:
    import numpy as np

    on_rail = np.abs(ts.v) >= VALVE_RANGE_V * (1 - 1e-6)
    if on_rail.mean() > RAIL_FRACTION:
        raise SimulationUnstable(
            f"{kind} run: the valve command sat on its +-{VALVE_RANGE_V:g} V rails for {100 * on_rail.mean():.0f} % of the run; "
            "a saturated loop is not a linear measurement (lower --amplitude-v, check the servo gain); nothing written"
        )


def run(args: argparse.Namespace) -> int:
    import os
    import time
    import warnings
    from dataclasses import asdict

    import numpy as np

    from samii.outputs import OutputFolder, check_output_file, create_parent, with_size

    t_start = time.perf_counter()
    sweep, stepped, plan = _excitations(args)
    names = list(_OUTPUTS[args.method]) + ["bode.png", "run.json"]
    folder = OutputFolder(args.out, names, overwrite=args.overwrite)
    rerun_path = check_output_file(args.rerun, overwrite=args.overwrite, option="--rerun", beside=folder) if args.rerun else None

    from tqdm import tqdm

    from samii.formats import write_frf_csv, write_text
    from samii.frequency_response import SUSTAINED_POINTS, max_deviation
    from samii.measure.campaign import linearised_frf, measure
    from samii.measure.daq import SensorNoise
    from samii.sim.cli_modes import parse_overrides
    from samii.sim.model import default_params, load_model, params_with_overrides, read_params_file
    from samii.sim.plugin import hydraulic_params

    overrides = parse_overrides(args.set)
    model = load_model(args.model, overrides=overrides or None)
    dt = float(model.opt.timestep)
    physics_hz = 1.0 / dt
    ratio = physics_hz / args.sample_rate_hz
    if abs(ratio - round(ratio)) > 1e-6 or physics_hz < args.sample_rate_hz:
        raise InputError(f"--sample-rate-hz {args.sample_rate_hz:g} must divide the physics rate {physics_hz:g} Hz")
    steps = sum(e.duration_s for _, e in plan) / dt
    if steps > MAX_PHYSICS_STEPS:
        raise InputError(
            f"the run would take {steps:.3g} physics steps of {dt:.3g} s (the model's timestep_s), more than the "
            f"{MAX_PHYSICS_STEPS:.0e} accepted: hours of computing and {8 * steps / 1e9:.3g} GB for each signal held "
            f"at the physics rate; a timestep_s of at least {dt * steps / MAX_PHYSICS_STEPS:.2g} s (the default is "
            "1e-3 s), or a shorter run"
        )
    _check_loop_stable(model)
    noise = SensorNoise() if args.noise else None
    rng = np.random.default_rng(args.seed)
    frame_steps = None
    if rerun_path:
        from samii.viz.recording import frame_steps_for

        frame_steps = frame_steps_for(model, args.rerun_fps)

    total_steps = sum(int(round(e.duration_s / dt)) for _, e in plan)
    bar = tqdm(total=total_steps, unit="step", unit_scale=True, desc="samii measure", disable=args.no_progress, file=sys.stderr)
    offset = [0]

    def progress(done: int, _total: int) -> None:
        bar.n = offset[0] + done
        bar.refresh()

    # the first measurement's record is timeseries.csv; the stepped one of --method both is timeseries_stepped.csv
    ts_names = {kind: ("timeseries.csv" if i == 0 else f"timeseries_{kind}.csv") for i, (kind, _) in enumerate(plan)}
    results = {}
    rrd_tmp = rerun_path.parent / f".{rerun_path.name}.{os.getpid()}.tmp" if rerun_path else None
    try:
        with folder:
            try:
                for kind, excitation in plan:
                    results[kind] = measure(
                        model,
                        excitation,
                        sample_rate_hz=args.sample_rate_hz,
                        noise=noise,
                        rng=rng,
                        frame_steps=frame_steps,
                        progress=progress,
                        timeseries_path=folder.path(ts_names[kind]),
                    )
                    _check_rails(results[kind].timeseries, kind)
                    offset[0] += int(round(excitation.duration_s / dt))
            finally:
                bar.close()
            sim_wall = sum(r.run.wall_s for r in results.values())
            simulated_s = sum(e.duration_s for _, e in plan)

            main = results.get("swept") or results["stepped"]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                ref_grid = np.geomspace(min(main.frf.freq_hz[0], 0.1), max(main.frf.freq_hz[-1], 40.0), 400)
                reference = linearised_frf(model, ref_grid)
                coh = main.frf.coherence(main.frf.channels[0])
                coh_ok = coh is not None and bool(np.any(np.isfinite(coh)))
                checks = {
                    kind: max_deviation(
                        r.frf, linearised_frf(model, r.frf.freq_hz), band_hz=(0.5, 35.0), min_coherence=0.95 if coh_ok or kind == "stepped" else None
                    )
                    for kind, r in results.items()
                }
            write_frf_csv(main.frf, folder.path("frf.csv"))
            if args.method == "both":
                write_frf_csv(results["stepped"].frf, folder.path("frf_stepped.csv"))

            from samii.viz.bode_plot import bode_plot

            amp = (sweep if "swept" in results else stepped).amplitude_v
            model_name = args.model or "embedded model"
            if overrides:
                model_name += " with " + ", ".join(f"{k}={v:g}" for k, v in overrides.items())
            title = f"samii measure: {_METHOD_LABEL[args.method]}, {amp:g} V, {'with' if noise else 'no'} sensor noise\n{model_name}"
            bode_plot(
                results.get("swept").frf if "swept" in results else None,
                stepped=results["stepped"].frf if "stepped" in results else None,
                reference=reference,
                reference_label="linearised simulator",
                title=title,
                path=folder.path("bode.png"),
            )

            try:
                if args.model is None:
                    params = asdict(params_with_overrides(default_params(), overrides))
                elif str(args.model).lower().endswith(".json"):  # a parameter file (samii calibrate): record what it held
                    params = asdict(params_with_overrides(read_params_file(args.model), overrides))
                else:
                    params = None  # an MJCF file: its physics is in the file
            except (OSError, ValueError):
                params = None
            hp = hydraulic_params(model)
            peaks = {
                kind: {
                    "load_pressure_pa": float(np.max(np.abs(r.timeseries.p_load))) if r.timeseries.p_load is not None else None,
                    "valve_command_v": float(np.max(np.abs(r.timeseries.v))),
                    "joint_angle_rad": float(np.max(np.abs(r.timeseries.theta))),
                }
                for kind, r in results.items()
            }
            outputs = [str(folder.final(n)) for n in names] + ([str(rerun_path)] if rerun_path else [])
            summary = {
                "command": "samii measure",
                "argv": sys.argv[1:],
                "method": args.method,
                "excitation": {kind: e.describe() for kind, e in plan},
                "daq": {
                    "sample_rate_hz": args.sample_rate_hz,
                    "antialias": main.timeseries.metadata.get("antialias"),
                    "sensor_noise": asdict(noise) if noise else None,
                    "seed": args.seed,
                },
                "frf": {k: v for k, v in main.frf.metadata.items() if k.startswith("frf_")},
                "model": {
                    "file": args.model or "embedded default",
                    "overrides": overrides,
                    "timestep_s": dt,
                    "params": params,
                    "hydraulic": {k: v for k, v in asdict(hp).items() if k != "source"},
                },
                "versions": _versions(),
                "timing": {
                    "simulated_s": simulated_s,
                    "simulation_wall_s": sim_wall,
                    "total_wall_s": time.perf_counter() - t_start,
                    "real_time_factor": simulated_s / sim_wall if sim_wall > 0 else None,
                },
                "vs_linearised_simulator_0.5_35_hz": checks[plan[0][0]],
                "peaks": peaks[plan[0][0]],
                "outputs": outputs,
            }
            if args.method == "both":
                summary["vs_linearised_simulator_0.5_35_hz_by_method"] = checks
                summary["peaks_by_method"] = peaks
            warnings_out = []
            for kind, pk in peaks.items():
                p_peak = pk["load_pressure_pa"]
                if p_peak is not None and p_peak > hp.supply_pressure:
                    warnings_out.append(
                        f"{kind} run: the load pressure reached {p_peak / 1e6:.2f} MPa, {100 * (p_peak / hp.supply_pressure - 1):.0f} % above the "
                        f"{hp.supply_pressure / 1e6:.3g} MPa supply: the motor pumped oil in faster than the partly closed valve returns it "
                        "to the supply (no relief valve is modelled; a rig's would clip the pressure). "
                        "The response is far from small-signal: lower --amplitude-v"
                    )
            for kind, check in checks.items():
                # a swept sine's dense grid: the deviation of a band (a point whose coherence is high by chance deviated
                # 6.8 dB at 0.1 V with sensor noise, and lowering the amplitude was advised); a stepped sine's every point
                key = "sustained_db" if kind == "swept" else "max_abs_db"
                ch = max(check, key=lambda c: check[c][key], default=None)
                if ch is not None and check[ch][key] > LINEARITY_WARN_DB:
                    st = check[ch]
                    where = (
                        f"over a band (the median of {SUSTAINED_POINTS} neighbouring coherent points, 0.5-35 Hz; {st['sustained_deg']:.0f} deg)"
                        if kind == "swept"
                        else f"(coherent points, 0.5-35 Hz; {st['max_abs_deg']:.0f} deg)"
                    )
                    warnings_out.append(
                        f"{kind} run: {ch} lies {st[key]:.1f} dB from the linearised simulator {where}: the response at {amp:g} V "
                        "is far from small-signal (valve and orifice nonlinearity), so this FRF is not the plant's linear model; "
                        "lower --amplitude-v to measure that"
                    )
            if "swept" in results and not coh_ok:
                warnings_out.append(
                    "one swept-sine record cannot estimate coherence (--averages 1): the coherence panels are empty "
                    "and the check against the linearised simulator uses every point"
                )
            if warnings_out:
                summary["warnings"] = warnings_out
            write_text(folder.path("run.json"), dumps(summary, indent=2) + "\n")
            if rerun_path is not None:
                from samii.viz.recording import RunRecord, recording_failed, write_recording

                runs = [RunRecord(kind, results[kind].timeseries, results[kind].run.frame_t_s, results[kind].run.frame_qpos,
                                  sweep_hz=exc.frequency_hz(results[kind].timeseries.t),
                                  label=f"samii measure: {kind} sine, {exc.amplitude_v:g} V on the valve command, joint 2 under its position loop")
                        for kind, exc in plan]  # fmt: skip
                create_parent(rrd_tmp)
                try:
                    write_recording(rrd_tmp, model, runs, application_id="samii_measure", thin_frames=args.rerun_fps is None)
                except (RuntimeError, OSError) as exc:  # rerun's writer reports file-system failures as RuntimeError
                    raise recording_failed(exc, rerun_path) from None
        if rrd_tmp is not None:  # the recording lives outside --out: moved into place once the folder is complete
            os.replace(rrd_tmp, rerun_path)
    finally:
        if rrd_tmp is not None and rrd_tmp.exists():
            rrd_tmp.unlink()
    summary["timing"]["total_wall_s"] = time.perf_counter() - t_start
    if args.json:
        print(dumps(summary, indent=2))
        return 0
    tm = summary["timing"]
    print(
        f"samii measure: {_METHOD_LABEL[args.method]}, {simulated_s:.0f} s simulated in {sim_wall:.1f} s "
        f"({tm['real_time_factor']:.0f}x real time), {tm['total_wall_s']:.1f} s in all"
    )
    for kind, pk in peaks.items():
        print(
            f"{kind}: peak load pressure {pk['load_pressure_pa'] / 1e6:.2f} MPa (supply {hp.supply_pressure / 1e6:.3g} MPa), "
            f"peak valve command {pk['valve_command_v']:.2f} V"
        )
    for w in summary.get("warnings", []):
        print(f"samii measure: warning: {w}")
    for kind, check in checks.items():
        cond = "coherence > 0.95" if coh_ok or kind == "stepped" else "every point"
        for ch, st in check.items():
            print(
                f"{kind} {ch}: within {st['max_abs_db']:.2f} dB and {st['max_abs_deg']:.2f} deg of the linearised simulator "
                f"over 0.5-35 Hz ({cond}, {st['points']} points)"
            )
    for p in summary["outputs"]:
        print(f"wrote {with_size(p)}")
    return 0
