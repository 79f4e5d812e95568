"""Independent computations of one stage on the machine's cores: forked workers, results returned by reference.

The diagnosis' forward selection fits dozens of candidate models a round, each independent of the others (one per
kind of the library, one per rival of a swap). ``fork_map(fn, items)`` runs ``fn`` on each item in forked worker
processes and returns the results in the items' order, equal to ``[fn(x) for x in items]``.

Why fork: ``fn`` and the items close over the stage's data (the datasets, the baseline, effect kinds whose laws are
lambdas), which a spawned worker would have to receive pickled, and lambdas do not pickle; a forked worker has them
already (copy-on-write). Only the results travel, pickled, and every object registered with :func:`sharing` (the
kinds, the baseline, the datasets) travels as a reference that the parent resolves to its own object: a fit comes
back holding the parent's own kinds and baseline, as a serial computation's would.

It runs serially (same results, same order) on one core, for one item, inside a worker (no nesting), where the
platform cannot fork, and when the environment sets ``SAMII_WORKERS=1``. Workers run in a process group of their own
and ignore Ctrl-C and hangups: the parent takes every signal and stops them (no traceback per worker, no hang).
"""

from __future__ import annotations

import contextlib
import copyreg
import io
import multiprocessing
import os
import pickle
import signal
import types
import warnings
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TypeVar

from samii.errors import InputError

__all__ = ["fork_calls", "fork_map", "sharing", "workers"]

T = TypeVar("T")
R = TypeVar("R")

#: Objects results may refer to, by id (the parent's, which a forked worker shares): see :func:`sharing`.
_SHARED: dict[int, Any] = {}
#: The computation a forked pool runs: (fn, items); set in the parent just before the fork.
_TASK: tuple[Callable, list] | None = None
#: True in a worker: a fork_map there runs serially.
_IN_WORKER = False


def workers() -> int:
    """Worker processes :func:`fork_map` uses: ``SAMII_WORKERS`` when set (a positive integer), else the cores this
    process may run on."""
    env = os.environ.get("SAMII_WORKERS", "").strip()
    if env:
        try:
            n = int(env)
        except ValueError:
            n = 0
        if n < 1:
            raise InputError(f"environment variable SAMII_WORKERS: expected a positive integer, got {env!r}")
        return n
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


@contextlib.contextmanager
def sharing(*objects: Any) -> Iterator[None]:
    """Within the block, results of :func:`fork_map` that hold any of ``objects`` come back holding the parent's
    own object (not a copy): they must exist before the fork, and stay alive through the block."""
    added = {id(o): o for o in objects if id(o) not in _SHARED}
    _SHARED.update(added)
    try:
        yield
    finally:
        for k in added:
            _SHARED.pop(k, None)


def _proxy_of(d: dict) -> types.MappingProxyType:
    return types.MappingProxyType(d)


def _mappingproxy(mp: types.MappingProxyType) -> tuple:
    return _proxy_of, (dict(mp),)


class _Pickler(pickle.Pickler):
    #: read-only views (a file's metadata) travel as views of a copy
    dispatch_table = {**copyreg.dispatch_table, types.MappingProxyType: _mappingproxy}

    def persistent_id(self, obj: Any) -> int | None:
        i = id(obj)
        return i if i in _SHARED and _SHARED[i] is obj else None


class _Unpickler(pickle.Unpickler):
    def persistent_load(self, pid: int) -> Any:
        return _SHARED[pid]


_CONTROLLER = None
#: The signals a command stops on (samii.cli): blocked while workers are forked, so that each is born deaf to them.
_STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}


def _one_blas_thread():
    """A context in which BLAS uses one thread (threadpoolctl; its scan of the loaded libraries made once)."""
    global _CONTROLLER
    if _CONTROLLER is None:
        from threadpoolctl import ThreadpoolController

        _CONTROLLER = ThreadpoolController()
    return _CONTROLLER.limit(limits=1, user_api="blas")


def _init_worker() -> None:
    global _IN_WORKER
    _IN_WORKER = True
    # A signal to the command's process group (a terminal's Ctrl-C or hangup, `kill -TERM -PGID`) is the parent's to act
    # on: it terminates the pool. A worker killed by it may die holding the pool's task-queue lock, which the parent's
    # terminate() then waits for forever (a main job given SIGTERM 13 s in hung); so a worker runs in a process group
    # of its own, ignores Ctrl-C and hangups, and ends by the parent's terminate() (SIGTERM). A parent killed outright
    # closes the pipes, and the workers end on their own. The worker was forked with the stop signals blocked (forked
    # unblocked, one born as a group signal came ran the parent's handler: a traceback): a SIGTERM pending here is
    # terminate()'s or the group's, and ends it now (discarded below, the worker outlived terminate(), whose join hung);
    # the others are discarded.
    if signal.SIGTERM in signal.sigpending():
        os._exit(0)
    for sig in _STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    os.setpgid(0, 0)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # terminate() ends it quietly


def _run(i: int) -> bytes:
    fn, items = _TASK
    buf = io.BytesIO()
    _Pickler(buf, protocol=pickle.HIGHEST_PROTOCOL).dump(fn(items[i]))
    return buf.getvalue()


def fork_map(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(x) for x in items]``, computed in forked workers (module docstring); an exception in ``fn`` is raised here."""
    global _TASK
    items = list(items)
    if _IN_WORKER:  # nested: in turn, in this worker (its BLAS already on one thread)
        return [fn(x) for x in items]
    n = min(workers(), len(items))
    # one BLAS thread a worker: two workers of two threads each on two cores spin against each other (a diagnosis
    # took 2-3x longer); the serial path does the same, so the bits do not depend on the workers
    with _one_blas_thread():
        if n <= 1 or "fork" not in multiprocessing.get_all_start_methods():
            return [fn(x) for x in items]
        _TASK = (fn, items)
        try:
            with warnings.catch_warnings():
                # Python 3.12+ warns that forking a process with threads (BLAS's) may deadlock; the workers run numpy only
                warnings.simplefilter("ignore", DeprecationWarning)
                pool = None
                try:
                    # forked with the stop signals blocked, in this thread and in the pool's own threads, which inherit
                    # the mask and fork its replacement workers; a signal meanwhile is raised here once the pool exists,
                    # and the finally terminates it (a pool cut off while starting left its workers running, orphaned)
                    before = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
                    try:
                        pool = multiprocessing.get_context("fork").Pool(n, initializer=_init_worker)
                    finally:
                        signal.pthread_sigmask(signal.SIG_SETMASK, before)
                    blobs = pool.map(_run, range(len(items)), chunksize=1)
                finally:
                    if pool is not None:
                        pool.terminate()  # (what the with-statement does)
        finally:
            _TASK = None
    return [_Unpickler(io.BytesIO(b)).load() for b in blobs]


def _call(job: Callable[[], R]) -> R:
    return job()


def fork_calls(jobs: Iterable[Callable[[], R]]) -> list[R]:
    """``[job() for job in jobs]``, computed as :func:`fork_map` computes (different computations at once)."""
    return fork_map(_call, jobs)
