"""Parameter overrides as a user writes them, ``NAME=VALUE`` (``--set``), read into a mapping of names to numbers.

The names are checked when the model is built (:func:`samii.sim.model.params_with_overrides`; ``samii params``
lists them).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

from samii.errors import InputError

__all__ = ["parse_overrides", "as_overrides", "name_value"]


def name_value(text: str) -> tuple[str, float]:
    """``NAME=VALUE`` with a finite number: ``("beam.length_m", 4.3)``; ValueError saying what is wrong."""
    name, sep, value = text.partition("=")
    if not sep or not name.strip():
        raise ValueError(f"expected NAME=VALUE, got {text!r}")
    try:
        v = float(value)
    except ValueError:
        raise ValueError(f"{text!r}: value {value!r} is not a number") from None
    if not math.isfinite(v):
        raise ValueError(f"{text!r}: expected a finite number, got {value!r}")
    return name.strip(), v


def parse_overrides(items: Iterable[str]) -> dict[str, float]:
    """``["beam.length_m=4.3", ...]`` as a dict; InputError naming ``--set`` for a malformed or repeated one."""
    out = {}
    for item in items:
        try:
            name, number = name_value(item)
        except ValueError as exc:
            raise InputError(f"--set {exc} (samii params lists the names)") from None
        if name in out:
            raise InputError(f"--set {name}: given twice")
        out[name] = number
    return out


def as_overrides(overrides: Iterable[str] | Mapping[str, float] | None) -> dict[str, float]:
    """Overrides given as ``--set`` texts or as a mapping of names to numbers, as that mapping."""
    if isinstance(overrides, Mapping):
        return {str(k): float(v) for k, v in overrides.items()}
    return parse_overrides(overrides or ())
