"""What a long library call reports while it runs: the stage it is in, and how far it has come.

The library reports to a :class:`Progress` it is given; what shows it (a tqdm bar on a terminal) is the command
line's. A call given no progress reports to :data:`SILENT`.
"""

from __future__ import annotations

from typing import Protocol

__all__ = ["Progress", "SILENT"]


class Progress(Protocol):
    def stage(self, what: str) -> None:
        """The call is now doing ``what`` (a phrase: "fitting the notebook's 3-mode model")."""

    def advance(self, n: int = 1) -> None:
        """``n`` more units of the call's work are done (its stages, unless the call says otherwise)."""


class _Silent:
    def stage(self, what: str) -> None:
        pass

    def advance(self, n: int = 1) -> None:
        pass


#: Progress that goes nowhere.
SILENT: Progress = _Silent()
