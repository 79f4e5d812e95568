"""The errors every stage raises and the exit codes the ``samii`` command maps them to.

Library code raises :class:`InputError` for input a user can fix (a file, an
option, a parameter value): its message is one line that names the file or
option, the line or column where that helps, and what was expected.
:class:`SimulationUnstable` marks a simulation that diverged or never reached a
usable state (a loop oscillating on its own, a valve sitting on its rails): a
finding about the model, not data. The command line (:mod:`samii.cli`) turns
them into one line on stderr and an exit code:

======  ==============================================================
code    meaning
======  ==============================================================
0       done
1       an internal error (a bug: please report it with ``SAMII_DEBUG=1``)
2       bad input: an option, a file, a parameter value
3       the simulation is unstable or diverged
130     interrupted (Ctrl-C); 128 + N for signal N (SIGTERM 143, SIGHUP 129)
======  ==============================================================

Imports nothing heavy.
"""

from __future__ import annotations

import contextlib

__all__ = [
    "EXIT_BAD_INPUT",
    "EXIT_INTERNAL",
    "EXIT_INTERRUPTED",
    "EXIT_OK",
    "EXIT_UNSTABLE",
    "InputError",
    "SimulationUnstable",
    "Interrupted",
]

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_BAD_INPUT = 2
EXIT_UNSTABLE = 3
EXIT_INTERRUPTED = 130


class InputError(ValueError):
    """Input a user can fix; the message is one line naming the file or option and what was expected."""


def input_error_of(path, exc: Exception) -> InputError:
    """A library's ValueError or KeyError on the data of ``path`` as bad input naming the file (once)."""
    text = str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)
    return InputError(text if text.startswith(str(path)) else f"{path}: {text}")


class SimulationUnstable(RuntimeError):
    """The simulation diverged (non-finite state, MuJoCo's bad-acceleration reset) or oscillates on its own."""


class Interrupted(KeyboardInterrupt):
    """A termination signal (SIGTERM, SIGHUP) turned into an exception, so ``finally`` blocks clean up."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


#: Signals the command line has received (``samii.cli`` appends to it). A handler's exception can be
#: swallowed by library code it interrupts (an optional import wrapped in a bare ``except``), so the
#: places that make a run's results permanent check this list too (:func:`raise_if_signalled`).
SIGNALS_RECEIVED: list[int] = []

#: The outputs a command has begun writing, once it has accepted its input (:class:`samii.outputs.OutputFolder`
#: on entry appends its folder): a ``ValueError`` that is not an :class:`InputError` after that is a failure of
#: ours, not of the input, and the command line reports it as one (exit 1); a full disk is named by them.
OUTPUTS_STARTED: list[str] = []


def mark_outputs_started(where) -> None:
    """Note that the run's input was accepted and its outputs are being written to ``where`` (see :data:`OUTPUTS_STARTED`)."""
    OUTPUTS_STARTED.append(str(where))


#: The outputs a command has put in place whole (its --out, after the commit): a signal received after that stops the
#: command, and the command line says they were complete, not that nothing was kept.
OUTPUTS_DONE: list[str] = []

_HOLDING = [0]


def holding() -> bool:
    """Inside :func:`uninterrupted`: the command line's signal handlers note a signal and let the block finish."""
    return _HOLDING[0] > 0


@contextlib.contextmanager
def uninterrupted(done=None):
    """The few renames that put a run's outputs in place (and remove what they replace): a signal received meanwhile
    takes effect when the block ends, never half-way (an interrupted swap left neither the old folder nor the new).
    ``done``: the outputs, marked complete (:data:`OUTPUTS_DONE`) when the block ends without an exception."""
    _HOLDING[0] += 1
    try:
        yield
    finally:
        _HOLDING[0] -= 1
    if done is not None and (not OUTPUTS_STARTED or OUTPUTS_STARTED[0] == str(done)):  # (the command's own --out, not a
        OUTPUTS_DONE.append(str(done))  # stage's folder inside the main job's staging)
    if not _HOLDING[0]:
        raise_if_signalled()


def raise_if_signalled() -> None:
    """Raise the interruption for a signal received earlier whose exception did not get through."""
    if SIGNALS_RECEIVED:
        signum = SIGNALS_RECEIVED[0]
        if signum == 2:  # SIGINT
            raise KeyboardInterrupt
        raise Interrupted(signum)
