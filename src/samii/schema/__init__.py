"""The version of the JSON documents samii writes into its output folders, and the check of a document read back.

``summary.json`` (the main job's), ``run.json`` (``samii measure``'s and ``samii closedloop``'s), ``fit.json``
(``samii fit``'s), ``diagnosis.json`` and ``robust.json`` carry ``"schema_version"``: the layout of their fields. A
reader takes a document of this version or an older one, and refuses a newer one naming its version (a folder written
by a later samii), rather than read fields it does not know by the names it does. A document without the key was
written before versions were stated: version 0, whose fields are those of version 1.

History: 0 (no key), the layouts of samii 0.1.0; 1, the same fields with ``schema_version`` first (``fit.json`` took
the key later than the others, without a change of its fields: one without it is version 0 as well).

:func:`read_document` reads one of these documents from a main job's folder, checked; :func:`read_typed` reads it
into its type, :func:`document` is the object a record is written as (a writer builds its record with :func:`record_of`). The types: :mod:`samii.schema.summary`
(``summary.json``), :mod:`samii.schema.closed_loop` (a closed-loop run's ``run.json``), :mod:`samii.schema.measurement`
(a measurement's ``run.json``), :mod:`samii.schema.diagnosis` (``diagnosis.json``), :mod:`samii.schema.robust`
(``robust.json``); how a document becomes a type and back: :mod:`samii.schema.typed`."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from samii import __version__
from samii.errors import InputError
from samii.json_output import non_finite_fields, read_json
from samii.schema.typed import EMPTY, OPTIONAL, as_json, key, read_as, record_of

__all__ = [
    "SCHEMA_VERSION",
    "versioned",
    "schema_version",
    "read_document",
    "read_file",
    "read_as",
    "read_typed",
    "as_json",
    "record_of",
    "document",
    "key",
    "OPTIONAL",
    "EMPTY",
]

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


def read_document(folder, rel: str, tp=None):
    """The JSON object at ``rel`` in the run folder ``folder`` (a main job's), checked (:func:`read_file`), as type
    ``tp`` (None: the object as parsed)."""

    path = Path(folder) / rel
    return read_file(path, "main job's file", tp, missing=f"{path}: missing; is {folder} a main job's output (samii run)?",
                     again="run samii run again for a report")  # fmt: skip


def read_file(path, what: str, tp=None, *, missing: str | None = None, again: str = "write it again"):
    """The JSON document samii wrote at ``path`` (a ``what``), as type ``tp`` (:func:`read_typed`; None: the object
    as parsed), checked: a missing, malformed or damaged file (NaN, which samii never writes) and one of a newer
    schema_version is an InputError naming it (``missing``: the message for a file that is not there; ``again``: what
    to do about a damaged one)."""

    data = read_json(path, what, missing=missing)
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a JSON object")
    schema_version(data, path)
    bad = non_finite_fields(data)
    if bad:  # samii writes null, never NaN or Infinity: the file was damaged after it was written (no number is trusted)
        shown = ", ".join(bad[:4]) + (f" and {len(bad) - 4} more" if len(bad) > 4 else "")
        raise InputError(f"{path}: field {shown} holds NaN or an infinity, which samii never writes: the file is damaged; {again}")
    if tp is None:
        return data
    try:
        return read_typed(tp, data, path)
    except InputError as exc:  # a field missing or of the wrong kind: written by no samii
        raise InputError(f"{exc} (the file is not as samii writes it; {again})") from None


def document(record) -> dict:
    """The JSON object a record (one of this package's types) is written as, this samii's ``schema_version`` first."""
    return versioned(as_json(record))


def read_typed(tp, doc, where):
    """The document ``doc`` read from ``where`` as type ``tp``: its version checked (:func:`schema_version`), its
    fields read into their types (:func:`read_as`); InputError naming the file and field."""
    if not isinstance(doc, Mapping):
        raise InputError(f"{where}: expected a JSON object")
    schema_version(doc, where)
    return read_as(tp, {k: v for k, v in doc.items() if k != "schema_version"}, where)
