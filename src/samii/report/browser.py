"""A screenshot of a page in a real headless browser: Chromium, from the system's packages.

Used to check ``report.html`` as a reader sees it (``samii report DIR --screenshot PNG``, the
report's test and ``experiments/report``). Chromium's ``--screenshot`` captures its window only, so
the window is made tall and the empty rows below the page are cut off.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from samii.outputs import create_parent

__all__ = ["find_browser", "screenshot", "Screenshot"]

_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")


@dataclass(frozen=True)
class Screenshot:
    path: Path
    width: int
    height: int  #: after cutting the empty rows below the page
    browser: str


def find_browser() -> str | None:
    """The Chromium to use: ``$SAMII_BROWSER`` if set, else the first of chromium, chromium-browser, google-chrome on PATH."""
    env = os.environ.get("SAMII_BROWSER")
    if env:
        return shutil.which(env) or (env if Path(env).is_file() else None)
    for name in _NAMES:
        found = shutil.which(name)
        if found:
            return found
    return None


def screenshot(page: Path, png: Path, *, width: int = 1200, max_height: int = 16000, timeout_s: float = 30.0) -> Screenshot:
    """Render ``page`` (a local HTML file) headless at ``width`` px and save it as ``png``, cut below the page's end.

    Raises ``RuntimeError`` when no browser is found or it fails. The browser reaches no network: every
    host name resolves to nowhere (``--host-resolver-rules``) and every address, a literal IP or
    loopback included, goes through a proxy on a closed port (the discard port, 9), so a page that
    needed the network would show it.
    """
    from PIL import Image, ImageChops  # (lazy: imports PIL, only when called)

    browser = find_browser()
    if browser is None:
        raise RuntimeError("no Chromium found (apt-get install chromium, or set SAMII_BROWSER)")
    page, png = Path(page).absolute(), Path(png)
    last = ""
    for _attempt in range(3):  # headless Chromium now and then never exits after writing; see _run
        with tempfile.TemporaryDirectory(prefix="samii-browser-", ignore_cleanup_errors=True) as profile:
            raw = Path(profile) / "shot.png"
            cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--no-first-run", "--mute-audio",
                   f"--user-data-dir={profile}", "--host-resolver-rules=MAP * ~NOTFOUND", "--proxy-server=127.0.0.1:9", "--proxy-bypass-list=<-loopback>", "--run-all-compositor-stages-before-draw",
                   f"--window-size={width},{max_height}", f"--screenshot={raw}", page.as_uri()]  # fmt: skip
            ok, last = _run(cmd, raw, timeout_s)
            if ok:
                img = Image.open(raw).convert("RGB")
                break
    else:
        raise RuntimeError(f"{Path(browser).name} failed on {page}: {last}")
    bg = img.getpixel((img.width - 1, img.height - 1))  # the page's background, below its end
    box = ImageChops.difference(img, Image.new("RGB", img.size, bg)).point(lambda v: 255 if v > 6 else 0).getbbox()
    bottom = box[3] + 24 if box else img.height
    img = img.crop((0, 0, img.width, min(bottom, img.height)))

    img.save(create_parent(png), optimize=True)
    return Screenshot(png, img.width, img.height, Path(browser).name)


def _run(cmd: list[str], raw: Path, timeout_s: float) -> tuple[bool, str]:
    """Run the browser until it exits or its screenshot is complete (about 1 run in 10, headless Chromium
    150 writes the file and then never exits: it is stopped once the file has stopped growing and reads
    as a whole PNG). Returns (screenshot written, why not)."""
    from PIL import Image  # (lazy: imports PIL, only when called)

    log = raw.with_name("browser.log")  # a file, not a pipe: a chatty browser cannot block on a full pipe
    with open(log, "w") as err_file:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err_file)
    deadline = time.monotonic() + timeout_s
    size = -1
    try:
        while time.monotonic() < deadline:
            try:
                proc.wait(timeout=0.5)
                break
            except subprocess.TimeoutExpired:
                pass
            now = raw.stat().st_size if raw.is_file() else -1
            if now > 0 and now == size:
                try:
                    Image.open(raw).load()
                    return True, ""
                except OSError:
                    pass
            size = now
        else:
            return False, f"no screenshot after {timeout_s:g} s"
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    err = log.read_text(errors="replace") if log.is_file() else ""
    if proc.returncode != 0 or not raw.is_file():
        said = " | ".join(err.strip().splitlines()[-3:])
        return False, f"exit {proc.returncode}" + (f": {said}" if said else "") + ("" if raw.is_file() else ", no screenshot written")
    return True, ""
