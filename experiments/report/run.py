"""The main job's report.html as a reader sees it: screenshots in a real headless Chromium, for the README.

Runs ``samii run`` (the embedded model, seed 0) into a temporary folder, or uses ``--folder`` if given,
renders its ``report.html`` in Debian's Chromium with every host unreachable (the page must need no
network), and writes

* ``assets/report.png``: the page's first screen (header, summary, model);
* ``assets/report_control.png``: the control section (the closed-loop table, Figures 11.1-11.5, the damping controller);
* ``experiments/report/out/report_full.png``: the whole page at half scale, for its layout.

    python experiments/report/run.py [--folder SAMII_RUN]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ASSETS = ROOT / "assets"
OUT = Path(__file__).resolve().parent / "out"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--folder", type=Path, help="an existing main job's folder (default: run samii into a temporary one)")
    args = ap.parse_args()
    from PIL import Image

    from samii.report.browser import screenshot

    with tempfile.TemporaryDirectory() as tmp:
        folder = args.folder
        if folder is None:
            folder = Path(tmp) / "samii_run"
            subprocess.run(
                [str(Path(sys.executable).parent / "samii"), "run", "--out", str(folder), "--no-progress"], check=True, stdout=subprocess.DEVNULL
            )
        full = Path(tmp) / "full.png"
        shot = screenshot(folder / "report.html", full, width=1200)
        img = Image.open(full)
        print(f"page: {shot.width}x{shot.height} px ({shot.browser})")
        ASSETS.mkdir(exist_ok=True)
        OUT.mkdir(exist_ok=True)
        img.crop((0, 0, img.width, min(img.height, 1300))).save(ASSETS / "report.png", optimize=True)
        # the control section alone: the same page cut before its heading and after it (same style, same figures)
        page = (folder / "report.html").read_text(encoding="utf-8")
        head, rest = page.split("<main>", 1)
        section = rest[rest.index('<h2 id="control">') : rest.index('<h2 id="diagnosis">')]
        cut = folder / ".report_control.html"
        cut.write_text(f"{head}<main>{section}</main></body></html>", encoding="utf-8")
        try:
            screenshot(cut, ASSETS / "report_control.png", width=1200)
        finally:
            cut.unlink()
        half = img.resize((img.width // 2, img.height // 2), Image.LANCZOS)
        half.quantize(colors=256).save(OUT / "report_full.png", optimize=True)  # a palette: a third of the size, the same to the eye
        for p in (ASSETS / "report.png", ASSETS / "report_control.png", OUT / "report_full.png"):
            print(f"wrote {p.relative_to(ROOT)} ({Image.open(p).size[0]}x{Image.open(p).size[1]}, {p.stat().st_size / 1e3:.0f} kB)")


if __name__ == "__main__":
    main()
