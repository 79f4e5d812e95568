"""Fixtures shared by the command-line batteries and the main job's tests, and how many workers samii forks in them."""

from __future__ import annotations

import os
import shutil

import pytest


def pytest_configure(config):
    """Where pytest-xdist shares the tests out (pyproject.toml), its workers already keep the cores busy: each runs
    samii's own work in one process unless the environment sets ``SAMII_WORKERS`` (the usable cores divided by the test
    workers: 1 where ``-n auto`` starts one per core). A worker per core forked inside each test worker ran four
    processes on two cores and cost more than it shared (README, "Tests"); the results are the same bits either way
    (samii.forkmap). The forking paths are tested where a test asks for its workers by name: tests/test_forkmap.py, the
    signal, robust and cluster tests, the ``runs`` main job a, and test_diagnose_sim.py's ``clean_cli``."""
    count = os.environ.get("PYTEST_XDIST_WORKER_COUNT")
    if count and "SAMII_WORKERS" not in os.environ:
        from samii.forkmap import workers  # (unset: the cores this process may run on)

        os.environ["SAMII_WORKERS"] = str(max(1, workers() // int(count)))


@pytest.fixture()
def out_dir(tmp_path):
    """An existing output folder holding a file of the user's: a failed run must leave it exactly so."""
    d = tmp_path / "out"
    d.mkdir()
    (d / "keep.txt").write_text("the user's")
    return d


@pytest.fixture()
def cwd(tmp_path, monkeypatch):
    """An empty working folder: a refused run must leave it empty (no output, no temp file)."""
    d = tmp_path / "cwd"
    d.mkdir()
    monkeypatch.chdir(d)
    return d


@pytest.fixture(scope="session")
def runs(tmp_path_factory, worker_id):
    """Two main jobs with the same seed (about 13 s each on 2 cores), read by test_main_job.py, test_report.py,
    test_pipeline.py and test_fault_battery.py: ``a`` by the command (``samii run``) on two workers (its diagnosis, the
    notebook's controllers and the measurement's figure forked beside the other stages), ``b`` by the library
    (``samii.pipeline.run()`` into a temporary folder, then ``Run.save``) in one process, so that test_pipeline.py's
    comparison of the two also compares the stages forked with the same stages in turn. Run once per test session:
    where pytest-xdist shares the tests out (pyproject.toml), the first worker to ask runs them into the folder the
    workers share, under a lock, and the others read its folders."""
    if worker_id == "master":  # pytest-xdist's name for a session it does not share out (-n 0)
        return _main_jobs(tmp_path_factory.mktemp("main"))
    import fcntl

    shared = tmp_path_factory.getbasetemp().parent / "main-jobs"  # one folder per session, above each worker's own
    with open(shared.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, also if the worker dies
        if not (shared / "done").is_file():
            shutil.rmtree(shared, ignore_errors=True)  # what a worker that died half-way left
            shared.mkdir()
            out = _main_jobs(shared)
            (shared / "done").touch()
            return out
    return [shared / "a", shared / "b"]


def _main_jobs(base):
    import subprocess
    import sys

    from samii.cli import main

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = base / f".a.samii-run-{dead.pid}"  # what a main job killed outright (SIGKILL) leaves beside its --out
    (stale / "measure").mkdir(parents=True)
    from samii.pipeline import run

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SAMII_WORKERS", "2")
        assert main(["run", "--out", str(base / "a"), "--seed", "3", "--no-progress"]) == 0
        mp.setenv("SAMII_WORKERS", "1")
        run(seed=3).save(base / "b")
    out = [base / "a", base / "b"]
    assert not stale.exists(), "a rerun into the same --out removes what a killed run left (issue 36)"
    return out


class Heard:
    """A samii.progress.Progress that keeps what it was told, in order (the ``heard`` fixture)."""

    def __init__(self):
        self.said, self.total, self.done = [], None, 0.0

    def expect(self, total):
        self.said.append(("expect", total))
        self.total = total

    def advance(self, n=1):
        self.said.append(("advance", n))
        self.done += n

    def stage(self, what):
        self.said.append(("stage", what))

    @property
    def stages(self):
        return [v for k, v in self.said if k == "stage"]


@pytest.fixture
def heard():
    """A progress that keeps what a long call reports (samii.progress.Progress)."""
    return Heard()


def empty_summary(seed: int = 0):
    """A main job's summary with nothing in it: what a test's stubbed pipeline stages return (samii.schema.summary)."""
    from samii.schema.summary import (
        DAMPING_FIELDS,
        FIT_FIELDS,
        DampingSummary,
        DiagnosisSummary,
        FitSummary,
        MeasurementSummary,
        ModesSummary,
        RunSummary,
    )

    none = dict.fromkeys
    return RunSummary(seed=seed, model_file="embedded default", overrides=(), modes=ModesSummary((), (), None),
                      measurement=MeasurementSummary("none", 0.1, 1e3, 1.0, None), closed_loop={},
                      fit=FitSummary(**none(FIT_FIELDS), params={}, stderr={}, eq9_4={}),
                      damping_design=DampingSummary(**none(DAMPING_FIELDS)), diagnosis=DiagnosisSummary("none", (), {}, {}))  # fmt: skip


@pytest.fixture
def stub_summary():
    """:func:`empty_summary`, for a test that stubs the pipeline's stages."""
    return empty_summary
