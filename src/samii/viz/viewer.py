"""A recording opened in the real Rerun viewer, headless: what its views report, and a screenshot.

The viewer that comes with rerun-sdk runs without a window (``rerun --headless``, driven through
``rerun.experimental.ViewerClient``) on any Vulkan driver, a software one included (Mesa's
lavapipe: Debian's ``mesa-vulkan-drivers``). :class:`HeadlessViewer` opens a ``.rrd`` there,
moves the time cursor, lists the stored layout's views with what each reports it failed to show,
and saves screenshots of the window or of one view; :func:`view_recording` does it once.
"""

from __future__ import annotations

import glob
import os
import shutil
import socket
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

__all__ = ["ViewState", "ViewerReport", "HeadlessViewer", "graphics_available", "view_recording"]

#: Where Vulkan's loader looks for drivers (ICD manifests).
_ICD_DIRS = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d")


@dataclass(frozen=True)
class ViewState:
    """One view of the stored layout as the viewer shows it."""

    view_id: str
    kind: str  #: "3D", "TimeSeries", "TextLog", "TextDocument", ...
    name: str
    origin: str
    problems: tuple[str, ...]  #: what the view reports it could not show (empty when healthy)


@dataclass(frozen=True)
class ViewerReport:
    """What the viewer showed for a recording."""

    viewer_version: str
    views: tuple[ViewState, ...]
    time_s: float | None  #: where the time cursor was put
    screenshot: Path | None
    errors: tuple[str, ...]  #: the viewer's own error messages while showing it


def graphics_available() -> bool:
    """Whether a Vulkan driver is installed (a GPU's or a software one): the viewer needs one, with
    or without a window. ``VK_ICD_FILENAMES``/``VK_DRIVER_FILES`` count when set."""
    if os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES"):
        return True
    return any(glob.glob(os.path.join(d, "*.json")) for d in _ICD_DIRS)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class HeadlessViewer:
    """The Rerun viewer without a window, showing one recording: a context manager::

        with HeadlessViewer("run.rrd") as v:
            v.show(2.4)
            v.screenshot("run.png")                                  # the whole window, 1920x1080
            v.screenshot("3d.png", view="closedloop: true scale")    # one view, by name

    Raises RuntimeError when no viewer can start (see :func:`graphics_available`) or the
    recording does not load within ``timeout_s``."""

    def __init__(self, rrd, *, timeout_s: float = 60.0, settle_s: float = 0.4):
        self.rrd = Path(rrd).resolve()
        if not self.rrd.is_file():
            raise FileNotFoundError(f"{self.rrd}: no such recording")
        self.timeout_s, self.settle_s = timeout_s, settle_s
        self.time_s: float | None = None
        self._viewer = None

    def __enter__(self) -> HeadlessViewer:
        from rerun.experimental import ViewerClient  # (lazy: imports rerun, only when called)

        # the viewer writes its runtime files under XDG_RUNTIME_DIR; a container may not set one:
        # then a folder of its own for the spawned viewer, removed on exit (our environment unchanged)
        self._runtime_dir = None
        if not os.environ.get("XDG_RUNTIME_DIR"):
            self._runtime_dir = tempfile.mkdtemp(prefix="samii-rerun-")
            os.environ["XDG_RUNTIME_DIR"] = self._runtime_dir
        try:
            self._viewer = ViewerClient.spawn(headless=True, port=_free_port(), hide_welcome_screen=True)
        except Exception as exc:
            self._cleanup()
            raise RuntimeError(
                f"the Rerun viewer could not start headless (it needs a Vulkan driver, a software one will do: "
                f"Debian's mesa-vulkan-drivers): {' '.join(str(exc).split())}"
            ) from exc
        finally:
            if self._runtime_dir is not None:
                del os.environ["XDG_RUNTIME_DIR"]  # the spawned viewer has it
        try:
            self._viewer.get_state()  # the viewer answers (not another program on the port): raises within 15 s
            self._viewer.open(str(self.rrd))
            deadline = time.monotonic() + self.timeout_s
            while True:
                state = self._viewer.get_state()
                if not state.loading and any(r.timelines for r in state.recordings) and state.views:
                    break
                if time.monotonic() > deadline:
                    raise RuntimeError(f"{self.rrd}: the viewer did not finish loading it within {self.timeout_s:g} s")
                time.sleep(0.2)
            self._viewer.set_time(play_state="paused")
            self._settle()
        except BaseException:
            self._close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self._close()

    def _close(self) -> None:
        try:
            self._viewer.quit()
        except Exception:  # noqa: BLE001 - a viewer that will not quit must not hide the error that got us here
            pass
        finally:
            self._cleanup()

    def _cleanup(self) -> None:
        if self._runtime_dir is not None:
            shutil.rmtree(self._runtime_dir, ignore_errors=True)
            self._runtime_dir = None

    def show(self, time_s: float) -> None:
        """Put the time cursor at ``time_s`` on the ``time`` timeline, paused, and wait until the
        window stops changing: the viewer fetches a large recording's chunks for that time only
        then (until they arrive, bodies sit at the origin)."""
        self._viewer.set_time("time", duration=float(time_s), play_state="paused")
        self.time_s = float(time_s)
        self._settle()

    def _settle(self) -> None:
        """Wait until three small screenshots ``settle_s`` apart are identical (``timeout_s`` at most,
        then go on with what is shown)."""
        deadline = time.monotonic() + self.timeout_s
        shots: list[bytes] = []
        while time.monotonic() < deadline:
            time.sleep(self.settle_s)
            shots = (shots + [self._viewer.take_screenshot(max_size=640)])[-3:]
            if len(shots) == 3 and shots[0] == shots[1] == shots[2]:
                return

    def views(self) -> tuple[ViewState, ...]:
        """The stored layout's views as the viewer shows them, with what each failed to show."""
        return tuple(ViewState(v.view_id, v.view_class, v.name, v.origin,
                               tuple(f"{r.severity}: {r.summary}" + (f" ({r.details})" if r.details else "") for r in v.reports))
                     for v in self._viewer.get_state().views)  # fmt: skip

    def screenshot(self, path, *, view: str | None = None) -> Path:
        """Save the window (or the view named ``view``) as a PNG at ``path``."""
        path = Path(path).resolve()
        path.parent.mkdir(parents=True, exist_ok=True)
        view_id = None
        if view is not None:
            found = [v.view_id for v in self.views() if v.name == view]
            if not found:
                raise KeyError(f"{self.rrd}: no view named {view!r} (views: {', '.join(v.name for v in self.views())})")
            view_id = found[0]
        self._viewer.save_screenshot(str(path), view_id=view_id)
        return path

    def errors(self) -> tuple[str, ...]:
        """The viewer's own error messages so far."""
        return tuple(e.message for e in self._viewer.get_logs() if e.level.lower() == "error")

    def report(self, screenshot: Path | None = None) -> ViewerReport:
        return ViewerReport(self._viewer.get_state().viewer_version or "", self.views(), self.time_s, screenshot, self.errors())


def view_recording(rrd, *, time_s: float | None = None, screenshot=None, timeout_s: float = 60.0) -> ViewerReport:
    """Open ``rrd`` in a headless Rerun viewer (:class:`HeadlessViewer`), put the time cursor at
    ``time_s`` (default: where the viewer puts it, paused), report its views, and with
    ``screenshot`` (a .png path) save the whole window (1920x1080) there."""
    with HeadlessViewer(rrd, timeout_s=timeout_s) as v:
        if time_s is not None:
            v.show(time_s)
        shot = v.screenshot(screenshot) if screenshot is not None else None
        return v.report(shot)
