"""``samii measure``: the rig's swept- or stepped-sine Bode test, run in the simulator.

Writes into ``--out`` (default ``measure_out``): ``timeseries.csv`` and
``frf.csv`` (DATA_FORMATS.md), ``bode.png``, ``run.json``; with ``--method
both`` also ``timeseries_stepped.csv`` and ``frf_stepped.csv``; with ``--rerun
FILE.rrd`` a Rerun recording. Imports nothing heavy at module level.
"""

from __future__ import annotations

import argparse
import json
import sys

__all__ = ["add_arguments", "run"]

_OUTPUTS = {"swept": ("timeseries.csv", "frf.csv"), "stepped": ("timeseries.csv", "frf.csv"), "both": ("timeseries.csv", "frf.csv", "timeseries_stepped.csv", "frf_stepped.csv")}
#: Animation rate of the Rerun recording: a frame every 40 physics steps (25 fps at 1 ms).
_FRAME_STEPS = 40


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", metavar="DIR", default="measure_out", help="output folder (default measure_out)")
    parser.add_argument("--method", choices=("swept", "stepped", "both"), default="swept",
                        help="swept sine 0.1-40 Hz (default), stepped sine at --freqs-hz, or both (stepped points overlaid)")
    parser.add_argument("--freqs-hz", type=_positive, nargs="+", metavar="F", help="stepped-sine frequencies [Hz] (default 14 points over 0.5-35 Hz)")
    parser.add_argument("--amplitude-v", type=_positive, default=None, metavar="V", help="excitation amplitude added to the valve command (default 0.1 V)")
    parser.add_argument("--averages", type=int, default=3, metavar="N", help="swept-sine repetitions averaged (default 3, as on the rig)")
    parser.add_argument("--tail-s", type=_positive, default=None, metavar="S",
                        help="rest after each sweep, for the response to decay (default 20 s: 6.5 time constants of the embedded model's base mode 1)")
    parser.add_argument("--band-hz", type=_positive, nargs=2, metavar=("LO", "HI"), default=(0.1, 40.0), help="swept-sine band (default 0.1 40)")
    parser.add_argument("--sample-rate-hz", type=_positive, default=1000.0, metavar="HZ", help="DAQ sampling rate (default 1000; must divide the physics rate)")
    parser.add_argument("--noise", action="store_true", help="add sensor noise (typical lab levels, see samii.measure.daq.SensorNoise)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the sensor-noise generator (default 0)")
    parser.add_argument("--model", metavar="XML", help="MJCF file (default: the embedded SAMII model)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="override a model parameter, e.g. hydraulic.supply_pressure=2.1e7 (repeatable)")
    parser.add_argument("--rerun", metavar="FILE.rrd", help="also write a Rerun recording: the arm and beam moving and the measured signals")
    parser.add_argument("--overwrite", action="store_true", help="replace existing output files")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--json", action="store_true", help="print the run summary as JSON")


def _versions() -> dict[str, str]:
    from importlib import metadata

    out = {}
    for name in ("samii", "numpy", "scipy", "mujoco", "matplotlib", "rerun-sdk", "control"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def run(args: argparse.Namespace) -> int:
    import time
    from dataclasses import asdict
    from pathlib import Path

    import numpy as np

    from samii.frequency_response import max_deviation
    from samii.measure.daq import SensorNoise
    from samii.measure.excitation import SteppedSine, SweptSine
    from samii.measure.io import write_frf_csv

    t_start = time.perf_counter()
    out = Path(args.out)
    names = list(_OUTPUTS[args.method]) + ["bode.png", "run.json"]
    try:
        sweep = SweptSine(
            start_hz=args.band_hz[0], stop_hz=args.band_hz[1], repetitions=args.averages,
            **({} if args.tail_s is None else {"tail_s": args.tail_s}),
            **({} if args.amplitude_v is None else {"amplitude_v": args.amplitude_v}),
        )
        stepped = SteppedSine(**({} if args.freqs_hz is None else {"freqs_hz": tuple(args.freqs_hz)}),
                              **({} if args.amplitude_v is None else {"amplitude_v": args.amplitude_v}))
    except ValueError as exc:
        print(f"samii measure: error: {exc}", file=sys.stderr)
        return 2
    existing = [n for n in names if (out / n).exists()]
    if args.rerun and Path(args.rerun).exists():
        existing.append(str(args.rerun))
    if existing and not args.overwrite:
        print(f"samii measure: error: {out} already holds {', '.join(existing)}; pass --overwrite to replace", file=sys.stderr)
        return 2

    import warnings

    from tqdm import tqdm

    from samii.measure.campaign import linearised_frf, measure
    from samii.sim.cli_modes import parse_overrides
    from samii.sim.model import default_params, load_model, params_with_overrides
    from samii.sim.plugin import hydraulic_params

    overrides = parse_overrides(args.set)
    try:
        model = load_model(args.model, overrides=overrides or None)
    except (OSError, ValueError) as exc:
        print(f"samii measure: error: {exc}", file=sys.stderr)
        return 2
    dt = float(model.opt.timestep)
    physics_hz = 1.0 / dt
    if abs(physics_hz / args.sample_rate_hz - round(physics_hz / args.sample_rate_hz)) > 1e-6 or physics_hz < args.sample_rate_hz:
        print(f"samii measure: error: --sample-rate-hz {args.sample_rate_hz:g} must divide the physics rate {physics_hz:g} Hz", file=sys.stderr)
        return 2
    noise = SensorNoise() if args.noise else None
    rng = np.random.default_rng(args.seed)
    frame_steps = _FRAME_STEPS if args.rerun else None

    plan = [("swept", sweep)] if args.method in ("swept", "both") else []
    if args.method in ("stepped", "both"):
        plan.append(("stepped", stepped))
    total_steps = sum(int(round(e.duration_s / dt)) for _, e in plan)
    bar = tqdm(total=total_steps, unit="step", unit_scale=True, desc="samii measure", disable=args.no_progress, file=sys.stderr)
    offset = [0]

    def progress(done: int, _total: int) -> None:
        bar.n = offset[0] + done
        bar.refresh()

    from samii.sim.simulate import SimulationUnstable

    # the first measurement's record is timeseries.csv; the stepped one of --method both is timeseries_stepped.csv
    ts_names = {kind: ("timeseries.csv" if i == 0 else f"timeseries_{kind}.csv") for i, (kind, _) in enumerate(plan)}
    out.mkdir(parents=True, exist_ok=True)
    written = []
    results = {}
    try:
        for kind, excitation in plan:
            results[kind] = measure(model, excitation, sample_rate_hz=args.sample_rate_hz, noise=noise, rng=rng, frame_steps=frame_steps,
                               progress=progress, timeseries_path=out / ts_names[kind], overwrite=args.overwrite)
            written.append(out / ts_names[kind])
            offset[0] += int(round(excitation.duration_s / dt))
    except SimulationUnstable as exc:
        bar.close()
        print(f"samii measure: error: {exc}", file=sys.stderr)
        return 3
    except FileExistsError as exc:  # a file appeared in --out meanwhile
        bar.close()
        print(f"samii measure: error: {exc}", file=sys.stderr)
        return 2
    bar.close()
    sim_wall = sum(r.run.wall_s for r in results.values())
    simulated_s = sum(e.duration_s for _, e in plan)

    main = results.get("swept") or results["stepped"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ref_grid = np.geomspace(min(main.frf.freq_hz[0], 0.1), max(main.frf.freq_hz[-1], 40.0), 400)
        reference = linearised_frf(model, ref_grid)
        ref_at = linearised_frf(model, main.frf.freq_hz)
    written.append(write_frf_csv(main.frf, out / "frf.csv", overwrite=args.overwrite))
    if args.method == "both":
        written.append(write_frf_csv(results["stepped"].frf, out / "frf_stepped.csv", overwrite=args.overwrite))

    from samii.viz.bode_plot import bode_plot

    amp = (sweep if "swept" in results else stepped).amplitude_v
    title = f"samii measure: {args.method} sine, {amp:g} V, {'with' if noise else 'no'} sensor noise"
    png = out / "bode.png"
    if png.exists() and not args.overwrite:  # appeared meanwhile
        print(f"samii measure: error: {png} exists; pass --overwrite", file=sys.stderr)
        return 2
    if "swept" in results:
        bode_plot(results["swept"].frf, stepped=results["stepped"].frf if "stepped" in results else None,
                  reference=reference, reference_label="linearised simulator", title=title, path=png)
    else:
        bode_plot(None, stepped=results["stepped"].frf, reference=reference, reference_label="linearised simulator", title=title, path=png)
    written.append(png)

    if args.rerun:
        from samii.measure.recording import write_rerun_recording

        first = results.get("swept") or results["stepped"]
        written.append(write_rerun_recording(args.rerun, model, first.timeseries, frame_t_s=first.run.frame_t_s, frame_qpos=first.run.frame_qpos))

    try:
        if args.model is None:
            params = asdict(params_with_overrides(default_params(), overrides))
        elif str(args.model).lower().endswith(".json"):  # a parameter file (samii calibrate): record what it held
            from samii.sim.model import read_params_file

            params = asdict(params_with_overrides(read_params_file(args.model), overrides))
        else:
            params = None  # an MJCF file: its physics is in the file
    except (OSError, ValueError):
        params = None
    hp = hydraulic_params(model)
    summary = {
        "command": "samii measure",
        "argv": sys.argv[1:],
        "method": args.method,
        "excitation": {kind: e.describe() for kind, e in plan},
        "daq": {"sample_rate_hz": args.sample_rate_hz, "antialias": main.timeseries.metadata.get("antialias"),
                "sensor_noise": asdict(noise) if noise else None, "seed": args.seed},
        "frf": {k: v for k, v in main.frf.metadata.items() if k.startswith("frf_")},
        "model": {"file": args.model or "embedded default", "overrides": overrides, "timestep_s": dt,
                  "params": params, "hydraulic": {k: v for k, v in asdict(hp).items() if k != "source"}},
        "versions": _versions(),
        "timing": {"simulated_s": simulated_s, "simulation_wall_s": sim_wall, "total_wall_s": time.perf_counter() - t_start,
                   "real_time_factor": simulated_s / sim_wall if sim_wall > 0 else None},
        "vs_linearised_simulator_0.5_35_hz": max_deviation(main.frf, ref_at, band_hz=(0.5, 35.0), min_coherence=0.95),
        "peaks": {"load_pressure_pa": float(np.max(np.abs(main.timeseries.p_load))) if main.timeseries.p_load is not None else None,
                  "valve_command_v": float(np.max(np.abs(main.timeseries.v))), "joint_angle_rad": float(np.max(np.abs(main.timeseries.theta)))},
        "outputs": [str(p) for p in written] + [str(out / "run.json")],
    }
    p_peak = summary["peaks"]["load_pressure_pa"]
    if p_peak is not None and p_peak > hp.supply_pressure:
        summary["warnings"] = [
            f"the load pressure reached {p_peak / 1e6:.2f} MPa, {100 * (p_peak / hp.supply_pressure - 1):.0f} % above the "
            f"{hp.supply_pressure / 1e6:.3g} MPa supply: the motor pumped oil in faster than the partly closed valve returns it "
            "to the supply (no relief valve is modelled; a rig's would clip the pressure). "
            "The response is far from small-signal: lower --amplitude-v"
        ]
    run_json = out / "run.json"
    from samii.measure.io import write_text

    write_text(run_json, json.dumps(summary, indent=2, default=str) + "\n", overwrite=args.overwrite)
    summary["timing"]["total_wall_s"] = time.perf_counter() - t_start
    if args.json:
        print(json.dumps(summary, indent=2, default=str))
        return 0
    tm = summary["timing"]
    print(f"samii measure: {args.method} sine, {simulated_s:.0f} s simulated in {sim_wall:.1f} s "
          f"({tm['real_time_factor']:.0f}x real time), {tm['total_wall_s']:.1f} s in all")
    print(f"peak load pressure {summary['peaks']['load_pressure_pa'] / 1e6:.2f} MPa (supply {hp.supply_pressure / 1e6:.3g} MPa), "
          f"peak valve command {summary['peaks']['valve_command_v']:.2f} V")
    for w in summary.get("warnings", []):
        print(f"samii measure: warning: {w}")
    for ch, s in summary["vs_linearised_simulator_0.5_35_hz"].items():
        print(f"{ch}: within {s['max_abs_db']:.2f} dB and {s['max_abs_deg']:.2f} deg of the linearised simulator over 0.5-35 Hz (coherence > 0.95)")
    for p in summary["outputs"]:
        print(f"wrote {p}")
    return 0
