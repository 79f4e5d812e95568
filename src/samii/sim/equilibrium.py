"""Static equilibrium of SAMII under gravity: beam sag, held joints, hydraulic holding pressure."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.optimize import least_squares

__all__ = ["Equilibrium", "static_equilibrium"]


@dataclass(frozen=True)
class Equilibrium:
    qpos: np.ndarray
    act: np.ndarray
    #: max |qacc| [rad/s²] and max |act_dot| [1/s] left at the solution
    residual_qacc: float
    residual_act_dot: float


def static_equilibrium(model: mujoco.MjModel, *, qpos0: np.ndarray | None = None, act0: np.ndarray | None = None, tol: float = 1e-12) -> Equilibrium:
    """Solve qacc = 0 and act_dot = 0 at zero velocity and zero ctrl.

    Starts from the ``home`` keyframe (or the given guess). Unknowns are all
    joint positions and activations; the hinge-only model has nq = nv. Where a
    direction is free (joint 2 with the position loop open, an integrator),
    the least-squares step leaves it at the starting value.
    """
    if model.nq != model.nv:
        raise ValueError(f"static_equilibrium expects a hinge/slide-only model (nq == nv), got nq={model.nq}, nv={model.nv}")
    data = mujoco.MjData(model)
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "home")
    if key >= 0:
        mujoco.mj_resetDataKeyframe(model, data, key)
    x0 = np.concatenate([data.qpos if qpos0 is None else qpos0, data.act if act0 is None else act0])
    nq = model.nq

    def residual(x: np.ndarray) -> np.ndarray:
        data.qpos[:] = x[:nq]
        data.act[:] = x[nq:]
        data.qvel[:] = 0.0
        data.ctrl[:] = 0.0
        mujoco.mj_forward(model, data)
        return np.concatenate([data.qacc, data.act_dot])

    sol = least_squares(residual, x0, xtol=tol, ftol=tol, gtol=tol, method="lm" if x0.size <= 2 * model.nv + 10 else "trf", x_scale="jac")
    r = residual(sol.x)
    qacc_res = float(np.max(np.abs(r[: model.nv]))) if model.nv else 0.0
    act_res = float(np.max(np.abs(r[model.nv :]))) if model.na else 0.0
    if not np.all(np.isfinite(sol.x)) or qacc_res > 1e-6:
        raise RuntimeError(f"static equilibrium not found: max |qacc| = {qacc_res:.3g} rad/s² after {sol.nfev} evaluations ({sol.message})")
    return Equilibrium(qpos=sol.x[:nq].copy(), act=sol.x[nq:].copy(), residual_qacc=qacc_res, residual_act_dot=act_res)
