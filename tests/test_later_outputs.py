"""Outputs a stage leaves for later (``later=True``, samii.outputs.LaterOutput): the main job draws the measurement's
Bode figure, its recording and the fit's figure beside the stages that wait on each other, not between them
(samii.pipeline). What the caller writes later must be the files the stage would have written itself, and the stage's
own record must name them as before."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from samii.identify.fit_file import FitRequest, fit_frf_file
from samii.identify.report import write_fit_outputs
from samii.measure.bode_test import BodeTestRequest, run_bode_test
from samii.viz.recording import read_scalars

#: a short swept sine (2-20 Hz, one record: 35 s simulated), with sensor noise: the same seed gives the same data
_REQUEST = BodeTestRequest(band_hz=(2.0, 20.0), averages=1, noise=True, seed=1)


@pytest.mark.slow
def test_the_figures_and_recording_left_for_later_are_the_ones_the_stages_write(tmp_path):
    now = run_bode_test(tmp_path / "now", _REQUEST, rerun=tmp_path / "now.rrd")
    (tmp_path / "later").mkdir()
    (tmp_path / "later" / "bode.png").write_text("an earlier run's")
    later = run_bode_test(tmp_path / "later", _REQUEST, rerun=tmp_path / "later.rrd", later=True, overwrite=True)
    assert now.later == ()
    # the folder is committed without them (an earlier run's figure removed: never two runs mixed), and run.json
    # names them all the same
    assert sorted(p.name for p in (tmp_path / "later").iterdir()) == ["frf.csv", "run.json", "timeseries.csv"]
    assert not (tmp_path / "later.rrd").exists()
    named = [tmp_path / "later" / n for n in ("timeseries.csv", "frf.csv", "bode.png", "run.json")] + [tmp_path / "later.rrd"]
    assert [Path(p) for p in later.record.outputs] == named and len(now.record.outputs) == len(named)
    # the figure may be drawn in a forked worker, the recording only in this process (rerun's threads)
    assert [(o.path, o.forks) for o in later.later] == [(tmp_path / "later" / "bode.png", True), (tmp_path / "later.rrd", False)]
    for o in later.later:
        o.write()
    assert (tmp_path / "later" / "bode.png").read_bytes() == (tmp_path / "now" / "bode.png").read_bytes()
    assert not list(tmp_path.rglob(".*tmp*"))  # (each written under a temporary name, then moved)
    entities = ["/swept/accel_m_s2/accel", "/swept/angle_deg/theta"]
    a, b = read_scalars(tmp_path / "now.rrd", entities), read_scalars(tmp_path / "later.rrd", entities)
    assert set(a) == set(b) == set(entities)
    assert all(np.array_equal(a[e][0], b[e][0]) and np.array_equal(a[e][1], b[e][1]) for e in entities)

    frf = tmp_path / "now" / "frf.csv"
    request = FitRequest(phase_weights=(0.1, 0.5), profiles="off")  # (a sweep of weights: two figures)
    (tmp_path / "fit_later").mkdir()
    (tmp_path / "fit_later" / "parameters.png").write_text("an earlier run's")
    fit_later = fit_frf_file(frf, request, out=tmp_path / "fit_later", later=True, overwrite=True)
    assert sorted(p.name for p in (tmp_path / "fit_later").iterdir()) == ["fit_pw0.1.json", "fit_pw0.5.json"]
    assert [(o.path.name, o.forks) for o in fit_later.later] == [("bode_fit.png", True), ("parameters.png", True)]
    assert [Path(p).name for p in fit_later.written] == ["fit_pw0.1.json", "fit_pw0.5.json", "bode_fit.png", "parameters.png"]
    for o in fit_later.later:
        o.write()
    # the same fits written by the stage's own writer (samii fit's), figures and all
    write_fit_outputs(fit_later.data, fit_later.results, tmp_path / "fit_now", note=f"data: {frf}")
    for name in ("fit_pw0.1.json", "fit_pw0.5.json", "bode_fit.png", "parameters.png"):
        assert (tmp_path / "fit_later" / name).read_bytes() == (tmp_path / "fit_now" / name).read_bytes(), name
    assert not list(tmp_path.rglob(".*tmp*"))
