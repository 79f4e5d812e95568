"""Argument types for the ``samii`` command line: each rejects a bad value at parse time.

argparse reports a rejected value as ``samii CMD: error: argument --opt: <why>``
(exit 2) before any work starts. Every numeric option uses one of these types,
so ``nan``, ``inf``, negative or absurd values never reach a simulation.
Imports nothing heavy.
"""

from __future__ import annotations

import argparse
import math

__all__ = ["finite_float", "float_in", "int_in", "name_value", "positive_float", "nonnegative_float", "nonempty_path", "seed"]


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def finite_float(text: str) -> float:
    """Any finite number."""
    return _number(text)


def float_in(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False, hi_open: bool = False, unit: str = ""):
    """A finite number in [lo, hi] (open ends with ``lo_open``/``hi_open``; ``None`` for no bound)."""
    u = f" {unit}" if unit else ""

    def parse(text: str) -> float:
        v = _number(text)
        if lo is not None and (v < lo or (lo_open and v == lo)):
            raise argparse.ArgumentTypeError(f"expected a number {'>' if lo_open else '>='} {lo:g}{u}, got {text!r}")
        if hi is not None and (v > hi or (hi_open and v == hi)):
            raise argparse.ArgumentTypeError(f"expected a number {'<' if hi_open else '<='} {hi:g}{u}, got {text!r}")
        return v

    parse.__name__ = "number"
    return parse


def int_in(lo: int | None = None, hi: int | None = None):
    """An integer in [lo, hi] (``None`` for no bound); ``2.5`` is refused, not truncated."""

    def parse(text: str) -> int:
        try:
            v = int(text, 10)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if lo is not None and v < lo:
            raise argparse.ArgumentTypeError(f"expected an integer >= {lo}, got {text!r}")
        if hi is not None and v > hi:
            raise argparse.ArgumentTypeError(f"expected an integer <= {hi}, got {text!r}")
        return v

    parse.__name__ = "integer"
    return parse


def positive_float(text: str) -> float:
    """A finite number > 0."""
    v = _number(text)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def nonnegative_float(text: str) -> float:
    """A finite number >= 0."""
    v = _number(text)
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return v


def name_value(text: str) -> tuple[str, float]:
    """``NAME=VALUE`` with a finite number: ``("beam.length_m", 4.3)`` (``--set``, ``--start``)."""
    name, sep, value = text.partition("=")
    if not sep or not name.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    try:
        v = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: value {value!r} is not a number") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a finite number, got {value!r}")
    return name.strip(), v


def nonempty(what: str):
    """An argument type: text that is not empty or blank (``what`` names what is expected, for the message)."""

    def parse(text: str) -> str:
        if not text.strip():
            raise argparse.ArgumentTypeError(f"expected {what}, got an empty string")
        return text

    return parse


def nonempty_path(text: str) -> str:
    """A path that is not empty or blank (``--out ''`` would silently mean the current folder)."""
    return nonempty("a path")(text)


#: A random-generator seed: numpy accepts 0 .. 2**128 - 1.
seed = int_in(0, 2**63 - 1)
