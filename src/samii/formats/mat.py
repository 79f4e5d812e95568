"""The rig-era MATLAB ``.mat`` Bode layout (notebook ch. 9) -> :class:`samii.FrequencyResponse`."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Literal

import numpy as np

from samii.errors import InputError
from samii.formats.files import MAX_ABS_VALUE, DataFormatError, _looks_text, _names, _num, _read_bytes, _short
from samii.formats.frf_csv import MAX_FREQ_HZ, RADIAN_CHECK_MAX, _bad_magnitude, _bad_phase, _phase_in_radians
from samii.frequency_response import FrequencyResponse

#: Variable names of the rig-era .mat file per channel (notebook ch. 9, samiierr.m):
#: magnitude (linear) and phase (degrees).
MAT_CHANNELS: Mapping[str, tuple[str, str]] = {
    "act": ("mean_io_mr", "mean_io_ph"),
    "base": ("mean_a2_j2a_mr", "mean_a2_j2a_ph"),
}
#: Frequency-vector names tried, in this order, when the caller names none. The
#: notebook does not print the name; these are the usual ones for a vector in Hz.
MAT_FREQ_NAMES: tuple[str, ...] = ("freq_hz", "freq", "f", "frequency", "hz", "fr", "mean_io_f", "mean_io_freq")

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
    from scipy.io import loadmat  # (lazy: scipy.io is slow to import; only needed here)

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

    if not sys.executable or getattr(sys, "frozen", False):
        return _loadmat_in_process(path, data)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", PYTHONPATH=os.pathsep.join(p for p in sys.path if isinstance(p, str) and p))
    try:
        proc = subprocess.run([sys.executable, "-c", _MAT_CHILD], input=data, capture_output=True, timeout=MAT_TIMEOUT_S, env=env)
    except subprocess.TimeoutExpired:
        raise DataFormatError(
            path, f"reading the .mat file took longer than {MAT_TIMEOUT_S:g} s (samii.formats.mat.MAT_TIMEOUT_S); is it corrupt?"
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
