"""The commands' progress bar: a :class:`samii.progress.Progress` shown by tqdm on stderr.

One bar for every command: on a terminal only unless the command says otherwise, never with ``--no-progress``; made at the
call's first report (the library calls report once their request has passed its checks, so a refusal shows none);
its stage after the units as a postfix.
"""

from __future__ import annotations

import sys
import time

__all__ = ["Bar"]


class Bar:
    """A tqdm bar on stderr that a library call reports to (stage, advance, expect).

    ``desc`` names the command; ``disable`` is tqdm's: None shows the bar on a terminal only, True never
    (``--no-progress``), False on any stderr (``samii measure``'s and ``samii design``'s, as before); ``delay`` [s]:
    shown only once the call has taken that long (its stages too); the other options are tqdm's (``unit``, what the
    call counts; ``total``, when the command knows it before the call does; ``leave``, ``unit_scale``, ``bar_format``).
    """

    def __init__(self, desc: str, *, disable: bool | None = None, delay: float = 0.0, **options) -> None:
        self._options = dict(desc=desc, disable=disable, delay=delay, file=sys.stderr, dynamic_ncols=True, **options)
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
