"""JSON documents to and from frozen dataclasses: :func:`read_as` reads a parsed document into the types of a
dataclass's fields, :func:`as_json` writes one back as JSON values, :func:`record_of` is the writer's side of it.

A field's type says what the document holds there: ``float``, ``int``, ``bool``, ``str``, one of these
(``int | str``), ``X | None``,
``tuple[X, ...]``, ``tuple[X, Y]``, ``Mapping[str, X]``, a bare ``Mapping`` (an object kept as written: a part whose
keys vary, as a parameter file's groups), or another dataclass. Numbers are kept as read (a whole number stays one),
so a document read and written back is the same document. A field's metadata may give its key in the file
(:func:`key`, for a key that is no Python name) and make it optional (:data:`OPTIONAL`: absent when None).

Reading a file, a value of the wrong kind is an InputError naming the file and the field; a field absent is refused,
but for one with a default or one that admits null (read as null: a field added since a folder was written), and a
list marked :data:`EMPTY`, absent or null, which reads as none. Writing, :func:`record_of` reads the writer's own
document strictly (a key its type does not know or one missing but an optional one, a value of the wrong kind: a
programming error, TypeError), so a file is written only as its type says."""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import MISSING, fields, is_dataclass
from types import UnionType
from typing import Union, get_args, get_origin, get_type_hints

from samii.errors import InputError
from samii.json_output import finite_or_none

__all__ = ["read_as", "as_json", "record_of", "key", "OPTIONAL", "EMPTY"]

_ROOT = "(the document)"

#: A field's metadata: absent from the document when None (a key written only sometimes).
OPTIONAL = {"optional": True}
#: A field's metadata: a list that reads as none when absent or null (as the first readers took it, samii 0.1.0).
EMPTY = {"empty": True}


def key(name: str, **more) -> dict:
    """A field's metadata: its key in the document is ``name``."""
    return {"key": name, **more}


def read_as(tp, doc, where, *, at: str = _ROOT, strict: bool = False):
    """``doc`` (parsed JSON) read as type ``tp`` (a dataclass, or any type a field may have) from ``where`` (a
    file's path, in messages), at field ``at`` of it (default: the whole document); InputError naming the field of a
    value of the wrong kind or a field missing. ``strict``: the writer's check (:func:`record_of`): a key the type does
    not know is refused too, and every error is TypeError."""
    return _Reader(where, strict).read(tp, doc, at)


def as_json(value):
    """``value`` as JSON values: a dataclass as an object of its fields in order (by their keys, an optional one left
    out when None), tuples as lists, mappings as dicts."""
    if is_dataclass(value) and not isinstance(value, type):
        out = {}
        for f in fields(value):
            v = getattr(value, f.name)
            if v is None and f.metadata.get("optional"):
                continue
            out[f.metadata.get("key", f.name)] = as_json(v)
        return out
    if isinstance(value, Mapping):
        return {k: as_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [as_json(v) for v in value]
    return value


def record_of(tp, doc, who: str):
    """The document ``doc`` that ``who`` (a function, in a programming error) builds, as a ``tp``: read strictly (a
    key ``tp`` does not know or a value of the wrong kind is TypeError, the writer's mistake), numpy values and
    non-finite numbers made JSON first (:func:`samii.json_output.finite_or_none`)."""
    return read_as(tp, finite_or_none(doc), who, strict=True)


@functools.cache
def _hints(cls) -> dict:
    """``cls``'s field types, resolved once per class (``get_type_hints`` evaluates every annotation string again at
    each call: 0.3 s of a main job's 440 reads under cProfile, stop 74)."""
    return get_type_hints(cls)


class _Reader:
    def __init__(self, where, strict: bool):
        self.where, self.strict = where, strict

    def _error(self, text: str):
        if self.strict:
            return TypeError(f"{self.where} writes a document its schema does not describe: {text}")
        return InputError(f"{self.where}: {text}")

    def fail(self, path: str, value, expected: str):
        text = repr(value)
        shown = text if len(text) <= 40 else text[:40] + "..."
        raise self._error(f"field '{path}' holds {shown}; expected {expected}")

    def part(self, cls, d, path: str):
        """An instance of dataclass ``cls`` from the object ``d`` at ``path``."""
        d = self.read(Mapping, d, path)
        hints = _hints(cls)
        values = {}
        known = set()
        for f in fields(cls):
            name = f.metadata.get("key", f.name)
            known.add(name)
            where = name if path == _ROOT else f"{path}.{name}"
            has_default = f.default is not MISSING or f.default_factory is not MISSING
            if f.metadata.get("empty") and d.get(name) is None:  # (a list absent or null: none)
                values[f.name] = ()
            elif name in d:
                values[f.name] = self.read(hints[f.name], d[name], where)
            elif self.strict and not f.metadata.get("optional"):  # (a writer writes every key but an optional one)
                raise self._error(f"field '{where}' is missing")
            elif _admits_none(hints[f.name]) and not has_default:
                values[f.name] = None
            elif not has_default:
                raise self._error(f"field '{where}' is missing")
        if self.strict and set(d) - known:
            raise self._error(f"field '{sorted(set(d) - known)[0]}' of {path} is not in {cls.__name__}")
        return cls(**values)

    def read(self, tp, v, path: str, *, or_null: bool = False):
        """``v`` read as type ``tp`` at ``path`` (``or_null``: said to admit null, in a message)."""
        null = " or null" if or_null else ""
        if _admits_none(tp):
            return None if v is None else self.read(_without_none(tp), v, path, or_null=True)
        origin, args = get_origin(tp) or tp, get_args(tp)
        if tp in _PLAIN:
            if not _is(v, tp):
                self.fail(path, v, _PLAIN[tp][0] + null)
        elif origin in (Union, UnionType) and all(a in _PLAIN for a in args):  # (int | str: one of plain kinds)
            if not any(_is(v, a) for a in args):
                self.fail(path, v, " or ".join(_PLAIN[a][0] for a in args) + null)
        elif is_dataclass(tp):
            return self.part(tp, v, path)
        elif origin is tuple:
            each = args[0] if len(args) == 2 and args[1] is Ellipsis else None
            kinds = [each] * len(v) if each and isinstance(v, list) else list(args)
            if each:
                said = "a list of " + ("some numbers" if each is float else _PLAIN[each][1] if each in _PLAIN else "objects")
            elif len(set(args)) == 1 and args[0] in _PLAIN:
                said = f"a list of {len(args)} {_PLAIN[args[0]][1]}"
            else:
                said = f"a list of {len(args)} values"
            if not isinstance(v, list) or len(v) != len(kinds):
                self.fail(path, v, said + null)
            if not all(_is(x, k) for x, k in zip(v, kinds) if k in _PLAIN):  # (a list of plain values shown whole)
                self.fail(path, v, said + null)
            return tuple(self.read(k, x, f"{path}[{i}]") for i, (x, k) in enumerate(zip(v, kinds)))
        elif origin is Mapping:
            if not isinstance(v, Mapping):
                self.fail(path, v, "an object" + null)
            if args:
                return {k: self.read(args[1], x, f"{path}.{k}") for k, x in v.items()}
        else:  # (a type this reader was not taught: a programming error, not the file's)
            raise TypeError(f"read_as cannot read {tp!r}")
        return v


#: The plain kinds a field can have: (one said, several said).
_PLAIN = {
    float: ("a number", "numbers"),
    int: ("a whole number", "whole numbers"),
    bool: ("true or false", "true or false values"),
    str: ("a string", "strings"),
}


def _admits_none(tp) -> bool:
    return get_origin(tp) in (Union, UnionType) and type(None) in get_args(tp)


def _without_none(tp):
    inner = [a for a in get_args(tp) if a is not type(None)]
    if len(inner) != 1:  # (a programming error: the reader says which kind it expects, one)
        raise TypeError(f"read_as reads X | None, not {tp!r}")
    return inner[0]


def _is(x, kind) -> bool:
    if kind is float:
        return not isinstance(x, bool) and isinstance(x, (int, float))
    if kind is int:
        return not isinstance(x, bool) and isinstance(x, int)
    return isinstance(x, kind)
