"""``samii measure``: the rig's swept- or stepped-sine Bode test, run in the simulator.

Writes into ``--out`` (default ``measure_out``): ``timeseries.csv`` and
``frf.csv`` (DATA_FORMATS.md), ``bode.png``, ``run.json``; with ``--method
both`` also ``timeseries_stepped.csv`` and ``frf_stepped.csv``; with ``--rerun
FILE.rrd`` a Rerun recording. The test itself is :func:`samii.measure.bode_test.run_bode_test`; this module parses
the options, shows progress and prints its summary.
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
    add_seed,
    add_set,
    float_in,
    int_in,
    positive_float,
)
from samii.json_output import dumps
from samii.measure.bode_test import METHOD_LABEL, MIN_AMPLITUDE_V, VALVE_RANGE_V

__all__ = ["add_arguments", "run"]


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
    add_seed(parser, "seed of the sensor-noise generator, an integer >= 0 (default 0)")
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


def run(args: argparse.Namespace) -> int:
    from samii.cli_progress import Bar
    from samii.measure.bode_test import BodeTestRequest, run_bode_test
    from samii.outputs import with_size

    request = BodeTestRequest(
        method=args.method,
        freqs_hz=None if args.freqs_hz is None else tuple(args.freqs_hz),
        amplitude_v=args.amplitude_v,
        averages=args.averages,
        tail_s=args.tail_s,
        band_hz=tuple(args.band_hz),
        sample_rate_hz=args.sample_rate_hz,
        noise=args.noise,
        seed=args.seed,
    )
    with Bar("samii measure", unit="step", unit_scale=True, disable=args.no_progress) as bar:
        test = run_bode_test(
            args.out,
            request,
            model=args.model,
            overrides=args.set,
            rerun=args.rerun,
            rerun_fps=args.rerun_fps,
            overwrite=args.overwrite,
            progress=bar,
            argv=sys.argv[1:],
        )
    if args.json:
        from samii.schema import document

        print(dumps(document(test.record), indent=2))
        return 0
    tm = test.record.timing
    print(
        f"samii measure: {METHOD_LABEL[args.method]}, {tm.simulated_s:.0f} s simulated in {tm.simulation_wall_s:.1f} s "
        f"({tm.real_time_factor:.0f}x real time), {tm.total_wall_s:.1f} s in all"
    )
    for kind, pk in test.peaks.items():
        print(
            f"{kind}: peak load pressure {pk['load_pressure_pa'] / 1e6:.2f} MPa (supply {test.supply_pressure_pa / 1e6:.3g} MPa), "
            f"peak valve command {pk['valve_command_v']:.2f} V"
        )
    for w in test.warnings:
        print(f"samii measure: warning: {w.text}")
    for kind, check in test.checks.items():
        cond = "coherence > 0.95" if test.coherence_ok or kind == "stepped" else "every point"
        for ch, st in check.items():
            print(
                f"{kind} {ch}: within {st['max_abs_db']:.2f} dB and {st['max_abs_deg']:.2f} deg of the linearised simulator "
                f"over 0.5-35 Hz ({cond}, {st['points']} points)"
            )
    for p in test.written:
        print(f"wrote {with_size(p)}")
    return 0
