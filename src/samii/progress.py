"""What a long library call reports while it runs: the stage it is in, and how far it has come.

Every long call (the main job's pipeline, a Bode test, a simulation, a fit, a diagnosis, a robustness study, the
notebook's seed report, the damping design) reports to a :class:`Progress` it is given: ``expect(total)`` once it
knows how many units of work it has (physics steps, fit stages, samples, candidates: each call says which),
``advance(n)`` as units are done, ``stage(what)`` for what it is doing. What shows it (a tqdm bar on a terminal) is
the command line's (``samii.cli_progress``). A call given no progress reports to :data:`SILENT`.

A call that runs another long call hands it :func:`part`: a share of its own units (the nested call's total mapped
onto it), its stages said with a prefix, its ``expect`` kept to itself.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

__all__ = ["Progress", "SILENT", "part", "said"]


class Progress(Protocol):
    def stage(self, what: str) -> None:
        """The call is now doing ``what`` (a phrase: "fitting the notebook's 3-mode model")."""

    def advance(self, n: float = 1) -> None:
        """``n`` more units of the call's work are done."""

    def expect(self, total: float) -> None:
        """The call's work is ``total`` units (said once, before it advances; a call that cannot know never says)."""


class _Silent:
    def stage(self, what: str) -> None:
        pass

    def advance(self, n: float = 1) -> None:
        pass

    def expect(self, total: float) -> None:
        pass


#: Progress that goes nowhere.
SILENT: Progress = _Silent()


class _Part:
    def __init__(self, parent: Progress, units: float, prefix: str) -> None:
        self._parent, self._units, self._prefix = parent, float(units), prefix
        self._scale = 0.0 if units == 0 else 1.0  # until the nested call says its total

    def stage(self, what: str) -> None:
        self._parent.stage(self._prefix + what)

    def advance(self, n: float = 1) -> None:
        if self._scale:
            self._parent.advance(n * self._scale)

    def expect(self, total: float) -> None:
        self._scale = self._units / total if total > 0 and self._units else 0.0


def part(progress: Progress | None, units: float = 0.0, *, prefix: str = "") -> Progress:
    """The progress to hand a nested call: its work (its ``expect``) counts as ``units`` of ``progress``'s (0: it
    counts nothing, its stages are said only; before it says its total, one of its units is one of the parent's);
    its stages are said with ``prefix``."""
    return SILENT if progress is None or progress is SILENT else _Part(progress, units, prefix)


class _Said(_Silent):
    def __init__(self, say: Callable[[str], None]) -> None:
        self._say = say

    def stage(self, what: str) -> None:
        self._say(what)


def said(say: Callable[[str], None] | None) -> Progress:
    """A progress whose stages go to ``say`` (a line printer, say), the rest nowhere."""
    return SILENT if say is None else _Said(say)
