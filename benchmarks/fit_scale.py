"""How ``samii fit`` scales with the number of frequency points.

Rig FFTs have thousands of lines; the notebook's swept sine had a few hundred.
This writes synthetic FRF files of 247 (what ``samii measure`` writes by
default), 10,000 and 100,000 points and times ``samii fit FILE --out DIR``
on each, in this process (``samii.cli.main``, after a warm-up run, so
Python's start-up and imports, about 1.5-2.5 s on the shared machine, are not
counted; ``--subprocess`` also times the whole command). Printed per size: the
time to read the file, to fit, and of the whole command (read, fit, JSON and
plots), each the median of ``--repeats`` runs, and the ratios of the fit's
and the command's times to the 247-point run's, measured in the same run.

Goals (issue: fit scale): time linear in the points; 10,000 points under 2 s,
100,000 under 20 s.

Data: ``samii.identify.studies.synthetic_rig_frf`` (eq 9.4 in SI plus the
stand-in rig's unmodelled effects and 3-average swept-sine noise, coherence
included) on a log grid over 0.1-40 Hz (``--grid linear``: FFT-like lines
40/N ... 40 Hz). Run::

    python benchmarks/fit_scale.py [--repeats 3] [--grid log|linear] [--subprocess]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _timing import median_time

from samii.cli import main as samii_main
from samii.formats import read_frf_csv, write_frf_csv
from samii.identify.fit import fit
from samii.identify.studies import synthetic_rig_frf

SIZES = (247, 10_000, 100_000)
GOALS_S = {10_000: 2.0, 100_000: 20.0}


def write_data(folder: Path, n: int, grid: str) -> Path:
    f = np.geomspace(0.1, 40.0, n) if grid == "log" else np.linspace(40.0 / n, 40.0, n)
    return write_frf_csv(synthetic_rig_frf(f, rng=np.random.default_rng(2003)), folder / f"frf_{n}.csv", overwrite=True)


def command(path: Path, out: Path) -> None:
    with contextlib.redirect_stdout(io.StringIO()):
        code = samii_main(["fit", str(path), "--out", str(out), "--overwrite", "--no-progress"])
    if code != 0:
        raise SystemExit(f"samii fit {path} exited with {code}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3, help="runs per size; the median is printed (default 3)")
    ap.add_argument("--grid", choices=("log", "linear"), default="log")
    ap.add_argument("--subprocess", action="store_true", help="also time the whole `samii fit` command in a new process (start-up included)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        files = {n: write_data(folder, n, args.grid) for n in SIZES}
        command(files[SIZES[0]], folder / "warm-up")  # imports, caches
        rows = []
        for n in SIZES:
            path, out = files[n], folder / f"out_{n}"
            t_read = median_time(lambda: read_frf_csv(path), args.repeats)  # noqa: B023 - called within this iteration
            data = read_frf_csv(path)
            t_fit = median_time(lambda: fit(data, weighting="auto"), args.repeats)  # noqa: B023 - called within this iteration
            t_cmd = median_time(lambda: command(path, out), args.repeats)  # noqa: B023 - called within this iteration
            t_proc = None
            if args.subprocess:
                t = time.perf_counter()
                subprocess.run(
                    [sys.executable, "-m", "samii.cli", "fit", str(path), "--out", str(out), "--overwrite", "--no-progress"],
                    check=True,
                    stdout=subprocess.DEVNULL,
                )
                t_proc = time.perf_counter() - t
            rows.append((n, path.stat().st_size / 2**20, t_read, t_fit, t_cmd, t_proc))
    base, base_fit = rows[0][4], rows[0][3]
    print(f"samii fit on synthetic FRF files ({args.grid} grid 0.1-40 Hz), median of {args.repeats} runs in this process")
    head = (
        f"{'points':>8} {'file MB':>8} {'read [s]':>9} {'fit [s]':>8} {'fit ratio':>9} {'command [s]':>12} {'cmd ratio':>9} "
        f"{'points ratio':>12} {'us/point':>9} {'goal':>10}"
    )
    if args.subprocess:
        head += f" {'new process [s]':>16}"
    print(head)
    for n, mb, t_read, t_fit, t_cmd, t_proc in rows:
        goal = GOALS_S.get(n)
        verdict = "" if goal is None else (f"<{goal:g} s {'met' if t_cmd < goal else 'NOT MET'}")
        line = (
            f"{n:>8d} {mb:8.2f} {t_read:9.3f} {t_fit:8.3f} {t_fit / base_fit:9.1f} {t_cmd:12.3f} {t_cmd / base:9.1f} "
            f"{n / rows[0][0]:12.1f} {1e6 * t_cmd / n:9.1f} {verdict:>10}"
        )
        if args.subprocess:
            line += f" {t_proc:16.2f}"
        print(line)
    print("fit = samii.identify.fit(data, weighting='auto'): 4 starts, refinement on all points (above 1000), uncertainty, lack of fit")
    print("command = samii.cli.main(['fit', FILE, '--out', DIR]): read + fit + text report + fit.json + bode_fit.png; ratios to the 247-point run")


if __name__ == "__main__":
    main()
