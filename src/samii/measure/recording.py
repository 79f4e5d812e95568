"""Rerun recording of a measurement run: the arm and beam moving, and the measured signals.

Logging only (rerun and mujoco are imported when called); nothing here computes
a result. Entities:

- ``world/<body>/<geom>``: every MuJoCo geom of the model (boxes, capsules, cylinders)
  with its world pose at each animation frame (timeline ``time``, seconds);
- ``signals/valve_command_v``, ``signals/excitation_v``, ``signals/joint_angle_rad``,
  ``signals/base_accel_m_s2``, ``signals/load_pressure_pa``: the DAQ record.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from samii.measure.timeseries import TimeSeries

__all__ = ["write_rerun_recording"]

_SIGNALS = (
    ("v", "valve_command_v"),
    ("r", "excitation_v"),
    ("theta", "joint_angle_rad"),
    ("accel", "base_accel_m_s2"),
    ("p_load", "load_pressure_pa"),
)


def _geom_archetype(rr, mujoco, gtype: int, size: np.ndarray, rgba: np.ndarray):
    color = [int(round(255 * c)) for c in rgba]
    if gtype == mujoco.mjtGeom.mjGEOM_BOX:
        return rr.Boxes3D(half_sizes=[size[:3]], colors=[color], fill_mode="solid")
    if gtype == mujoco.mjtGeom.mjGEOM_CAPSULE:  # MuJoCo: centred, half-length size[1] along z
        return rr.Capsules3D(lengths=[2 * size[1]], radii=[size[0]], translations=[[0, 0, -size[1]]], colors=[color])
    if gtype == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return rr.Cylinders3D(lengths=[2 * size[1]], radii=[size[0]], centers=[[0, 0, 0]], colors=[color], fill_mode="solid")
    if gtype == mujoco.mjtGeom.mjGEOM_SPHERE:
        return rr.Ellipsoids3D(half_sizes=[[size[0]] * 3], colors=[color], fill_mode="solid")
    return None  # planes, meshes: not drawn


def write_rerun_recording(path, model, ts: TimeSeries, *, frame_t_s: np.ndarray, frame_qpos: np.ndarray, application_id: str = "samii_measure") -> Path:
    """Write a ``.rrd`` file with the model animated at ``frame_t_s`` and the signals of ``ts``.

    Parameters
    ----------
    path : path-like
        Output ``.rrd`` file (replaced if it exists: the caller checks overwrite rules).
    model : mujoco.MjModel
    ts : TimeSeries
        DAQ record (its time axis is the ``time`` timeline).
    frame_t_s, frame_qpos : arrays
        Animation frames: times [s] and joint positions (frames, nq).
    """
    import mujoco
    import rerun as rr

    path = Path(path)
    rec = rr.RecordingStream(application_id)
    rec.save(path)
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    data = mujoco.MjData(model)
    n_frames = len(frame_t_s)
    pos = np.empty((n_frames, model.ngeom, 3))
    quat = np.empty((n_frames, model.ngeom, 4))
    q = np.empty(4)
    for i, qpos in enumerate(frame_qpos):
        data.qpos[:] = qpos
        mujoco.mj_kinematics(model, data)
        pos[i] = data.geom_xpos
        for g in range(model.ngeom):
            mujoco.mju_mat2Quat(q, data.geom_xmat[g])
            quat[i, g] = (q[1], q[2], q[3], q[0])  # MuJoCo w,x,y,z -> Rerun x,y,z,w
    frames = rr.TimeColumn("time", duration=np.asarray(frame_t_s, float))
    for g in range(model.ngeom):
        arch = _geom_archetype(rr, mujoco, int(model.geom_type[g]), model.geom_size[g], model.geom_rgba[g])
        if arch is None:
            continue
        body = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.geom_bodyid[g])) or f"body_{model.geom_bodyid[g]}"
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom_{g}"
        entity = f"world/{body}/{name}"  # the pose logged is the geom's world pose
        rec.log(entity, arch, static=True)
        rec.send_columns(entity, indexes=[frames], columns=rr.Transform3D.columns(translation=pos[:, g], quaternion=quat[:, g]))
    samples = rr.TimeColumn("time", duration=ts.t)
    for column, label in _SIGNALS:
        values = getattr(ts, column)
        if values is None:
            continue
        rec.log(f"signals/{label}", rr.SeriesLines(names=label), static=True)
        rec.send_columns(f"signals/{label}", indexes=[samples], columns=rr.Scalars.columns(scalars=values))
    rec.flush()
    rec.disconnect()
    return path
