"""``samii calibrate DATA --param NAME ...``: fit the simulator's physics to FRF data.

Imports nothing heavy at module level (the ``samii`` command imports every
stage's cli module to build its help).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from samii.cli_args import add_band, add_json, add_model, add_out, add_overwrite, add_set, float_in, int_in, name_value
from samii.errors import InputError, input_error_of

__all__ = ["add_arguments", "run", "load_target"]

#: Output files written into --out.
OUTPUTS = ("calibration.json", "calibrated_params.json", "calibration_bode.png")
#: Named model curves that can stand in for data.
NOTEBOOK_TARGETS = ("eq9.4",)


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


def load_target(source: str):
    """The FRF to calibrate to: a file, or the notebook's eq 9.4 curves in SI with theta in degrees.

    eq 9.4 was fitted to theta in degrees (unity feedback 1 V/deg gives its K1 = 27.9/s), so its
    theta/v is converted from deg/V to rad/V and its xdd/theta from per degree to per radian; its
    acceleration unit is not stated, so the base channel keeps that unknown factor.
    """
    import numpy as np

    from samii.frequency_response import FrequencyResponse

    if source.lower() in NOTEBOOK_TARGETS:
        from samii import notebook as nb
        from samii.identify.structures import ModelStructure
        from samii.measure.frf import log_frequency_grid

        st = ModelStructure.notebook_3mode("s4")
        f = log_frequency_grid(0.1, 40.0, 100)
        deg = 180.0 / np.pi
        act = st.response(nb.EQ9_4, f, "act") / deg  # theta_deg / v -> theta_rad / v
        base = st.response(nb.EQ9_4, f, "base") * deg  # xdd / theta_deg -> xdd / theta_rad (xdd in the notebook's unit)
        return FrequencyResponse(
            f, act=act, base=base, metadata={"source": "notebook eq 9.4 over 0.1-40 Hz; theta in degrees converted to rad; acceleration unit unknown"}
        )
    path = Path(source)
    if not path.is_file():
        raise InputError(f"DATA {source!r}: no such file (DATA is an FRF CSV, a rig-era .mat, or one of {', '.join(NOTEBOOK_TARGETS)})")
    if path.suffix.lower() not in (".csv", ".mat", ".txt"):
        raise InputError(f"DATA {source}: expected an FRF CSV (docs/DATA_FORMATS.md) or a rig-era .mat, not a {path.suffix or 'suffix-less'} file")
    from samii.formats import is_mat_file

    if is_mat_file(path):  # (the content decides: a text file named .mat is read as the CSV it is)
        from samii.formats import read_mat_bode

        return read_mat_bode(path)
    from samii.formats import read_frf_csv

    return read_frf_csv(path)


def _channels(text: str, data) -> tuple[str, ...]:
    """``--channels act,base`` checked against the channels a calibration can use and the data hold."""
    names = tuple(c.strip() for c in text.split(","))
    allowed = ("act", "base", "total")
    if not names or any(n not in allowed for n in names) or len(set(names)) != len(names):
        raise InputError(f"--channels {text!r}: expected distinct names from {', '.join(allowed)}, comma-separated")
    missing = [n for n in names if n not in data.channels]
    if missing:
        raise InputError(f"--channels {text!r}: the data have no {', '.join(missing)} channel (they hold {', '.join(data.channels)})")
    return names


def run(args: argparse.Namespace) -> int:
    from samii.outputs import OutputFolder
    from samii.sim.overrides import parse_overrides

    prog = "samii calibrate"
    folder = OutputFolder(args.out, OUTPUTS, overwrite=args.overwrite) if args.out else None
    if args.model is not None and Path(args.model).suffix.lower() != ".json":
        raise InputError(
            f"--model {args.model}: calibrate needs a parameter file (.json, e.g. samii_params.json or a calibrated_params.json), "
            "not an MJCF file, whose physics is not parametrised"
        )
    overrides = parse_overrides(args.set)
    from samii.calibrate.calibrate import calibrate
    from samii.sim.model import default_params, params_with_overrides, read_params_file

    base = read_params_file(args.model) if args.model else default_params()
    if overrides:
        base = params_with_overrides(base, overrides)
    from samii.calibrate.simulator import check_parameter_name

    for name in args.param:  # before the data are read: the name is the command line's, not the file's
        try:
            check_parameter_name(base, name)
        except ValueError as exc:
            raise InputError(f"--param {name}: {str(exc).split(': ', 1)[-1]}") from None
    for option, given in (("--start", args.start), ("--bound", args.bound)):
        unknown = sorted({name for name, _ in given} - set(args.param))
        if unknown:
            raise InputError(f"{option} {', '.join(unknown)}: not calibrated; {option} applies to the --param names ({', '.join(args.param)})")
    data = load_target(args.data)
    channels = _channels(args.channels, data) if args.channels is not None else None
    confirm = None
    if args.confirm:
        from samii.measure.excitation import SweptSine

        lo = max(0.1, float(data.freq_hz[0]))
        hi = min(40.0, float(data.freq_hz[-1]))
        if not lo < hi:
            raise InputError(f"--confirm: the data's band {data.freq_hz[0]:g}-{data.freq_hz[-1]:g} Hz leaves nothing of 0.1-40 Hz to sweep")
        confirm = SweptSine(start_hz=lo, stop_hz=hi)
    try:
        result = calibrate(
            data,
            args.param,
            base=base,
            start=dict(args.start),
            bounds=dict(args.bound),
            phase_weight=args.phase_weight,
            band_hz=tuple(args.band_hz) if args.band_hz else None,
            channels=channels,
            weighting=args.weighting,
            max_nfev=args.max_iterations,
            confirm=confirm,
            data_source=args.data,
        )
    except (KeyError, ValueError) as exc:  # the data's validation (too few frequencies, a zero response, ...): name the file
        if isinstance(exc, InputError):
            raise
        raise input_error_of(args.data, exc) from None
    written = []
    if folder is not None:
        with folder:
            _write_outputs(result, data, folder)
        written = folder.written
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


def _write_outputs(result, data, folder) -> None:
    """Report JSON, parameter file and overlay Bode plot, staged in ``folder`` (:class:`samii.outputs.OutputFolder`)."""
    from samii.viz.figures import pyplot, save_figure

    pyplot()  # on Agg: the figure below goes to a file

    from samii.calibrate.simulator import SimulatorFRF
    from samii.formats import write_text
    from samii.viz.fit_plot import plot_fit_overlay

    structure = SimulatorFRF(result.params, result.names)
    models = {"start": (structure, dict(result.start)), "calibrated": (structure, dict(result.values))}
    note = (
        f"data: {result.data_source}; calibrated: "
        + ", ".join(f"{n} = {result.values[n]:.4g}" for n in result.names)
        + f"; phase weight {result.phase_weight:g}"
    )
    if "gain.base" in result.names:
        note += "; xdd in the data's own unit: the model curves are multiplied by gain.base"
    fig = plot_fit_overlay(
        data,
        models,
        channels=result.channels,
        band_hz=result.band_hz,
        title="samii calibrate: linearised simulator against the data",
        note=note,
        n_model_points=300,
    )
    save_figure(fig, folder.path("calibration_bode.png"))
    write_text(folder.path("calibration.json"), result.to_json(indent=2) + "\n")
    result.write_params(folder.path("calibrated_params.json"))
