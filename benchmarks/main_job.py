"""How long the main job takes (``samii``: the whole pipeline on the embedded model), stage by stage, on this
machine's cores and, as the baseline measured in the same run, in one process (``SAMII_WORKERS=1``: every stage one
after the other, as before issue 34). The folder is the same either way (every file but time stamps and the
recordings' ids, compared when this was written).

Goal (issue 34, item 3): the main job in at most 12 s on 2 cores, on the machine the issue was measured on: the time
here is also printed scaled to that machine by the plain step (``_timing.on_issue_machine``).

    python benchmarks/main_job.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile

from _timing import goal_line, step_yardstick, yardstick_line

_RUN = """
import json, sys, tempfile, time
from samii import pipeline

class Stages:
    def __init__(self):
        self.t, self.name, self.times = time.perf_counter(), None, {}
    def expect(self, n): pass
    def advance(self, n=1): pass
    def stage(self, name):
        now = time.perf_counter()
        if self.name is not None:
            self.times[self.name] = self.times.get(self.name, 0.0) + now - self.t
        self.t, self.name = now, name

p = Stages()
t = time.perf_counter()
pipeline.run(sys.argv[1], progress=p)
p.stage(None)
print(json.dumps({"total": time.perf_counter() - t, "stages": p.times}))
"""


def _once(workers: str | None) -> dict:
    """The main job in a fresh process (imports warm from the disk cache, as a user's second run)."""
    import json

    env = dict(os.environ)
    env.pop("SAMII_WORKERS", None)
    if workers:
        env["SAMII_WORKERS"] = workers
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run([sys.executable, "-c", _RUN, os.path.join(tmp, "run")], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3, help="runs of each, interleaved; the median is kept (default 3)")
    args = ap.parse_args()
    runs: dict[str, list[dict]] = {"this machine's cores": [], "one process (SAMII_WORKERS=1)": []}
    _once(None)  # warm the disk cache
    for _ in range(args.repeats):
        runs["this machine's cores"].append(_once(None))
        runs["one process (SAMII_WORKERS=1)"].append(_once("1"))
    print(f"the main job on the embedded model, {os.cpu_count()} cores, median of {args.repeats} runs of each (library call, wall time)")
    step = step_yardstick()
    print(yardstick_line(step))
    totals = {}
    for label, rs in runs.items():
        totals[label] = statistics.median(r["total"] for r in rs)
        each = ", ".join(f"{r['total']:.1f}" for r in rs)
        print(f"  {label:<32} {totals[label]:5.1f} s  (runs {each})")
    base, fast = totals["one process (SAMII_WORKERS=1)"], totals["this machine's cores"]
    print(f"on the cores / in one process: {fast / base:.2f}")
    print(goal_line("the main job on the cores", fast, 12.0, step))
    print("stages (median, s): on the cores | in one process")
    names = list(runs["this machine's cores"][0]["stages"])
    for n in names:
        a = statistics.median(r["stages"].get(n, 0.0) for r in runs["this machine's cores"])
        b = statistics.median(r["stages"].get(n, 0.0) for r in runs["one process (SAMII_WORKERS=1)"])
        print(f"  {n:<52} {a:5.2f} | {b:5.2f}")


if __name__ == "__main__":
    main()
