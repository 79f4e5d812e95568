"""Rerun recordings of simulated runs, one layout for every command that simulates.

Logging only (rerun is imported when called): the figures logged are computed by
:mod:`samii.sim.modal` and MuJoCo's kinematics. A recording holds one or more runs; run
``NAME``'s entities are

- ``NAME/deformed/<body>``: each body's world pose per animation frame, the joints' deviations
  from the ``home`` pose multiplied by the deformation scale (the beam's by ``beam_scale``, the
  arm's by ``arm_scale``; both in the 3D view's name and in ``about``); the geoms are
  logged once, static, as children ``NAME/deformed/<body>/<geom>`` with their pose in the body;
- ``NAME/deformed/tip_trail``: the beam tip's last ``TRAIL_S`` seconds as fading points;
- ``NAME/true_scale/<body>``: the same at true scale (the beam's real motion is sub-millimetre);
- time series grouped by unit, the unit in each group's name: ``NAME/angle_deg/{theta,theta_ref}``
  (joint 2 from the nominal pose), ``NAME/accel_m_s2/accel``, ``NAME/volts/{v,r,command}`` (valve
  command, excitation, the controller's command while it runs) and ``NAME/volts/switch_on`` (a
  marker at the switch-on), ``NAME/pressure_mpa/p_load``, ``NAME/displacement_mm/{tip,mode_1,
  mode_2,mode_3}`` (the tip's displacement along the accelerometer's axis and each base mode's
  share of it: the modal coordinates), ``NAME/frequency_hz/sweep`` (the excitation's
  instantaneous frequency), ``NAME/events`` (the switch-on as a text log);
- ``about``: one text document with the scales, the modes, and each run's frame rate.

Several runs in one recording are a comparison (a closed-loop run and the same scenario under the
servo amplifier alone, the notebook's Figure 11.4): one deformation scale for all, their series in
the same panels, the later runs' names tagged with the run's and their colours dimmed
(and of the modal coordinates only the first run's, the later ones' tip beside it).

Timeline ``time`` (seconds of the run). The blueprint stored with the recording puts the 3D
views (deformed beside true scale) beside one time-series panel per unit.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import mujoco
import numpy as np

from samii.sim.modal import modal_projection
from samii.sim.model import make_data
from samii.sim.sensors import accel_axis_world, accel_site
from samii.timeseries import TimeSeries
from samii.viz.thinning import BUCKETS_PER_PERIOD, FRAMES_PER_PERIOD_SWEPT, MIN_BUCKET_RATE_HZ, MIN_THINNED_FPS, RING_S, buckets, envelope, kept

__all__ = ["RunRecord", "RecordingInfo", "write_recording", "recording_failed", "read_scalars", "frame_steps_for", "TRAIL_S", "BEAM_DEFLECTION_SHOWN"]

#: The default deformation scale shows the run's largest tip deflection as this fraction of the beam's length.
BEAM_DEFLECTION_SHOWN = 0.05
#: The arm joints' largest deviation is shown at most this large [rad] (15 deg): scaled like the
#: beam, a step of a few degrees would spin the arm round.
ARM_DEVIATION_SHOWN_RAD = np.radians(15.0)
#: Length of the tip's trail [s] and the number of points it is drawn with.
TRAIL_S = 0.6
TRAIL_POINTS = 20
#: The viewer's dark background (grey level): what the trail fades into and later runs are dimmed towards.
BACKGROUND = 40.0
#: Most runs whose 3D views are stacked in rows; beyond, they are tabs.
MAX_3D_ROWS = 2
#: Frames per period of the fastest base mode shown (mode 3), and the lowest frame rate [1/s].
FRAMES_PER_PERIOD = 4
MIN_FPS = 100.0


@dataclass(frozen=True)
class RunRecord:
    """One simulated run to record: its DAQ record and its animation frames (SI units)."""

    name: str  #: entity root, e.g. "measure", "with_controller"
    timeseries: TimeSeries
    frame_t_s: np.ndarray  #: (frames,)
    frame_qpos: np.ndarray  #: (frames, nq)
    sweep_hz: np.ndarray | None = None  #: instantaneous sweep frequency at ``timeseries.t``
    switch_on_s: float | None = None  #: the controller's switch-on (Loper test)
    label: str = ""  #: one line on what the run is
    model: mujoco.MjModel | None = None  #: the run's own model when not the recording's (e.g. a simulator with a body added)


@dataclass(frozen=True)
class RecordingInfo:
    """What :func:`write_recording` wrote (also in the recording's ``about`` document)."""

    path: Path
    beam_scale: float
    arm_scale: float
    fps: float
    modes_hz: tuple[float, ...]
    max_tip_deflection_m: float
    runs: tuple[str, ...] = field(default_factory=tuple)


def frame_steps_for(model: mujoco.MjModel, fps: float | None = None) -> int:
    """Physics steps per animation frame: ``fps`` if given, else at least ``FRAMES_PER_PERIOD``
    frames per period of base mode 3 and at least ``MIN_FPS`` (100 frames/s on the embedded model)."""

    dt = float(model.opt.timestep)
    if fps is None:
        f3 = float(modal_projection(model).freq_hz[-1])
        fps = max(MIN_FPS, FRAMES_PER_PERIOD * f3)
        return max(1, int(np.floor(1.0 / (fps * dt))))
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"frame rate must be a positive number of frames per second, got {fps!r}")
    return max(1, int(round(1.0 / (fps * dt))))


def _beam_dofs(model: mujoco.MjModel) -> np.ndarray:
    """qpos addresses of the beam's joints (the clamp, the hinges, the clamp's Maxwell node, and a
    body on a compliant mount at its end, ``beam.tip_body_*``: part of the structure's deflection)."""
    out = []
    for j in range(model.njnt):
        name = model.joint(j).name
        if name.startswith(("clamp", "beam_", "tip_body")):
            out.append(int(model.jnt_qposadr[j]))
    return np.array(out, int)


def _beam_length(model: mujoco.MjModel, data: mujoco.MjData) -> float:
    """The beam's length [m]: the long sides of the ``beam_*`` bodies' geoms added up (else root to tip site)."""
    total = 0.0
    for b in range(model.nbody):
        if model.body(b).name.startswith("beam_"):
            for g in range(model.body_geomadr[b], model.body_geomadr[b] + model.body_geomnum[b]):
                if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX:
                    total += 2 * float(np.max(model.geom_size[g]))
    if total > 0:
        return total
    root = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "beam_0")
    return float(np.linalg.norm(data.site_xpos[accel_site(model)] - data.xpos[root])) if root >= 0 else 1.0


def _poses(model: mujoco.MjModel, qpos: np.ndarray, site: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body positions (frames, nbody, 3) and quaternions x,y,z,w (frames, nbody, 4), both float32,
    and the tip site (frames, 3)."""
    data = mujoco.MjData(model)
    n = len(qpos)
    pos = np.empty((n, model.nbody, 3), np.float32)  # rerun's transforms are float32
    quat = np.empty((n, model.nbody, 4), np.float32)
    tip = np.empty((n, 3))
    # the arrays' views into MjData fetched once (each attribute access builds a new view)
    q_view, xpos, xquat, site_xpos = data.qpos, data.xpos, data.xquat, data.site_xpos[site]
    kinematics = mujoco.mj_kinematics
    for i in range(n):
        q_view[:] = qpos[i]
        kinematics(model, data)
        pos[i] = xpos
        quat[i] = xquat
        tip[i] = site_xpos
    return pos, np.ascontiguousarray(quat[:, :, [1, 2, 3, 0]]), tip


@dataclass(frozen=True, eq=False)
class _Kinematics:
    """A model's pieces the recording needs: its rest pose, the tip site, the modal projection,
    and which joints are the beam's."""

    model: mujoco.MjModel
    home: mujoco.MjData
    site: int
    projection: object
    beam: np.ndarray  #: qpos addresses of the beam's joints

    @classmethod
    def of(cls, model: mujoco.MjModel) -> _Kinematics:
        return cls(model, make_data(model), accel_site(model), modal_projection(model), _beam_dofs(model))

    def scale(self, beam_scale: float, arm_scale: float) -> np.ndarray:
        out = np.full(self.model.nq, arm_scale)
        out[self.beam] = beam_scale
        return out


def _scales(parts, length: float, beam_scale: float | None) -> tuple[float, float, float]:
    """(beam scale, arm scale, largest tip deflection [m]) for runs ``parts``: (kinematics, joint
    positions (frames, nq), tip-site positions (frames, 3)).

    The beam's default: its largest tip deflection shown as ``BEAM_DEFLECTION_SHOWN`` of its
    ``length`` (1 when the tip does not move). The arm joints get the same scale unless that would
    show a joint's deviation beyond ``ARM_DEVIATION_SHOWN_RAD``; then the largest that does not
    (never below 1)."""
    deflection, arm_dev = 0.0, 0.0
    for kin, q, tip in parts:
        if not len(q):
            continue
        arm = np.setdiff1d(np.arange(kin.model.nq), kin.beam)
        deflection = max(deflection, float(np.max(np.linalg.norm(tip - kin.home.site_xpos[kin.site], axis=1))))
        if arm.size:
            arm_dev = max(arm_dev, float(np.max(np.abs(q[:, arm] - kin.home.qpos[arm]))))
    if beam_scale is None:
        beam_scale = BEAM_DEFLECTION_SHOWN * length / deflection if deflection > 0 else 1.0
    arm_scale = beam_scale if arm_dev * beam_scale <= ARM_DEVIATION_SHOWN_RAD else max(1.0, ARM_DEVIATION_SHOWN_RAD / arm_dev)
    return float(beam_scale), float(arm_scale), deflection


#: Geom types drawn (planes and meshes are not).
_DRAWN = (mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_SPHERE)


def _geom_archetype(rr, gtype: int, size: np.ndarray, rgba: np.ndarray):
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


def _body_name(model: mujoco.MjModel, b: int) -> str:
    return model.body(b).name or f"body_{b}"


def _time_column(rr, t_s: np.ndarray):
    """The ``time`` timeline at ``t_s`` [s], given as whole nanoseconds (4x faster than rerun's own
    conversion of float seconds)."""
    ns = np.round(np.asarray(t_s, float) * 1e9).astype(np.int64)
    return rr.TimeColumn("time", duration=ns.view("timedelta64[ns]"))


def _geoms(rr, model: mujoco.MjModel) -> dict[int, list]:
    """{body: [(geom name, its pose in the body, its archetype)]} of the geoms drawn, built once per
    model (a recording logs them under each run's two views)."""
    out: dict[int, list] = {}
    for b in range(1, model.nbody):
        for g in range(model.body_geomadr[b], model.body_geomadr[b] + model.body_geomnum[b]):
            arch = _geom_archetype(rr, int(model.geom_type[g]), model.geom_size[g], model.geom_rgba[g])
            if arch is not None:
                q = model.geom_quat[g]
                pose = rr.Transform3D(translation=model.geom_pos[g], quaternion=[q[1], q[2], q[3], q[0]])
                out.setdefault(b, []).append((model.geom(g).name or f"geom_{g}", pose, arch))
    return out


def _log_model(rec, rr, model: mujoco.MjModel, geoms: dict[int, list], root: str, t_s: np.ndarray, pos: np.ndarray, quat: np.ndarray) -> None:
    """Geoms once (static, in their body; ``geoms`` from :func:`_geoms`), one transform per body per frame."""
    frames = _time_column(rr, t_s)
    for b, drawn in geoms.items():
        entity = f"{root}/{_body_name(model, b)}"
        for gname, pose, arch in drawn:
            rec.log(f"{entity}/{gname}", pose, arch, static=True)
        if model.body_weldid[b] == 0 and len(pos):  # fixed to the world: one static pose
            rec.log(entity, rr.Transform3D(translation=pos[0, b], quaternion=quat[0, b]), static=True)
        else:
            rec.send_columns(entity, indexes=[frames], columns=rr.Transform3D.columns(translation=pos[:, b], quaternion=quat[:, b]))


def _series(rec, rr, entity: str, t_s: np.ndarray, values: np.ndarray, name: str, color) -> None:
    rec.log(entity, rr.SeriesLines(names=name, colors=[color]), static=True)
    rec.send_columns(entity, indexes=[_time_column(rr, t_s)], columns=rr.Scalars.columns(scalars=values))


def _trail(rec, rr, entity: str, t_s: np.ndarray, tip: np.ndarray, fps: float, keep: np.ndarray | None = None) -> None:
    """The tip's last ``TRAIL_S`` seconds at each frame (of the uniformly spaced ``t_s``, those in ``keep``),
    as ``TRAIL_POINTS`` points fading with age."""
    keep = np.ones(len(t_s), bool) if keep is None else keep
    stride = max(1, int(round(TRAIL_S * fps / TRAIL_POINTS)))
    lag = np.arange(TRAIL_POINTS) * stride
    idx = np.clip(np.flatnonzero(keep)[:, None] - lag[None, :], 0, None)
    t_s = t_s[keep]
    n = len(t_s)
    age = np.linspace(0.0, 1.0, TRAIL_POINTS)
    # Rerun draws points opaque (alpha is ignored, rerun-io/rerun#1611): the trail fades by blending
    # its orange into the 3D view's dark background
    fade = (1 - 0.85 * age)[:, None]
    colors = np.round(fade * np.array([255.0, 140.0, 0.0]) + (1 - fade) * BACKGROUND).astype(np.uint8)
    radii = 0.02 * (1 - 0.7 * age)
    cols = rr.Points3D.columns(positions=tip[idx].reshape(-1, 3), colors=np.tile(colors, (n, 1)), radii=np.tile(radii, n))
    rec.send_columns(entity, indexes=[_time_column(rr, t_s)], columns=cols.partition(np.full(n, TRAIL_POINTS)))


_COLORS = {"theta": (31, 119, 180), "theta_ref": (150, 150, 150), "accel": (214, 39, 40), "v": (44, 160, 44), "r": (148, 103, 189),
           "command": (255, 127, 14), "p_load": (140, 86, 75), "tip": (230, 230, 230), "mode_1": (31, 119, 180), "mode_2": (255, 127, 14),
           "mode_3": (44, 160, 44), "sweep": (23, 190, 207)}  # fmt: skip
#: (group entity, its panel's title) in the blueprint's order
GROUPS = (("angle_deg", "Angle [deg]"), ("accel_m_s2", "Acceleration [m/s²]"), ("volts", "Voltage [V]"), ("pressure_mpa", "Pressure [MPa]"),
          ("displacement_mm", "Tip displacement and base modes [mm]"), ("frequency_hz", "Sweep frequency [Hz]"))  # fmt: skip


#: How far the later runs of a comparison are dimmed towards the viewer's dark background, by rank.
DIMMED = (0.0, 0.45, 0.7)


def _thinning(run: RunRecord, thin_frames: bool = True, thin_signals: bool = True) -> tuple[np.ndarray | None, np.ndarray]:
    """``(sample buckets, frames kept)`` of a swept run (:mod:`samii.viz.thinning`): None and every frame
    for any other run (every sample unless ``thin_signals``, every frame unless ``thin_frames``)."""
    nf = len(run.frame_t_s)
    if run.sweep_hz is None:
        return None, np.ones(nf, bool)
    drive = np.asarray(run.sweep_hz, float)
    bucket = buckets(run.timeseries.t, drive, per_period=BUCKETS_PER_PERIOD, min_rate=MIN_BUCKET_RATE_HZ) if thin_signals else None
    if nf == 0 or not thin_frames:
        return bucket, np.ones(nf, bool)
    at_frames = np.interp(run.frame_t_s, run.timeseries.t, np.nan_to_num(drive, nan=0.0))
    return bucket, kept(run.frame_t_s, at_frames, per_period=FRAMES_PER_PERIOD_SWEPT, min_rate=MIN_THINNED_FPS)


def _log_signals(
    rec,
    rr,
    run: RunRecord,
    projection,
    *,
    tag: str = "",
    rank: int = 0,
    modes: bool = True,
    bucket: np.ndarray | None = None,
    frame_keep: np.ndarray | None = None,
) -> list[str]:
    """Log ``run``'s time series (the tip and the modes at its frames, from ``projection``) and
    return the groups it filled; ``tag`` prefixes the series' names. The later runs of a comparison
    (``rank`` > 0), in the same panels, have their colours dimmed (:data:`DIMMED`) towards the
    viewer's dark background; only one run's modal coordinates are logged (``modes``), the
    others' tip beside them. ``bucket``: the record's samples in buckets, of which each signal keeps
    its envelope; ``frame_keep``: the frames kept (:mod:`samii.viz.thinning`; default all)."""
    ts = run.timeseries
    root = run.name
    groups = set()
    frame_keep = np.ones(len(run.frame_t_s), bool) if frame_keep is None else frame_keep

    def put(group: str, key: str, values, name: str, t=None, mask=None) -> None:
        if values is None:
            return
        color = np.asarray(_COLORS[key], float)
        dim = DIMMED[min(rank, len(DIMMED) - 1)]
        color = (1 - dim) * color + dim * BACKGROUND
        values = np.asarray(values, float)
        if t is None:  # at the record's samples: its envelope in each bucket
            t, m = ts.t, (None if bucket is None else envelope(values, bucket))
        else:
            m = mask
        if m is not None:
            t, values = t[m], values[m]
        _series(rec, rr, f"{root}/{group}/{key}", t, values, tag + name, [int(x) for x in color])
        groups.add(group)

    put("angle_deg", "theta", np.degrees(ts.theta), "θ joint 2 [deg]")
    put("angle_deg", "theta_ref", None if ts.theta_ref is None else np.degrees(ts.theta_ref), "θ_ref [deg]")
    put("accel_m_s2", "accel", ts.accel, "base acceleration ẍ [m/s²]")
    put("volts", "v", ts.v, "valve command v [V]")
    put("volts", "r", ts.r, "excitation r [V]")
    command = ts.extra.get("command")
    on = np.zeros(ts.t.size, bool)
    if command is not None:  # shown while the controller runs
        on = np.isfinite(command) & (ts.extra["controller_on"] > 0.5 if "controller_on" in ts.extra else True)
        if np.any(on):
            put(
                "volts",
                "command",
                command,
                "controller command [V]",
                t=ts.t,
                mask=on if bucket is None else on & envelope(np.where(on, command, np.nan), bucket),
            )
    put("pressure_mpa", "p_load", None if ts.p_load is None else ts.p_load / 1e6, "load pressure [MPa]")
    if len(run.frame_t_s):
        q = run.frame_qpos[frame_keep]
        put("displacement_mm", "tip", 1e3 * projection.tip_m(q), "tip displacement [mm]", t=run.frame_t_s[frame_keep])
        if modes:
            shares = projection.shares_m(q)
            for k, f in enumerate(projection.freq_hz):
                put("displacement_mm", f"mode_{k + 1}", 1e3 * shares[:, k], f"mode {k + 1} ({f:.2f} Hz) [mm]", t=run.frame_t_s[frame_keep])
    put("frequency_hz", "sweep", run.sweep_hz, "sweep frequency [Hz]")
    if run.switch_on_s is not None:
        rec.set_time("time", duration=float(run.switch_on_s))
        rec.log(f"{root}/events", rr.TextLog(f"controller switched on at {run.switch_on_s:.3f} s", level="INFO"))
        if np.any(on):
            rec.log(f"{root}/volts/switch_on", rr.Scalars([float(command[np.argmax(on)])]),
                    rr.SeriesPoints(names="controller switched on", markers="diamond", marker_sizes=8, colors=[_COLORS["tip"]]))  # fmt: skip
        rec.reset_time()
    return [g for g, _ in GROUPS if g in groups]


def _eye(model: mujoco.MjModel, home: mujoco.MjData) -> dict:
    """Where the 3D views' camera starts: the whole structure in view, looking across the
    accelerometer's axis (the base's vibration lies in the picture's plane), turned 30 deg and
    raised 15 deg for depth."""

    drawn = [g for g in range(model.ngeom) if model.geom_type[g] in _DRAWN]
    if drawn:  # each geom's bounding sphere
        r = model.geom_rbound[drawn][:, None]
        lo, hi = (home.geom_xpos[drawn] - r).min(axis=0), (home.geom_xpos[drawn] + r).max(axis=0)
    else:
        lo, hi = home.xpos[1:].min(axis=0), home.xpos[1:].max(axis=0)
    centre = (lo + hi) / 2
    extent = max(float(np.max(hi - lo)), 0.5)
    z = np.array([0.0, 0.0, 1.0])
    a = np.asarray(accel_axis_world(model, home), float)
    a = a - (a @ z) * z
    a = a / np.linalg.norm(a) if np.linalg.norm(a) > 1e-9 else np.array([1.0, 0.0, 0.0])
    across = np.cross(z, a)
    turn, rise = np.radians(30.0), np.radians(15.0)
    d = np.cos(turn) * across + np.sin(turn) * a
    position = centre + 1.35 * extent * (np.cos(rise) * d + np.sin(rise) * z)
    return {"position": position.tolist(), "look_target": centre.tolist(), "eye_up": z.tolist()}


def _view3d_name(run: RunRecord, beam_scale: float, arm_scale: float) -> str:
    return f"{run.name}: beam ×{beam_scale:.3g}, arm ×{arm_scale:.3g}"


def _blueprint(rrb, runs, groups_by_run: dict[str, list[str]], beam_scale: float, arm_scale: float, eye: dict):
    views3d = []
    for run in runs:  # the deformed view beside the true-scale one, a row per run with frames
        if not len(run.frame_t_s):
            continue
        views3d.append(rrb.Horizontal(
            rrb.Spatial3DView(origin=f"/{run.name}/deformed", name=_view3d_name(run, beam_scale, arm_scale), eye_controls=rrb.EyeControls3D(**eye)),
            rrb.Spatial3DView(origin=f"/{run.name}/true_scale", name=f"{run.name}: true scale", eye_controls=rrb.EyeControls3D(**eye)),
            column_shares=[3, 2], name=run.name))  # fmt: skip
    if len(views3d) > MAX_3D_ROWS:  # many runs: one row at a time, as tabs
        views3d = [rrb.Tabs(*views3d)]
    panels = []
    for group, title in GROUPS:
        contents = [f"/{run.name}/{group}/**" for run in runs if group in groups_by_run[run.name]]
        if contents:
            panels.append(rrb.TimeSeriesView(origin="/", contents=contents, name=title, plot_legend=rrb.PlotLegend(corner="RightTop")))
    events = [f"/{run.name}/events" for run in runs if run.switch_on_s is not None]
    left = list(views3d)
    below = []
    if events:
        below.append(rrb.TextLogView(origin="/", contents=events, name="Events"))
    below.append(rrb.TextDocumentView(origin="/about", name="About this recording"))
    left.append(rrb.Tabs(*below) if len(below) > 1 else below[0])
    shares = [4] * len(views3d) + [1 + len(views3d) // 2]
    return rrb.Blueprint(rrb.Horizontal(rrb.Vertical(*left, row_shares=shares), rrb.Vertical(*panels), column_shares=[3, 2]),
                         rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
                         rrb.TimePanel(state="collapsed", timeline="time"))  # fmt: skip


def write_recording(
    path,
    model: mujoco.MjModel,
    runs,
    *,
    application_id: str,
    beam_scale: float | None = None,
    fps: float | None = None,
    thin_frames: bool = True,
    thin_signals: bool = True,
) -> RecordingInfo:
    """Write ``runs`` (:class:`RunRecord`) of ``model`` to the ``.rrd`` file ``path`` with the stored layout.

    ``beam_scale``: the deformation scale (default: the largest tip deflection shown as
    ``BEAM_DEFLECTION_SHOWN`` of the beam's length). ``fps``: the frame
    rate the frames were kept at (for the trail; default from their times). The file is replaced
    if it exists (the caller applies the overwrite rules). A swept run (``sweep_hz`` given) is thinned
    where the sweep is slow (:mod:`samii.viz.thinning`): its signals keep their envelope, its frames
    the motion (``thin_frames`` False: every frame, as a frame rate the user asked for;
    ``thin_signals`` False: every sample).
    """
    import rerun as rr  # (lazy: imports rerun, only when called)
    import rerun.blueprint as rrb  # (lazy: imports rerun, only when called)

    path = Path(path)
    kin: dict[int, _Kinematics] = {id(model): _Kinematics.of(model)}
    for r in runs:
        if r.model is not None and id(r.model) not in kin:
            kin[id(r.model)] = _Kinematics.of(r.model)
    main = kin[id(model)]
    runs = [
        replace(
            r, frame_t_s=np.asarray(r.frame_t_s, float), frame_qpos=np.asarray(r.frame_qpos, float).reshape(len(r.frame_t_s), (r.model or model).nq)
        )
        for r in runs
    ]
    run_kin = [kin[id(r.model or model)] for r in runs]
    projection = main.projection

    rec = rr.RecordingStream(application_id)
    rec.set_log_time_enabled(False)  # the one timeline is the run's time
    # rerun encodes into a stream this process writes to the file at the end: a file sink's writer thread that dies
    # on a full disk left rerun's flush, then its drop, waiting for ever (rerun 0.41), while a write here fails at once
    # with the OS's own error. The stream is read once, whole: bytes read part by part fail the file's CRC check
    # (RrdReader, rerun 0.41), so the recording is held in memory until then (a 60 s run's 12 MB: +55 MB peak).
    stream = rec.binary_stream()
    out = open(path, "wb")
    try:
        # the signals first: rerun encodes and writes them on its own thread while the poses are computed here
        # the modal coordinates of the first run with frames (measured data have none)
        with_modes = next((r.name for r in runs if len(r.frame_t_s)), None)
        keeps = [_thinning(r, thin_frames, thin_signals) for r in runs]
        groups_by_run = {run.name: _log_signals(rec, rr, run, k.projection, tag="" if len(runs) == 1 else f"{run.name}: ", rank=i,
                                                modes=run.name == with_modes, bucket=bucket, frame_keep=frame_keep)
                         for i, (run, k, (bucket, frame_keep)) in enumerate(zip(runs, run_kin, keeps))}  # fmt: skip
        true_poses = [_poses(k.model, r.frame_qpos, k.site) for r, k in zip(runs, run_kin)]
        length = _beam_length(model, main.home)
        beam_scale, arm_scale, deflection = _scales([(k, r.frame_qpos, p[2]) for r, k, p in zip(runs, run_kin, true_poses)], length, beam_scale)
        rate = fps
        modes = ", ".join(f"{f:.2f}" for f in projection.freq_hz)
        about = [f"# {application_id}\n",
                 f"- **deformation scale**: beam deflection ×{beam_scale:.4g}, arm joints' deviations from the nominal pose ×{arm_scale:.4g} "
                 f"(the largest tip deflection in this recording, {1e3 * deflection:.4g} mm, is shown as {100 * beam_scale * deflection / length:.3g} % "
                 f"of the beam's {length:.3g} m; the arm's scale is the beam's unless a joint would turn more than "
                 f"{np.degrees(ARM_DEVIATION_SHOWN_RAD):.0f}°, never below 1); the true-scale view is beside it",
                 f"- **tip trail**: the last {TRAIL_S} s of the beam tip (deformed)",
                 f"- **modal coordinates**: each base mode's share of the tip displacement along the accelerometer's axis, "
                 f"from the undamped shapes of the structure with joint 2 held ({modes} Hz)\n"]  # fmt: skip
        geoms_of = {key: _geoms(rr, k.model) for key, k in kin.items()}  # logged under each run's two views
        for run, k, (pos_true, quat_true, _), (bucket, fk) in zip(runs, run_kin, true_poses, keeps):
            t, q = run.frame_t_s, run.frame_qpos
            samples_per_s = 1 / float(np.median(np.diff(run.timeseries.t)))
            thinned = bucket is not None
            if len(t):
                if rate is None:
                    rate = 1.0 / float(np.median(np.diff(t))) if len(t) > 1 else MIN_FPS
                rec.log(run.name, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
                pos_def, quat_def, tip_def = _poses(k.model, k.home.qpos + (q - k.home.qpos) * k.scale(beam_scale, arm_scale), k.site)
                geoms = geoms_of[id(k.model)]
                _log_model(rec, rr, k.model, geoms, f"{run.name}/true_scale", t[fk], pos_true[fk], quat_true[fk])
                _log_model(rec, rr, k.model, geoms, f"{run.name}/deformed", t[fk], pos_def[fk], quat_def[fk])
                _trail(rec, rr, f"{run.name}/deformed/tip_trail", t, tip_def, rate, keep=fk)
                frames = (f"{rate:.4g} frames per second ({len(t)} frames): the 3D views, the tip and the modes; the other signals "
                          f"at the record's {samples_per_s:.4g} samples/s")  # fmt: skip
                if thinned:
                    frames = (
                        f"the 3D views, the tip and the modes in {int(fk.sum())} of the run's {len(t)} frames ({rate:.4g} per second), "
                        f"at least {FRAMES_PER_PERIOD_SWEPT} per period of the highest frequency the sweep drove in the last {RING_S:g} s "
                        f"and {MIN_THINNED_FPS:g} per second; the other signals at the record's {samples_per_s:.4g} samples/s where the sweep "
                        f"is fast, and where it is slow each one's smallest and largest sample in every {BUCKETS_PER_PERIOD}th of that "
                        f"period (at least every {1 / MIN_BUCKET_RATE_HZ:g} s): the curves' peaks and the noise's width are the record's; "
                        "every sample is in the run's time series file"
                    )
            else:
                frames = f"no animation frames (no joint positions: e.g. measured data); the signals at {samples_per_s:.4g} samples/s"
            own = "" if k is main else f"\n- its own model: base modes {', '.join(f'{f:.2f}' for f in k.projection.freq_hz)} Hz"
            about.append(f"## {run.name}\n\n{run.label}\n\n- {frames}{own}\n")
        rec.log("about", rr.TextDocument("\n".join(about), media_type="text/markdown"), static=True)
        rec.send_property(
            "deformation", rr.AnyValues(beam_scale=beam_scale, arm_scale=arm_scale, max_tip_deflection_m=deflection, fps=float(rate or 0.0))
        )
        rec.send_blueprint(_blueprint(rrb, runs, groups_by_run, beam_scale, arm_scale, _eye(model, main.home)))
        out.write(stream.read(flush=True) or b"")
    finally:
        out.close()
        try:  # emptied on any failure or interrupt too: rerun warns of data it drops with its stream (a Rust log line)
            stream.read(flush=True, flush_timeout_sec=2.0)
        except Exception:  # noqa: BLE001 (the failure being raised is the one to report)
            pass
        rec.disconnect()
    return RecordingInfo(
        path, beam_scale, arm_scale, float(rate or 0.0), tuple(float(f) for f in projection.freq_hz), deflection, tuple(r.name for r in runs)
    )


def recording_failed(exc: Exception, final) -> OSError:
    """The error to raise when writing the recording for ``--rerun final`` failed with ``exc``: an OSError naming
    ``final`` (not the temporary file beside it) that keeps the OS's error number (a full disk is said so), or
    rerun's own message (it reports its writer's failures as RuntimeError)."""
    if isinstance(exc, OSError) and exc.errno is not None:
        # absolute: the main job writes its recordings inside its hidden staging folder, where the CLI names --out instead
        err = OSError(exc.errno, f"--rerun {final}: {exc.strerror}", str(Path(final).absolute()))
        err.user_path = True  # (the CLI names this file on a full disk, not the first output begun)
        return err
    return OSError(f"--rerun {final}: the recording could not be written ({' '.join(str(exc).split())})")


def read_scalars(path, entities) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Read time series back from a recording: {entity: (t [s], values)} for each entity path in
    ``entities`` (e.g. ``"/swept/displacement_mm/tip"``) that holds scalars on the ``time``
    timeline, sorted by time (``rerun.chunk.RrdReader``)."""
    import rerun.chunk as rc  # (lazy: imports rerun, only when called)

    want = {e if e.startswith("/") else f"/{e}" for e in ([entities] if isinstance(entities, str) else entities)}
    parts: dict[str, list] = {}
    for chunk in rc.RrdReader(str(path)).store().stream():
        entity = str(chunk.entity_path)
        if chunk.is_static or entity not in want:
            continue
        batch = chunk.to_record_batch()
        if "Scalars:scalars" not in batch.schema.names:
            continue
        t = batch.column("time").cast("int64").to_numpy() * 1e-9
        v = np.array([x[0] if x else np.nan for x in batch.column("Scalars:scalars").to_pylist()], float)
        parts.setdefault(entity, []).append((t, v))
    out = {}
    for entity, chunks in parts.items():
        t = np.concatenate([c[0] for c in chunks])
        v = np.concatenate([c[1] for c in chunks])
        order = np.argsort(t, kind="stable")
        out[entity] = (t[order], v[order])
    return out
