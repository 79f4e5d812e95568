"""Base modes as coordinates: a run's joint positions projected onto the beam's mode shapes.

The base modes (``samii modes``) are those of the structure with joint 2 held. Here they are the
undamped modes of that structure linearised at the ``home`` keyframe: mass matrix ``M`` from
``mj_fullM``, stiffness ``K`` the derivative of the generalised force in the positions at rest
(``mjd_inverseFD``; symmetric to 1e-10), joint 2's row and column removed (held), shapes from
the generalised symmetric eigenproblem ``K phi = w^2 M phi`` normalised so that
``phi^T M phi = I``, whence ``eta = phi^T M dq``.
A configuration's deviation from ``home`` (joint 2 left out) is written in those shapes,
``dq = sum_k phi_k eta_k``; the recording shows each mode's share of the tip's displacement along
the accelerometer's axis, ``c phi_k eta_k`` [m] (``c`` the site's Jacobian along that axis), so
the modes' shares add up to the tip's (linearised) displacement.

Undamped shapes of a lightly damped structure are a close approximation: their frequencies
(1.73, 9.85, 23.8 Hz on the embedded model) are within 5 % of the damped base modes (1.74,
9.86, 24.9 Hz; the clamp's Maxwell element stiffens mode 3 at its frequency), and positions
alone fix the coordinates (a recording keeps positions, not velocities).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import scipy.linalg

from samii.sim.model import JOINT, make_data
from samii.sim.sensors import accel_axis_world, accel_site

__all__ = ["ModalProjection", "modal_projection"]


@dataclass(frozen=True)
class ModalProjection:
    """Tip displacement per base mode from joint positions: ``tip_m = (qpos - home) @ weights.T``."""

    freq_hz: np.ndarray  #: (k,) undamped frequencies of the base modes kept [Hz]
    weights: np.ndarray  #: (k, nq) row k: mode k's share of the tip displacement per qpos deviation [m/rad]
    tip: np.ndarray  #: (nq,) the tip's linearised displacement per qpos deviation [m/rad]
    home_qpos: np.ndarray  #: (nq,)

    def shares_m(self, qpos: np.ndarray) -> np.ndarray:
        """(frames, k) each mode's share of the tip's displacement [m] at joint positions ``qpos`` (frames, nq)."""
        return (np.atleast_2d(qpos) - self.home_qpos) @ self.weights.T

    def tip_m(self, qpos: np.ndarray) -> np.ndarray:
        """(frames,) the tip's linearised displacement [m] along the accelerometer's axis."""
        return (np.atleast_2d(qpos) - self.home_qpos) @ self.tip


def modal_projection(model: mujoco.MjModel, *, n_modes: int = 3) -> ModalProjection:
    """The first ``n_modes`` base modes of ``model`` (joint 2 held) as coordinates (see module doc).

    Needs hinge/slide joints only (``nq == nv``), as SAMII's model has.
    """

    if model.nq != model.nv:
        raise ValueError(f"modal coordinates need hinge or slide joints only (nq = {model.nq}, nv = {model.nv})")
    data = make_data(model)
    nv = model.nv
    M = np.zeros((nv, nv))
    mujoco.mj_fullM(model, data, M)
    # K = d(generalised force)/dq at rest: MuJoCo's inverse-dynamics derivative (qacc = 0; DfDq is stored transposed)
    rest = make_data(model)
    rest.qacc[:] = 0.0
    dfdq = np.zeros((nv, nv))
    mujoco.mjd_inverseFD(model, rest, 1e-6, 1, dfdq, None, None, None, None, None, None)
    K = dfdq.T
    j2 = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, JOINT)
    keep = np.array([i for i in range(nv) if j2 < 0 or i != model.jnt_dofadr[j2]])
    Kh = K[np.ix_(keep, keep)]
    Mh = M[np.ix_(keep, keep)]
    w2, phi = scipy.linalg.eigh(0.5 * (Kh + Kh.T), 0.5 * (Mh + Mh.T))  # ascending; M-orthonormal shapes: phi.T M phi = I
    modes = np.flatnonzero(w2 > 0)[:n_modes]
    psi = phi[:, modes].T @ Mh  # modal coordinates of a deviation: eta = phi.T M dq

    site = accel_site(model)
    jac = np.zeros((3, nv))
    mujoco.mj_jacSite(model, data, jac, None, site)
    c = accel_axis_world(model, data) @ jac
    tip = np.zeros(model.nq)
    tip[keep] = c[keep]
    weights = np.zeros((len(modes), model.nq))
    weights[:, keep] = (c[keep] @ phi[:, modes])[:, None] * psi
    return ModalProjection(np.sqrt(w2[modes]) / (2 * np.pi), weights, tip, data.qpos.copy())
