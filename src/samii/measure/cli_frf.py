"""``samii frf TIMESERIES.csv``: the closed-loop frequency response of a measured time series.

The excitation ``r`` is the instrument (H = S_ry / S_rv per record, DATA_FORMATS.md);
the repetition length of ``r`` is read off the data when the file has no
``# record_s:`` line (``samii.measure.records``), or given with ``--record-s``.
A stepped sine whose header states its schedule (as ``samii measure --method
stepped`` writes it) is estimated dwell by dwell as the measurement did.
Writes ``frf.csv`` (with coherence, ready for ``samii fit``) and ``bode.png``
into ``--out``. Imports nothing heavy at module level.
"""

from __future__ import annotations

import argparse

from samii.cli_args import add_band, add_json, add_out, add_overwrite, nonempty_path, positive_float
from samii.errors import InputError

__all__ = ["add_arguments", "run"]

OUTPUTS = ("frf.csv", "bode.png")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "timeseries", metavar="TIMESERIES", type=nonempty_path, help="time-series CSV (DATA_FORMATS.md: t, v, theta, accel and the excitation r)"
    )
    add_out(parser, "output folder (default frf_out)", default="frf_out")
    parser.add_argument(
        "--record-s",
        type=positive_float,
        metavar="S",
        help="length of one repetition of the excitation [s] (default: the file's record_s line, else found from r)",
    )
    add_band(parser, "frequency band (default: the file's start_hz/stop_hz, else 0.1-40 Hz below 0.45 x the sample rate)")
    add_overwrite(parser, "replace files already in --out")
    add_json(parser, "print the summary as JSON")


def read_measured(path: str, *, record_s: float | None, band_hz):
    """A time-series CSV as :class:`samii.diagnose.measured.Measured`; InputError naming the file for what a user can fix."""
    from pathlib import Path

    from samii.diagnose.measured import load
    from samii.formats import csv_header, is_mat_file

    p = Path(path)
    if is_mat_file(p):
        raise InputError(f"{path}: a MATLAB file; samii frf expects a time-series CSV (t, v, theta, accel, r)")
    header = csv_header(p)
    if "freq_hz" in header and "t" not in header:
        raise InputError(
            f"{path}: this is already a frequency response (columns {', '.join(header[:4])}, ...); samii frf expects a time series "
            "(t, v, theta, accel, r), as samii measure writes timeseries.csv"
        )
    if "t" not in header:
        from samii.formats import read_timeseries_csv

        read_timeseries_csv(p)  # raises, naming the file and the columns it lacks
    return load(p, band_hz=band_hz, record_s=record_s)


def _layout_line(m) -> str:
    """How the time series was cut: its records, or a stepped sine's dwells."""
    lay = m.layout
    if lay is None:  # a stepped sine (samii.diagnose.measured.from_stepped)
        return f"a stepped sine of {m.frf.freq_hz.size} dwells (the windows its header's schedule places)"
    return f"{lay.n_records} records of {lay.record_s:.6g} s"


def summary(m) -> dict:
    lay = m.layout
    frf = m.frf
    return {
        "source": m.source,
        "sample_rate_hz": m.sample_rate_hz,
        "records": None
        if lay is None
        else {"record_s": lay.record_s, "start_s": lay.start_s, "n_records": lay.n_records, "operating_point_s": lay.baseline_s, "how": lay.how},
        "dwells": int(frf.freq_hz.size) if lay is None else None,
        "band_hz": [float(frf.freq_hz[0]), float(frf.freq_hz[-1])],
        "n_points": int(frf.freq_hz.size),
        "channels": list(frf.channels),
        "noise": m.noise_source,
        "amplitude_v": m.amplitude_v,
        "warnings": list(m.warnings),
    }


def run(args: argparse.Namespace) -> int:
    from samii.outputs import OutputFolder

    band = tuple(args.band_hz) if args.band_hz else None
    folder = OutputFolder(args.out, OUTPUTS, overwrite=args.overwrite)
    m = read_measured(args.timeseries, record_s=args.record_s, band_hz=band)
    from samii.formats import write_frf_csv
    from samii.viz.bode_plot import bode_plot

    with folder:
        write_frf_csv(m.frf, folder.path("frf.csv"))
        title = f"{args.timeseries}: {_layout_line(m)}"
        if m.aliasing:  # (an aliased estimate looks like any noisy FRF: the figure says it, as the command does)
            title += f"\nALIASED: {m.sample_rate_hz:g} samples/s resolve only up to {m.sample_rate_hz / 2:g} Hz (see the command's warnings)"
        if m.layout is None:  # a stepped sine: its dwells as points, as samii measure draws them
            bode_plot(None, stepped=m.frf, title=title, path=folder.path("bode.png"))
        else:
            bode_plot(m.frf, title=title, path=folder.path("bode.png"))
    info = summary(m)
    info["written"] = [str(p) for p in folder.written]
    if args.json:
        from samii.json_output import dumps

        print(dumps(info, indent=2))
        return 0
    lay = m.layout
    if lay is None:
        print(f"samii frf: {args.timeseries}: {_layout_line(m)}")
        print(f"  {info['n_points']} points, {info['band_hz'][0]:.3g}-{info['band_hz'][1]:.3g} Hz, channels {', '.join(info['channels'])}")
    else:
        print(f"samii frf: {args.timeseries}: {lay.n_records} records of {lay.record_s:.6g} s from t = {lay.start_s:.6g} s ({lay.how})")
        print(
            f"  operating point: the first {lay.baseline_s:.3g} s of each record; band {info['band_hz'][0]:.3g}-{info['band_hz'][1]:.3g} Hz, "
            f"{info['n_points']} points, channels {', '.join(info['channels'])}"
        )
    print(f"  noise: {m.noise_source}")
    for w in m.warnings:
        print(f"samii frf: warning: {w}")
    for p in folder.written:
        print(f"wrote {p}")
    return 0
