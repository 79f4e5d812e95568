"""JSON that every parser reads: non-finite numbers become ``null``, never ``NaN`` or ``Infinity``;
and JSON files read with an error that names the file (:func:`read_json`).

Python's :mod:`json` writes ``NaN`` and ``Infinity`` by default, which are not JSON
(RFC 8259) and break ``jq`` and JavaScript. Every command's ``--json`` and every
JSON file the project writes go through :func:`dumps`; a ``null`` where a number is
expected means "not defined" (e.g. a standard error of a parameter the data do not
determine).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from samii.errors import InputError

__all__ = ["dumps", "finite_or_none", "non_finite_fields", "read_json"]


def read_json(path, what: str, *, missing: str | None = None) -> Any:
    """The JSON value in file ``path``; a missing, unreadable or malformed file is an InputError naming
    it as ``what`` (``missing``: the message for a file that is not there)."""

    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(missing or f"{what} {path} does not exist") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder; expected a {what}") from None
    except OSError as exc:  # (the OS's words without its number and the path again)
        raise InputError(f"{path}: cannot be read as a {what} ({(exc.strerror or str(exc)).lower()})") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: cannot be read as a {what} (not UTF-8 text: {exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from None
    except RecursionError:
        raise InputError(f"{path}: JSON nested too deeply to be a {what}") from None


def non_finite_fields(obj: Any, where: str = "") -> list[str]:
    """Where ``obj`` (parsed JSON) holds NaN or an infinity, as field paths (``closed_loop.x.theta.settle_s``,
    ``modes[2]``). samii never writes them (:func:`dumps`), so in a file of ours they mark damage."""
    if isinstance(obj, float):
        return [] if math.isfinite(obj) else [where or "(the value)"]
    if isinstance(obj, dict):
        return [p for k, v in obj.items() for p in non_finite_fields(v, f"{where}.{k}" if where else str(k))]
    if isinstance(obj, list):
        return [p for i, v in enumerate(obj) for p in non_finite_fields(v, f"{where}[{i}]")]
    return []


def finite_or_none(obj: Any) -> Any:
    """``obj`` as plain JSON values: numpy scalars and arrays as Python ones, complex numbers as
    ``[re, im]``, dict keys as strings, and every non-finite float replaced by None."""

    if isinstance(obj, dict):
        return {str(k): finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return finite_or_none(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, (complex, np.complexfloating)):  # a pole or zero: [re, im]
        return [finite_or_none(float(obj.real)), finite_or_none(float(obj.imag))]
    return obj


def dumps(obj: Any, **kwargs) -> str:
    """:func:`json.dumps` of :func:`finite_or_none` (``obj``), refusing any NaN left."""
    kwargs.setdefault("default", str)
    return json.dumps(finite_or_none(obj), allow_nan=False, **kwargs)
