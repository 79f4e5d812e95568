"""The time-series CSV format (DATA_FORMATS.md) <-> :class:`samii.timeseries.TimeSeries`."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from samii.formats.files import (
    _AXIS_FMT,
    _VALUE_FMT,
    DataFormatError,
    _cell,
    _check_metadata,
    _commit,
    _format_rows,
    _format_table,
    _num,
    _read_table,
    _refuse_existing,
    _remove_quietly,
    _short,
    _Table,
    _tmp_path,
    _write_atomic,
)
from samii.timeseries import (
    OPTIONAL_COLUMNS,
    REQUIRED_COLUMNS,
    TIME_UNIFORMITY_RTOL,
    TimeSeries,
    first_nonuniform_step,
    typical_step,
)

#: Relative tolerance of the time step against ``# sample_rate_hz:``: 1e-3. A
#: rate written by hand with 4 significant digits (or by ``%g``) passes; a time
#: column in ms, us or a rate in kHz (factors of 1000) or a decimated record
#: (a factor of 2 or more) does not.
SAMPLE_RATE_RTOL = 1e-3


def read_timeseries_csv(path) -> TimeSeries:
    """Read a time-series CSV (DATA_FORMATS.md) into a :class:`TimeSeries`.

    Raises
    ------
    DataFormatError
        On any defect; the message names the file, line and/or column.
    """
    table = _read_table(path, known=lambda name: name in REQUIRED_COLUMNS or name in OPTIONAL_COLUMNS)
    table.require(REQUIRED_COLUMNS)
    t = table.col("t")
    if t.size < 2:
        raise table.error("a time series needs at least 2 samples, got 1", row=0)
    i = first_nonuniform_step(t)
    if i is not None:
        ref, step = typical_step(t), float(t[i] - t[i - 1])
        if not ref > 0:
            message = f"expected increasing time, got a typical step of {_num(ref)} s (is 't' the time column?)"
        else:
            hint = ""
            if step <= 0:
                hint = "; the time repeats or runs backwards"
            elif step / ref >= 1.5 and abs(step / ref - round(step / ref)) < 0.1:
                missing = round(step / ref) - 1
                hint = f"; {missing} sample{'s' if missing > 1 else ''} missing?"
            elif _rounded_time(t, 2.0**-50):  # a time far from 0 (Unix time) in double precision: its rounding there
                hint = (
                    f"; t reaches {np.max(np.abs(t)):.6g} s (a clock's time, Unix time?), where a double-precision number "
                    f"keeps only {np.max(np.abs(t)) * 2.0**-52:.2g} s: write t from the first sample's time (t - t[0])"
                )
            elif _rounded_time(t):
                mean = (t[-1] - t[0]) / (t.size - 1)
                hint = (
                    f"; the steps scatter about {mean:.9g} s by no more than the rounding of 7 significant digits (single "
                    "precision): write t with more digits, or as the sample index over the sample rate"
                )
            message = (
                f"expected uniformly increasing time (every step within {TIME_UNIFORMITY_RTOL:g} of the typical step "
                f"{ref:.9g} s), got a step of {step:.9g} s from line {int(table.lines[i - 1])}{hint}"
            )
        raise table.error(message, row=i, column="t")
    _check_sample_rate(table, t)
    if table.has("spool"):
        spool = table.col("spool")
        bad = np.flatnonzero(np.abs(spool) > 1.0)
        if bad.size:
            raise table.error(f"expected a spool position in -1...1, got {_num(spool[bad[0]])}", row=int(bad[0]), column="spool")
    standard = set(REQUIRED_COLUMNS) | set(OPTIONAL_COLUMNS)
    try:
        return TimeSeries(
            **{name: table.col(name) for name in REQUIRED_COLUMNS},
            **{name: table.col(name) for name in OPTIONAL_COLUMNS if table.has(name)},
            extra={name: table.col(name) for name in table.header if name not in standard},
            metadata=table.metadata,
        )
    except ValueError as exc:  # the checks above should have said it first
        raise DataFormatError(table.path, str(exc)) from None


def _rounded_time(t: np.ndarray, eps: float = 2.0**-23) -> bool:
    """The steps of ``t`` differ from their mean by no more than rounding ``t`` to a precision of ``eps`` does: a few
    units of ``eps`` of the largest time (2^-23: a logger's float32 time stamps; 2^-50: double precision's few units)."""
    mean = (t[-1] - t[0]) / (t.size - 1)
    quantum = float(np.max(np.abs(t))) * eps
    return bool(mean > 0 and np.max(np.abs(np.diff(t) - mean)) <= 4.0 * quantum)


def stated_sample_rate(text: str | None) -> float | None:
    """The rate a ``# sample_rate_hz:`` value states: a plain number (no unit, no digit separators), else None."""
    if text is None or "_" in text:
        return None
    try:
        return float(text)
    except ValueError:
        return None


def _stated_rate(table: _Table) -> float | None:
    """The ``# sample_rate_hz:`` line's rate (None without one). Anything but a rate (text, "1 kHz", <= 0, nan, inf) is
    refused naming the line: an FRF header's "abc" was passed over without a word, its Nyquist check and a diagnosis'
    sampling model skipped."""
    text = table.metadata.get("sample_rate_hz")
    if text is None:
        return None
    rate = stated_sample_rate(text)
    if rate is None or not 0 < rate < float("inf"):  # (a sampling model divides by it)
        raise DataFormatError(
            table.path,
            f"expected '# sample_rate_hz:' to give a positive number of samples per second, got {_cell(text)}",
            line=table.metadata_lines.get("sample_rate_hz"),
        )
    return rate


def _check_sample_rate(table: _Table, t: np.ndarray) -> None:
    """The time step must agree with a ``# sample_rate_hz:`` line, if there is one."""
    rate = _stated_rate(table)
    if rate is None:
        return
    text = table.metadata["sample_rate_hz"]
    line = table.metadata_lines.get("sample_rate_hz")
    dt = typical_step(t)
    ratio = dt * rate
    if abs(ratio - 1.0) <= SAMPLE_RATE_RTOL:
        return

    def near(x):
        return abs(ratio / x - 1.0) < 0.01

    if near(1e3):
        hint = "is the time in ms?"
    elif near(1e6):
        hint = "is the time in us?"
    elif near(1e-3):
        hint = "is the rate in kHz?"
    elif ratio > 1.5 and abs(ratio - round(ratio)) < 0.01 * ratio:
        hint = f"was the record decimated by {round(ratio)}, or is the rate wrong?"
    else:
        hint = "which of the two is wrong?"
    raise DataFormatError(
        table.path,
        f"the time column steps by {dt:.9g} s but '# sample_rate_hz: {_short(text)}' (line {line}) says {1.0 / rate:.9g} s; {hint}",
        line=line,
        column="t",
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
        self._last_t: float | None = None
        self.rows = 0
        self._fh = None
        self._tmp = _tmp_path(self.path)
        try:
            self._fh = open(self._tmp, "x", encoding="utf-8", newline="\n")
            self._fh.write(head)
        except BaseException:  # no object to abort: clean up here
            self.abort()
            raise

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
            raise ValueError(f"{self.path}: non-finite value in column {name!r} at t = {_num(t[i])} s; the record is not written")
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
        try:
            fh, self._fh = self._fh, None
            fh.close()
            if self.rows < 2:
                raise ValueError(f"{self.path}: a time series needs at least 2 samples, got {self.rows}; nothing written")
            _commit(self._tmp, self.path, self.overwrite)
        finally:
            _remove_quietly(self._tmp)
        return self.path

    def abort(self) -> None:
        """Drop the partial file; nothing is written."""
        try:
            if self._fh is not None:
                fh, self._fh = self._fh, None
                fh.close()
        finally:
            _remove_quietly(self._tmp)

    def __del__(self) -> None:  # a writer dropped without close() or abort(): leave no temporary file
        try:
            if getattr(self, "_fh", None) is not None:
                self.abort()
        except Exception:
            pass

    def __enter__(self) -> TimeSeriesCsvWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
