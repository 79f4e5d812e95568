"""Where the test suite's time goes (issue 34, item 4: the README's test command in at most 6 minutes on 2 cores).

Runs the README's test command (``pytest``: pytest-xdist over the machine's cores, pyproject.toml) with a hook in
every Python process it starts (the pytest workers, the processes they fork, the commands they run), and prints:

- the wall time against the goal, and how busy the workers were: the sum of the tests' own durations per worker
  against the wall time (pytest's ``--durations``; a worker waiting on a lock, a sleep or a subprocess counts as busy);
- the CPU seconds of every process together, and how many of them went to each kind of work the hook times:
  least-squares fits (``scipy.optimize.least_squares``: samii.diagnose's, samii.identify's and the calibrations'),
  figures (matplotlib's ``Figure.savefig`` and ``tight_layout``: drawing and laying out, not building them),
  simulation (``mujoco.rollout.rollout``, ``mujoco.mj_step``) and sympy's ``simplify``; what is left is everything
  else (imports, building figures, FRF estimation, the tests' own work);
- the same by test module, most CPU first, and the slowest tests.

Goal: the suite's wall time at most 360 s on 2 cores, on the machine issue 34 was measured on: the wall time here is
also printed scaled to that machine by the plain step (``_timing.on_issue_machine``). The CPU is the measure to bring
down: with the workers busy all along, the wall time is about the CPU seconds divided by the cores.

    python benchmarks/suite_cost.py [--top 20] [-- PYTEST_ARGS...]

(``-- tests/test_diagnose_units.py`` measures one module; ``-n 0`` one process.) A process started with an
environment of its own that drops ``PYTHONPATH`` is not counted. The hook changes no result: it times the calls
and passes them on.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _timing import goal_line, step_yardstick, yardstick_line

GOAL_S = 360.0

#: sitecustomize.py put first on PYTHONPATH: per process, the CPU seconds spent in a few functions, by the test running
#: (PYTEST_CURRENT_TEST, which pytest sets in the environment its subprocesses inherit), written as JSON lines at exit
#: (also at os._exit, which samii's command and forked workers end with); a forked child starts its counts afresh.
HOOK = r"""
import atexit, importlib.abc, importlib.util, json, os, sys, time

_OUT = os.environ["SAMII_SUITE_COST_OUT"]
_acc, _busy, _start = {}, set(), [time.process_time(), None]


def _test():
    return os.environ.get("PYTEST_CURRENT_TEST", "").rsplit(" ", 1)[0] or None


def _timed(kind, f):
    def timed(*a, **k):
        if kind in _busy:  # (nested: counted once, by the outer call)
            return f(*a, **k)
        _busy.add(kind)
        t = time.process_time()
        try:
            return f(*a, **k)
        finally:
            _busy.discard(kind)
            key = (_test(), kind)
            _acc[key] = _acc.get(key, 0.0) + time.process_time() - t

    timed.__wrapped__ = f
    return timed


def _dump():
    key = (_start[1], "process")
    _acc[key] = _acc.get(key, 0.0) + time.process_time() - _start[0]
    rows = [json.dumps({"test": t, "kind": k, "s": s, "pid": os.getpid()}) for (t, k), s in _acc.items()]
    _acc.clear()
    with open(_OUT, "a") as fh:
        fh.write("".join(r + "\n" for r in rows))


def _forked():
    _acc.clear()
    _busy.clear()
    _start[:] = [time.process_time(), _test()]


_start[1] = _test()
os.register_at_fork(after_in_child=_forked)
atexit.register(_dump)
_exit = os._exit


def _exit_counted(code):
    try:
        _dump()
    except Exception:
        pass
    _exit(code)


os._exit = _exit_counted
_PATCH = {
    "scipy.optimize._lsq.least_squares": [(None, "least_squares", "fits")],
    "matplotlib.figure": [("Figure", "savefig", "figures"), ("Figure", "tight_layout", "figures")],
    "mujoco": [(None, "mj_step", "simulation")],
    "mujoco.rollout": [(None, "rollout", "simulation")],
    "sympy.simplify.simplify": [(None, "simplify", "sympy")],
}


class _Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name not in _PATCH:
            return None
        sys.meta_path.remove(self)
        try:
            spec = importlib.util.find_spec(name)
        finally:
            sys.meta_path.insert(0, self)
        if spec is None or spec.loader is None:
            return spec
        run = spec.loader.exec_module

        def exec_module(module):
            run(module)
            for owner, attr, kind in _PATCH[name]:
                obj = getattr(module, owner) if owner else module
                setattr(obj, attr, _timed(kind, getattr(obj, attr)))

        spec.loader.exec_module = exec_module
        return spec


sys.meta_path.insert(0, _Finder())
"""

KINDS = ("fits", "figures", "simulation", "sympy")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--top", type=int, default=20, help="modules and slowest tests to list")
    ap.add_argument("pytest_args", nargs="*", help="after --: passed to pytest")
    args = ap.parse_args()
    root = Path(__file__).resolve().parent.parent
    step = step_yardstick()  # (before the suite, on a quiet machine)
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "sitecustomize.py").write_text(HOOK)
        out = Path(tmp) / "cost.jsonl"
        env = dict(os.environ, SAMII_SUITE_COST_OUT=str(out), PYTHONPATH=os.pathsep.join(filter(None, [tmp, os.environ.get("PYTHONPATH")])))
        cmd = [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-v", "--durations=0", *args.pytest_args]
        t = time.perf_counter()
        run = subprocess.run(cmd, cwd=root, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        wall = time.perf_counter() - t
        rows = [json.loads(line) for line in out.read_text().splitlines()] if out.exists() else []
    text = run.stdout.splitlines()
    print(next((ln for ln in reversed(text) if re.search(r"(passed|failed).* in [0-9.]+s", ln)), f"pytest exit {run.returncode}"))
    if run.returncode != 0:
        print("\n".join(text[-40:]))
        print(f"the suite did not pass (exit {run.returncode}): its times are not the suite's")
    # the tests' own durations, by worker ("[gw0] [ 3%] PASSED tests/...::name")
    worker = {m.group(2): m.group(1) for ln in text if (m := re.match(r"\[(gw\d+)\] \[\s*\d+%\] \w+ (\S+)", ln))}
    durations = [(float(m.group(1)), m.group(2), m.group(3)) for ln in text if (m := re.match(r"([0-9.]+)s (call|setup|teardown)\s+(\S+)", ln))]
    busy: dict[str, float] = collections.defaultdict(float)
    for s, _, test in durations:
        busy[worker.get(test, "main")] += s
    print(yardstick_line(step))
    print(goal_line("the suite's wall time", wall, GOAL_S, step))
    print("busy (the tests' durations per worker): " + ", ".join(f"{w} {s:.0f} s ({s / wall:.0%})" for w, s in sorted(busy.items())))
    cpu = sum(r["s"] for r in rows if r["kind"] == "process")
    by_kind = {k: sum(r["s"] for r in rows if r["kind"] == k) for k in KINDS}
    cores = os.cpu_count() or 1
    print(
        f"CPU of every process: {cpu:.0f} s ({cpu / (wall * cores):.0%} of {cores} cores over the wall time), in {sum(r['kind'] == 'process' for r in rows)} processes"
    )
    for k in KINDS:
        print(f"  {k:<11} {by_kind[k]:7.0f} s  {by_kind[k] / max(cpu, 1e-9):5.0%}")
    rest = cpu - sum(by_kind.values())
    print(f"  {'the rest':<11} {rest:7.0f} s  {rest / max(cpu, 1e-9):5.0%}")
    # by module: a pytest worker's own process is counted from its start, before any test, so its CPU is no module's;
    # a module's is that of the processes its tests started (forks, commands), and the kinds' times wherever they ran
    mods: dict[str, dict[str, float]] = collections.defaultdict(lambda: collections.defaultdict(float))
    for r in rows:
        if r["test"]:
            mods[r["test"].split("::")[0]][r["kind"]] += r["s"]
    wall_mod: dict[str, float] = collections.defaultdict(float)
    for s, _, test in durations:
        wall_mod[test.split("::")[0]] += s
    print(
        f"\nby module (durations: the tests' wall time; started: the CPU of the processes they forked or ran; the kinds: CPU, those included), top {args.top}"
    )
    print(f"{'module':<44} {'durations':>9} {'started':>9} " + " ".join(f"{k:>10}" for k in KINDS))
    for m, s in sorted(wall_mod.items(), key=lambda x: -x[1])[: args.top]:
        print(f"{m:<44} {s:9.0f} {mods[m].get('process', 0.0):9.0f} " + " ".join(f"{mods[m].get(k, 0.0):10.0f}" for k in KINDS))
    print(f"\nslowest {args.top}")
    for s, phase, test in sorted(durations, reverse=True)[: args.top]:
        print(f"{s:7.1f} s {phase:<8} {test}")
    return run.returncode


if __name__ == "__main__":
    sys.exit(main())
