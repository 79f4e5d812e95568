"""samii.formats: readers and writers for the file formats of DATA_FORMATS.md (the ground floor: every stage reads
and writes its data through them; they import only the value types :class:`samii.timeseries.TimeSeries` and
:class:`samii.FrequencyResponse`).

* time-series CSV  <->  :class:`~samii.timeseries.TimeSeries`
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

Modules: ``files`` (what a reader refuses before parsing, the CSV table, the writers' temporary file),
``timeseries_csv``, ``frf_csv``, ``mat``. Import the public names from here.
"""

from samii.formats.files import (
    MAX_ABS_VALUE,
    MAX_FILE_BYTES,
    MAX_LINE_CHARS,
    MAX_LINES,
    DataFormatError,
    csv_header,
    file_head,
    is_mat_file,
    write_text,
)
from samii.formats.frf_csv import MAG_RANGE, MAX_ABS_PHASE_DEG, MAX_FREQ_HZ, read_frf_csv, write_frf_csv
from samii.formats.mat import MAT_CHANNELS, MAT_FREQ_NAMES, MAT_TIMEOUT_S, read_mat_bode
from samii.formats.timeseries_csv import SAMPLE_RATE_RTOL, TimeSeriesCsvWriter, read_timeseries_csv, stated_sample_rate, write_timeseries_csv

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
    "stated_sample_rate",
    "read_frf_csv",
    "write_frf_csv",
    "read_mat_bode",
    "write_text",
]
