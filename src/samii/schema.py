"""The version of the JSON documents samii writes into its output folders, and the check of a document read back.

``summary.json`` (the main job's), ``run.json`` (``samii measure``'s and ``samii closedloop``'s), ``fit.json``
(``samii fit``'s), ``diagnosis.json`` and ``robust.json`` carry ``"schema_version"``: the layout of their fields. A
reader takes a document of this version or an older one, and refuses a newer one naming its version (a folder written
by a later samii), rather than read fields it does not know by the names it does. A document without the key was
written before versions were stated: version 0, whose fields are those of version 1.

History: 0 (no key), the layouts of samii 0.1.0; 1, the same fields with ``schema_version`` first (``fit.json`` took
the key later than the others, without a change of its fields: one without it is version 0 as well).

:func:`read_document` reads one of these documents from a main job's folder, checked."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from samii import __version__
from samii.errors import InputError
from samii.json_output import non_finite_fields, read_json

__all__ = ["SCHEMA_VERSION", "versioned", "schema_version", "read_document"]

#: The version this samii writes and the newest it reads.
SCHEMA_VERSION = 1


def versioned(doc: Mapping) -> dict:
    """``doc`` with ``schema_version`` first (a document's version is the first thing a reader checks)."""
    return {"schema_version": SCHEMA_VERSION, **{k: v for k, v in doc.items() if k != "schema_version"}}


def schema_version(doc: Mapping, where) -> int:
    """The version of document ``doc`` read from ``where`` (a file's path): 0 without the key; InputError naming the
    file for a version that is not a whole number, or one newer than this samii reads."""
    v = doc.get("schema_version", 0)
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise InputError(f"{where}: field 'schema_version' holds {v!r}; expected a whole number >= 0 (the file is damaged)")
    if v > SCHEMA_VERSION:
        raise InputError(
            f"{where}: schema_version {v}, written by a newer samii; this one ({__version__}) reads versions up to "
            f"{SCHEMA_VERSION}: upgrade samii to read it"
        )
    return v


def read_document(folder, rel: str) -> dict:
    """The JSON object at ``rel`` in the run folder ``folder`` (a main job's), checked: a missing, malformed or damaged
    file (NaN, which samii never writes) and one of a newer schema_version is an InputError naming it."""

    folder = Path(folder)
    path = folder / rel
    data = read_json(path, "main job's file", missing=f"{path}: missing; is {folder} a main job's output (samii run)?")
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a JSON object")
    schema_version(data, path)
    bad = non_finite_fields(data)
    if bad:  # samii writes null, never NaN or Infinity: the file was damaged after the run (no number shown is trusted)
        shown = ", ".join(bad[:4]) + (f" and {len(bad) - 4} more" if len(bad) > 4 else "")
        raise InputError(
            f"{path}: field {shown} holds NaN or an infinity, which samii never writes: the file is damaged; run samii run again for a report"
        )
    return data
