"""Cost of a simulation step with the samii.hydraulic plugin against a plain MuJoCo actuator.

Usage::

    python benchmarks/step_cost.py [--model samii|inertia] [--steps 5000] [--repeats 7]

The same model is compiled twice from one MjSpec: as is (joint 2 driven by the hydraulic plugin,
two extra states in ``mjData.act``) and with that actuator replaced by a plain ``<position>``
actuator on joint 2 (kp = the closed-valve oil-column stiffness 4 beta Dm^2/Vt, critically
damped). Both run from the ``home`` keyframe (the plain-inertia model: from rest at the reference
angle) with zero valve command (the position actuator: its set point), in one process,
alternating, after a warm-up. Two loops are timed:

* ``rollout``: ``mujoco.rollout`` (the step loop in C++, one thread): the cost of ``mj_step``;
* ``python``: ``mj_step`` called from a Python loop, as ``samii`` steps when it needs ctrl per step.

Printed: microseconds per step (median over repeats), the ratio plugin/plain, and the real-time
factor timestep/(wall time per step). Goals (issue 2): ratio <= 1.2, >= 100x real time.
"""

from __future__ import annotations

import argparse
import statistics
import time

import mujoco
import numpy as np
from mujoco import rollout

from samii.sim import plugin

JOINT = ACTUATOR = "joint2"


def hydraulic_spec(source: str) -> mujoco.MjSpec:
    """The MjSpec with the hydraulic actuator: SAMII's default model or the plain-inertia probe."""
    plugin.load_plugin()
    if source == "samii":
        from samii.sim.model import load_spec

        spec, _ = load_spec()
        return spec
    return mujoco.MjSpec.from_string(plugin.probe_xml(timestep=1e-3))


def with_position_actuator(spec: mujoco.MjSpec) -> mujoco.MjSpec:
    """Copy of ``spec`` with the hydraulic actuator replaced by a plain position actuator."""
    params = plugin.spec_hydraulic_params(spec)[ACTUATOR]
    plain = spec.copy()
    plain.delete(plain.actuator(ACTUATOR))
    for instance in list(plain.plugins):
        plain.delete(instance)
    position = plain.add_actuator(name=ACTUATOR, target=JOINT, trntype=mujoco.mjtTrn.mjTRN_JOINT)
    position.set_to_position(kp=params.hydraulic_stiffness, dampratio=1.0)
    for key in plain.keys:
        key.act = np.zeros(0)
        key.ctrl = np.array([params.reference_angle])
    return plain


def initial_state(model: mujoco.MjModel, ctrl: float, theta0: float) -> tuple[mujoco.MjData, np.ndarray]:
    """Data and full physics state at the ``home`` keyframe, or joint 2 at ``theta0`` without one."""
    data = mujoco.MjData(model)
    if model.nkey:
        mujoco.mj_resetDataKeyframe(model, data, 0)
    else:
        data.qpos[model.jnt_qposadr[model.joint(JOINT).id]] = theta0
    data.ctrl[:] = ctrl
    mujoco.mj_forward(model, data)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, state, spec)
    return data, state


def time_rollout(model, data, state, ctrl, nstep) -> float:
    control = np.full((1, nstep, model.nu), ctrl)
    start = time.perf_counter()
    rollout.rollout(model, data, state[None], control)
    return (time.perf_counter() - start) / nstep


def time_python(model, data, state, ctrl, nstep) -> float:
    mujoco.mj_setState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    step = mujoco.mj_step
    start = time.perf_counter()
    for _ in range(nstep):
        data.ctrl[0] = ctrl
        step(model, data)
    return (time.perf_counter() - start) / nstep


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", choices=("samii", "inertia"), default="samii")
    parser.add_argument("--steps", type=int, default=5000, help="steps per timed run")
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)

    spec = hydraulic_spec(args.model)
    hydraulic = plugin.compile_spec(spec)
    plain = with_position_actuator(spec).compile()
    reference = plugin.spec_hydraulic_params(spec)[ACTUATOR].reference_angle
    cases = {
        "plugin": (hydraulic, *initial_state(hydraulic, 0.0, reference), 0.0),
        "plain": (plain, *initial_state(plain, reference, reference), reference),
    }
    results = {}
    for loop, timer in (("rollout", time_rollout), ("python", time_python)):
        samples = {name: [] for name in cases}
        for repeat in range(args.repeats + 1):  # first round: warm-up, discarded
            for name, (model, data, state, ctrl) in cases.items():
                t = timer(model, data, state, ctrl, args.steps)
                if repeat:
                    samples[name].append(t)
        results[loop] = {name: statistics.median(s) for name, s in samples.items()}

    dt = hydraulic.opt.timestep
    print(
        f"model: {args.model} (nq {hydraulic.nq}, nv {hydraulic.nv}, na {hydraulic.na}), timestep {dt * 1e3:g} ms, "
        f"{args.steps} steps x {args.repeats} repeats, median"
    )
    print(f"{'loop':<8} {'plugin us/step':>15} {'plain us/step':>14} {'ratio':>6} {'plugin x real time':>19}")
    for loop, r in results.items():
        ratio = r["plugin"] / r["plain"]
        print(f"{loop:<8} {r['plugin'] * 1e6:15.2f} {r['plain'] * 1e6:14.2f} {ratio:6.3f} {dt / r['plugin']:19.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
