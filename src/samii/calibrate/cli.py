"""``samii calibrate DATA --param NAME ...``: fit the simulator's physics to FRF data.

Imports nothing heavy at module level (the ``samii`` command imports every
stage's cli module to build its help).
"""

from __future__ import annotations

import argparse
import math

from samii.cli_args import add_band, add_json, add_model, add_out, add_overwrite, add_set, float_in, int_in, name_value

__all__ = ["add_arguments", "run"]


def _name_bounds(text: str) -> tuple[str, tuple[float, float]]:
    name, sep, value = text.partition("=")
    lo, sep2, hi = value.partition(":")
    if not sep or not sep2 or not name.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=LO:HI, got {text!r}")
    try:
        bounds = (float(lo), float(hi))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: LO and HI must be numbers") from None
    if not all(math.isfinite(b) for b in bounds) or not bounds[0] < bounds[1]:
        raise argparse.ArgumentTypeError(f"{text!r}: expected finite LO < HI")
    return name.strip(), bounds


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "data",
        metavar="DATA",
        help="FRF CSV (docs/DATA_FORMATS.md), a rig-era .mat, or eq9.4: the notebook's fitted model "
        "(theta taken in degrees; its acceleration unit is unknown, so calibrate gain.base with it)",
    )
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME",
        required=True,
        help="physical parameter to calibrate, a --set name such as beam.clamp_stiffness_Nm_rad or "
        "hydraulic.total_volume; gain.base / gain.act for a sensor of unknown unit (repeatable)",
    )
    parser.add_argument(
        "--start",
        action="append",
        default=[],
        type=name_value,
        metavar="NAME=VALUE",
        help="starting value of a calibrated parameter (default: the model's value; a channel gain starts at the data's level against the model's)",
    )
    parser.add_argument(
        "--bound",
        action="append",
        default=[],
        type=_name_bounds,
        metavar="NAME=LO:HI",
        help="bounds of a calibrated parameter (default: physical limits where known, else a factor 10 around the start)",
    )
    parser.add_argument(
        "--phase-weight",
        type=float_in(0, 100),
        default=0.1,
        metavar="W",
        help="weight on the phase error in degrees (default 0.1, the notebook's eq 9.4)",
    )
    add_band(parser, "use only LO <= f <= HI Hz (default: all the data)")
    parser.add_argument("--channels", default=None, metavar="C1,C2", help="channels in the cost (default act,base where present)")
    parser.add_argument(
        "--weighting",
        choices=("auto", "none", "coherence"),
        default="auto",
        help="none: the notebook's cost; coherence: points weighted by the random error their coherence predicts; "
        "auto (default): coherence when the data have it for every channel in the cost, else none (as samii fit)",
    )
    add_model(
        parser,
        "parameter file to start from (default: the embedded model's); an MJCF file cannot be calibrated, its physics is not parametrised",
        metavar="PARAMS.json",
    )
    add_set(parser, "override a model parameter before calibrating (repeatable)")
    parser.add_argument("--max-iterations", type=int_in(1, 100000), default=60, metavar="N", help="solver iterations at most (default 60)")
    parser.add_argument(
        "--confirm",
        action="store_true",
        help="also measure the calibrated model with a swept sine in the nonlinear simulator and compare (about 5 s)",
    )
    add_out(parser, "write calibration.json, calibrated_params.json (for --model) and calibration_bode.png here")
    add_overwrite(parser, "replace files already in --out")
    add_json(parser, "print the machine-readable report")


def run(args: argparse.Namespace) -> int:
    from samii.calibrate.calibrate_file import CalibrateRequest, calibrate_file

    prog = "samii calibrate"
    request = CalibrateRequest(
        params=tuple(args.param),
        start=dict(args.start),
        bounds=dict(args.bound),
        phase_weight=args.phase_weight,
        band_hz=tuple(args.band_hz) if args.band_hz else None,
        channels=args.channels,
        weighting=args.weighting,
        model=args.model,
        overrides=tuple(args.set),
        max_iterations=args.max_iterations,
        confirm=args.confirm,
    )
    done = calibrate_file(args.data, request, out=args.out, overwrite=args.overwrite)
    result, written = done.result, done.written
    if args.json:
        print(result.to_json(indent=2))
        return 0
    r = result
    print(
        f"{prog}: {args.data}: {len(r.names)} parameter(s), band {r.band_hz[0]:.3g}-{r.band_hz[1]:.3g} Hz, channels {', '.join(r.channels)}, "
        f"phase weight {r.phase_weight:g}, weighting {r.weighting}"
    )
    print(r.table())
    print(
        f"cost {r.cost_start:.6g} -> {r.cost:.6g}; {r.nfev} iterations, {r.elapsed_s:.1f} s; {r.status}; converged {'yes' if r.converged else 'NO'}"
    )
    for c in r.channels:
        (d0, p0), (d1, p1) = r.rms_start[c], r.rms[c]
        print(f"RMS error {c}: {d0:.3g} dB / {p0:.3g} deg -> {d1:.3g} dB / {p1:.3g} deg")
    if r.confirmation:
        conf = r.confirmation
        print(f"checked by a {conf['method']} ({conf['elapsed_s']:.1f} s): RMS error against the data of")
        for c in r.channels:
            m, lin = conf["rms_error_measured"][c], conf["rms_error_linearised"][c]
            print(
                f"  {c}: the measured calibrated model {m['db']:.3g} dB / {m['deg']:.3g} deg; its linearisation {lin['db']:.3g} dB / {lin['deg']:.3g} deg"
            )
    lof = r.lack_of_fit
    print(f"lack of fit: {lof.verdict()} ({lof.rule})")
    for w in r.warnings:
        print(f"warning: {w}")
    if not r.converged:
        print("warning: NOT converged: see the warnings above; try other --start values, --bound, more --max-iterations, or fewer parameters")
    for p in written:
        print(f"wrote {p}")
    return 0
