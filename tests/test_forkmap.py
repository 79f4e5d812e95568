"""samii.forkmap: computations of one stage in forked workers, equal to computing them in turn.

The forward selection's fits run through it (samii.diagnose.select): the diagnosis must be the same bit for bit
whatever the number of workers, and a fit must come back holding the parent's own kinds and baseline.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from samii import forkmap
from samii.diagnose.effects import library
from samii.diagnose.model import Baseline, Dataset, notebook_reference, start_params
from samii.diagnose.rig import EffectRig
from samii.diagnose.select import forward_select
from samii.errors import InputError
from samii.identify.structures import ModelStructure
from samii.measure.excitation import SweptSine
from samii.measure.measured import from_timeseries

pytestmark = pytest.mark.skipif("fork" not in __import__("multiprocessing").get_all_start_methods(), reason="no fork here")


@pytest.fixture
def two_workers(monkeypatch):
    monkeypatch.setenv("SAMII_WORKERS", "2")


class _Unpicklable:
    """Holds a lambda: pickling it fails, as pickling an effect kind would."""

    def __init__(self, k):
        self.k = k
        self.law = lambda x: x * k


def test_results_in_order_closures_and_shared_objects_by_reference(two_workers):
    shared = [_Unpicklable(k) for k in range(5)]
    scale = np.arange(3.0)  # a closure over the parent's data: the workers have it without pickling
    with forkmap.sharing(*shared):
        out = forkmap.fork_map(lambda s: (s, s.law(scale), os.getpid()), shared)
    assert [o[0] for o in out] == shared and all(o[0] is s for o, s in zip(out, shared))  # the parent's own objects
    for (_, v, _), s in zip(out, shared):
        np.testing.assert_array_equal(v, scale * s.k)
    assert {pid for *_, pid in out} - {os.getpid()}, "computed in workers"


def test_processes_bounds_the_workers_and_done_hears_every_item(monkeypatch):
    """``processes`` caps the workers whatever ``SAMII_WORKERS`` says (``samii robust --workers N``), 1 is this
    process; ``done`` is called here once per item as its result comes in (a progress bar's advance)."""
    import time

    monkeypatch.setenv("SAMII_WORKERS", "4")
    heard = []
    out = forkmap.fork_map(lambda x: (time.sleep(0.01), os.getpid())[1], range(12), processes=2, done=lambda: heard.append(os.getpid()))
    assert len(set(out) - {os.getpid()}) == 2 and heard == [os.getpid()] * 12
    heard.clear()
    assert forkmap.fork_map(lambda x: os.getpid(), range(3), processes=1, done=lambda: heard.append(1)) == [os.getpid()] * 3 and heard == [1] * 3


def test_an_unshared_object_that_cannot_travel_fails_loudly(two_workers):
    with pytest.raises(Exception, match="pickle|lambda"):
        forkmap.fork_map(lambda k: _Unpicklable(k), [1, 2])


def test_an_exception_in_a_worker_is_raised_in_the_parent(two_workers):
    def f(x):
        if x == 2:
            raise InputError(f"item {x}: bad")
        return x

    with pytest.raises(InputError, match="item 2: bad"):
        forkmap.fork_map(f, [1, 2, 3])


def test_nested_maps_run_serially_in_the_worker(two_workers):
    out = forkmap.fork_map(lambda x: (os.getpid(), forkmap.fork_map(lambda y: (os.getpid(), x * y), [1, 2, 3])), [1, 2])
    for pid, inner in out:
        assert [p for p, _ in inner] == [pid] * 3  # the inner map ran in the worker itself
    assert [[v for _, v in inner] for _, inner in out] == [[1, 2, 3], [2, 4, 6]]


def test_workers_from_the_environment(monkeypatch):
    monkeypatch.setenv("SAMII_WORKERS", "1")
    assert forkmap.workers() == 1
    assert forkmap.fork_map(lambda x: os.getpid(), [1, 2]) == [os.getpid()] * 2  # serial in this process
    for bad in ("0", "two", "-1"):
        monkeypatch.setenv("SAMII_WORKERS", bad)
        with pytest.raises(InputError, match="SAMII_WORKERS: expected a positive integer"):
            forkmap.workers()
    monkeypatch.delenv("SAMII_WORKERS")
    assert forkmap.workers() >= 1


@pytest.mark.slow
def test_forward_selection_is_the_same_bit_for_bit_on_one_worker_or_two(monkeypatch):
    """A 4 ms command delay on EffectRig (eq 9.4), 3 short sweeps: selection, values and every candidate's chi2
    the same whether the fits run in turn or in two workers."""
    fs = 1000.0
    sw = SweptSine(amplitude_v=0.1, start_hz=0.3, stop_hz=40.0, repetitions=3, seconds_per_octave=4.0, cycles_per_octave=4.0)
    r = sw.signal(np.arange(int(round(sw.duration_s * fs))) / fs)
    ts = EffectRig(command_delay_s=0.004).simulate(r, sample_rate_hz=fs, rng=np.random.default_rng(3))
    m = from_timeseries(ts, source="rig.csv")
    st = ModelStructure.notebook_3mode()
    kinds = library(fixed_baseline=False, channels=("act", "base"))
    runs = []
    for n in ("1", "2"):
        monkeypatch.setenv("SAMII_WORKERS", n)
        b = Baseline(structure=st, params=(start_params(m, st),), reference=notebook_reference())
        base, final, steps, tried = forward_select([Dataset.from_measured(m)], b, kinds)
        assert all(e.kind is k for e in final.effects for k in kinds if k.label == e.kind.label)  # the parent's kinds
        runs.append((base.chi2, final.chi2, [(e.kind.label, e.values) for e in final.effects], [t.get("chi2") for t in tried]))
    assert runs[0] == runs[1]
    assert [label for label, _ in runs[0][2]] == ["delay/command"]


def test_read_only_views_travel_as_views(two_workers):
    """A measured file's metadata is a read-only view (MappingProxyType), which pickle cannot take by itself."""
    from types import MappingProxyType

    out = forkmap.fork_map(lambda k: MappingProxyType({"k": k, "fs": 1000.0}), [1, 2])
    assert all(isinstance(o, MappingProxyType) for o in out) and [dict(o) for o in out] == [{"k": 1, "fs": 1000.0}, {"k": 2, "fs": 1000.0}]


def test_a_worker_that_dies_loses_only_its_item(two_workers):
    """A worker killed mid-item (from outside, or by the kernel out of memory) left multiprocessing's Pool.map waiting
    for its result for ever (a main job under load hung 12 minutes). Now the parent computes that item itself, says
    so, and the results are those of a serial computation."""
    import signal

    def f(x):
        if x == 3 and forkmap._IN_WORKER:
            os.kill(os.getpid(), signal.SIGKILL)
        return x * x

    with pytest.warns(RuntimeWarning, match=r"a worker process ended \(signal 9\) while computing item 4 of 6"):
        assert forkmap.fork_map(f, range(6)) == [x * x for x in range(6)]


def test_every_worker_dead_the_parent_computes_the_rest(two_workers):
    import signal

    def f(x):
        if forkmap._IN_WORKER:
            os.kill(os.getpid(), signal.SIGKILL)
        return -x

    with pytest.warns(RuntimeWarning, match="computed again; the results are those of a serial run"):
        assert forkmap.fork_map(f, range(5)) == [0, -1, -2, -3, -4]


_PIDS_SCRIPT = """
import os, sys, time
from samii import forkmap

def fn(x):
    with open(sys.argv[1] + f".{x}", "w") as f:
        f.write(str(os.getpid()))
    time.sleep(60)
    return x

forkmap.fork_map(fn, [0, 1])
"""


def _gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] == "Z"  # a zombie until init reaps it: ended
    except FileNotFoundError:
        return True


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="no /proc here")
def test_workers_end_with_a_parent_killed_outright(tmp_path):
    """SIGKILL to the command alone (no process group): its workers, each in a group of its own, computed on for as
    long as their item took (orphans holding the command's stdout). Now they die with it."""
    import signal
    import subprocess
    import sys
    import time

    script = tmp_path / "k.py"
    script.write_text(_PIDS_SCRIPT)
    stem = tmp_path / "pid"
    p = subprocess.Popen([sys.executable, str(script), str(stem)], env=dict(os.environ, SAMII_WORKERS="2"))
    pids = []
    try:
        for _ in range(600):  # (a hang guard: the workers start in well under a second)
            files = [tmp_path / f"pid.{k}" for k in (0, 1)]
            if all(f.exists() and f.read_text() for f in files):
                pids = [int(f.read_text()) for f in files]
                break
            time.sleep(0.1)
        assert len(pids) == 2 and p.poll() is None
        p.kill()
        p.wait()
        for _ in range(100):
            if all(_gone(pid) for pid in pids):
                break
            time.sleep(0.1)
        assert all(_gone(pid) for pid in pids), "a worker outlived its parent"
    finally:
        for pid in pids:
            if not _gone(pid):
                os.kill(pid, signal.SIGKILL)
        if p.poll() is None:
            p.kill()


_START_SCRIPT = """
import os, signal, sys
from samii import forkmap
from samii.cli import _install_signal_handlers
from samii.errors import Interrupted

real = forkmap._fork_worker
pids = []

def fork_then_signal(parent, others):
    w = real(parent, others)
    pids.append(w.pid)
    if len(pids) == 1:  # the first worker forked, the second not yet: a signal to the whole group
        os.killpg(0, signal.SIGTERM)
    return w

forkmap._fork_worker = fork_then_signal
_install_signal_handlers()
try:
    forkmap.fork_map(lambda x: x, [1, 2, 3])
except Interrupted as exc:
    print(" ".join(map(str, pids)), flush=True)
    sys.exit(128 + exc.signum)
"""


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="no /proc here")
def test_a_group_signal_as_workers_are_forked_leaves_none(tmp_path):
    """A signal to the command's process group while its workers were being forked left one orphaned in a lock in
    about 2 of 6 tries (multiprocessing's Pool forked it from a helper thread). Now one line's worth of exit (143), and
    every worker forked is gone."""
    import subprocess
    import sys

    script = tmp_path / "s.py"
    script.write_text(_START_SCRIPT)
    p = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120, start_new_session=True,
                       env=dict(os.environ, SAMII_WORKERS="2"))  # fmt: skip
    assert p.returncode == 143 and p.stderr == "", p.stderr
    pids = [int(x) for x in p.stdout.split()]
    assert len(pids) == 2 and all(_gone(pid) for pid in pids)


def test_fork_later_runs_a_stage_in_a_worker_while_the_block_runs_here(two_workers):
    """The main job's diagnosis runs in a worker while the closed-loop trials run here: the job gets its own process
    (its fork_map in turn inside it, one core each), the block goes on at once, the result comes back by value."""
    import tempfile
    import time
    from pathlib import Path

    marker = Path(tempfile.mkdtemp()) / "job ended"

    def job():
        inner = forkmap.fork_map(lambda x: os.getpid(), range(3))  # (in turn, in the job's own worker)
        time.sleep(1.0)
        marker.touch()
        return os.getpid(), inner

    with forkmap.fork_later(job) as result:
        went_on = not marker.exists()  # (the block runs while the job does)
        pid, inner = result()
    assert went_on and marker.exists() and pid != os.getpid() and inner == [pid] * 3


def _pipes_open_here() -> set[str]:
    """The pipes this process holds an end of, as /proc names them (``pipe:[inode]``)."""
    links = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            links.add(os.readlink(f"/proc/self/fd/{fd}"))
        except OSError:  # (the listing's own descriptor, closed by now)
            pass
    return {link for link in links if link.startswith("pipe:")}


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="reads /proc")
def test_a_worker_forked_later_holds_no_end_of_an_earlier_workers_pipes(two_workers):
    """The main job's blocks nest: the measurement's figure is drawn in one worker while the diagnosis is forked into
    another, and fork_maps run beside both. A worker that kept an end of an earlier worker's task pipe kept that worker
    from seeing its end (the parent closing the pipe), and the parent waiting for it, until the later one ended too."""

    def earlier_pipes() -> set[str]:
        return {f"pipe:[{os.fstat(c.fileno()).st_ino}]" for w in forkmap._LATER for c in (w.tasks, w.results)}

    with forkmap.fork_later(lambda: "drawn") as first:
        firsts = earlier_pipes()
        with forkmap.fork_later(_pipes_open_here) as second:
            both = earlier_pipes()
            inherited = second()
            in_a_map = forkmap.fork_map(lambda _: _pipes_open_here(), range(2))
        assert first() == "drawn"
    assert len(firsts) == 2 and len(both) == 4 and firsts < both  # (each worker's task and result pipes)
    assert inherited and not inherited & firsts  # (the second worker's own pipes only)
    assert len(in_a_map) == 2 and all(pipes and not pipes & both for pipes in in_a_map)
    assert not forkmap._LATER


def test_a_stop_signal_as_fork_later_forks_stops_the_block_and_leaves_no_worker(two_workers, monkeypatch):
    """A stop signal that comes while the worker is forked (blocked then, raised as the mask is restored) stops the
    block as the command's handler says, and the worker is stopped too: it was taken out of the open blocks' list
    before it was ever put in (a ValueError, the signal only its context, and the worker left running)."""
    import signal
    import threading

    class Stopped(Exception):
        pass

    def stop(signum, frame):
        raise Stopped

    real = forkmap._fork_worker

    def fork_then_signalled(*args):
        worker = real(*args)
        # to this thread, which blocks it: pending until fork_later restores the mask. (Sent to the process, pytest-
        # xdist's I/O thread took it at once, and it was raised here, before the worker was known: not this case.)
        signal.pthread_kill(threading.main_thread().ident, signal.SIGHUP)
        return worker

    monkeypatch.setattr(forkmap, "_fork_worker", fork_then_signalled)
    before = signal.signal(signal.SIGHUP, stop)
    try:
        with pytest.raises(Stopped), forkmap.fork_later(lambda: __import__("time").sleep(60)):
            pytest.fail("the block ran")
    finally:
        signal.signal(signal.SIGHUP, before)
        left = _children()
        for pid in left:  # (so that a failure here is this test's alone)
            os.kill(int(pid), signal.SIGKILL)
            os.waitpid(int(pid), 0)
    assert not forkmap._LATER and not left


def test_fork_later_raises_the_jobs_error_and_leaves_no_worker(two_workers):
    def bad():
        raise InputError("stage `samii diagnose`: bad file")

    with forkmap.fork_later(bad) as result:
        for _ in range(2):  # (asked again, the same error: not a wait for a worker that has nothing more to send)
            with pytest.raises(InputError, match="bad file"):
                result()
    # a block that fails (or never asks) ends the worker: none is left behind
    with pytest.raises(KeyError), forkmap.fork_later(lambda: __import__("time").sleep(60)):
        {}["a trial that fails"]
    assert not _children()


def test_fork_later_on_one_worker_runs_the_job_here_when_asked(monkeypatch):
    """With one worker the job runs here, once, when first asked, with one BLAS thread as in a worker (the same bits
    either way); its error is kept and raised again."""
    from threadpoolctl import threadpool_info

    monkeypatch.setenv("SAMII_WORKERS", "1")
    calls = []

    def job():
        calls.append(os.getpid())
        return {lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"}

    with forkmap.fork_later(job) as result:
        assert calls == []  # (not before it is asked for)
        assert result() == {1} and result() == {1}
    assert calls == [os.getpid()]
    with forkmap.fork_later(lambda: {}["x"]) as result:
        for _ in range(2):
            with pytest.raises(KeyError):
                result()


def test_fork_later_computes_here_what_a_killed_worker_lost(two_workers):
    import signal

    def job():
        if forkmap._IN_WORKER:
            os.kill(os.getpid(), signal.SIGKILL)
        return "here"

    with pytest.warns(RuntimeWarning, match=r"a worker process ended \(signal 9\)"), forkmap.fork_later(job) as result:
        assert result() == "here"


def _children() -> list[str]:
    import subprocess

    return subprocess.run(["pgrep", "-P", str(os.getpid())], capture_output=True, text=True).stdout.split()
