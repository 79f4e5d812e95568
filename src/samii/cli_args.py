"""Argument types for the ``samii`` command line: each rejects a bad value at parse time.

argparse reports a rejected value as ``samii CMD: error: argument --opt: <why>``
(exit 2) before any work starts. Every numeric option uses one of these types,
so ``nan``, ``inf``, negative or absurd values never reach a simulation.
Imports nothing heavy.
"""

from __future__ import annotations

import argparse
import math

__all__ = [
    "finite_float",
    "float_in",
    "int_in",
    "name_value",
    "positive_float",
    "nonnegative_float",
    "nonempty_path",
    "seed",
    "add_band",
    "add_out",
    "add_overwrite",
    "add_json",
    "add_model",
    "add_set",
    "add_rerun",
    "add_seed",
    "add_no_progress",
]


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
    from samii.sim.overrides import name_value as parse

    try:
        return parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


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


# ---- the options many commands share, declared once (each command says what its --out holds, --json prints) ----


class _Band(argparse.Action):
    """``--band-hz LO HI``: two positive numbers with LO < HI, checked at parse time."""

    def __call__(self, parser, namespace, values, option_string=None):
        lo, hi = values
        if not lo < hi:
            parser.error(f"{option_string} {lo:g} {hi:g}: expected LO < HI")
        setattr(namespace, self.dest, tuple(values))


def add_band(parser: argparse.ArgumentParser, help: str, *, default: tuple[float, float] | None = None) -> None:
    """``--band-hz LO HI`` (Hz, 0 < LO < HI)."""
    parser.add_argument("--band-hz", type=positive_float, nargs=2, metavar=("LO", "HI"), default=default, action=_Band, help=help)


def add_out(parser: argparse.ArgumentParser, help: str, *, default: str | None = None, metavar: str = "DIR") -> None:
    """``--out``: where the command writes (a non-empty path)."""
    parser.add_argument("--out", metavar=metavar, type=nonempty_path, default=default, help=help)


def add_overwrite(parser: argparse.ArgumentParser, help: str = "replace existing output files") -> None:
    """``--overwrite``, with ``--force`` its alias on every command (``args.overwrite``)."""
    parser.add_argument("--overwrite", "--force", dest="overwrite", action="store_true", help=f"{help} (--force is an alias)")


def add_json(parser: argparse.ArgumentParser, help: str = "print the result as JSON") -> None:
    """``--json``: machine-readable output on stdout."""
    parser.add_argument("--json", action="store_true", help=help)


def add_model(
    parser: argparse.ArgumentParser, help: str = "MJCF or parameter .json file (default: the embedded SAMII model)", *, metavar: str = "XML"
) -> None:
    """``--model``: the simulator's model file."""
    parser.add_argument("--model", metavar=metavar, type=nonempty_path, help=help)


def add_set(parser: argparse.ArgumentParser, help: str = "override a model parameter (samii params lists them); repeatable") -> None:
    """``--set NAME=VALUE``, repeatable (``args.set``: the texts, parsed by the command)."""
    parser.add_argument("--set", metavar="NAME=VALUE", action="append", default=[], help=help)


#: --rerun-fps's help where a command keeps every frame.
RERUN_FPS_HELP = "animation frames per second in the recording (default: 4 per period of base mode 3, at least 100)"


def add_rerun(parser: argparse.ArgumentParser, help: str, *, fps_help: str = RERUN_FPS_HELP) -> None:
    """``--rerun FILE.rrd`` (a Rerun recording beside the outputs) and ``--rerun-fps F``, its frame rate."""
    parser.add_argument("--rerun", metavar="FILE.rrd", type=nonempty_path, help=help)
    parser.add_argument("--rerun-fps", metavar="F", type=positive_float, default=None, help=fps_help)


def _antialias(text: str) -> str | float:
    if text.strip().lower() == "auto":
        return "auto"
    v = _number(text)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"expected auto or a corner > 0 Hz, got {text!r}")
    return v


_antialias.__name__ = "corner"


def add_antialias(parser: argparse.ArgumentParser) -> None:
    """``--antialias [HZ]``: the controller card's anti-alias filter (``args.antialias``: None, "auto" or the corner)."""
    parser.add_argument(
        "--antialias",
        nargs="?",
        const="auto",
        default=None,
        type=_antialias,
        metavar="HZ",
        help="the controller's data acquisition filters theta and accel before it samples them: an 8th-order Butterworth "
        "low-pass, as the measurement's DAQ, at HZ or, without it, at a quarter of the controller's sample rate (default: none)",
    )


def add_seed(parser: argparse.ArgumentParser, help: str, *, default: int | None = 0) -> None:
    """``--seed S``: a random generator's seed, an integer >= 0."""
    parser.add_argument("--seed", type=seed, default=default, help=help)


def add_no_progress(parser: argparse.ArgumentParser) -> None:
    """``--no-progress``: no progress display on stderr."""
    parser.add_argument("--no-progress", action="store_true", help="no progress display on stderr")
