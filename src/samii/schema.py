"""The version of the JSON documents samii writes into its output folders, and the check of a document read back.

``summary.json`` (the main job's), ``run.json`` (``samii measure``'s and ``samii closedloop``'s), ``diagnosis.json``
and ``robust.json`` carry ``"schema_version"``: the layout of their fields. A reader takes a document of this version
or an older one, and refuses a newer one naming its version (a folder written by a later samii), rather than read
fields it does not know by the names it does. A document without the key was written before versions were stated
(samii 0.1.0 before this module): version 0, whose fields are those of version 1.

History: 0 (no key), the layouts of samii 0.1.0; 1, the same fields with ``schema_version`` first.
"""

from __future__ import annotations

from collections.abc import Mapping

from samii.errors import InputError

__all__ = ["SCHEMA_VERSION", "versioned", "schema_version"]

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
        from samii import __version__

        raise InputError(
            f"{where}: schema_version {v}, written by a newer samii; this one ({__version__}) reads versions up to "
            f"{SCHEMA_VERSION}: upgrade samii to read it"
        )
    return v
