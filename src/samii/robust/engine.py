"""Where a study's samples run: in this process, or on Dask (a local cluster or a user's).

* ``Engine(workers=0)``: one after the other in this process.
* ``Engine(workers=N)``: a local Dask cluster of N single-threaded worker processes (fresh
  processes: samii is imported and the hydraulic plugin registered in each, by :class:`SamiiWorkerPlugin`).
* ``Engine(scheduler="tcp://host:8786")``: a user's Dask cluster, unchanged; its workers need samii
  installed (the same version; the plugin checks and names a worker that lacks it).

Results come back in sample order whatever order the workers finish in, so a study's table does not
depend on the engine.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

from samii.robust.task import SampleResult, SampleTask, run_sample

__all__ = ["Engine", "SamiiWorkerPlugin", "configured_scheduler"]


def configured_scheduler() -> str | None:
    """The scheduler address in Dask's own configuration (``DASK_SCHEDULER_ADDRESS``, ``~/.config/dask``), if any."""
    try:
        import dask
    except ImportError:  # pragma: no cover - dask is a dependency
        return None
    addr = dask.config.get("scheduler-address", None)
    return str(addr) if addr else None


def _worker_setup(version: str) -> str:
    """Register samii's hydraulic plugin in this worker process and check samii's version; returns it."""
    import samii
    from samii.sim.plugin import load_plugin

    load_plugin()
    have = getattr(samii, "__version__", None) or _installed_version()
    if version and have != version:
        raise RuntimeError(f"this worker has samii {have}, the client {version}: install the same samii on every worker")
    return have


def _installed_version() -> str:
    from importlib import metadata

    try:
        return metadata.version("samii")
    except metadata.PackageNotFoundError:  # pragma: no cover - a source tree on the path
        return "unknown"


def _worker_plugin_class():
    from distributed.diagnostics.plugin import WorkerPlugin

    class SamiiWorkerPlugin(WorkerPlugin):
        """At every worker's start (and on workers that join later): import samii and register the hydraulic plugin."""

        name = "samii"

        def __init__(self, version: str):
            self.version = version

        def setup(self, worker):
            _worker_setup(self.version)

    return SamiiWorkerPlugin


def SamiiWorkerPlugin(version: str | None = None):  # noqa: N802 - a factory named like the class it returns
    """A Dask worker plugin registering samii's MuJoCo plugin in each worker (distributed is imported only here)."""
    return _worker_plugin_class()(version if version is not None else _installed_version())


@dataclass
class Engine:
    """Runs sample tasks. Use as a context manager to keep a Dask cluster up over several :meth:`map` calls;
    without it, each call starts and stops its own."""

    workers: int = 0  #: 0: in this process; N: a local Dask cluster of N worker processes
    scheduler: str | None = None  #: a Dask scheduler's address: the user's cluster
    _client: object = field(default=None, repr=False)
    _cluster: object = field(default=None, repr=False)

    def describe(self) -> str:
        if self.scheduler:
            return f"Dask cluster at {self.scheduler}"
        if self.workers:
            return f"local Dask cluster, {self.workers} worker process{'es' if self.workers > 1 else ''}"
        return "in this process"

    @property
    def uses_dask(self) -> bool:
        return bool(self.scheduler or self.workers)

    def __enter__(self) -> "Engine":
        if self.uses_dask and self._client is None:
            import dask
            from distributed import Client, LocalCluster

            if self.scheduler:
                self._client = Client(self.scheduler, timeout="30s")
            else:
                # fresh worker processes, one thread each (a MuJoCo run is single-threaded), no dashboard
                # Dask's statistical profiler samples each worker's stack every 10 ms, holding the GIL to do it:
                # 20 % of a 0.3 s sample here. Off, and the event loop's watchdog and system monitor polled less
                # often, the engine costs about what the study's own bookkeeping does (benchmarks/robust_scaling.py)
                quiet = {"distributed.worker.daemon": False, "distributed.worker.profile.enabled": False,
                         "distributed.admin.tick.interval": "1s", "distributed.admin.system-monitor.interval": "2s"}
                with dask.config.set(quiet):
                    self._cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True, dashboard_address=None,
                                                 silence_logs=40)  # fmt: skip
                self._client = Client(self._cluster)
            self._client.register_plugin(SamiiWorkerPlugin())
        return self

    def __exit__(self, *exc) -> None:
        if self._client is not None:
            self._client.close()
        if self._cluster is not None:
            self._cluster.close()
        self._client = self._cluster = None

    def map(self, tasks: Sequence[SampleTask], progress: Callable[[int], None] | None = None) -> list[SampleResult]:
        """Run every task; the results in the tasks' order."""
        if not self.uses_dask:
            out = []
            for t in tasks:
                out.append(run_sample(t))
                if progress:
                    progress(1)
            return out
        if self._client is None:
            with self:
                return self._dask(tasks, progress)
        return self._dask(tasks, progress)

    def _dask(self, tasks, progress) -> list[SampleResult]:
        import uuid

        from distributed import as_completed

        study = uuid.uuid4().hex[:12]  # keys unique to this study: a shared cluster may hold another study's results
        futures = self._client.map(run_sample, list(tasks), pure=False, key=[f"samii-sample-{study}-{t.index}" for t in tasks])
        by_key = {}
        for fut in as_completed(futures):
            by_key[fut.key] = fut.result()
            if progress:
                progress(1)
        return [by_key[f.key] for f in futures]
