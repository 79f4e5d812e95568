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
and/or column and what was expected. :class:`DataFormatError` is a
:class:`samii.errors.InputError`, so the command line reports it as bad input
(exit 2) in one line.

Beyond DATA_FORMATS.md the readers also refuse, with the same kind of message:

* anything that is not a regular file (a folder, a named pipe, a socket, a
  device such as ``/dev/zero``) and a file larger than :data:`MAX_FILE_BYTES`,
  a CSV of more than :data:`MAX_LINES` lines or with a line longer than
  :data:`MAX_LINE_CHARS` (so no input can hang a reader or exhaust memory);
  binary data and text that is not UTF-8 (a UTF-8 byte-order mark, as Excel
  writes, is accepted; so are Windows and old-Mac line endings); the temporary
  files of an interrupted write (``.NAME.PID.TOKEN.tmp``);
* numbers no measurement produces (see :data:`MAX_ABS_VALUE`,
  :data:`MAG_RANGE`, :data:`MAX_ABS_PHASE_DEG`, :data:`MAX_FREQ_HZ`), and a time
  column whose step disagrees with a ``# sample_rate_hz:`` line.

Writers refuse to replace an existing file unless ``overwrite=True``; they
always write a temporary file in the target's folder first and move it into
place, so a reader never sees half a file, and remove it whatever goes wrong
(Ctrl-C included).
"""

from __future__ import annotations

import io
import os
import re
import secrets
import stat
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Literal

import numpy as np

from samii.errors import InputError
from samii.frequency_response import CHANNELS, FrequencyResponse
from samii.measure.timeseries import (
    OPTIONAL_COLUMNS,
    REQUIRED_COLUMNS,
    TIME_UNIFORMITY_RTOL,
    TimeSeries,
    first_nonuniform_step,
    typical_step,
)

__all__ = [
    "DataFormatError",
    "csv_header",
    "file_head",
    "is_mat_file",
    "MAG_RANGE",
    "MAT_CHANNELS",
    "MAX_ABS_PHASE_DEG",
    "MAX_ABS_VALUE",
    "MAX_FILE_BYTES",
    "MAX_FREQ_HZ",
    "MAX_LINE_CHARS",
    "MAX_LINES",
    "MAT_TIMEOUT_S",
    "SAMPLE_RATE_RTOL",
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

#: Largest file a reader takes [bytes]: 256 MiB. A rig record of 8 columns is
#: about 110 bytes a row, so this is some 40 minutes at 1 kHz (4 at 10 kHz);
#: the CSV reader holds the text, its lines and the numbers at once (about 5
#: times the file), so a larger file is better split into records or decimated.
MAX_FILE_BYTES = 256 * 2**20
#: Longest CSV line [characters]: 1 Mi. A header or row of a thousand columns is
#: some 25 k characters; a longer line is binary data or a file without line breaks.
MAX_LINE_CHARS = 2**20
#: Most lines in a CSV: 10 million (2.8 hours at 1 kHz). The parser keeps one
#: Python string per line (some 60 bytes each, however short the line), so a
#: file of short lines could otherwise take 20 times its size in memory.
MAX_LINES = 10_000_000
#: Largest magnitude of any number in a CSV cell or .mat vector: 1e100. No
#: measured quantity in SI units comes near it (a load pressure is ~1e7 Pa),
#: and it keeps squares and products (power spectra, the fit's cost) far from
#: float overflow (1.8e308: 1e300 squared is inf).
MAX_ABS_VALUE = 1e100
#: Range of a linear FRF magnitude: 1e-20...1e20 (-400...+400 dB). SAMII's
#: channels lie within about 1e-4...1e4 in SI units; the range leaves 16 orders
#: of margin either way and refuses what has no dB value (0) or no meaning
#: (1e300, whose square overflows). The fit works on 20*log10|H|.
MAG_RANGE = (1e-20, 1e20)
#: Largest |phase| [deg]: 1e5 (about 280 turns). Each pole or zero turns the
#: phase by at most 90 deg and a delay tau by 360*f*tau: SAMII's channels (a
#: few poles, millisecond delays, below 1 kHz) stay within a few thousand
#: degrees even unwrapped; 1e5 deg would take a 0.28 s delay at 1 kHz. A phase
#: beyond it is a corrupt cell or a unit slip, not a measured phase.
MAX_ABS_PHASE_DEG = 1e5
#: Highest frequency [Hz]: 1 MHz. Hydraulics, beam and sensors carry nothing
#: above tens of kHz; beyond 1 MHz a frequency axis is corrupt or in the wrong unit.
MAX_FREQ_HZ = 1e6
#: Relative tolerance of the time step against ``# sample_rate_hz:``: 1e-3. A
#: rate written by hand with 4 significant digits (or by ``%g``) passes; a time
#: column in ms, us or a rate in kHz (factors of 1000) or a decimated record
#: (a factor of 2 or more) does not.
SAMPLE_RATE_RTOL = 1e-3

_BOM = b"\xef\xbb\xbf"
# the writers' temporary files: see _tmp_path
_TMP_NAME = re.compile(r"\..+\.\d+\.[0-9a-f]{12}\.tmp")
_SHOW = 40  # characters of a cell or name shown in a message


def _show_path(path: Path) -> str:
    text = str(path)
    return text if text.isprintable() else repr(text)


def _num(x) -> str:
    """A number for a message: ``0.16``, ``1e+300``, ``nan``; never ``np.float64(0.16)``."""
    x = float(x)
    text = f"{x:.12g}"
    return text if float(text) == x or x != x else repr(x)


def _short(text: str) -> str:
    """A cell, name or metadata value for a message, cut to a readable length."""
    text = text.strip()
    return text if len(text) <= _SHOW else text[:_SHOW] + f"... ({len(text)} characters)"


def _cell(text: str) -> str:
    """repr of a cell or name for a message, cut to a readable length."""
    text = text.strip()
    return repr(text) if len(text) <= _SHOW else repr(text[:_SHOW]) + f"... ({len(text)} characters)"


def _names(names) -> str:
    names = list(names)
    shown = ", ".join(_cell(n) for n in names[:12])
    return shown + (f", ... ({len(names) - 12} more)" if len(names) > 12 else "")


class DataFormatError(InputError):
    """A data file does not follow DATA_FORMATS.md (or cannot be read at all).

    An :class:`samii.errors.InputError` (so a ``ValueError``): the command line
    reports it in one line and exits with code 2.

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
        where = _show_path(self.path)
        if line is not None:
            where += f", line {line}"
        if column is not None:
            where += f", column {_cell(column)}"
        message = re.sub(r"\s*[\r\n]+\s*", " ", str(message)).strip()  # one line, whatever a library said
        super().__init__(f"{where}: {message}")


# --------------------------------------------------------------------------- reading a file


def _file_kind(mode: int) -> str | None:
    """What a non-regular file is, for a message; None for a regular file."""
    if stat.S_ISREG(mode):
        return None
    for test, name in (
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISFIFO, "a named pipe (FIFO)"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def _size(n: int) -> str:
    return f"{n / 2**20:.1f} MiB" if n >= 2**20 else f"{n} bytes"


def _too_big(path: Path, size: int | None) -> DataFormatError:
    got = f"is {_size(size)}" if size is not None else "grew beyond that while being read"
    return DataFormatError(
        path, f"the file {got}; the readers take at most {_size(MAX_FILE_BYTES)} (samii.measure.io.MAX_FILE_BYTES): split the record or decimate it"
    )


def _read_bytes(path) -> bytes:
    """The bytes of a regular file of at most MAX_FILE_BYTES; DataFormatError for anything else.

    Never blocks on a FIFO (opened non-blocking, then checked) and never reads
    more than MAX_FILE_BYTES + 1 bytes, whatever the file is.
    """
    path = Path(path)
    if _TMP_NAME.fullmatch(path.name):
        raise DataFormatError(
            path,
            "is a temporary file of a write that was interrupted (.NAME.PID.TOKEN.tmp) and may be "
            "incomplete; read the finished file, or delete this one",
        )
    try:
        st = os.stat(path)
    except FileNotFoundError:
        folder = path.parent
        raise DataFormatError(path, "file not found" if folder.is_dir() else f"file not found (folder {_show_path(folder)} does not exist)") from None
    except NotADirectoryError:
        raise DataFormatError(path, "file not found (a part of the path is a file, not a folder)") from None
    except PermissionError:
        raise DataFormatError(path, "cannot be read: permission denied on a folder of its path") from None
    except ValueError as exc:  # an embedded NUL
        raise DataFormatError(path, f"is not a valid file name ({exc})") from None
    except OSError as exc:
        raise DataFormatError(path, f"cannot be read ({exc.strerror or exc})") from None
    kind = _file_kind(st.st_mode)
    if kind is not None:
        raise DataFormatError(path, f"is {kind}; expected a regular file")
    if st.st_size > MAX_FILE_BYTES:
        raise _too_big(path, st.st_size)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except PermissionError:
        raise DataFormatError(path, "is not readable (permission denied)") from None
    except OSError as exc:
        raise DataFormatError(path, f"cannot be opened ({exc.strerror or exc})") from None
    with io.FileIO(fd, "rb", closefd=True) as fh:
        try:
            kind = _file_kind(os.fstat(fd).st_mode)  # the file opened may not be the one checked
            if kind is not None:
                raise DataFormatError(path, f"is {kind}; expected a regular file")
            chunks, size = [], 0
            while size <= MAX_FILE_BYTES:
                chunk = fh.read(min(MAX_FILE_BYTES + 1 - size, 16 * 2**20))
                if not chunk:
                    break
                chunks.append(chunk)
                size += len(chunk)
        except OSError as exc:
            raise DataFormatError(path, f"cannot be read ({exc.strerror or exc})") from None
    if size > MAX_FILE_BYTES:  # it grew since stat
        raise _too_big(path, None)
    return b"".join(chunks)


def _line_and_char(data: bytes, offset: int) -> tuple[int, int]:
    """1-based line and character of byte ``offset`` in ``data``, line breaks counted as _decode makes them."""
    head = data[:offset]
    line = head.count(b"\n") + head.count(b"\r") - head.count(b"\r\n") + 1  # \r\n, \r and \n each end a line
    start = max(head.rfind(b"\n"), head.rfind(b"\r")) + 1
    return line, len(head[start:].decode("utf-8", errors="replace")) + 1


# signatures of files that are often taken for a CSV
_MAGIC = (
    (b"MATLAB", "a MATLAB .mat file"),
    (b"\x89HDF", "an HDF5 file (a MATLAB v7.3 .mat?)"),
    (b"PK\x03\x04", "a zip archive (an Excel .xlsx workbook?)"),
    (b"\xd0\xcf\x11\xe0", "an Excel .xls workbook"),
)


def _decode(path: Path, data: bytes) -> str:
    """UTF-8 text of a CSV, BOM dropped, line endings made ``\\n``; DataFormatError if it is no text."""
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise DataFormatError(path, "is UTF-16 text (Excel's 'Unicode text'); expected UTF-8: save it as 'CSV UTF-8'")
    if data.startswith(_BOM):
        data = data[len(_BOM) :]
    for magic, what in _MAGIC:
        if data.startswith(magic):
            raise DataFormatError(path, f"is {what}; expected comma-separated text")
    nul = data.find(b"\x00")
    if nul >= 0:
        line, char = _line_and_char(data, nul)
        raise DataFormatError(path, f"holds binary data (a NUL byte at character {char}); expected comma-separated text", line=line)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line, char = _line_and_char(data, exc.start)
        raise DataFormatError(
            path,
            f"expected UTF-8 text, got the byte 0x{data[exc.start]:02x} at character {char} (Latin-1 or Windows-1252 text? save the file as UTF-8)",
            line=line,
        ) from None
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    return text


# --------------------------------------------------------------------------- CSV core


class _Table:
    """Parsed CSV: metadata, header, numeric data and the file line of every row."""

    def __init__(
        self,
        path: Path,
        metadata: dict[str, str],
        header: list[str],
        header_line: int,
        data: np.ndarray,
        lines: np.ndarray,
        metadata_lines: dict[str, int] | None = None,
    ):
        self.path, self.metadata, self.header, self.header_line = path, metadata, header, header_line
        self.data, self.lines = data, lines
        self.metadata_lines = metadata_lines or {}

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
            hint = ""
            if any(len(n) >= 2 and n[0] == n[-1] and n[0] in "\"'" for n in self.header):
                hint = "; column names are not quoted in this format"
            raise DataFormatError(
                self.path,
                f"missing required column{'s' if len(missing) > 1 else ''} {', '.join(map(repr, missing))}; "
                f"the header has {_names(self.header)} (names are case-sensitive){hint}",
                line=self.header_line,
            )


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return "_" not in text


def _read_table(path, known: Callable[[str], bool] | None = None) -> _Table:
    """The file's metadata, header and numbers. ``known``: the columns the format defines; any other column is ignored
    (DATA_FORMATS.md) and, when it holds anything but finite numbers (a text note, a NaN of a logger's spare channel),
    left out of the table instead of refusing the file (None: every column is checked)."""
    path = Path(path)
    text = _decode(path, _read_bytes(path))
    if not text.strip():
        raise DataFormatError(path, "the file is empty; expected optional '#' comment lines, a header row and data rows")
    n_lines = text.count("\n") + 1
    if n_lines > MAX_LINES:
        raise DataFormatError(
            path, f"the file has {n_lines} lines; the readers take at most {MAX_LINES} (samii.measure.io.MAX_LINES): split the record or decimate it"
        )
    all_lines = text.split("\n")
    del text
    if max(map(len, all_lines)) > MAX_LINE_CHARS:
        k = next(k for k, line in enumerate(all_lines) if len(line) > MAX_LINE_CHARS)
        raise DataFormatError(
            path,
            f"the line is {len(all_lines[k])} characters long; expected at most {MAX_LINE_CHARS} "
            "(samii.measure.io.MAX_LINE_CHARS): is this a CSV file with line breaks?",
            line=k + 1,
        )
    metadata: dict[str, str] = {}
    metadata_lines: dict[str, int] = {}
    header: list[str] | None = None
    header_line = 0
    data_lines: list[str] = []
    line_numbers: list[int] = []
    for number, raw in enumerate(all_lines, start=1):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            if header is not None:
                raise DataFormatError(path, "comment lines are allowed only before the header row", line=number)
            key, sep, value = line[1:].partition(":")
            if sep and key.strip():
                metadata[key.strip()] = value.strip()
                metadata_lines[key.strip()] = number
            continue
        if header is None:
            header = [name.strip() for name in line.split(",")]
            header_line = number
            if len(header) == 1:  # both formats need 2 columns or more
                for sep, name in ((";", "';'"), ("\t", "tabs"), ("|", "'|'")):
                    if sep in line:
                        raise DataFormatError(path, f"the header {_cell(line)} seems separated by {name}; expected commas", line=number)
            if all(_is_number(name) for name in header):
                raise DataFormatError(
                    path, f"the first row holds numbers ({_cell(line)}); expected a header row of column names before the data", line=number
                )
            for k, name in enumerate(header):
                if not name:
                    raise DataFormatError(path, f"header cell {k + 1} is empty; expected a column name", line=number)
            dupes = sorted(n for n, count in Counter(header).items() if count > 1)  # not header.count: O(n^2) on a huge header
            if dupes:
                raise DataFormatError(path, f"duplicate column name(s) {_names(dupes)} in the header", line=number)
            plain = _plain_rows(all_lines, number)
            if plain is not None:  # every line after the header a data row as it stands: no loop over them
                data_lines, line_numbers = plain
                break
            continue
        data_lines.append(line)
        line_numbers.append(number)
    del all_lines
    if header is None:
        raise DataFormatError(path, "the file is empty apart from comment lines; expected a header row and data rows after them")
    if not data_lines:
        raise DataFormatError(path, "the header is not followed by any data row", line=header_line)
    other = [] if known is None else [name for name in header if not known(name)]
    data, header = _parse_numbers(path, header, data_lines, line_numbers, other)
    bad = ~(np.abs(data) <= MAX_ABS_VALUE)  # NaN, inf and absurd values at once
    if other and np.any(bad):  # an ignored column that is not all numbers is left out, not refused
        drop = {header[c] for c in np.flatnonzero(np.any(bad, axis=0)) if header[c] in other}
        if drop:
            keep = [c for c, name in enumerate(header) if name not in drop]
            data, header = data[:, keep], [header[c] for c in keep]
            bad = bad[:, keep]
            data_lines = [",".join(cells[c] for c in keep) for cells in (line.split(",") for line in data_lines)]
    if np.any(bad):
        row, col = np.argwhere(bad)[0]
        cell = data_lines[row].split(",")[col]
        if np.isfinite(data[row, col]):
            message = f"expected a number within +-{MAX_ABS_VALUE:g} (no measurement comes near it), got {_cell(cell)}"
        else:
            message = f"expected a finite number, got {_cell(cell)}"
        raise DataFormatError(path, message, line=line_numbers[row], column=header[col])
    return _Table(path, metadata, header, header_line, data, np.asarray(line_numbers), metadata_lines)


def _plain_rows(all_lines: list[str], header_line: int) -> tuple[list[str], np.ndarray] | None:
    """The lines after the header (``header_line``, 1-based) and their numbers when every one of them is a data row as it
    stands (no blank or comment line, no space around it; blank lines at the end dropped), found with string searches
    over them at once; else None (the reader's loop takes each line as it comes)."""
    end = len(all_lines)
    while end > header_line and not all_lines[end - 1].strip():
        end -= 1
    body = all_lines[header_line:end]
    if not body:
        return None
    text = "\n".join(body)
    # (plain ASCII: no other space str.strip would take off)
    if not text.isascii() or any(c in text for c in ("#", "\n\n", " ", "\t", "\f", "\v")):
        return None
    return body, np.arange(header_line + 1, end + 1)


def _loadtxt(lines: list[str]) -> np.ndarray:
    return np.loadtxt(lines, delimiter=",", comments=None, ndmin=2, dtype=float)


def _parse_numbers(path: Path, header: list[str], lines: list[str], numbers: list[int], other: Sequence[str] = ()) -> tuple[np.ndarray, list[str]]:
    """The rows' numbers and the header of their columns: ``other`` columns (ignored by the format) that do not parse are
    left out; any other defect is refused, naming its line and column."""
    try:  # fast path: numpy's C parser
        return _loadtxt(lines).reshape(len(lines), len(header)), header
    except ValueError:
        pass
    n = len(header)
    if other:
        bad_rows = [number for line, number in zip(lines, numbers) if line.count(",") != n - 1]
        if not bad_rows:
            cells = [line.split(",") for line in lines]
            drop = {c for c, name in enumerate(header) if name in other and not all(_is_number(row[c]) for row in cells)}
            if drop:
                keep = [c for c in range(n) if c not in drop]
                kept_lines = [",".join(row[c] for c in keep) for row in cells]
                data, _ = _parse_numbers(path, [header[c] for c in keep], kept_lines, numbers)
                return data, [header[c] for c in keep]
    for line, number in zip(lines, numbers):  # slow path: find and name the defect
        if line.count(",") != n - 1:
            got = line.count(",") + 1
            hint = ""
            if got == 1:
                for sep, name in ((";", "';'"), ("\t", "tabs")):
                    if sep in line:
                        hint = f"; the row seems separated by {name}"
                        break
            raise DataFormatError(path, f"expected {n} comma-separated values (one per header column), got {got}{hint}", line=number)
        for name, cell in zip(header, line.split(",")):
            if not _is_number(cell):
                raise DataFormatError(path, f"expected a number, got {_cell(cell)}", line=number, column=name)
    # every cell is a number to Python but not to numpy's parser: find the first row it refuses
    lo, hi = 0, len(lines)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        try:
            _loadtxt(lines[lo:mid])
            lo = mid
        except ValueError:
            hi = mid
    row = lines[lo]
    for name, cell in zip(header, row.split(",")):
        try:
            _loadtxt([cell])
        except ValueError:
            raise DataFormatError(path, f"expected a number, got {_cell(cell)}", line=numbers[lo], column=name) from None
    raise DataFormatError(path, "expected a row of numbers; the row cannot be parsed", line=numbers[lo])


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
    # a fresh name opened exclusively, so the file gets the user's umask (mkstemp would make it 0600);
    # the readers refuse names of this pattern (_TMP_NAME): a stale one is never taken for data
    return path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(6)}.tmp"


def _refuse_existing(path: Path) -> FileExistsError:
    # the library cannot know how its caller spells the choice: name both
    return FileExistsError(f"{_show_path(path)} exists; refusing to overwrite it unless asked to (overwrite=True / --overwrite)")


def _remove_quietly(tmp: Path) -> None:
    try:
        os.unlink(tmp)
    except FileNotFoundError:
        pass


def _commit(tmp: Path, path: Path, overwrite: bool) -> None:
    """Move the finished ``tmp`` into place; without ``overwrite`` never clobber ``path``.

    ``tmp`` is gone afterwards, whether this succeeds or raises (Ctrl-C included).
    """
    try:
        if overwrite:
            os.replace(tmp, path)
        else:
            os.link(tmp, path)  # fails if the file appeared meanwhile: never clobbers
    except FileExistsError:
        raise _refuse_existing(path) from None
    finally:
        _remove_quietly(tmp)


def _write_atomic(path, text: str, overwrite: bool) -> Path:
    path = Path(path)
    if path.exists() and not overwrite:
        raise _refuse_existing(path)
    tmp = _tmp_path(path)
    try:  # one try from the creation on: no exception (KeyboardInterrupt included) leaves tmp behind
        with open(tmp, "x", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
        _commit(tmp, path, overwrite)
    except OSError as exc:
        if exc.filename is None:  # a failed write (a full disk) names no file: name the one being written
            raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None
        raise
    finally:
        _remove_quietly(tmp)
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


# --------------------------------------------------------------------------- what a file is


def file_head(path: Path, size: int = 65536) -> bytes:
    """The first ``size`` bytes of a regular file (never opens a FIFO or a device), else b""."""
    if not path.is_file():
        return b""
    try:
        with open(path, "rb") as fh:
            return fh.read(size)
    except OSError:
        return b""


def is_mat_file(path: Path) -> bool:
    """The header of a MATLAB v5+ file under any name, or a .mat suffix on a file that is not text (a v4 file has no
    header): a text file named .mat is read as the CSV it is (the content decides, not the name)."""
    head = file_head(path, 64)
    if head.startswith(b"MATLAB"):
        return True
    return path.suffix.lower() == ".mat" and not _looks_text(head)


def _looks_text(head: bytes) -> bool:
    return bool(head) and all(32 <= b < 127 or b in (9, 10, 13) or b >= 0x80 for b in head)


def csv_header(path: Path) -> list[str]:
    """Column names of a CSV's header row (the first line neither blank nor a comment), or [] if none is found."""
    text = file_head(path).decode("utf-8", errors="replace").lstrip("\ufeff")
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            return [c.strip() for c in line.split(",")]
    return []


def _frf_column(name: str) -> bool:
    """A column the FRF format defines: freq_hz and each channel's magnitude, phase and coherence."""
    return name == "freq_hz" or any(name in (f"{ch}_mag", f"{ch}_phase_deg", f"{ch}_coh") for ch in CHANNELS)


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


# --------------------------------------------------------------------------- frequency response


def _check_nyquist(table: _Table, f: np.ndarray) -> None:
    """A response estimated from records sampled at a stated ``# sample_rate_hz:`` (a plain number) ends at its Nyquist
    frequency: a point above it contradicts the header (a diagnosis models the sampling from it)."""
    rate = _stated_rate(table)
    if rate is None:
        return
    text = table.metadata["sample_rate_hz"]
    bad = np.flatnonzero(f > rate / 2)
    if bad.size:
        raise table.error(
            f"frequency {_num(f[bad[0]])} Hz lies above the Nyquist frequency {rate / 2:g} Hz of '# sample_rate_hz: "
            f"{_short(text)}' (line {table.metadata_lines.get('sample_rate_hz')}): no record sampled so holds a "
            "response there; the header or the frequencies are wrong",
            row=int(bad[0]),
            column="freq_hz",
        )


def read_frf_csv(path) -> FrequencyResponse:
    """Read a frequency-response CSV (DATA_FORMATS.md) into a :class:`~samii.FrequencyResponse`.

    Channels present as ``<ch>_mag`` (linear) and ``<ch>_phase_deg`` (wrapped or
    unwrapped), with optional ``<ch>_coh``. Other columns are ignored.

    Raises
    ------
    DataFormatError
        On any defect; the message names the file, line and/or column.
    """
    table = _read_table(path, known=_frf_column)
    table.require(("freq_hz",))
    f = table.col("freq_hz")
    bad = np.flatnonzero(f <= 0)
    if bad.size:
        raise table.error(f"expected a positive frequency, got {_num(f[bad[0]])}", row=int(bad[0]), column="freq_hz")
    bad = np.flatnonzero(f > MAX_FREQ_HZ)
    if bad.size:
        raise table.error(
            f"expected a frequency up to {MAX_FREQ_HZ:g} Hz, got {_num(f[bad[0]])} (in rad/s, or corrupt?)", row=int(bad[0]), column="freq_hz"
        )
    bad = np.flatnonzero(np.diff(f) <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        what = "a repeated" if f[k] == f[k - 1] else "a decreasing"
        raise table.error(
            f"expected strictly increasing frequency, got {what} {_num(f[k])} after {_num(f[k - 1])} (line {int(table.lines[k - 1])})",
            row=k,
            column="freq_hz",
        )
    _check_nyquist(table, f)
    kw = {}
    for ch in CHANNELS:
        mag_name, ph_name, coh_name = f"{ch}_mag", f"{ch}_phase_deg", f"{ch}_coh"
        if table.has(mag_name) != table.has(ph_name):
            have, lack = (mag_name, ph_name) if table.has(mag_name) else (ph_name, mag_name)
            raise DataFormatError(table.path, f"column {have!r} needs its partner {lack!r}", line=table.header_line, column=lack)
        if not table.has(mag_name):
            if table.has(coh_name):
                raise DataFormatError(
                    table.path, f"coherence without its channel: expected {mag_name!r} and {ph_name!r}", line=table.header_line, column=coh_name
                )
            continue
        mag, phase = table.col(mag_name), table.col(ph_name)
        k, message = _bad_magnitude(mag)
        if message:
            raise table.error(message, row=k, column=mag_name)
        k, message = _bad_phase(phase)
        if message:
            raise table.error(message, row=k, column=ph_name)
        if (why := _phase_in_radians(ch, mag, phase)) is not None:
            raise DataFormatError(
                table.path,
                f"every value of {ph_name!r} lies within +-{RADIAN_CHECK_MAX:.3g} ({phase.size} points): "
                f"that is a phase in radians; expected degrees ({why})",
                line=table.header_line,
                column=ph_name,
            )
        kw[ch] = mag * np.exp(1j * np.unwrap(np.radians(phase)))
        if table.has(coh_name):
            coh = table.col(coh_name)
            bad = np.flatnonzero((coh < 0) | (coh > 1))
            if bad.size:
                raise table.error(f"expected a coherence in 0...1, got {_num(coh[bad[0]])}", row=int(bad[0]), column=coh_name)
            kw[coh_name] = coh
    if not any(ch in kw for ch in CHANNELS):
        raise DataFormatError(
            table.path,
            "no channel found: expected at least one pair of columns act_mag/act_phase_deg, base_mag/base_phase_deg or total_mag/total_phase_deg",
            line=table.header_line,
        )
    try:
        return FrequencyResponse(f, metadata=table.metadata, **kw)
    except ValueError as exc:  # the checks above should have said it first
        raise DataFormatError(table.path, str(exc)) from None


def _bad_magnitude(mag: np.ndarray) -> tuple[int, str]:
    """(index, message) of the first magnitude out of MAG_RANGE, or (-1, "")."""
    lo, hi = MAG_RANGE
    bad = np.flatnonzero(~((mag >= lo) & (mag <= hi)))
    if not bad.size:
        return -1, ""
    k = int(bad[0])
    if mag[k] < 0:
        return k, f"expected a non-negative linear magnitude (not dB), got {_num(mag[k])}"
    return k, (
        f"expected a linear magnitude within {lo:g}...{hi:g} ({20 * np.log10(lo):+.0f}...{20 * np.log10(hi):+.0f} dB), "
        f"got {_num(mag[k])}" + (" (a magnitude of 0 has no dB value: is the channel connected?)" if mag[k] == 0 else "")
    )


#: theta/v phase columns this long are checked for radians: every value within RADIAN_CHECK_MAX (3 pi: an
#: unwrapped phase in radians to -540 deg) is not a phase in degrees of an integrator.
RADIAN_CHECK_POINTS = 10
RADIAN_CHECK_MAX = 3.0 * np.pi


#: A magnitude peak this prominent [dB] is a resonance, across which a phase in degrees swings far beyond +-3 pi.
RADIAN_CHECK_PEAK_DB = 6.0


def _phase_in_radians(ch: str, mag: np.ndarray, phase: np.ndarray) -> str | None:
    """Why a phase column whose every value lies within +-RADIAN_CHECK_MAX (3 pi) of RADIAN_CHECK_POINTS or more points
    cannot be in degrees, or None. theta/v (``act``) and xdd/v (``total``) integrate: -90 deg at low frequency, lagging
    further past the actuator's resonance. xdd/theta (``base``) may stay near 0 deg over a band below its first mode
    (its s^4 rise), so it is held to it only where its magnitude shows a resonance: across one a phase in degrees swings
    by about 180. (In radians, wrapped or not, each stays within 3 pi over 0.1-40 Hz.)"""
    if phase.size < RADIAN_CHECK_POINTS or not np.all(np.abs(phase) <= RADIAN_CHECK_MAX):
        return None
    if ch in ("act", "total"):
        return f"{'theta/v' if ch == 'act' else 'xdd/v'}'s phase is near -90 deg at low frequency, where theta/v integrates"
    from scipy.signal import find_peaks

    with np.errstate(divide="ignore"):
        db = 20.0 * np.log10(np.abs(mag))
    peaks, _ = find_peaks(np.nan_to_num(db, neginf=-400.0), prominence=RADIAN_CHECK_PEAK_DB)
    if peaks.size:
        return (
            f"its magnitude has a resonance {RADIAN_CHECK_PEAK_DB:g} dB or more above its surroundings, across which a phase "
            "in degrees swings by about 180"
        )
    return None


def _bad_phase(phase: np.ndarray) -> tuple[int, str]:
    """(index, message) of the first phase beyond MAX_ABS_PHASE_DEG, or (-1, "")."""
    bad = np.flatnonzero(~(np.abs(phase) <= MAX_ABS_PHASE_DEG))
    if not bad.size:
        return -1, ""
    k = int(bad[0])
    return k, (
        f"expected a phase within +-{MAX_ABS_PHASE_DEG:g} deg (about {MAX_ABS_PHASE_DEG / 360:.0f} turns; "
        f"no measured phase comes near it), got {_num(phase[k])}"
    )


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


#: Longest a .mat file may take to parse [s] (a 256 MiB file takes a few seconds).
MAT_TIMEOUT_S = 120.0

# Runs scipy.io.loadmat in a child process. scipy's compiled MAT-5 reader
# trusts the type codes in the file: a corrupt file (one damaged byte in a
# variable's name or tag) can crash the interpreter with a segmentation fault
# (seen with scipy 1.17; also scipy issue #6072), which no ``except`` catches.
# In a child the crash becomes a clear error; it costs some 0.3 s a file.
# stdin: the file's bytes; stdout: an .npz of the numeric variables
# ("v_" + name) and "__other__", one "name<TAB>description" per other variable;
# exit 3 with "Type: message" on stderr if loadmat raises.
_MAT_CHILD = r"""
import io, sys
sys.path[:] = [p for p in sys.path if p]  # not the working folder (-c puts it first): a stray numpy.py there
import numpy as np
from scipy.io import loadmat
data = sys.stdin.buffer.read()
try:
    mat = loadmat(io.BytesIO(data), squeeze_me=True)
except BaseException as exc:
    sys.stderr.write(type(exc).__name__ + ": " + " ".join(str(exc).split())[:300])
    sys.exit(3)
out, other = {}, []
for name, value in mat.items():
    if name.startswith("__"):
        continue
    arr = value if isinstance(value, np.ndarray) else (np.asarray(value) if np.isscalar(value) and not isinstance(value, (str, bytes)) else None)
    if arr is not None and arr.dtype.kind in "iufc":
        out["v_" + name] = arr
    else:
        desc = f"dtype {arr.dtype} shape {arr.shape}" if arr is not None else f"a {type(value).__name__}"
        other.append(name + "\t" + desc)
out["__other__"] = np.array(other, dtype=str)
buf = io.BytesIO()
np.savez(buf, **out)
sys.stdout.buffer.write(buf.getvalue())
"""


def _loadmat_in_process(path: Path, data: bytes) -> dict:
    from scipy.io import loadmat  # scipy.io is slow to import; only needed here

    try:
        raw = loadmat(io.BytesIO(data), squeeze_me=True)
    except Exception as exc:  # scipy raises assorted types on garbage (MatReadError, ValueError, IndexError, MemoryError...)
        raise _not_mat(path, data, f"{type(exc).__name__}: {exc}") from None
    mat: dict = {}
    for name, value in raw.items():
        if name.startswith("__"):
            continue
        arr = np.asarray(value) if isinstance(value, (np.ndarray, int, float, complex, np.number)) else None
        if arr is not None and arr.dtype.kind in "iufc":
            mat[name] = arr
        else:
            mat[name] = f"dtype {arr.dtype} shape {arr.shape}" if arr is not None else f"a {type(value).__name__}"
    return mat


def _not_mat(path: Path, data: bytes, why: str) -> DataFormatError:
    if why.startswith("NotImplementedError"):  # scipy's word for v7.3 (HDF5)
        return DataFormatError(path, f"cannot read this MAT-file version ({_short(why)}); save it with -v7 or earlier")
    head = data[:64]
    hint = (
        "; it looks like text: a samii CSV (DATA_FORMATS.md) is read as one whatever its name"
        if _looks_text(head) and not head.startswith(b"MATLAB")
        else ""
    )
    return DataFormatError(path, f"not a MATLAB .mat file (v4 to v7.2) that can be read ({' '.join(why.split())[:200] or '-'}){hint}")


def _loadmat_isolated(path: Path, data: bytes) -> dict:
    """The variables of a .mat file: numeric arrays by name, a description for any other variable.

    loadmat runs in a child Python (see _MAT_CHILD); where no child can be
    started (a frozen application, no interpreter) it runs in this process.
    """
    import signal
    import subprocess
    import sys

    if not sys.executable or getattr(sys, "frozen", False):
        return _loadmat_in_process(path, data)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", PYTHONPATH=os.pathsep.join(p for p in sys.path if isinstance(p, str) and p))
    try:
        proc = subprocess.run([sys.executable, "-c", _MAT_CHILD], input=data, capture_output=True, timeout=MAT_TIMEOUT_S, env=env)
    except subprocess.TimeoutExpired:
        raise DataFormatError(
            path, f"reading the .mat file took longer than {MAT_TIMEOUT_S:g} s (samii.measure.io.MAT_TIMEOUT_S); is it corrupt?"
        ) from None
    except OSError:  # no interpreter to start
        return _loadmat_in_process(path, data)
    if proc.returncode < 0:
        try:
            sig = signal.Signals(-proc.returncode).name
        except ValueError:
            sig = f"signal {-proc.returncode}"
        raise DataFormatError(path, f"the MATLAB reader (scipy.io.loadmat) crashed on this file ({sig}): the file is corrupt or not a MAT-file")
    if proc.returncode == 3:
        raise _not_mat(path, data, proc.stderr.decode("utf-8", "replace"))
    if proc.returncode != 0:  # the child could not run (its environment), not the file's fault
        return _loadmat_in_process(path, data)
    try:
        with np.load(io.BytesIO(proc.stdout), allow_pickle=False) as npz:
            mat = {key[2:]: npz[key] for key in npz.files if key.startswith("v_")}
            for entry in npz["__other__"].tolist():
                name, _, desc = entry.partition("\t")
                mat[name] = desc
    except Exception:  # a garbled reply: read here instead
        return _loadmat_in_process(path, data)
    return mat


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
        Not a regular file, unreadable, not a MAT-file (v4 to v7.2), missing or
        malformed vector, bad frequency axis, magnitude or phase out of range,
        NaN or infinite values.

    Notes
    -----
    ``scipy.io.loadmat`` runs in a child Python process: scipy's compiled
    reader can crash the interpreter on a corrupt file, which in the child is
    a clear error instead. This costs some 0.3 s a file.
    """
    path = Path(path)
    if freq_unit not in ("hz", "rad/s"):
        raise InputError(f"freq_unit must be 'hz' or 'rad/s', got {freq_unit!r}")
    data = _read_bytes(path)
    if not data:
        raise DataFormatError(path, "the file is empty; expected a MATLAB .mat file")
    if data[:4] == b"\x89HDF" or data[512:516] == b"\x89HDF":
        raise DataFormatError(path, "is a MATLAB v7.3 (HDF5) file, which this reader cannot read; save it with -v7 or earlier")
    mat = _loadmat_isolated(path, data)
    del data
    names = sorted(mat)
    holds = _names(names) or "nothing"

    def vector(name: str) -> np.ndarray:
        try:
            arr = mat[name]
        except KeyError:
            raise DataFormatError(path, f"no variable {name!r}; the file holds {holds}", column=name) from None
        if isinstance(arr, str):  # not numeric: its description
            raise DataFormatError(path, f"expected a non-empty real numeric vector, got {arr}", column=name)
        if arr.ndim == 0:  # one value (loadmat squeezes a 1x1 matrix to a scalar): a vector of one, judged as such below
            arr = arr.reshape(1)
        if arr.ndim != 1 or arr.size == 0 or not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
            raise DataFormatError(path, f"expected a non-empty real numeric vector, got dtype {arr.dtype} shape {arr.shape}", column=name)
        arr = arr.astype(float)
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            raise DataFormatError(path, f"expected finite numbers, got {_num(arr[bad[0]])} at element {bad[0] + 1}", column=name)
        bad = np.flatnonzero(np.abs(arr) > MAX_ABS_VALUE)
        if bad.size:
            raise DataFormatError(
                path,
                f"expected numbers within +-{MAX_ABS_VALUE:g} (no measurement comes near it), got {_num(arr[bad[0]])} at element {bad[0] + 1}",
                column=name,
            )
        return arr

    if freq_name is None:
        found = [n for n in MAT_FREQ_NAMES if n in mat]
        if not found:
            raise DataFormatError(
                path,
                f"no frequency vector under the names tried ({', '.join(MAT_FREQ_NAMES)}); the file holds {holds}: pass freq_name=",
            )
        freq_name = found[0]
    f = vector(freq_name)
    if freq_unit == "rad/s":
        f = f / (2.0 * np.pi)
    bad = np.flatnonzero(f <= 0)
    if bad.size:
        raise DataFormatError(path, f"expected positive frequencies, got {_num(f[bad[0]])} at element {bad[0] + 1}", column=freq_name)
    bad = np.flatnonzero(f > MAX_FREQ_HZ)
    if bad.size:
        raise DataFormatError(
            path,
            f"expected frequencies up to {MAX_FREQ_HZ:g} Hz, got {_num(f[bad[0]])} Hz at element {bad[0] + 1}"
            + (" (in rad/s? pass freq_unit='rad/s')" if freq_unit == "hz" else ""),
            column=freq_name,
        )
    bad = np.flatnonzero(np.diff(f) <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise DataFormatError(
            path, f"expected strictly increasing frequencies, got {_num(f[k])} after {_num(f[k - 1])} at element {k + 1}", column=freq_name
        )
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
        for name, arr, check in ((mag_name, mag, _bad_magnitude), (ph_name, ph, _bad_phase)):
            k, message = check(arr)
            if message:
                raise DataFormatError(path, f"{message} at element {k + 1}", column=name)
        if (why := _phase_in_radians(ch, mag, ph)) is not None:  # (the rig-era files' phases are in degrees too)
            raise DataFormatError(
                path,
                f"every value lies within +-{RADIAN_CHECK_MAX:.3g} ({ph.size} points): that is a phase in radians; expected degrees ({why})",
                column=ph_name,
            )
        kw[ch] = mag * np.exp(1j * np.unwrap(np.radians(ph)))
    if not kw:
        pairs = "; ".join(f"{m}/{p}" for m, p in MAT_CHANNELS.values())
        raise DataFormatError(path, f"no Bode data: expected the vectors {pairs}; the file holds {holds}")
    meta = {"source": f"MATLAB file {path.name}", "freq_vector": freq_name}
    meta.update({f"{ch}_vectors": "/".join(MAT_CHANNELS[ch]) for ch in kw})
    try:
        return FrequencyResponse(f, metadata=meta, **kw)
    except ValueError as exc:  # the checks above should have said it first
        raise DataFormatError(path, str(exc)) from None
