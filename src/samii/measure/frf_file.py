"""``samii frf``'s library call: a measured time series' closed-loop FRF (the excitation ``r`` as the instrument) with
the random error of every point, written as ``frf.csv`` (with coherence, ready for ``samii fit``) and ``bode.png``.

The repetition length of ``r`` is read off the data when the file has no ``# record_s:`` line
(:mod:`samii.measure.records`), or given; a stepped sine whose header states its schedule (as ``samii measure --method
stepped`` writes it) is estimated dwell by dwell as the measurement did (:mod:`samii.measure.measured`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from samii.errors import InputError
from samii.formats import csv_header, is_mat_file, read_timeseries_csv, write_frf_csv
from samii.outputs import OutputFolder
from samii.viz.bode_plot import bode_plot

__all__ = ["FrfOfFile", "frf_of_file", "read_measured", "OUTPUTS"]

#: The files written into ``out``.
OUTPUTS = ("frf.csv", "bode.png")


@dataclass(frozen=True)
class FrfOfFile:
    measured: object  #: samii.measure.measured.Measured: the FRF, each point's variance, the records' layout, warnings
    written: tuple[Path, ...] = ()  #: the files written

    def layout_text(self) -> str:
        """How the time series was cut: its records, or a stepped sine's dwells."""
        m = self.measured
        if m.layout is None:  # a stepped sine (samii.measure.measured.from_stepped)
            return f"a stepped sine of {m.frf.freq_hz.size} dwells (the windows its header's schedule places)"
        return f"{m.layout.n_records} records of {m.layout.record_s:.6g} s"

    def to_dict(self) -> dict:
        """The summary ``samii frf --json`` prints."""
        m = self.measured
        lay, frf = m.layout, m.frf
        records = None
        if lay is not None:
            records = {
                "record_s": lay.record_s,
                "start_s": lay.start_s,
                "n_records": lay.n_records,
                "operating_point_s": lay.baseline_s,
                "how": lay.how,
            }
        return {
            "source": m.source,
            "sample_rate_hz": m.sample_rate_hz,
            "records": records,
            "dwells": int(frf.freq_hz.size) if lay is None else None,
            "band_hz": [float(frf.freq_hz[0]), float(frf.freq_hz[-1])],
            "n_points": int(frf.freq_hz.size),
            "channels": list(frf.channels),
            "noise": m.noise_source,
            "amplitude_v": m.amplitude_v,
            "warnings": list(m.warnings),
            "written": [str(p) for p in self.written],
        }


def read_measured(path, *, record_s: float | None = None, band_hz=None):
    """A time-series CSV as :class:`samii.measure.measured.Measured`; InputError naming the file for what a user can fix."""
    from samii.measure.measured import load  # (lazy: imports scipy, only when called)

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
        read_timeseries_csv(p)  # raises, naming the file and the columns it lacks
    return load(p, band_hz=band_hz, record_s=record_s)


def frf_of_file(path, *, out, record_s: float | None = None, band_hz=None, overwrite: bool = False) -> FrfOfFile:
    """The FRF of the time series at ``path``, written into the folder ``out`` (checked before any work; all or
    nothing)."""

    folder = OutputFolder(out, OUTPUTS, overwrite=overwrite)
    done = FrfOfFile(read_measured(path, record_s=record_s, band_hz=tuple(band_hz) if band_hz else None))
    m = done.measured
    with folder:
        write_frf_csv(m.frf, folder.path("frf.csv"))
        title = f"{path}: {done.layout_text()}"
        if m.aliasing:  # (an aliased estimate looks like any noisy FRF: the figure says it, as the command does)
            title += f"\nALIASED: {m.sample_rate_hz:g} samples/s resolve only up to {m.sample_rate_hz / 2:g} Hz (see the command's warnings)"
        if m.layout is None:  # a stepped sine: its dwells as points, as samii measure draws them
            bode_plot(None, stepped=m.frf, title=title, path=folder.path("bode.png"))
        else:
            bode_plot(m.frf, title=title, path=folder.path("bode.png"))
    return replace(done, written=tuple(folder.written))
