"""``samii frf TIMESERIES.csv``: the closed-loop frequency response of a measured time series.

The excitation ``r`` is the instrument (H = S_ry / S_rv per record, DATA_FORMATS.md);
the repetition length of ``r`` is read off the data when the file has no
``# record_s:`` line (``samii.measure.records``), or given with ``--record-s``.
A stepped sine whose header states its schedule (as ``samii measure --method
stepped`` writes it) is estimated dwell by dwell as the measurement did.
Writes ``frf.csv`` (with coherence, ready for ``samii fit``) and ``bode.png``
into ``--out`` (:func:`samii.measure.frf_file.frf_of_file`, the library call). Imports nothing heavy at module level.
"""

from __future__ import annotations

import argparse

from samii.cli_args import add_band, add_json, add_out, add_overwrite, nonempty_path, positive_float

__all__ = ["add_arguments", "run"]


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


def run(args: argparse.Namespace) -> int:
    from samii.measure.frf_file import frf_of_file

    done = frf_of_file(args.timeseries, out=args.out, record_s=args.record_s, band_hz=args.band_hz, overwrite=args.overwrite)
    m, info = done.measured, done.to_dict()
    if args.json:
        from samii.json_output import dumps

        print(dumps(info, indent=2))
        return 0
    lay = m.layout
    if lay is None:
        print(f"samii frf: {args.timeseries}: {done.layout_text()}")
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
    for p in done.written:
        print(f"wrote {p}")
    return 0
