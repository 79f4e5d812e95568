"""The commands' progress bar: a :class:`samii.progress.Progress` shown by tqdm on stderr.

One bar for every command: on a terminal only (tqdm's ``disable=None``), never with ``--no-progress``; made at the
call's first report (the library calls report once their request has passed its checks, so a refusal shows none);
its stage after the units as a postfix.
"""

from __future__ import annotations

import sys
import time

__all__ = ["Bar"]


class Bar:
    """A tqdm bar on stderr that a library call reports to (stage, advance, expect).

    ``desc`` names the command; ``unit`` its units (what the call it is given counts); ``total`` when the command
    knows it before the call does (the call's ``expect`` replaces it); ``delay`` [s]: shown only once the call has
    taken that long (and its stages too); ``leave``: kept on screen when done; ``bar_format``: tqdm's, where the
    default does not say it; ``terminal_only`` False: shown on any stderr (``samii measure``'s, as before).
    """

    def __init__(
        self,
        desc: str,
        *,
        unit: str = "step",
        total: float | None = None,
        enabled: bool = True,
        terminal_only: bool = True,
        delay: float = 0.0,
        leave: bool = True,
        unit_scale: bool = False,
        bar_format: str | None = None,
    ) -> None:
        self._options = dict(
            desc=desc,
            unit=unit,
            total=total,
            delay=delay,
            leave=leave,
            unit_scale=unit_scale,
            file=sys.stderr,
            dynamic_ncols=True,
            disable=(None if terminal_only else False) if enabled else True,
            **({"bar_format": bar_format} if bar_format else {}),
        )
        self._delay = delay
        self._start = time.monotonic()
        self._bar = None

    def _make(self):
        from tqdm import tqdm

        self._bar = tqdm(**self._options)
        return self._bar

    @property
    def bar(self):
        """The tqdm bar (made on first use)."""
        return self._make() if self._bar is None else self._bar

    def _refresh(self) -> None:
        """Redraw for a stage or a total (an advance redraws itself): after the delay (a refresh shows a bar tqdm's
        delay still holds back), at most every tqdm mininterval (a log gets no more lines than the advances give);
        marked as printed, so that closing a ``leave=False`` bar clears it."""
        bar = self.bar
        if bar.disable:  # (a disabled tqdm keeps no clock)
            return
        now = bar._time()
        if time.monotonic() - self._start >= self._delay and now - bar.last_print_t >= bar.mininterval:
            bar.refresh()
            bar.last_print_t = now

    def stage(self, what: str) -> None:
        self.bar.set_postfix_str(what, refresh=False)
        self._refresh()

    def advance(self, n: float = 1) -> None:
        self.bar.update(n)

    def expect(self, total: float) -> None:
        if self._bar is None:  # made with it (tqdm draws a new bar itself)
            self._options["total"] = total
            self._make()
            return
        self.bar.total = total
        self._refresh()

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()

    def __enter__(self) -> Bar:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
