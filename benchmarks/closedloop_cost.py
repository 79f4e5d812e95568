"""Cost of a closed loop with a 1 kHz controller against open-loop stepping of the same model and length.

Usage::

    python benchmarks/closedloop_cost.py [--seconds 60] [--repeats 5]

Times, in one process after a warm-up (median over repeats), for ``--seconds`` of simulated time:

* ``open loop``: one ``mujoco.rollout`` of the embedded model (the servo amplifier alone) with a
  zero excitation from the ``home`` keyframe: plain ``mj_step`` (the baseline);
* ``card, servo only``: the closed-loop model (reference and noise inputs, no controller) through
  :func:`samii.closedloop.run.run_loop`: what the runner adds (four input columns, its signals);
* ``card, cancel``: the chapter-10 compensator (6 states) at 1 kHz inside the plugin, a 5 deg step;
* ``card, 16 / 64 states``: controllers of 16 and 64 states (the card's limit) with negligible
  gains, to show how the card's cost grows with the controller's size;
* ``python loop``: the same compensator called from Python once per step around ``mj_step``
  (``LinearController.step``): what running the controller outside the simulation costs.

Printed: wall times, ratios to the open loop, and real-time factors. Goal (issue 10): a 1 kHz
controller within 1.3x of open-loop stepping (so >= 100x real time on one core).
"""

from __future__ import annotations

import argparse
import math

import mujoco
import numpy as np
from _timing import median_time, plain_rollout

from samii.closedloop.card import build_card_model
from samii.closedloop.controllers import notebook_cancel
from samii.closedloop.run import run_loop
from samii.sim.model import load_model, load_spec, make_data


def _median_time(fn, repeats: int) -> float:
    return median_time(fn, repeats, warm_up=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated time per run (default 60 s)")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()

    model = load_model()
    qpos, act = model.key_qpos[0].copy(), model.key_act[0].copy()
    dt = float(model.opt.timestep)
    n = int(round(args.seconds / dt))
    open_loop = plain_rollout(model, make_data(model), n)

    theta_ref = np.zeros(n)
    theta_ref[int(1.0 / dt) :] = math.radians(5.0)

    def card(controller, replaces):
        spec, _ = load_spec()
        return build_card_model(spec, controller, replaces_servo=replaces, home_qpos=qpos, home_act=act)

    cm_servo = card(None, False)
    cancel = notebook_cancel()
    cm_cancel = card(cancel.controller, True)

    times = {
        "open loop (mj_step)": _median_time(open_loop, args.repeats),
        "card, servo only": _median_time(lambda: run_loop(cm_servo, theta_ref), args.repeats),
        "card, cancel (6 states, 1 kHz)": _median_time(lambda: run_loop(cm_cancel, theta_ref), args.repeats),
    }

    # larger controllers: the card's cost grows with the states (n^2 per step); gains tiny so the response is the servo loop's
    from samii.controller import LinearController

    rng = np.random.default_rng(0)
    for ns in (16, 64):
        Q = np.linalg.qr(rng.normal(size=(ns, ns)))[0]
        big = LinearController(0.9 * Q, 1e-9 * rng.normal(size=(ns, 3)), 1e-9 * rng.normal(size=(1, ns)), np.zeros((1, 3)),
                               sample_time_s=dt, inputs=("theta_ref", "theta", "accel"))  # fmt: skip
        cm_big = card(big, False)
        times[f"card, {ns} states (1 kHz)"] = _median_time(lambda: run_loop(cm_big, theta_ref), args.repeats)  # noqa: B023 - called within this iteration

    # the Python loop, on a tenth of the run (scaled)
    m_py = load_model(overrides={"hydraulic.position_gain": 0.0})
    m_py.key_qpos[0], m_py.key_act[0] = qpos, act
    from samii.sim.sensors import accel_offset, accel_weights

    adr, w = accel_weights(m_py)
    off = accel_offset(m_py)
    th_adr = int(m_py.sensor_adr[mujoco.mj_name2id(m_py, mujoco.mjtObj.mjOBJ_SENSOR, "theta")])
    c = cancel.controller
    n_py = n // 10

    def python_loop():
        d = make_data(m_py)
        c.reset()
        for k in range(n_py):
            mujoco.mj_forward(m_py, d)
            d.ctrl[0] = c.step({"theta_ref": theta_ref[k], "theta": d.sensordata[th_adr] - math.pi / 2,
                                "accel": float(d.sensordata[adr:adr + 3] @ w) - off})  # fmt: skip
            mujoco.mj_step(m_py, d)

    times["python loop, cancel (scaled from 1/10)"] = _median_time(python_loop, max(1, args.repeats // 2)) * 10

    base = times["open loop (mj_step)"]
    print(f"{args.seconds:g} s simulated at {1 / dt:g} Hz physics, {n} steps; median of {args.repeats}")
    for name, t in times.items():
        print(f"  {name:42s} {t:8.3f} s   {t / base:5.2f} x open loop   {args.seconds / t:7.0f} x real time")
    ratio = times["card, cancel (6 states, 1 kHz)"] / base
    print(f"goal: a 1 kHz controller within 1.3 x open-loop stepping: {ratio:.2f} x ({'met' if ratio <= 1.3 else 'NOT met'})")


if __name__ == "__main__":
    main()
