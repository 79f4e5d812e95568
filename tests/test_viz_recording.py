"""Rerun recordings read back (rerun-sdk's ``rerun.chunk.RrdReader``): entities, timeline, frame
rate, values equal to the data they came from, the deformation scale, the blueprint.

Physics checked on the way: a closed-loop run and its comparison under the servo amplifier alone
are the same simulation until the controller is switched on; the modal coordinates of an impulse at the beam's tip are mode 1's
(the tip impulse excites mode 1 almost alone: it carries > 99 % of the tip's motion), their sum
is the tip's displacement, and the deformed view's tip moves ``beam_scale`` times the true one.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from samii.cli import main

rc = pytest.importorskip("rerun.chunk")


def _read(path):
    """{entity: {"static": [record batches], "time": [record batches]}} of the recording, and the blueprint's texts."""
    reader = rc.RrdReader(str(path))
    out: dict[str, dict[str, list]] = {}
    for chunk in reader.store().stream():
        kind = "static" if chunk.is_static else "time"
        out.setdefault(chunk.entity_path, {"static": [], "time": []})[kind].append(chunk.to_record_batch())
    blueprints = reader.blueprints()
    names = []
    for entry in blueprints:
        for chunk in reader.store(store=entry).stream():
            batch = chunk.to_record_batch()
            for name in batch.schema.names:
                if name.endswith(":name") or name.endswith("display_name"):
                    names += [str(v) for v in batch.column(name).to_pylist()]
    return out, names, blueprints


def _column(batches, name):
    """Time [s] and values of a component over all chunks, sorted by time."""
    t, v = [], []
    for b in batches:
        t.append(b.column("time").cast("int64").to_numpy() * 1e-9)
        v.append(np.asarray(b.column(name).to_pylist(), dtype=object))
    t = np.concatenate(t)
    order = np.argsort(t, kind="stable")
    return t[order], np.concatenate(v)[order]


def _scalars(batches):
    t, v = _column(batches, "Scalars:scalars")
    return t, np.array([x[0] for x in v], float)


@pytest.fixture(scope="module")
def loper(tmp_path_factory):
    """``samii closedloop --controller damping --scenario loper --rerun``: the Loper test (switch-on mid-run)."""
    d = tmp_path_factory.mktemp("loper")
    rrd = d / "run.rrd"
    assert main(["closedloop", "--controller", "damping", "--scenario", "loper", "--duration-s", "6", "--out", str(d / "out"),
                 "--no-plots", "--rerun", str(rrd)]) == 0  # fmt: skip
    from samii.formats import read_timeseries_csv

    return _read(rrd) + (read_timeseries_csv(d / "out" / "timeseries.csv"), rrd)


def test_recording_has_the_layout_and_the_data(loper):
    rec, names, blueprints = loper[:3]
    ts = loper[3]
    root = "/closedloop"
    # 3D: one transform per body per frame, geoms static under their body, at both scales; the tip's trail
    for view in ("deformed", "true_scale"):
        for body in ("beam_0", "beam_4", "l0", "link2", "link6"):
            assert rec[f"{root}/{view}/{body}"]["time"], f"{view}/{body} has no transforms"
            assert not rec[f"{root}/{view}/{body}"]["static"]
        geoms = [e for e in rec if e.startswith(f"{root}/{view}/link2/")]
        assert geoms and all(rec[e]["static"] and not rec[e]["time"] for e in geoms)
    assert rec[f"{root}/deformed/tip_trail"]["time"]
    # frame rate: 4 frames per period of base mode 3 (~24-25 Hz), at least 100/s
    t, _ = _column(rec[f"{root}/deformed/link2"]["time"], "Transform3D:translation")
    assert np.allclose(np.diff(t), 0.01, atol=1e-9) and t[-1] >= 5.9
    # signals grouped by unit, equal to the run's timeseries.csv (converted to the unit in the name)
    for entity, values in ((f"{root}/angle_deg/theta", np.degrees(ts.theta)), (f"{root}/angle_deg/theta_ref", np.degrees(ts.theta_ref)),
                           (f"{root}/accel_m_s2/accel", ts.accel), (f"{root}/volts/v", ts.v), (f"{root}/volts/r", ts.r),
                           (f"{root}/pressure_mpa/p_load", ts.p_load / 1e6)):  # fmt: skip
        tt, vv = _scalars(rec[entity]["time"])
        assert np.allclose(tt, ts.t, atol=1e-9), entity
        assert np.allclose(vv, values, rtol=1e-9, atol=1e-12), entity
    # the controller's command only while it runs; the switch-on marked
    tt, vv = _scalars(rec[f"{root}/volts/command"]["time"])
    on = ts.extra["controller_on"] > 0.5
    assert np.allclose(tt, ts.t[on], atol=1e-9) and np.allclose(vv, ts.extra["command"][on])
    t_on, _ = _scalars(rec[f"{root}/volts/switch_on"]["time"])
    assert t_on[0] == pytest.approx(ts.t[on][0], abs=1e-9)
    _, text = _column(rec[f"{root}/events"]["time"], "TextLog:text")
    assert "switched on" in str(text[0])
    # the comparison (Figure 11.4 as a recording): the same scenario under the servo amplifier alone, in the same
    # panels; identical to the controlled run until the switch-on, different after it
    assert rec["/servo_loop_alone/deformed/link2"]["time"] and "/servo_loop_alone/volts/command" not in rec
    tc, ac = _scalars(rec["/servo_loop_alone/accel_m_s2/accel"]["time"])
    ta, aa = _scalars(rec[f"{root}/accel_m_s2/accel"]["time"])
    assert np.allclose(tc, ta)
    before, after = ta < t_on[0] - 1e-9, ta > t_on[0] + 0.2
    assert np.allclose(aa[before], ac[before], rtol=0, atol=1e-9 * np.abs(ac).max())
    assert np.sqrt(np.mean((aa[after] - ac[after]) ** 2)) > 0.1 * np.sqrt(np.mean(ac[after] ** 2))
    series_names = [str(v) for b in rec["/servo_loop_alone/accel_m_s2/accel"]["static"] for v in b.column("SeriesLines:names").to_pylist()]
    assert any("servo_loop_alone:" in n for n in series_names)
    # modal coordinates and the tip, in mm
    tt, tip = _scalars(rec[f"{root}/displacement_mm/tip"]["time"])
    shares = np.array([_scalars(rec[f"{root}/displacement_mm/mode_{k}"]["time"])[1] for k in (1, 2, 3)])
    assert np.allclose(tt, t) and np.abs(tip).max() > 1.0  # mm: the Loper step moves the tip by millimetres
    assert np.sqrt(np.mean((shares.sum(axis=0) - tip) ** 2)) < 0.02 * np.sqrt(np.mean(tip**2))
    # the comparison's tip beside it; its modes left out (one set of modes per panel)
    assert rec["/servo_loop_alone/displacement_mm/tip"]["time"] and "/servo_loop_alone/displacement_mm/mode_1" not in rec
    # one About document for the recording (a view shows one document), naming both runs and the scale
    assert [e for e in rec if e.endswith("/about")] == ["/about"]
    about = str(rec["/about"]["static"][0].column("TextDocument:text").to_pylist()[0])
    assert "## closedloop" in about and "## servo_loop_alone" in about and "deformation scale" in about
    # poses: at t = 0 the run rests in home; Rerun's quaternions are x, y, z, w
    from samii.sim.model import load_model, make_data

    model = load_model()
    home = make_data(model)
    for body in ("beam_4", "link2", "link6"):
        b = model.body(body).id
        _, quat = _column(rec[f"{root}/true_scale/{body}"]["time"], "Transform3D:quaternion")
        _, trans = _column(rec[f"{root}/true_scale/{body}"]["time"], "Transform3D:translation")
        assert np.allclose(np.asarray(quat[0], float).ravel(), home.xquat[b][[1, 2, 3, 0]], atol=1e-6), body
        assert np.allclose(np.asarray(trans[0], float).ravel(), home.xpos[b], atol=1e-6), body
    # the layout is stored: 3D views naming the scale, one time-series panel per unit
    assert blueprints
    joined = " | ".join(names)
    for title in ("beam ×", "true scale", "Angle [deg]", "Acceleration [m/s²]", "Voltage [V]", "Pressure [MPa]",
                  "Tip displacement and base modes [mm]"):  # fmt: skip
        assert title in joined, f"no view {title!r} in the blueprint: {joined}"


def test_deformation_scale_magnifies_the_beam(loper):
    """The deformed tip moves beam_scale times the true tip; the largest shown deflection is 5 % of the beam."""
    from samii.sim.model import load_model, make_data

    rec = loper[0]
    props = rec["/__properties/deformation"]["static"][0]
    beam_scale = props.column("beam_scale").to_pylist()[0][0]
    model = load_model()
    home = make_data(model)
    l0 = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "l0")
    _, true = _column(rec["/closedloop/true_scale/l0"]["time"], "Transform3D:translation")
    _, shown = _column(rec["/closedloop/deformed/l0"]["time"], "Transform3D:translation")
    true = np.array([np.asarray(x, float).ravel() for x in true]) - home.xpos[l0]
    shown = np.array([np.asarray(x, float).ravel() for x in shown]) - home.xpos[l0]
    big = np.linalg.norm(true, axis=1) > 0.3 * np.linalg.norm(true, axis=1).max()
    ratio = np.linalg.norm(shown[big], axis=1) / np.linalg.norm(true[big], axis=1)
    assert np.allclose(ratio, beam_scale, rtol=0.03), (beam_scale, ratio.min(), ratio.max())
    # the beam's length: its segments' boxes end to end (4.29 m; the model card's 4.6482 m includes the mount)
    beam = sum(2 * model.geom_size[g].max() for g in range(model.ngeom) if model.body(model.geom_bodyid[g]).name.startswith("beam_"))
    deflection = props.column("max_tip_deflection_m").to_pylist()[0][0]
    assert beam_scale * deflection == pytest.approx(0.05 * beam, rel=1e-9)


def test_modal_coordinates_of_a_tip_impulse_are_mode_1():
    """An impulse at the tip excites base mode 1 almost alone; the modes' shares add up to the tip's displacement,
    which agrees with the kinematic one (the projection is the linearisation about home)."""
    from samii.sim.linearize import base_modes
    from samii.sim.modal import modal_projection
    from samii.sim.model import load_model, load_spec, make_data
    from samii.sim.sensors import accel_weights

    model = load_model()
    proj = modal_projection(model)
    spec, _ = load_spec()
    data = make_data(model)
    theta2 = data.qpos[model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "joint2")]]
    assert np.allclose(proj.freq_hz, [m.freq_hz for m in base_modes(spec, theta2)], rtol=0.06)
    site = int(model.sensor_objid[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, "base_accel")])
    _, direction = accel_weights(model)
    jac = np.zeros((3, model.nv))
    mujoco.mj_jacSite(model, data, jac, None, site)
    c = direction @ jac
    data.qvel[:] = c * 0.02 / (c @ c)  # a 0.02 m/s kick at the tip along the accelerometer's axis
    home_tip = make_data(model).site_xpos[site].copy()
    q, tip = [], []
    for i in range(3000):
        mujoco.mj_step(model, data)
        if i % 5 == 0:
            q.append(data.qpos.copy())
            tip.append((data.site_xpos[site] - home_tip) @ direction)
    q, tip = np.array(q), np.array(tip)
    shares = proj.shares_m(q)
    rms = np.sqrt(np.mean(shares**2, axis=0))
    assert rms[0] > 0.99 * np.sqrt(np.mean(tip**2))
    assert np.all(rms[1:] < 0.01 * rms[0])
    assert np.sqrt(np.mean((proj.tip_m(q) - tip) ** 2)) < 0.02 * np.sqrt(np.mean(tip**2))
    assert np.sqrt(np.mean((shares.sum(axis=1) - proj.tip_m(q)) ** 2)) < 0.01 * np.sqrt(np.mean(tip**2))


def test_measure_both_records_both_runs_with_the_sweep_frequency(tmp_path):
    rrd = tmp_path / "m.rrd"
    assert main(["measure", "--method", "both", "--band-hz", "5", "10", "--averages", "1", "--freqs-hz", "6", "9", "--tail-s", "1",
                 "--no-progress", "--out", str(tmp_path / "out"), "--rerun", str(rrd), "--rerun-fps", "50"]) == 0  # fmt: skip
    rec, names, _ = _read(rrd)
    for run in ("swept", "stepped"):
        assert rec[f"/{run}/deformed/link2"]["time"]
        t, f = _scalars(rec[f"/{run}/frequency_hz/sweep"]["time"])
        finite = f[np.isfinite(f)]
        assert finite.size and finite.min() >= 5 - 1e-9 and finite.max() <= 10 + 1e-9
    t, _ = _column(rec["/swept/deformed/link2"]["time"], "Transform3D:translation")
    assert np.allclose(np.diff(t), 0.02, atol=1e-9)  # --rerun-fps 50
    assert any("swept: beam ×" in n for n in names) and any("stepped: beam ×" in n for n in names)


def test_frame_rate_follows_base_mode_3():
    """4 frames per period of mode 3, at least 100/s: a shorter, lighter beam's mode 3 needs more frames."""
    from samii.sim.modal import modal_projection
    from samii.sim.model import load_model
    from samii.viz.recording import frame_steps_for

    assert frame_steps_for(load_model()) == 10  # mode 3 at 23.8 Hz: 4 x 23.8 < 100/s, so 100/s
    # (at the 1 ms step this beam's elements are too stiff to integrate, and load_model refuses it: a 0.25 ms step)
    stiff = load_model(overrides={"beam.length_m": 2.5, "beam.mass_per_length_kg_m": 3.0, "timestep_s": 2.5e-4})
    f3 = float(modal_projection(stiff).freq_hz[-1])
    steps = frame_steps_for(stiff)
    assert f3 > 30.0
    assert 1.0 / (steps * stiff.opt.timestep) >= 4 * f3 and 1.0 / ((steps + 1) * stiff.opt.timestep) < 4 * f3
    assert frame_steps_for(stiff, 50.0) == 80  # 50 frames a second of 4000 steps
    with pytest.raises(ValueError, match="positive"):
        frame_steps_for(stiff, 0.0)


def test_tip_trail_follows_the_deformed_tip(loper):
    """The trail at each frame: TRAIL_POINTS points, the newest the tip now, each older one the tip
    ``stride`` frames earlier (0.6 s in all), fading from orange towards the background; the newest
    point moves like the deformed beam (beam_scale times the true tip)."""
    from samii.viz.recording import TRAIL_POINTS, TRAIL_S

    rec = loper[0]
    t, pos = _column(rec["/closedloop/deformed/tip_trail"]["time"], "Points3D:positions")
    _, colors = _column(rec["/closedloop/deformed/tip_trail"]["time"], "Points3D:colors")
    pts = np.array([np.asarray([np.asarray(p, float) for p in row]) for row in pos])  # (frames, points, 3)
    assert pts.shape[1:] == (TRAIL_POINTS, 3)
    fps = 1 / np.median(np.diff(t))
    stride = int(round(TRAIL_S * fps / TRAIL_POINTS))
    for k in (1, 5, TRAIL_POINTS - 1):
        lag = k * stride
        assert np.allclose(pts[lag:, k], pts[: len(pts) - lag, 0], atol=1e-6), k
    c = np.array([int(x) for x in colors[100]], dtype=np.int64)  # packed RGBA: red in the top byte
    red = (c >> 24) & 0xFF
    assert red[0] == 255 and np.all(np.diff(red) < 0)  # the newest brightest, then fading
    # the newest point against the true tip: the deformation scale
    props = rec["/__properties/deformation"]["static"][0]
    beam_scale = props.column("beam_scale").to_pylist()[0][0]
    from samii.sim.model import load_model, make_data
    from samii.sim.sensors import accel_site

    model = load_model()
    home_tip = make_data(model).site_xpos[accel_site(model)]
    shown = np.linalg.norm(pts[:, 0] - home_tip, axis=1)
    assert shown.max() == pytest.approx(0.05 * 4.29, rel=0.05)  # 5 % of the beam's length, by the default scale
    assert beam_scale > 10


def test_blueprint_views_look_at_each_run(loper):
    """The stored layout's 3D views have the runs' deformed and true-scale roots as origins."""
    rrd_views = loper[2]
    assert rrd_views
    import rerun.chunk as rc

    origins = []
    path = loper[4]
    reader = rc.RrdReader(str(path))
    for entry in reader.blueprints():
        for chunk in reader.store(store=entry).stream():
            batch = chunk.to_record_batch()
            for name in batch.schema.names:
                if name.endswith("origin"):
                    origins += [str(v[0] if isinstance(v, list) else v) for v in batch.column(name).to_pylist() if v]
    for o in ("/closedloop/deformed", "/closedloop/true_scale", "/servo_loop_alone/deformed", "/servo_loop_alone/true_scale", "/about"):
        assert o in origins, (o, origins)


def test_a_run_with_its_own_model_and_a_run_without_frames(tmp_path):
    """A run may bring its own model (a simulator with a body on a compliant mount at the beam's end:
    one more joint, a slide, magnified like the beam), and a run of measured data has signals but no 3D."""
    from samii.sim.model import load_model, make_data
    from samii.timeseries import TimeSeries
    from samii.viz.recording import RunRecord, read_scalars, write_recording

    plain = load_model()
    body = load_model(overrides={"beam.tip_body_mass_kg": 0.5, "beam.tip_body_freq_hz": 15.0})
    assert body.nq == plain.nq + 1
    home = make_data(body)
    j = body.jnt_qposadr[body.joint("tip_body").id]
    t = np.arange(50) * 0.01
    q = np.tile(home.qpos, (t.size, 1))
    q[:, j] += 1e-4 * np.sin(2 * np.pi * 2 * t)  # the body alone moves, 0.1 mm
    zeros = np.zeros(t.size)
    ts = TimeSeries(t=t, v=zeros, theta=zeros, accel=zeros, r=zeros)
    rrd = tmp_path / "x.rrd"
    info = write_recording(
        rrd,
        plain,
        [RunRecord("data", ts, np.zeros(0), np.zeros((0, plain.nq))), RunRecord("sim", ts, t, q, model=body)],
        application_id="t",
        beam_scale=200.0,
    )
    assert info.runs == ("data", "sim")
    rec, names, _ = _read(rrd)
    assert not any(e.startswith("/data/deformed") or e.startswith("/data/true_scale") for e in rec)
    assert "/data/volts/r" in rec and "/sim/displacement_mm/mode_1" in rec  # modes of the first run with frames
    b = body.body("tip_body").id
    _, true = _column(rec["/sim/true_scale/tip_body"]["time"], "Transform3D:translation")
    _, shown = _column(rec["/sim/deformed/tip_body"]["time"], "Transform3D:translation")
    true = np.array([np.asarray(x, float).ravel() for x in true]) - home.xpos[b]
    shown = np.array([np.asarray(x, float).ravel() for x in shown]) - home.xpos[b]
    big = np.linalg.norm(true, axis=1) > 0.5e-4
    assert np.allclose(np.linalg.norm(shown[big], axis=1) / np.linalg.norm(true[big], axis=1), 200.0, rtol=1e-3)
    assert info.arm_scale == 200.0  # the arm does not move: the body's metres are not an arm joint's radians
    assert not any("data: beam" in n for n in names) and any("sim: beam ×200" in n for n in names)
    assert read_scalars(rrd, "/data/volts/r")["/data/volts/r"][0].size == t.size
