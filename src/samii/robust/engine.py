"""Where a study's samples run: in this process, in forked processes on this machine, or on a user's Dask cluster.

* ``Engine(workers=0)`` (or 1): one after the other in this process.
* ``Engine(workers=N)``: N worker processes forked from this one (:func:`samii.forkmap.fork_map`; the hydraulic
  plugin registered and samii imported already, nothing to ship but the task and its result).
* ``Engine(scheduler="tcp://host:8786")``: a user's Dask cluster, unchanged; its workers need samii
  installed (the same version; the plugin checks and names a worker that lacks it).

On one machine forked processes are what samii uses (``benchmarks/robust_scaling.py``, 2 cores, the 10 s step test,
a sample 67 ms in this process): 35 ms a sample in 2 forked processes, 34 ms in 2 threads of this process (within
the runs' spread of each other: 33.4 against 33.8 ms over 200 samples), 44 ms on a local Dask cluster of 2 worker
processes (its per-task cost, and half a second to start it). Threads run in parallel only while ``mujoco.rollout``
steps (it releases the GIL); the Python around each run, about a fifth of a sample, holds it, so threads cannot pass
about 5x whatever the cores, where processes scale with them.

Results come back in sample order whatever order the workers finish in, so a study's table does not
depend on the engine.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import threading
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field

import dask
from distributed import Client, wait
from distributed.comm import registry
from distributed.comm.addressing import parse_address, parse_host_port
from distributed.diagnostics.plugin import WorkerPlugin

import samii
from samii.errors import InputError, raise_if_signalled
from samii.forkmap import fork_map
from samii.progress import SILENT, Progress
from samii.robust.task import SampleResult, SampleTask, run_sample

__all__ = ["DEFAULT_CONNECT_TIMEOUT_S", "Engine", "SamiiWorkerPlugin", "check_address", "configured_scheduler"]

#: Seconds a scheduler has to answer the first contact: Dask's own connect timeout (30 s) bounds the TCP
#: connection, not the handshake after it, and a socket that accepts and never answers held a run past 100 s.
DEFAULT_CONNECT_TIMEOUT_S = 30.0


def configured_scheduler() -> str | None:
    """The scheduler address in Dask's own configuration (``DASK_SCHEDULER_ADDRESS``, ``~/.config/dask``), if any."""
    addr = dask.config.get("scheduler-address", None)
    return str(addr) if addr else None


class SamiiWorkerPlugin(WorkerPlugin):
    """At every worker's start (and on workers that join later): import samii, register its hydraulic plugin,
    and refuse a worker whose samii is not the client's version."""

    name = "samii"

    def __init__(self, version: str = samii.__version__):
        self.version = version

    def setup(self, worker):
        from samii.sim.plugin import load_plugin  # (lazy: imports mujoco, only when called)

        load_plugin()
        if samii.__version__ != self.version:  # (in a worker: its own installation's samii)
            raise RuntimeError(f"this worker has samii {samii.__version__}, the client {self.version}: install the same samii on every worker")


def _connects(registry, scheme: str) -> bool:
    """Whether Dask's backend for ``scheme`` can make a connector here."""
    try:
        registry.get_backend(scheme).get_connector()
    except Exception:  # noqa: BLE001 - a backend that cannot start says so its own way (ucx: TypeError, an abstract class)
        return False
    return True


def check_address(address: str, where: str) -> tuple[str, str, int] | None:
    """Refuse a scheduler address Dask cannot connect to, before any wait: an unknown scheme, no or an invalid port, a
    host name that does not resolve (``where``: the option or setting it came from, for the message). Returns (scheme,
    host, port) as Dask reads the address (``distributed.comm.addressing``), None for an in-process one."""

    schemes = sorted(registry.backends)
    try:
        scheme, location = parse_address(address)  # (no scheme: tcp, as Dask takes it)
    except ValueError:
        scheme, location = "", address
    if scheme not in registry.backends:
        raise InputError(
            f"{where} {address}: unknown address scheme {scheme!r}; a Dask scheduler listens on "
            f"{', '.join(s + '://' for s in schemes)} (e.g. tcp://host:8786)"
        )
    if scheme == "inproc":
        return None
    if not _connects(registry, scheme):  # (ucx: a class Dask keeps, with its transport in a package of its own)
        usable = [s + "://" for s in schemes if s != "inproc" and _connects(registry, s)]
        raise InputError(
            f"{where} {address}: this installation of Dask cannot connect over {scheme}:// (the transport's "
            f"own package is not installed); it connects over {', '.join(usable)} (e.g. tcp://host:8786)"
        )
    try:
        host, port = parse_host_port(location)
    except ValueError:
        host, port = "", -1
    if not host or not 0 < port < 65536:
        raise InputError(
            f"{where} {address}: expected HOST:PORT with a port from 1 to 65535 (e.g. tcp://host:8786, the port the scheduler printed at its start)"
        )
    try:
        socket.getaddrinfo(host, port)
    except OSError:
        raise InputError(f"{where} {address}: the host {host!r} is not known (its name does not resolve)") from None
    return scheme, host, port


def _connect(address: str, timeout_s: float, where: str = "--scheduler") -> Client:
    """A client of the scheduler at ``address``, or :class:`InputError` naming it (``where``: the option or setting it
    came from) when it refuses or does not answer within ``timeout_s`` (the attempt runs in a daemon thread: one that
    never returns is left behind without holding the process)."""

    parsed = check_address(address, where)
    if parsed is not None and parsed[0] in ("tcp", "tls", "ws", "wss"):  # all over TCP: a refused connection is known at once
        # (Dask retries it until its timeout)
        _, host, port = parsed
        try:
            socket.create_connection((host, port), timeout=min(timeout_s, 10.0)).close()
        except ConnectionRefusedError:
            raise InputError(
                f"{where} {address}: nothing listens there (connection refused); is the scheduler running, and is this its address and port?"
            ) from None
        except OSError:
            pass  # unreachable, slow: Dask's own attempt says so, within the timeout
    box: dict = {}

    def attempt() -> None:
        try:
            box["client"] = Client(address, timeout=f"{timeout_s}s")
        except BaseException as exc:  # noqa: BLE001 - handed to the caller
            box["error"] = exc

    thread = threading.Thread(target=attempt, name="samii-dask-connect", daemon=True)
    thread.start()
    deadline = time.monotonic() + timeout_s
    while thread.is_alive() and time.monotonic() < deadline:
        thread.join(min(0.2, max(deadline - time.monotonic(), 0.0)))
        raise_if_signalled()  # (a Ctrl-C whose exception a library's callback swallowed was lost until the timeout)
    if thread.is_alive():
        raise InputError(
            f"{where} {address}: no Dask scheduler answered within {timeout_s:g} s (check the address and port, "
            "or give more time with --scheduler-timeout)"
        )
    if "error" in box:
        exc = box["error"]
        if isinstance(exc, KeyboardInterrupt):
            raise exc
        if isinstance(exc, MemoryError):  # Dask read a length out of bytes that were no Dask message
            raise InputError(
                f"{where} {address}: something answered there, but not as a Dask scheduler (its first bytes "
                "read as no Dask message); check the address and port"
            ) from None
        raise InputError(
            f"{where} {address}: could not connect to a Dask scheduler ({type(exc).__name__}: {' '.join(str(exc).split())[:200]})"
        ) from None
    return box["client"]


@contextlib.contextmanager
def _quiet_dask_logs():
    """Dask's loggers (``distributed`` and every one below it) held at CRITICAL, then restored."""

    names = ["distributed"] + [n for n in logging.root.manager.loggerDict if n.startswith("distributed.")]
    saved = {n: logging.getLogger(n).level for n in names}
    for n in names:
        logging.getLogger(n).setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for n, level in saved.items():
            logging.getLogger(n).setLevel(level)


#: How often a study on a user's cluster looks at its scheduler while no sample comes back [s] (at most the timeout).
WATCH_INTERVAL_S = 2.0


def _silent_workers(workers: dict, heard: dict[str, tuple[float, float]], limit: float) -> list[str]:
    """The workers of ``workers`` (the scheduler's identity of each) whose heartbeat the scheduler has not had for
    ``limit`` seconds: each one's ``last_seen`` (the scheduler's clock) is compared with its own earlier value, timed
    on this process's clock (the two machines' clocks may differ), and ``heard`` is updated."""
    now = time.monotonic()
    for address, info in workers.items():
        seen = info.get("last_seen")
        if address not in heard or heard[address][0] != seen:
            heard[address] = (seen, now)
    for address in [a for a in heard if a not in workers]:
        del heard[address]
    return sorted(a for a, (_, since) in heard.items() if now - since > limit)


@dataclass
class Engine:
    """Runs sample tasks. Use as a context manager to keep the connection to a user's Dask cluster over several
    :meth:`map` calls; without it, each call connects and closes its own."""

    workers: int = 0  #: 0 or 1: in this process; N: N worker processes forked from this one
    scheduler: str | None = None  #: a Dask scheduler's address: the user's cluster
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S  #: how long the scheduler has to answer the first contact
    #: where ``scheduler`` came from, for messages: the option, or Dask's own configuration
    scheduler_source: str = "--scheduler"
    _client: object = field(default=None, repr=False)
    #: a study on the user's cluster failed: closing its client may fail too, and is not said again
    _failed: bool = field(default=False, repr=False)
    #: Dask's loggers held quiet while connected to a user's cluster (_quiet_dask_logs)
    _quiet: contextlib.ExitStack = field(default_factory=contextlib.ExitStack, repr=False)

    def describe(self) -> str:
        if self.scheduler:
            return f"Dask cluster at {self.scheduler}"
        if self.workers > 1:
            return f"in {self.workers} worker processes on this machine"
        return "in this process"

    @property
    def uses_dask(self) -> bool:
        return bool(self.scheduler)

    def __enter__(self) -> Engine:
        if self.uses_dask and self._client is None:
            # the client logs a lost scheduler, and its reconnection attempts, as ERROR with tracebacks: the study
            # says it in one line (_watched)
            self._quiet.enter_context(_quiet_dask_logs())
            try:
                self._client = _connect(self.scheduler, self.connect_timeout_s, self.scheduler_source)
            except BaseException:
                self._quiet.close()
                raise
            try:  # a scheduler without workers took the study and waited for ever, without a word
                self._client.wait_for_workers(1, timeout=self.connect_timeout_s)
            except TimeoutError:
                self.__exit__()
                raise InputError(
                    f"{self.scheduler_source} {self.scheduler}: the scheduler answered, but no worker joined it "
                    f"within {self.connect_timeout_s:g} s; start workers (dask worker {self.scheduler}), or "
                    "give them more time with --scheduler-timeout"
                ) from None
            self._client.register_plugin(SamiiWorkerPlugin())
        return self

    def __exit__(self, *exc) -> None:
        if self._client is not None:
            try:
                self._client.close(timeout=self.connect_timeout_s)
            except Exception:  # noqa: BLE001 - a lost or stopped scheduler: the study has already said so
                if not self._failed:
                    raise
        self._client = None
        self._failed = False
        self._quiet.close()

    def map(self, tasks: Sequence[SampleTask], progress: Progress | None = None) -> list[SampleResult]:
        """Run every task; the results in the tasks' order. ``progress`` (samii.progress.Progress) is told the tasks
        and advanced by each as it ends."""
        progress = progress or SILENT
        progress.expect(len(tasks))
        if not self.uses_dask:  # (fork_map runs in this process for one worker, as where the platform cannot fork)
            return fork_map(run_sample, tasks, processes=max(1, self.workers), done=progress.advance)
        if self._client is None:
            with self:
                return self._dask(tasks, progress)
        return self._dask(tasks, progress)

    def _dask(self, tasks, progress) -> list[SampleResult]:
        study = uuid.uuid4().hex[:12]  # keys unique to this study: a shared cluster may hold another study's results
        futures = self._client.map(run_sample, list(tasks), pure=False, key=[f"samii-sample-{study}-{t.index}" for t in tasks])
        nominal = {f.key for f, t in zip(futures, tasks) if t.index < 0}  # (the nominal plant: no drawn sample)
        return self._watched(futures, progress, nominal)

    def _holders(self, fut, limit: float) -> list[str] | None:
        """The workers that hold ``fut``'s result, as the scheduler says within ``limit`` seconds (None: it does not
        answer; [] it answers that none does)."""
        try:
            who = self._client.sync(self._client.scheduler.who_has, keys=[fut.key], callback_timeout=limit)
        except Exception:  # noqa: BLE001 - no answer within the limit, or the connection failed asking
            return None
        return sorted(who.get(fut.key) or [])

    def _watched(self, futures, progress, nominal: set) -> list[SampleResult]:
        """The results of a study on a user's cluster, watched: a scheduler that is lost, stops answering, or is left
        without a worker for ``connect_timeout_s``, or a worker the scheduler has not heard from for that long while no
        sample finished, ends the study with one line naming it (the cluster's own failures came as 30 lines of Dask's
        log and an "internal error", or as a wait for ever; a stopped worker as a silent wait of 5 minutes)."""

        where = f"{self.scheduler_source} {self.scheduler}"
        limit = self.connect_timeout_s
        pending, by_key = set(futures), {}
        no_worker_since = None
        heard: dict[str, tuple[float, float]] = {}  # worker -> (the scheduler's last_seen of it, when that last changed here)
        last_done = time.monotonic()

        def lost(what: str) -> InputError:
            drawn = sum(1 for f in futures if f.key not in nominal)
            done = sum(1 for k in by_key if k not in nominal)
            return InputError(
                f"{where}: during the study, after {done} of {drawn} samples, {what}; nothing "
                "was written (check the cluster, then run the study again)"
            )

        try:
            while pending:
                try:
                    done, pending = wait(pending, timeout=min(WATCH_INTERVAL_S, limit), return_when="FIRST_COMPLETED")
                except TimeoutError:
                    done = set()
                except Exception as exc:  # noqa: BLE001 - the connection's own failure (closed comm, cancelled)
                    if "cancel" in type(exc).__name__.lower():  # (Dask cancels every future when its scheduler is lost)
                        raise lost("the scheduler was lost (its connection closed)") from None
                    raise lost(f"the connection to the scheduler failed ({type(exc).__name__})") from None
                for fut in done:
                    if fut.status == "cancelled" or self._client.status not in ("running", "connecting"):
                        raise lost("the scheduler was lost (its connection closed)")
                    try:  # (fetched through the scheduler: bounded, a stopped one never answers)
                        by_key[fut.key] = fut.result(timeout=limit)
                    except TimeoutError:
                        # the result stays on the worker that made it: one stopped after finishing it keeps it, while
                        # the scheduler answers (under load the worker's stop came between the two, and was blamed on it)
                        if holders := self._holders(fut, limit):  # (None or []: the scheduler is the one not answering)
                            raise lost(
                                f"worker{'s' if len(holders) > 1 else ''} {', '.join(holders)} stopped answering (not heard "
                                f"from for {limit:g} s, no sample finished meanwhile)"
                            ) from None
                        raise lost(f"the scheduler stopped answering (nothing within {limit:g} s)") from None
                    except OSError as exc:
                        raise lost(f"the connection to the scheduler failed ({type(exc).__name__})") from None
                    except Exception as exc:  # noqa: BLE001 - a cancelled future: the scheduler dropped the study
                        if "cancel" in type(exc).__name__.lower():
                            raise lost("the scheduler was lost (the study's tasks were cancelled)") from None
                        raise
                    progress.advance()
                if done:
                    last_done = time.monotonic()
                if done or not pending:
                    continue
                if self._client.status not in ("running", "connecting"):
                    raise lost("the scheduler was lost (its connection closed)")
                try:  # a scheduler that stops answering (a hung host, a dropped network) keeps its connection open
                    workers = self._client.sync(self._client.scheduler.identity, callback_timeout=limit)["workers"]
                except Exception:  # noqa: BLE001 - no answer within the limit, or the connection failed asking
                    raise lost(f"the scheduler stopped answering (nothing within {limit:g} s)") from None
                if workers:
                    no_worker_since = None
                    if (silent := _silent_workers(workers, heard, limit)) and time.monotonic() - last_done > limit:
                        # a stopped or hung worker keeps its samples and its place: the scheduler drops it only after its
                        # worker-ttl (5 min by default), and robust waited that long without a word
                        raise lost(
                            f"worker{'s' if len(silent) > 1 else ''} {', '.join(silent)} stopped answering (not heard "
                            f"from for {limit:g} s, no sample finished meanwhile)"
                        )
                elif no_worker_since is None:
                    no_worker_since = time.monotonic()
                elif time.monotonic() - no_worker_since > limit:
                    raise lost(f"no worker was left for {limit:g} s (start workers: dask worker {self.scheduler})")
        except BaseException:
            self._failed = True  # (closing its client then fails too: see __exit__)
            raise
        return [by_key[f.key] for f in futures]
