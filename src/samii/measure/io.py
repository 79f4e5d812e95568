"""Readers and writers for the file formats of DATA_FORMATS.md.

* time-series CSV  <->  :class:`~samii.measure.timeseries.TimeSeries`
* frequency-response CSV  <->  :class:`~samii.FrequencyResponse`
* the rig-era MATLAB ``.mat`` Bode layout  ->  :class:`~samii.FrequencyResponse`

CSV rules: optional leading comment lines starting with ``#`` (a line
``# key: value`` is metadata, other comment lines are ignored), then one header
row of comma-separated column names, then one row per sample. Blank lines are
ignored. A comment line after the header is an error.

A reader never guesses: every defect (missing column, non-uniform time,
non-positive or non-increasing frequency, NaN or infinite value, negative
magnitude, coherence outside 0...1, empty file, header without rows, ragged row,
non-numeric cell) raises one :class:`DataFormatError` naming the file, the line
and/or column and what was expected. Writers refuse to replace an existing file
unless ``overwrite=True``; they always write a temporary file in the target's
folder first and move it into place, so a reader never sees half a file.
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path
from typing import Literal, Mapping

import numpy as np

from samii.frequency_response import CHANNELS, FrequencyResponse
from samii.measure.timeseries import (
    OPTIONAL_COLUMNS,
    REQUIRED_COLUMNS,
    TIME_UNIFORMITY_RTOL,
    TimeSeries,
    first_nonuniform_step,
)

__all__ = [
    "DataFormatError",
    "MAT_CHANNELS",
    "MAT_FREQ_NAMES",
    "read_timeseries_csv",
    "write_timeseries_csv",
    "TimeSeriesCsvWriter",
    "read_frf_csv",
    "write_frf_csv",
    "read_mat_bode",
    "write_text",
]

# Significant digits written. Time and frequency get 15 so that a uniform grid
# stays uniform to far better than the 1e-6 the format demands (a 1e5 s record
# keeps 1e-10 s resolution); signals get 10, far finer than any DAQ's ADC.
_AXIS_FMT = "%.15g"
_VALUE_FMT = "%.10g"

#: Variable names of the rig-era .mat file per channel (notebook ch. 9, samiierr.m):
#: magnitude (linear) and phase (degrees).
MAT_CHANNELS: Mapping[str, tuple[str, str]] = {
    "act": ("mean_io_mr", "mean_io_ph"),
    "base": ("mean_a2_j2a_mr", "mean_a2_j2a_ph"),
}
#: Frequency-vector names tried, in this order, when the caller names none. The
#: notebook does not print the name; these are the usual ones for a vector in Hz.
MAT_FREQ_NAMES: tuple[str, ...] = ("freq_hz", "freq", "f", "frequency", "hz", "fr", "mean_io_f", "mean_io_freq")


class DataFormatError(ValueError):
    """A data file does not follow DATA_FORMATS.md.

    Attributes
    ----------
    path : pathlib.Path
    line : int or None
        1-based line of the file (CSV), if the defect sits on one line.
    column : str or None
        Column (CSV) or variable (.mat) name, if one is at fault.
    """

    def __init__(self, path, message: str, *, line: int | None = None, column: str | None = None):
        self.path = Path(path)
        self.line = line
        self.column = column
        where = str(self.path)
        if line is not None:
            where += f", line {line}"
        if column is not None:
            where += f", column {column!r}"
        super().__init__(f"{where}: {message}")


# --------------------------------------------------------------------------- CSV core


class _Table:
    """Parsed CSV: metadata, header, numeric data and the file line of every row."""

    def __init__(self, path: Path, metadata: dict[str, str], header: list[str], header_line: int, data: np.ndarray, lines: np.ndarray):
        self.path, self.metadata, self.header, self.header_line = path, metadata, header, header_line
        self.data, self.lines = data, lines

    def has(self, name: str) -> bool:
        return name in self.header

    def col(self, name: str) -> np.ndarray:
        return self.data[:, self.header.index(name)]

    def error(self, message: str, *, row: int | None = None, column: str | None = None) -> DataFormatError:
        line = None if row is None else int(self.lines[row])
        return DataFormatError(self.path, message, line=line, column=column)

    def require(self, names: tuple[str, ...]) -> None:
        missing = [n for n in names if n not in self.header]
        if missing:
            raise DataFormatError(
                self.path,
                f"missing required column{'s' if len(missing) > 1 else ''} {', '.join(map(repr, missing))}; "
                f"the header has {', '.join(map(repr, self.header))} (names are case-sensitive)",
                line=self.header_line,
            )


def _read_table(path) -> _Table:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise DataFormatError(path, f"expected UTF-8 text, got undecodable bytes ({exc.reason} at byte {exc.start})") from None
    metadata: dict[str, str] = {}
    header: list[str] | None = None
    header_line = 0
    data_lines: list[str] = []
    line_numbers: list[int] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            if header is not None:
                raise DataFormatError(path, "comment lines are allowed only before the header row", line=number)
            key, sep, value = line[1:].partition(":")
            if sep and key.strip():
                metadata[key.strip()] = value.strip()
            continue
        if header is None:
            header = [name.strip() for name in line.split(",")]
            header_line = number
            for k, name in enumerate(header):
                if not name:
                    raise DataFormatError(path, f"header cell {k + 1} is empty; expected a column name", line=number)
            dupes = sorted({n for n in header if header.count(n) > 1})
            if dupes:
                raise DataFormatError(path, f"duplicate column name(s) {', '.join(map(repr, dupes))} in the header", line=number)
            continue
        data_lines.append(line)
        line_numbers.append(number)
    if header is None:
        raise DataFormatError(path, "the file is empty; expected optional '#' comment lines, a header row and data rows")
    if not data_lines:
        raise DataFormatError(path, "the header is not followed by any data row", line=header_line)
    data = _parse_numbers(path, header, data_lines, line_numbers)
    nonfinite = ~np.isfinite(data)
    if np.any(nonfinite):
        row, col = np.argwhere(nonfinite)[0]
        raise DataFormatError(path, f"expected a finite number, got {data[row, col]!r}", line=line_numbers[row], column=header[col])
    return _Table(path, metadata, header, header_line, data, np.asarray(line_numbers))


def _parse_numbers(path: Path, header: list[str], lines: list[str], numbers: list[int]) -> np.ndarray:
    try:  # fast path: numpy's C parser
        return np.loadtxt(lines, delimiter=",", comments=None, ndmin=2, dtype=float).reshape(len(lines), len(header))
    except ValueError as exc:
        fast_error = exc
    for line, number in zip(lines, numbers):  # slow path: find and name the defect
        cells = line.split(",")
        if len(cells) != len(header):
            raise DataFormatError(path, f"expected {len(header)} comma-separated values (one per header column), got {len(cells)}", line=number)
        for name, cell in zip(header, cells):
            try:
                float(cell)
            except ValueError:
                raise DataFormatError(path, f"expected a number, got {cell.strip()!r}", line=number, column=name) from None
    raise DataFormatError(path, f"could not parse the data rows: {fast_error}")


def _check_metadata(metadata: Mapping[str, str]) -> list[str]:
    out = []
    for key, value in metadata.items():
        key, value = str(key), str(value)
        if not key.strip() or ":" in key or "\n" in key or "\r" in key:
            raise ValueError(f"metadata key {key!r} must be non-empty and contain no ':' or line break")
        if "\n" in value or "\r" in value:
            raise ValueError(f"metadata value of {key!r} must be a single line, got {value!r}")
        out.append(f"# {key.strip()}: {value.strip()}\n")
    return out


def _tmp_path(path: Path) -> Path:
    # a fresh name opened exclusively, so the file gets the user's umask (mkstemp would make it 0600)
    return path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(6)}.tmp"


def _refuse_existing(path: Path) -> FileExistsError:
    return FileExistsError(f"{path} exists; refusing to overwrite it (pass overwrite=True)")


def _commit(tmp: Path, path: Path, overwrite: bool) -> None:
    """Move the finished ``tmp`` into place; without ``overwrite`` never clobber ``path``."""
    try:
        if overwrite:
            os.replace(tmp, path)
        else:
            os.link(tmp, path)  # fails if the file appeared meanwhile: never clobbers
    except FileExistsError:
        raise _refuse_existing(path) from None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _write_atomic(path, text: str, overwrite: bool) -> Path:
    path = Path(path)
    if path.exists() and not overwrite:
        raise _refuse_existing(path)
    tmp = _tmp_path(path)
    try:
        with open(tmp, "x", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    _commit(tmp, path, overwrite)
    return path


def write_text(path, text: str, *, overwrite: bool = False) -> Path:
    """Write ``text`` to ``path`` atomically; refuse to replace an existing file unless ``overwrite``."""
    return _write_atomic(path, text, overwrite)


def _format_rows(rows: np.ndarray, formats: list[str]) -> str:
    """CSV text of a 2-D array, one printf format per column.

    One %-format over all values: 1.4x faster than ``np.savetxt``'s row loop.
    """
    if rows.size == 0:
        return ""
    line = ",".join(formats) + "\n"
    return (line * rows.shape[0]) % tuple(rows.ravel().tolist())


def _format_table(metadata: Mapping[str, str], columns: Mapping[str, np.ndarray], formats: list[str]) -> str:
    head = "".join(_check_metadata(metadata)) + ",".join(columns) + "\n"
    return head + _format_rows(np.column_stack(list(columns.values())), formats)


# --------------------------------------------------------------------------- time series


def read_timeseries_csv(path) -> TimeSeries:
    """Read a time-series CSV (DATA_FORMATS.md) into a :class:`TimeSeries`.

    Raises
    ------
    DataFormatError
        On any defect; the message names the file, line and/or column.
    """
    table = _read_table(path)
    table.require(REQUIRED_COLUMNS)
    t = table.col("t")
    if t.size < 2:
        raise table.error("a time series needs at least 2 samples, got 1", row=0)
    i = first_nonuniform_step(t)
    if i is not None:
        mean = (t[-1] - t[0]) / (t.size - 1)
        raise table.error(
            f"expected uniformly increasing time (relative spacing within {TIME_UNIFORMITY_RTOL:g} of the mean step "
            f"{mean:.9g} s), got a step of {t[i] - t[i - 1]:.9g} s from the previous row",
            row=i,
            column="t",
        )
    if table.has("spool"):
        spool = table.col("spool")
        bad = np.flatnonzero(np.abs(spool) > 1.0)
        if bad.size:
            raise table.error(f"expected a spool position in -1...1, got {spool[bad[0]]!r}", row=int(bad[0]), column="spool")
    standard = set(REQUIRED_COLUMNS) | set(OPTIONAL_COLUMNS)
    return TimeSeries(
        **{name: table.col(name) for name in REQUIRED_COLUMNS},
        **{name: table.col(name) for name in OPTIONAL_COLUMNS if table.has(name)},
        extra={name: table.col(name) for name in table.header if name not in standard},
        metadata=table.metadata,
    )


def write_timeseries_csv(ts: TimeSeries, path, *, overwrite: bool = False) -> Path:
    """Write ``ts`` as a time-series CSV: metadata lines, header, one row per sample.

    Columns: t, v, theta, accel, the optional columns present, then ``ts.extra``.
    Time with 15 significant digits, signals with 10.

    Raises
    ------
    FileExistsError
        If ``path`` exists and ``overwrite`` is False.
    """
    columns = ts.columns()
    formats = [_AXIS_FMT] + [_VALUE_FMT] * (len(columns) - 1)
    return _write_atomic(path, _format_table(ts.metadata, columns, formats), overwrite)


class TimeSeriesCsvWriter:
    """Write a time-series CSV chunk by chunk while a record is being made.

    Same file as :func:`write_timeseries_csv`: metadata lines, header, rows.
    Rows go to a temporary file in the target's folder; :meth:`close` moves it
    into place, :meth:`abort` (or an exception inside ``with``) deletes it, so
    a reader never sees half a record and a failed run leaves nothing behind.

    Parameters
    ----------
    path : path-like
    columns : sequence of str
        Column names after ``t``, in file order; must include v, theta, accel.
    metadata : mapping of str to str
    overwrite : bool
        Replace an existing file (checked now and again at :meth:`close`).

    Examples
    --------
    >>> with TimeSeriesCsvWriter(path, ["v", "theta", "accel"], {"sample_rate_hz": "1000"}) as w:  # doctest: +SKIP
    ...     for t, cols in chunks:
    ...         w.write(t, cols)
    """

    def __init__(self, path, columns, metadata: Mapping[str, str], *, overwrite: bool = False) -> None:
        self.path = Path(path)
        self.columns = [str(c) for c in columns]
        missing = [c for c in REQUIRED_COLUMNS if c != "t" and c not in self.columns]
        if missing or "t" in self.columns or len(set(self.columns)) != len(self.columns):
            raise ValueError(f"columns must name each of v, theta, accel once and not t, got {self.columns}")
        self.overwrite = overwrite
        if self.path.exists() and not overwrite:
            raise _refuse_existing(self.path)
        head = "".join(_check_metadata(metadata)) + ",".join(["t", *self.columns]) + "\n"
        self._formats = [_AXIS_FMT] + [_VALUE_FMT] * len(self.columns)
        self._tmp = _tmp_path(self.path)
        self._fh = open(self._tmp, "x", encoding="utf-8", newline="\n")
        self._fh.write(head)
        self._last_t: float | None = None
        self.rows = 0

    def write(self, t: np.ndarray, columns: Mapping[str, np.ndarray]) -> None:
        """Append rows: times ``t`` [s] and every column named at construction."""
        if self._fh is None:
            raise ValueError(f"{self.path}: the writer is closed")
        t = np.asarray(t, float)
        cols = [t]
        for name in self.columns:
            if name not in columns:
                raise ValueError(f"{self.path}: chunk has no column {name!r}")
            cols.append(np.asarray(columns[name], float))
        rows = np.column_stack(cols)
        bad = ~np.isfinite(rows)
        if bad.any():
            i, j = np.argwhere(bad)[0]
            name = (["t", *self.columns])[j]
            raise ValueError(f"{self.path}: non-finite value in column {name!r} at t = {t[i]!r}; the record is not written")
        if t.size and ((self._last_t is not None and t[0] <= self._last_t) or np.any(np.diff(t) <= 0)):
            raise ValueError(f"{self.path}: time must increase from chunk to chunk")
        self._fh.write(_format_rows(rows, self._formats))
        if t.size:
            self._last_t = float(t[-1])
        self.rows += t.size

    def close(self) -> Path:
        """Finish the file and move it into place; returns its path."""
        if self._fh is None:
            return self.path
        self._fh.close()
        self._fh = None
        if self.rows < 2:
            os.unlink(self._tmp)
            raise ValueError(f"{self.path}: a time series needs at least 2 samples, got {self.rows}; nothing written")
        _commit(self._tmp, self.path, self.overwrite)
        return self.path

    def abort(self) -> None:
        """Drop the partial file; nothing is written."""
        if self._fh is not None:
            self._fh.close()
            self._fh = None
        if os.path.exists(self._tmp):
            os.unlink(self._tmp)

    def __enter__(self) -> "TimeSeriesCsvWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


# --------------------------------------------------------------------------- frequency response


def read_frf_csv(path) -> FrequencyResponse:
    """Read a frequency-response CSV (DATA_FORMATS.md) into a :class:`~samii.FrequencyResponse`.

    Channels present as ``<ch>_mag`` (linear) and ``<ch>_phase_deg`` (wrapped or
    unwrapped), with optional ``<ch>_coh``. Other columns are ignored.

    Raises
    ------
    DataFormatError
        On any defect; the message names the file, line and/or column.
    """
    table = _read_table(path)
    table.require(("freq_hz",))
    f = table.col("freq_hz")
    bad = np.flatnonzero(f <= 0)
    if bad.size:
        raise table.error(f"expected a positive frequency, got {f[bad[0]]!r}", row=int(bad[0]), column="freq_hz")
    bad = np.flatnonzero(np.diff(f) <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise table.error(f"expected strictly increasing frequency, got {f[k]!r} after {f[k - 1]!r}", row=k, column="freq_hz")
    kw = {}
    for ch in CHANNELS:
        mag_name, ph_name, coh_name = f"{ch}_mag", f"{ch}_phase_deg", f"{ch}_coh"
        if table.has(mag_name) != table.has(ph_name):
            have, lack = (mag_name, ph_name) if table.has(mag_name) else (ph_name, mag_name)
            raise DataFormatError(table.path, f"column {have!r} needs its partner {lack!r}", line=table.header_line, column=lack)
        if not table.has(mag_name):
            if table.has(coh_name):
                raise DataFormatError(table.path, f"coherence without its channel: expected {mag_name!r} and {ph_name!r}", line=table.header_line, column=coh_name)
            continue
        mag = table.col(mag_name)
        bad = np.flatnonzero(mag < 0)
        if bad.size:
            raise table.error(f"expected a non-negative linear magnitude, got {mag[bad[0]]!r}", row=int(bad[0]), column=mag_name)
        phase_rad = np.unwrap(np.radians(table.col(ph_name)))
        kw[ch] = mag * np.exp(1j * phase_rad)
        if table.has(coh_name):
            coh = table.col(coh_name)
            bad = np.flatnonzero((coh < 0) | (coh > 1))
            if bad.size:
                raise table.error(f"expected a coherence in 0...1, got {coh[bad[0]]!r}", row=int(bad[0]), column=coh_name)
            kw[coh_name] = coh
    if not any(ch in kw for ch in CHANNELS):
        raise DataFormatError(
            table.path,
            "no channel found: expected at least one pair of columns act_mag/act_phase_deg, base_mag/base_phase_deg "
            "or total_mag/total_phase_deg",
            line=table.header_line,
        )
    return FrequencyResponse(f, metadata=table.metadata, **kw)


def write_frf_csv(frf: FrequencyResponse, path, *, overwrite: bool = False) -> Path:
    """Write ``frf`` as a frequency-response CSV (magnitude linear, phase unwrapped in degrees).

    Raises
    ------
    FileExistsError
        If ``path`` exists and ``overwrite`` is False.
    """
    columns: dict[str, np.ndarray] = {"freq_hz": frf.freq_hz}
    for ch in frf.channels:
        columns[f"{ch}_mag"] = np.abs(frf.response(ch))
        columns[f"{ch}_phase_deg"] = frf.phase_deg(ch)
        coh = frf.coherence(ch)
        if coh is not None:
            columns[f"{ch}_coh"] = np.clip(coh, 0.0, 1.0)  # FrequencyResponse allows 1e-9 of round-off
    formats = [_AXIS_FMT] + [_VALUE_FMT] * (len(columns) - 1)
    return _write_atomic(path, _format_table(frf.metadata, columns, formats), overwrite)


# --------------------------------------------------------------------------- MATLAB


def read_mat_bode(path, *, freq_name: str | None = None, freq_unit: Literal["hz", "rad/s"] = "hz") -> FrequencyResponse:
    """Read rig-era swept-sine Bode data from a MATLAB ``.mat`` file (v4 to v7.2).

    The notebook's cost function (ch. 9, ``samiierr.m``) names the vectors
    ``mean_io_mr``, ``mean_io_ph`` (actuator theta/v: linear magnitude, phase in
    degrees) and ``mean_a2_j2a_mr``, ``mean_a2_j2a_ph`` (base xdd/theta). At
    least one complete pair must be present. The notebook does not name the
    frequency vector: pass ``freq_name``, or the names in :data:`MAT_FREQ_NAMES`
    are tried in order.

    Parameters
    ----------
    path : path-like
    freq_name : str, optional
        Name of the frequency vector in the file.
    freq_unit : {"hz", "rad/s"}
        Unit of that vector.

    Raises
    ------
    DataFormatError
        Unreadable file, missing or malformed vector, bad frequency axis,
        negative magnitude, NaN or infinite values.
    """
    from scipy.io import loadmat  # scipy.io is slow to import; only needed here

    path = Path(path)
    if freq_unit not in ("hz", "rad/s"):
        raise ValueError(f"freq_unit must be 'hz' or 'rad/s', got {freq_unit!r}")
    try:
        mat = loadmat(path, squeeze_me=True)
    except NotImplementedError as exc:  # v7.3 files are HDF5
        raise DataFormatError(path, f"cannot read this MAT-file version ({exc}); save it with -v7 or earlier") from None
    except FileNotFoundError:
        raise
    except Exception as exc:  # scipy raises assorted types on garbage (MatReadError, IndexError, ...)
        raise DataFormatError(path, f"not a readable MATLAB .mat file ({exc})") from None
    names = sorted(k for k in mat if not k.startswith("__"))

    def vector(name: str) -> np.ndarray:
        try:
            arr = np.asarray(mat[name])
        except KeyError:
            raise DataFormatError(path, f"no variable {name!r}; the file holds {', '.join(names) or 'nothing'}", column=name) from None
        if arr.ndim != 1 or arr.size == 0 or not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
            raise DataFormatError(path, f"expected a non-empty real numeric vector, got dtype {arr.dtype} shape {arr.shape}", column=name)
        arr = arr.astype(float)
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            raise DataFormatError(path, f"expected finite numbers, got {arr[bad[0]]!r} at element {bad[0] + 1}", column=name)
        return arr

    if freq_name is None:
        found = [n for n in MAT_FREQ_NAMES if n in mat]
        if not found:
            raise DataFormatError(
                path,
                f"no frequency vector under the names tried ({', '.join(MAT_FREQ_NAMES)}); the file holds "
                f"{', '.join(names) or 'nothing'}: pass freq_name=",
            )
        freq_name = found[0]
    f = vector(freq_name)
    if freq_unit == "rad/s":
        f = f / (2.0 * np.pi)
    bad = np.flatnonzero(f <= 0)
    if bad.size:
        raise DataFormatError(path, f"expected positive frequencies, got {f[bad[0]]!r} at element {bad[0] + 1}", column=freq_name)
    bad = np.flatnonzero(np.diff(f) <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise DataFormatError(path, f"expected strictly increasing frequencies, got {f[k]!r} after {f[k - 1]!r} at element {k + 1}", column=freq_name)
    kw = {}
    for ch, (mag_name, ph_name) in MAT_CHANNELS.items():
        if (mag_name in mat) != (ph_name in mat):
            lack = ph_name if mag_name in mat else mag_name
            raise DataFormatError(path, f"the {ch} channel needs both {mag_name!r} and {ph_name!r}", column=lack)
        if mag_name not in mat:
            continue
        mag, ph = vector(mag_name), vector(ph_name)
        for name, arr in ((mag_name, mag), (ph_name, ph)):
            if arr.size != f.size:
                raise DataFormatError(path, f"expected {f.size} elements like {freq_name!r}, got {arr.size}", column=name)
        bad = np.flatnonzero(mag < 0)
        if bad.size:
            raise DataFormatError(path, f"expected a non-negative linear magnitude, got {mag[bad[0]]!r} at element {bad[0] + 1}", column=mag_name)
        kw[ch] = mag * np.exp(1j * np.unwrap(np.radians(ph)))
    if not kw:
        pairs = "; ".join(f"{m}/{p}" for m, p in MAT_CHANNELS.values())
        raise DataFormatError(path, f"no Bode data: expected the vectors {pairs}; the file holds {', '.join(names) or 'nothing'}")
    meta = {"source": f"MATLAB file {path.name}", "freq_vector": freq_name}
    meta.update({f"{ch}_vectors": "/".join(MAT_CHANNELS[ch]) for ch in kw})
    return FrequencyResponse(f, metadata=meta, **kw)
