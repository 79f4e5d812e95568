"""Screenshots of samii's Rerun recordings in the real Rerun viewer, headless, for the README.

* ``assets/rerun_measure.png``: ``samii measure``'s default swept-sine run (0.1 V, 0.1-40 Hz,
  sensor noise on) at the moment of its largest tip deflection: the sweep passing base mode 1;
* ``assets/rerun_closedloop.png``: ``samii closedloop --controller damping --scenario release``:
  the tip impulse, the damping controller beside the servo loop alone (Figure 11.4's comparison),
  0.4 s after the impulse.

Each recording is made by the command a user runs, then opened in the viewer that comes with
rerun-sdk without a window (``samii.viz.viewer``; needs a Vulkan driver, e.g. Debian's
``mesa-vulkan-drivers``), the time cursor put at the moment shown, and the window saved.
The time of the largest deflection is read back from the recording (its tip series).

    python experiments/rerun_view/run.py [--keep DIR]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
ASSETS = ROOT / "assets"


def tip_series(rrd: Path, run: str) -> tuple[np.ndarray, np.ndarray]:
    """(t [s], tip displacement [mm]) of run ``run`` as logged in ``rrd``."""
    from samii.viz.recording import read_scalars

    return read_scalars(rrd, f"/{run}/displacement_mm/tip")[f"/{run}/displacement_mm/tip"]


def samii(*args: str) -> None:
    """The ``samii`` command installed beside this Python."""
    subprocess.run([str(Path(sys.executable).parent / "samii"), *args], check=True, cwd=ROOT, stdout=subprocess.DEVNULL)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--keep", type=Path, help="keep the recordings in this folder")
    args = parser.parse_args(argv)
    from samii.viz.viewer import graphics_available

    if not graphics_available():
        print("no Vulkan driver: install one (e.g. apt-get install mesa-vulkan-drivers)", file=sys.stderr)
        return 1
    if args.keep is None:
        with tempfile.TemporaryDirectory(prefix="samii-rerun-view-") as tmp:
            return make(Path(tmp))
    args.keep.mkdir(parents=True, exist_ok=True)
    return make(args.keep)


def make(work: Path) -> int:
    from samii.viz.viewer import view_recording

    ASSETS.mkdir(exist_ok=True)

    rrd = work / "measure.rrd"
    samii("measure", "--no-progress", "--noise", "--seed", "1", "--out", str(work / "measure"), "--rerun", str(rrd), "--overwrite")
    t, tip = tip_series(rrd, "swept")
    t_peak = float(t[np.argmax(np.abs(tip))])
    report = view_recording(rrd, time_s=t_peak, screenshot=ASSETS / "rerun_measure.png")
    reports = [report]
    print(
        f"measure: largest tip deflection {np.max(np.abs(tip)):.3g} mm at t = {t_peak:.2f} s; viewer {report.viewer_version}; "
        f"{len(report.views)} views; wrote {report.screenshot}"
    )

    rrd = work / "closedloop.rrd"
    samii("closedloop", "--controller", "damping", "--scenario", "release", "--out", str(work / "closedloop"), "--rerun", str(rrd), "--overwrite")
    report = view_recording(rrd, time_s=0.4, screenshot=ASSETS / "rerun_closedloop.png")
    print(f"closedloop: viewer {report.viewer_version}; {len(report.views)} views; wrote {report.screenshot}")
    for r in reports + [report]:
        for v in r.views:
            if v.problems:
                print(f"  view {v.name!r}: {'; '.join(v.problems)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
