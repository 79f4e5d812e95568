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

Why not ``multiprocessing.Pool`` (which this module used) or ``concurrent.futures``: a Pool's workers share one task
queue and its lock, and a Pool's helper thread forks replacement workers. A worker killed holding the lock left the
pool's shutdown (and the other workers) waiting for ever, and a group signal as a pool started left a worker the
parent did not know of, orphaned in a lock (2 of 6 tries); a worker that died mid-item left ``Pool.map`` waiting for
its result for ever (a main job under load hung 12 minutes, about 1 in 20). ``ProcessPoolExecutor`` shares the same
kind of queue. Here each worker has two pipes of its own (item indexes in, results out), only the calling thread
forks, the parent knows every pid and kills them all on any exception or signal, a worker dies with its parent, and a
worker that dies loses only its item, which another worker, or the parent when none is left, computes again (with a
warning).
"""

from __future__ import annotations

import contextlib
import copyreg
import ctypes
import io
import multiprocessing
import os
import pickle
import signal
import sys
import traceback
import types
import warnings
from collections.abc import Callable, Iterable, Iterator
from multiprocessing.connection import wait
from multiprocessing.pool import RemoteTraceback
from typing import Any, TypeVar

from samii.errors import InputError
from samii.threads import one_blas_thread

__all__ = ["fork_calls", "fork_later", "fork_map", "sharing", "workers"]

T = TypeVar("T")
R = TypeVar("R")

#: Objects results may refer to, by id (the parent's, which a forked worker shares): see :func:`sharing`.
_SHARED: dict[int, Any] = {}
#: The computation a forked pool runs: (fn, items); set in the parent just before the fork.
_TASK: tuple[Callable, list] | None = None
#: True in a worker: a fork_map there runs serially.
_IN_WORKER = False
#: The workers of the fork_later blocks open in this process: a process forked later closes their pipes' ends (one
#: left open in it kept such a worker alive, and its parent waiting on it, until that process ended too).
_LATER: list = []


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


#: The signals a command stops on (samii.cli): blocked while workers are forked, so that each is born deaf to them.
_STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}


def _init_worker() -> None:
    global _IN_WORKER
    _IN_WORKER = True
    # A signal to the command's process group (a terminal's Ctrl-C or hangup, `kill -TERM -PGID`) is the parent's to act
    # on: it stops its workers (_stop). So a worker runs in a process group of its own and ignores the stop signals but
    # SIGTERM. It was forked with them blocked (forked unblocked, one born as a group signal came ran the parent's
    # handler: a traceback): a SIGTERM pending here is the group's, and ends it now; the others are discarded.
    if signal.SIGTERM in signal.sigpending():
        os._exit(0)
    for sig in _STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    os.setpgid(0, 0)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


class _Worker:
    """One forked worker: its pid and the parent's ends of its two pipes (item indexes in, result blobs out)."""

    def __init__(self, pid: int, tasks, results):
        self.pid, self.tasks, self.results = pid, tasks, results
        self.status: int | None = None  # os.waitpid's, once reaped

    def close(self) -> None:
        self.tasks.close()
        self.results.close()

    def kill(self) -> None:
        if self.status is None:  # (not reaped: the pid is still this worker's, a zombie at worst)
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGKILL)

    def reap(self) -> int:
        if self.status is None:
            self.status = os.waitpid(self.pid, 0)[1]
        return self.status


def _die_with_parent(parent: int) -> None:
    """Linux: the kernel kills this worker when the thread that forked it ends (a parent killed outright, even by
    SIGKILL, leaves no worker computing on); elsewhere the closed task pipe ends it at its next item."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:  # the parent died before that took hold
        os._exit(0)


def _work(tasks, results) -> None:
    """A worker's life: an item's index in, its result's blob out (b"R" + the result, or b"E" + the exception), until
    the parent closes the task pipe or dies."""
    fn, items = _TASK
    while True:
        try:
            i = tasks.recv()
        except (EOFError, OSError):
            return
        try:
            buf = io.BytesIO()
            _Pickler(buf, protocol=pickle.HIGHEST_PROTOCOL).dump(fn(items[i]))
            blob = b"R" + buf.getvalue()
        except BaseException as exc:  # raised in the parent, with this traceback as its cause
            tb = "".join(traceback.format_exception(exc))
            try:
                blob = b"E" + pickle.dumps((exc, tb), protocol=pickle.HIGHEST_PROTOCOL)
            except Exception:  # an exception holding what cannot travel: its type, message and traceback do
                blob = b"E" + pickle.dumps((RuntimeError(f"{type(exc).__name__}: {exc}"), tb))
        try:
            results.send_bytes(blob)
        except OSError:  # the parent is gone
            return


def _fork_worker(parent: int, others: list[_Worker]) -> _Worker:
    tasks_r, tasks_w = multiprocessing.Pipe(duplex=False)
    results_r, results_w = multiprocessing.Pipe(duplex=False)
    pid = os.fork()
    if pid == 0:  # the worker: never returns into the parent's code
        code = 0
        try:
            _die_with_parent(parent)
            # the parent's ends, its own and the earlier workers' (a worker holding another's task pipe open kept that
            # one alive after the parent was gone)
            for conn in (tasks_w, results_r, *(c for w in others for c in (w.tasks, w.results))):
                conn.close()
            _init_worker()
            _work(tasks_r, results_w)
        except BaseException:
            code = 1
        finally:
            with contextlib.suppress(BaseException):
                sys.stdout.flush()
                sys.stderr.flush()
            os._exit(code)
    tasks_r.close()
    results_w.close()
    return _Worker(pid, tasks_w, results_r)


def _raise_from(blob: bytes) -> None:
    try:
        exc, tb = pickle.loads(blob)
    except Exception as unpickling:  # (an exception type whose arguments do not rebuild it)
        raise RuntimeError(f"a worker's exception could not be read back: {unpickling}") from None
    exc.__cause__ = RemoteTraceback(tb)  # (as multiprocessing's pools give it)
    raise exc


def _forked(fn: Callable, items: list, n: int, done: Callable[[], None] | None = None) -> list:
    """The items' results computed by ``n`` forked workers, one item at a time each, in the items' order.

    Each worker has pipes of its own and shares no lock with the others (a multiprocessing.Pool's workers share a queue
    lock: one killed holding it left the others, and the pool's shutdown, waiting for ever), and only this thread forks
    them (a Pool's helper thread forked replacements this thread did not know of: orphans). A worker that dies (killed
    from outside, out of memory) loses only its item, computed again by another or, none left, here, with a warning."""
    global _TASK
    _TASK = (fn, items)
    workers: list[_Worker] = []
    finished = False
    try:
        # forked with the stop signals blocked, so each worker is born deaf to them (see _init_worker); a signal
        # meanwhile is raised here once they all exist, and the finally stops them all
        sys.stdout.flush()
        sys.stderr.flush()
        before = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
        try:
            parent = os.getpid()
            for _ in range(n):
                workers.append(_fork_worker(parent, [*_LATER, *workers]))
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, before)
        results = _serve(fn, items, workers, done)
        finished = True
        return results
    finally:
        _TASK = None
        _stop(workers, kill=not finished)


_MISSING = object()


def _serve(fn: Callable, items: list, workers: list[_Worker], done: Callable[[], None] | None = None) -> list:
    results: list = [_MISSING] * len(items)
    todo = list(range(len(items)))[::-1]  # (popped from the end: in order)
    idle = list(workers)[::-1]
    busy: dict[Any, tuple[_Worker, int]] = {}
    while todo or busy:
        while todo and idle:
            w, i = idle.pop(), todo.pop()
            try:
                w.tasks.send(i)
            except OSError:  # died while waiting for an item
                _dead(w, None, len(items))
                todo.append(i)
                continue
            busy[w.results] = (w, i)
        if not busy:
            break  # every worker dead: the rest is computed here
        for conn in wait(list(busy)):
            w, i = busy.pop(conn)
            try:
                blob = conn.recv_bytes()
            except (EOFError, OSError):  # died computing it: another worker (or this process) computes it
                _dead(w, i, len(items))
                todo.append(i)
                continue
            if blob[:1] == b"E":
                _raise_from(blob[1:])
            results[i] = blob
            idle.append(w)
            if done is not None:
                done()
    for k in reversed(todo):
        results[k] = fn(items[k])
        if done is not None:
            done()
    return [_Unpickler(io.BytesIO(r[1:])).load() if isinstance(r, bytes) else r for r in results]


def _dead(w: _Worker, item: int | None, n: int) -> None:
    """A worker that ended unasked (killed from outside, out of memory): reaped, and said."""
    w.close()
    w.kill()
    status = w.reap()
    how = f"signal {os.WTERMSIG(status)}" if os.WIFSIGNALED(status) else f"exit code {os.waitstatus_to_exitcode(status)}"
    what = f"while computing item {item + 1} of {n}; it was computed again" if item is not None else "between items"
    warnings.warn(f"a worker process ended ({how}) {what}; the results are those of a serial run", RuntimeWarning, stacklevel=4)


def _stop(workers: list[_Worker], *, kill: bool) -> None:
    """Close every worker's pipes (an idle worker then ends) and wait for each; ``kill``: end them first (an
    exception or signal here: workers still computing). A signal while waiting kills the rest at once."""
    for w in workers:
        w.close()
        if kill:
            w.kill()
    try:
        for w in workers:
            w.reap()
    except BaseException:
        for w in workers:
            w.kill()
        raise


def fork_map(fn: Callable[[T], R], items: Iterable[T], *, processes: int | None = None, done: Callable[[], None] | None = None) -> list[R]:
    """``[fn(x) for x in items]``, computed in forked workers (module docstring); an exception in ``fn`` is raised here.

    ``processes``: at most this many workers (default :func:`workers`); ``done`` is called here as each item's result
    comes in (in whatever order they finish: a progress bar's advance)."""
    items = list(items)
    if _IN_WORKER:  # nested: in turn, in this worker (its BLAS already on one thread)
        return _serially(fn, items, done)
    n = min(workers() if processes is None else processes, len(items))
    # one BLAS thread a worker: two workers of two threads each on two cores spin against each other (a diagnosis
    # took 2-3x longer); the serial path does the same, so the bits do not depend on the workers
    with one_blas_thread():
        if n <= 1 or not hasattr(os, "fork"):
            return _serially(fn, items, done)
        with warnings.catch_warnings():
            # Python 3.12+ warns that forking a process with threads (BLAS's) may deadlock; the workers run numpy only
            warnings.simplefilter("ignore", DeprecationWarning)
            return _forked(fn, items, n, done)


def _serially(fn: Callable, items: list, done: Callable[[], None] | None) -> list:
    out = []
    for x in items:
        out.append(fn(x))
        if done is not None:
            done()
    return out


def _call(job: Callable[[], R]) -> R:
    return job()


def fork_calls(jobs: Iterable[Callable[[], R]]) -> list[R]:
    """``[job() for job in jobs]``, computed as :func:`fork_map` computes (different computations at once)."""
    return fork_map(_call, jobs)


@contextlib.contextmanager
def fork_later(job: Callable[[], R]) -> Iterator[Callable[[], R]]:
    """``job()`` computed in one forked worker while the block runs here (two stages that do not depend on each other,
    on two cores); the block gets a function that waits for the result and returns it (an exception in ``job`` is
    raised there, and again at every later call). The job runs with one BLAS thread wherever it runs, and a
    :func:`fork_map` inside it runs serially in the worker (the block has the other core). Leaving the block ends the
    worker: killed if the block raised or never asked. Blocks nest (the main job draws a figure in one worker while
    its diagnosis runs in another): every process forked later holds no end of an open block's pipes.

    Where :func:`fork_map` would run serially (one worker, inside a worker, no fork), ``job`` runs here when its
    result is first asked for; a worker that dies (killed from outside) has it computed here, with a warning."""
    outcome: list = []  # (True, result) or (False, exception), once known

    def here() -> None:
        try:
            with one_blas_thread():  # (as in the worker: the same bits wherever it runs)
                outcome.append((True, job()))
        except Exception as exc:  # noqa: BLE001 - raised to the caller by known()
            outcome.append((False, exc))

    def known() -> R:
        ok, value = outcome[0]
        if not ok:
            raise value
        return value

    if _IN_WORKER or workers() <= 1 or not hasattr(os, "fork"):

        def inline() -> R:
            if not outcome:
                here()
            return known()

        yield inline
        return
    global _TASK
    worker: _Worker | None = None
    finished = False
    try:
        _TASK = (_call, [job])
        sys.stdout.flush()
        sys.stderr.flush()
        with one_blas_thread(), warnings.catch_warnings():  # (the worker keeps the limit it is forked with; here it is restored)
            # Python 3.12+ warns that forking a process with threads (BLAS's) may deadlock; the worker runs numpy only
            warnings.simplefilter("ignore", DeprecationWarning)
            before = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
            try:
                worker = _fork_worker(os.getpid(), list(_LATER))
                _LATER.append(worker)  # (before a stop signal can be raised: the finally takes it out)
            finally:
                signal.pthread_sigmask(signal.SIG_SETMASK, before)  # (a signal meanwhile is raised here: the finally ends it)
        _TASK = None
        worker.tasks.send(0)

        def result() -> R:
            if not outcome:
                try:
                    blob = worker.results.recv_bytes()
                except (EOFError, OSError):  # died computing it
                    _dead(worker, 0, 1)
                    here()
                    return known()
                if blob[:1] == b"E":
                    try:
                        _raise_from(blob[1:])
                    except Exception as exc:  # noqa: BLE001 - kept, and raised again at every call
                        outcome.append((False, exc))
                else:
                    outcome.append((True, _Unpickler(io.BytesIO(blob[1:])).load()))
            return known()

        yield result
        finished = bool(outcome)
    finally:
        _TASK = None
        if worker is not None:
            if worker in _LATER:
                _LATER.remove(worker)
            _stop([worker], kill=not finished)
