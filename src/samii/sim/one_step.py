"""The simulator's one-step map about a state, from MuJoCo's finite-difference transition derivatives.

``mjd_transitionFD`` gives ``x[k+1] = A x[k] + B u[k]`` and ``y[k] = C x[k] + D u[k]`` with x = (dqpos, qvel, act) and
u = ctrl, the hydraulic plugin's states included, on the model with an ideal valve (:func:`small_signal`: a valve's dead
band or saturation has no small-signal derivative). Its eigenvalues say whether a compiled model's step resolves its
modes (:mod:`samii.sim.model`); :mod:`samii.sim.linearize` builds the linear models on it.
"""

from __future__ import annotations

import mujoco
import numpy as np

from samii.sim.plugin import ideal_valve_model

__all__ = ["small_signal", "transition", "one_step_poles"]


def small_signal(model: mujoco.MjModel, data: mujoco.MjData) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """The model with an ideal valve (``plugin.ideal_valve_model``) and a copy of ``data``'s state
    on it; ``(model, data)`` themselves when the valve is ideal already."""

    ideal = ideal_valve_model(model) if model.nplugin else model
    if ideal is model:
        return model, data
    out = mujoco.MjData(ideal)
    # the whole state, the plugin's included (a controller card switched off stays off); the copy
    # keeps the compiled plugin_state size, and the card's block comes first in both
    spec = int(mujoco.mjtState.mjSTATE_FULLPHYSICS) | int(mujoco.mjtState.mjSTATE_USER) | int(mujoco.mjtState.mjSTATE_WARMSTART)
    state = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, state, spec)
    mujoco.mj_setState(ideal, out, state, spec)
    mujoco.mj_forward(ideal, out)
    return ideal, out


def transition(model: mujoco.MjModel, data: mujoco.MjData, eps: float, with_sensors: bool):
    """``(A, B, C, D)`` of the one-step map about ``data`` (``C``, ``D`` None without sensors), valve ideal."""
    model, data = small_signal(model, data)
    nx = 2 * model.nv + model.na
    A = np.zeros((nx, nx))
    B = np.zeros((nx, model.nu))
    C = np.zeros((model.nsensordata, nx)) if with_sensors else None
    D = np.zeros((model.nsensordata, model.nu)) if with_sensors else None
    mujoco.mjd_transitionFD(model, data, eps, True, A, B, C, D)
    return A, B, C, D


def one_step_poles(model: mujoco.MjModel, data: mujoco.MjData, *, eps: float = 1e-6) -> np.ndarray:
    """Eigenvalues z of the one-step map about ``data``: the simulator is stable there when every ``|z| <= 1``."""
    A, _, _, _ = transition(model, data, eps, False)
    return np.linalg.eigvals(A)
