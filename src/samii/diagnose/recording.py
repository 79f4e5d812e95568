"""``samii diagnose --baseline sim --rerun FILE.rrd``: the simulator against the measured data, as
a Rerun recording (``samii.viz.recording``'s layout).

For each file with a time series, the runs are

- ``data`` (``data_2``, ... for later files): the file's own record, signals only (measured data
  have no joint positions, so no 3D);
- ``simulator_before``: the calibrated simulator measured like the file (the same sweep when the
  file's metadata gives it, noise-free: ``samii.diagnose.simulator.measurement_like``), in 3D;
- ``simulator_after``: the same with the effects found carried into it and recalibrated (left out
  when nothing was carried), in 3D with its own model (a carried mode adds a body).

These are the re-measurements whose FRFs the diagnosis's ``"simulator"`` block compares with the
data, made again with the joint positions kept. An FRF file (no time series) gives only the
simulator's runs, measured over its band.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["diagnosis_runs", "write_diagnosis_recording"]


def _sweep_hz(ts) -> np.ndarray | None:
    """The record's instantaneous sweep frequency at ``ts.t`` when its metadata states the sweep."""
    from samii.measure.excitation import SweptSine

    try:
        return SweptSine.from_metadata(ts.metadata).frequency_hz(ts.t)
    except (KeyError, ValueError, TypeError):
        return None


def diagnosis_runs(d, *, fps: float | None = None):
    """(the recording's model, the runs) of diagnosis ``d`` (``--baseline sim``)."""
    from samii.diagnose.simulator import measurement_like, sweep_like
    from samii.sim.model import load_model
    from samii.viz.recording import RunRecord, frame_steps_for

    rep = d.simulator
    if rep is None:
        raise ValueError("a recording of a diagnosis needs --baseline sim (the simulator to show against the data)")
    before = load_model(params=rep.before.params)
    after = None if rep.after is rep.before else load_model(params=rep.after.params)
    files = d.raw_measured or d.measured
    runs = []
    for i, m in enumerate(files):
        tag = "" if len(files) == 1 else f"_{i + 1}"
        if m.timeseries is not None:
            runs.append(RunRecord(f"data{tag}", m.timeseries, np.zeros(0), np.zeros((0, before.nq)), sweep_hz=_sweep_hz(m.timeseries),
                                  label=f"measured: {m.source}"))  # fmt: skip
        sweep = sweep_like(m)
        what = (f"{sweep.start_hz:g}-{sweep.stop_hz:g} Hz at {sweep.amplitude_v:g} V, {sweep.repetitions} sweep(s), no noise"
                + ("" if m.timeseries is not None and "start_hz" in m.timeseries.metadata else "; the file's sweep is not known: over its band"))
        for name, model, params, how in (("simulator_before", before, rep.before.params, f"calibrated to {rep.before.source}"),
                                         ("simulator_after", after, rep.after.params,
                                          f"with {', '.join(rep.carried)} carried and recalibrated")):  # fmt: skip
            if model is None:
                continue
            meas = measurement_like(params, m, frame_steps=frame_steps_for(model, fps))
            run = meas.run
            runs.append(RunRecord(f"{name}{tag}", meas.timeseries, run.frame_t_s, run.frame_qpos, sweep_hz=sweep.frequency_hz(meas.timeseries.t),
                                  label=f"the simulator {how}, measured like {m.source} ({what})", model=model))  # fmt: skip
    return before, runs


def write_diagnosis_recording(path, d, *, fps: float | None = None):
    """Write diagnosis ``d``'s data and simulator runs (:func:`diagnosis_runs`) to the ``.rrd`` ``path``."""
    from samii.viz.recording import write_recording

    model, runs = diagnosis_runs(d, fps=fps)
    return write_recording(Path(path), model, runs, application_id="samii_diagnose")
