"""``samii diagnose --baseline sim --rerun FILE.rrd``: the simulator against the measured data, as
a Rerun recording (``samii.viz.recording``'s layout).

For each file the runs are (with several files, suffixed ``_1``, ``_2``, ...)

- ``data``: the file's own record, signals only (measured data have no joint positions, so no
  3D), its time counted from its first sample; an FRF file has none;
- ``simulator_after``: the simulator with the effects found carried into it and recalibrated,
  measured like the file (``samii.diagnose.simulator.measurement_like``: the file's own sweep
  when its header states it, as ``samii measure`` writes it, else one over the file's band at its
  amplitude, not in step with the data; no noise), in 3D with its own model (a carried mode adds a
  body), with the modal coordinates; left out when nothing was carried;
- ``simulator_before``: the calibrated simulator before the carry, measured the same way, in 3D.

These are the re-measurements whose FRFs the diagnosis's ``"simulator"`` block compares with the
data, made again with the joint positions kept. The data are drawn brightest, the simulator after
the carry dimmer, before it dimmest.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from samii.measure.excitation import SweptSine

__all__ = ["diagnosis_runs", "write_diagnosis_recording"]


def _stated_sweep(meta):
    """The sweep a file's header states, or None."""

    try:
        return SweptSine.from_metadata(meta)
    except (KeyError, ValueError, TypeError):
        return None


def _sweep_hz(ts) -> np.ndarray | None:
    """The record's instantaneous sweep frequency at ``ts.t`` (from its first sample) when its
    header states the sweep."""
    sweep = _stated_sweep(ts.metadata)
    return None if sweep is None else sweep.frequency_hz(ts.t - ts.t[0])


def _from_zero(ts):
    """``ts`` with its time counted from its first sample (the simulator's runs start at 0)."""

    return ts if ts.t[0] == 0 else replace(ts, t=ts.t - ts.t[0])


def diagnosis_runs(d, *, fps: float | None = None):
    """(the recording's model, the runs) of diagnosis ``d`` (``--baseline sim``)."""
    from samii.diagnose.simulator import measurement_like, sweep_like  # (lazy: imports mujoco, scipy, only when called)
    from samii.sim.model import load_model  # (lazy: imports mujoco, only when called)
    from samii.viz.recording import RunRecord, frame_steps_for  # (lazy: imports mujoco, scipy, only when called)

    rep = d.simulator
    if rep is None:
        raise ValueError("a recording of a diagnosis needs --baseline sim (the simulator to show against the data)")
    before = load_model(params=rep.before.params)
    after = None if rep.after is rep.before else load_model(params=rep.after.params)
    files = d.raw_measured or d.measured
    runs = []
    for i, m in enumerate(files):
        tag = "" if len(files) == 1 else f"_{i + 1}"
        ts = m.timeseries
        if ts is not None:
            shift = "" if ts.t[0] == 0 else f" (its time from its first sample, {ts.t[0]:.6g} s)"
            runs.append(RunRecord(f"data{tag}", _from_zero(ts), np.zeros(0), np.zeros((0, before.nq)), sweep_hz=_sweep_hz(ts),
                                  label=f"measured: {m.source}{shift}"))  # fmt: skip
        sweep = sweep_like(m)
        stated = _stated_sweep(ts.metadata if ts is not None else m.frf.metadata) is not None
        what = f"{sweep.start_hz:g}-{sweep.stop_hz:g} Hz at {sweep.amplitude_v:g} V, {sweep.repetitions} sweep(s), no noise" + (
            "; the file's own sweep, in step with its record"
            if stated
            else "; the file's sweep is not stated in its header: one over its band, not in step with its record"
        )
        for name, model, params, how in (("simulator_after", after, rep.after.params, f"with {', '.join(rep.carried)} carried and recalibrated"),
                                         ("simulator_before", before, rep.before.params, f"calibrated to {rep.before.source}")):  # fmt: skip
            if model is None:
                continue
            meas = measurement_like(params, m, frame_steps=frame_steps_for(model, fps))
            run = meas.run
            runs.append(RunRecord(f"{name}{tag}", meas.timeseries, run.frame_t_s, run.frame_qpos, sweep_hz=sweep.frequency_hz(meas.timeseries.t),
                                  label=f"the simulator {how}, measured like {m.source} ({what})", model=model))  # fmt: skip
    return before, runs


def write_diagnosis_recording(path, d, *, fps: float | None = None, thin: bool = True):
    """Write diagnosis ``d``'s data and simulator runs (:func:`diagnosis_runs`) to the ``.rrd`` ``path``; ``thin``:
    where the sweep is slow keep what the eye needs (:mod:`samii.viz.thinning`), else every sample and frame."""
    from samii.viz.recording import write_recording  # (lazy: imports mujoco, scipy, only when called)

    model, runs = diagnosis_runs(d, fps=fps)
    return write_recording(Path(path), model, runs, application_id="samii_diagnose", thin_frames=thin and fps is None, thin_signals=thin)
