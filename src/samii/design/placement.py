"""Digital pole placement with an observer (notebook chapter 8).

Steps, as the notebook's ``digital_ss_11_05_03.m`` / ``clpolelocs.m``:

1. desired poles (:func:`desired_poles`): the eigenvalues of the model under
   unity theta feedback (``v = theta_ref - theta``); real poles kept; each
   complex pole moved to the requested damping ratio at the same magnitude
   (eq 8.2 -> eq 8.3 with zeta = 1/sqrt(2), :data:`samii.notebook.EQ8_3_ZETA`:
   the notebook does not print its damping ratio; 1/sqrt(2) reproduces every
   printed digit of eq 8.3, 0.707 does not, see ``samii design seed-report``);
2. the model is discretised by zero-order hold at the sample time (Matlab's
   ``c2d(..., 'zoh')``; here :func:`control.sample_system`);
3. state feedback by pole placement on the discrete model at ``z = exp(s T)``;
4. observer poles at twice the controller poles in the continuous domain,
   mapped by ``z = exp(2 s T)``; or a steady-state Kalman filter
   (:func:`control.dlqe`) with stated noise covariances.

Measurement timing. A sampled controller measures at ``t_k`` and then
applies ``v[k]``; just before ``t_k`` the plant still receives ``v[k-1]``, so a
model output with direct feedthrough (``xdd/v`` of the s^4 model is biproper)
reads ``y[k] = C x[k] + D v[k-1]``. The observer uses exactly that (it
remembers its last command), so the closed loop's eigenvalues are the
controller poles, the observer poles and one at ``z = 0`` (the held command),
whatever ``D`` is.

Reference: ``v = N theta_ref - K x_hat`` with ``N`` giving theta/theta_ref a
DC gain of 1.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Literal

import control
import numpy as np
from scipy import linalg

from samii import notebook as nb
from samii.design.controller import NOTEBOOK_UNITS, LinearController

__all__ = [
    "desired_poles",
    "unity_feedback_poles",
    "discretize",
    "place_continuous",
    "balance",
    "PlacementDesign",
    "design_placement",
]

ObserverKind = Literal["placement", "kalman"]


def _output_index(sys: control.StateSpace, name: str) -> int:
    names = list(sys.output_labels)
    if name not in names:
        raise ValueError(f"the model has no output {name!r}; its outputs are {names}")
    return names.index(name)


def unity_feedback_poles(sys: control.StateSpace, *, theta: str = "theta") -> np.ndarray:
    """Eigenvalues of the model with ``v = theta_ref - theta`` (eq 8.2 for the eq 1.4 model)."""
    i = _output_index(sys, theta)
    C, D = np.asarray(sys.C)[i : i + 1], np.asarray(sys.D)[i, 0]
    if D != 0:
        raise ValueError("theta/v must be strictly proper for unity theta feedback")
    return np.linalg.eigvals(np.asarray(sys.A) - np.asarray(sys.B) @ C)


def desired_poles(sys: control.StateSpace, zeta: float, *, theta: str = "theta", real_tol: float = 1e-9) -> np.ndarray:
    """The notebook's desired-pole rule (``clpolelocs.m``): eq 8.3 from eq 8.2 with ``zeta = 1/sqrt(2)``.

    Each complex pole ``p`` of the unity-theta-feedback loop becomes
    ``|p| (-zeta +- j sqrt(1 - zeta^2))``; real poles are kept.
    """
    if not 0 < zeta < 1:
        raise ValueError(f"zeta must be in (0, 1), got {zeta}")
    out = []
    for p in unity_feedback_poles(sys, theta=theta):
        if abs(p.imag) <= real_tol * max(abs(p), 1.0):
            out.append(complex(p.real, 0.0))
        else:
            out.append(abs(p) * complex(-zeta, np.sign(p.imag) * np.sqrt(1 - zeta**2)))
    return np.array(out)


def discretize(sys: control.StateSpace, sample_time_s: float) -> control.StateSpace:
    """Zero-order-hold discretisation (Matlab ``c2d(sys, T, 'zoh')``)."""
    if not sample_time_s > 0:
        raise ValueError(f"sample_time_s must be positive, got {sample_time_s}")
    return control.sample_system(sys, sample_time_s, method="zoh")


def balance(sys: control.StateSpace) -> control.StateSpace:
    """Diagonal similarity transform that balances ``A`` (LAPACK ``gebal``, no permutation).

    The canonical forms have coefficients spanning ten orders of magnitude;
    balancing leaves every transfer function and eigenvalue unchanged and
    makes the gains of a design on the model well scaled.
    """
    _, (scale, _) = linalg.matrix_balance(np.asarray(sys.A), permute=False, separate=True)
    T, Ti = np.diag(scale), np.diag(1.0 / scale)
    A, B, C = Ti @ np.asarray(sys.A) @ T, Ti @ np.asarray(sys.B), np.asarray(sys.C) @ T
    return control.ss(A, B, C, sys.D, sys.dt, inputs=list(sys.input_labels), outputs=list(sys.output_labels))


def _place(A: np.ndarray, B: np.ndarray, poles: np.ndarray) -> np.ndarray:
    # scipy's YT iteration maximises robustness after placing the poles exactly; for several
    # inputs it may stop before converging, which it reports as a warning. Accuracy is checked
    # by the tests (eigenvalues of the closed loop), not by that iteration.
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Convergence was not reached")
        return np.asarray(control.place(A, B, poles))


def place_continuous(sys: control.StateSpace, poles: np.ndarray) -> np.ndarray:
    """Continuous-time state feedback ``v = -K x`` with ``eig(A - B K) = poles`` (python-control :func:`control.place`)."""
    return _place(np.asarray(sys.A), np.asarray(sys.B), poles)


@dataclass(frozen=True)
class PlacementDesign:
    """A digital state-feedback controller with observer, designed on ``model``.

    Attributes
    ----------
    model : control.StateSpace
        Continuous model, input ``v`` [V], outputs including ``theta``; its units are the design's.
    discrete : control.StateSpace
        ZOH discretisation at ``sample_time_s``.
    poles_s, observer_poles_s : ndarray
        Controller and (for ``observer="placement"``) observer poles in s [1/s].
    poles_z, observer_poles_z : ndarray
        Their discrete images (for the Kalman filter: the filter's own poles).
    K : ndarray (1, n)
        State feedback gain, ``v = N theta_ref - K x_hat``.
    L : ndarray (n, n_measured)
        Observer (prediction-estimator) gain.
    N : float
        Reference gain for a unit DC gain of theta/theta_ref.
    measured : tuple of str
        Model outputs the observer reads.
    """

    model: control.StateSpace
    discrete: control.StateSpace
    sample_time_s: float
    zeta: float
    poles_s: np.ndarray
    poles_z: np.ndarray
    observer: ObserverKind
    observer_poles_s: np.ndarray | None
    observer_poles_z: np.ndarray
    K: np.ndarray
    L: np.ndarray
    N: float
    measured: tuple[str, ...]
    kalman_covariances: tuple[float, tuple[float, ...]] | None

    def controller(self, *, input_scale: dict[str, float] | None = None, model_units: str = NOTEBOOK_UNITS) -> LinearController:
        """The runnable controller: inputs ``theta_ref``, then the measured outputs (``theta``, ``accel``).

        ``input_scale`` converts the caller's signals to the model's units
        (e.g. ``{"theta": 180/pi, "theta_ref": 180/pi}`` for a model in degrees).
        """
        Ad, Bd = np.asarray(self.discrete.A), np.asarray(self.discrete.B)
        idx = [_output_index(self.discrete, m) for m in self.measured]
        Cm, Dm = np.asarray(self.discrete.C)[idx], np.asarray(self.discrete.D)[idx]
        K, L, N = self.K, self.L, self.N
        n, m = Ad.shape[0], len(idx)
        # state z = [x_hat; v_prev], input w = [theta_ref, y_1..y_m]
        A = np.zeros((n + 1, n + 1))
        A[:n, :n] = Ad - L @ Cm - Bd @ K
        A[:n, n:] = -L @ Dm
        A[n:, :n] = -K
        B = np.zeros((n + 1, 1 + m))
        B[:n, :1] = Bd * N
        B[:n, 1:] = L
        B[n, 0] = N
        C = np.concatenate([-K, [[0.0]]], axis=1)
        D = np.zeros((1, 1 + m))
        D[0, 0] = N
        inputs = ("theta_ref",) + tuple("accel" if s == "xdd" else s for s in self.measured)
        obs = "poles at 2x the controller's (continuous), z = exp(2 s T)" if self.observer == "placement" else "steady-state Kalman filter (dlqe)"
        return LinearController(
            A, B, C, D,
            sample_time_s=self.sample_time_s,
            inputs=inputs,
            input_scale=input_scale,
            name=f"pole placement (zeta {self.zeta:g}) with observer: {obs}",
            method="plant discretised by zero-order hold; placement and observer on the discrete model",
            model_units=model_units,
        )  # fmt: skip


def design_placement(
    model: control.StateSpace,
    *,
    sample_time_s: float,
    zeta: float = nb.EQ8_3_ZETA,
    observer: ObserverKind = "placement",
    observer_factor: float = 2.0,
    measured: tuple[str, ...] = ("theta", "xdd"),
    input_noise_std: float | None = None,
    measurement_noise_std: tuple[float, ...] | None = None,
    balanced: bool = True,
) -> PlacementDesign:
    """Design the chapter-8 controller on ``model`` (e.g. :func:`samii.design.canonical.numeric_statespace`).

    Parameters
    ----------
    zeta : float
        Damping of the desired complex poles; default 1/sqrt(2), the value
        that reproduces eq 8.3 (:data:`samii.notebook.EQ8_3_ZETA`).
    observer : {"placement", "kalman"}
        Observer poles at ``observer_factor`` times the controller poles, or a Kalman filter.
    input_noise_std, measurement_noise_std
        Kalman filter only: process noise entering with the valve command
        (standard deviation per sample, V) and noise on each measured output
        (model units). The notebook prints none of its values; they must be given.
    balanced : bool
        Design on :func:`balance` of the model (same poles and transfer
        functions, well-scaled gains); the design's ``model`` is then the balanced one.
    """
    if observer not in ("placement", "kalman"):
        raise ValueError(f"observer must be 'placement' or 'kalman', got {observer!r}")
    if balanced:
        model = balance(model)
    dsys = discretize(model, sample_time_s)
    T = sample_time_s
    p_s = desired_poles(model, zeta)
    p_z = np.exp(p_s * T)
    Ad, Bd = np.asarray(dsys.A), np.asarray(dsys.B)
    K = _place(Ad, Bd, p_z)
    idx = [_output_index(dsys, m) for m in measured]
    Cm = np.asarray(dsys.C)[idx]
    if observer == "placement":
        po_s = observer_factor * p_s
        po_z = np.exp(po_s * T)
        L = _place(Ad.T, Cm.T, po_z).T
        cov = None
    else:
        if input_noise_std is None or measurement_noise_std is None or len(measurement_noise_std) != len(measured):
            raise ValueError("a Kalman observer needs input_noise_std and one measurement_noise_std per measured output")
        QN = np.array([[input_noise_std**2]])
        RN = np.diag(np.asarray(measurement_noise_std, float) ** 2)
        # dlqe gives L for x_e[n+1] = A x_e + B u + L (y - C x_e - D u): a prediction estimator, as used here
        L, _, po_z = control.dlqe(Ad, Bd, Cm, QN, RN)
        L, po_s = np.asarray(L), None
        cov = (float(input_noise_std), tuple(float(x) for x in measurement_noise_std))
    # reference gain: theta/theta_ref = 1 at DC (z = 1) under v = N r - K x
    i = _output_index(dsys, "theta")
    Ct = np.asarray(dsys.C)[i : i + 1]
    dc = (Ct @ np.linalg.solve(np.eye(len(Ad)) - Ad + Bd @ K, Bd)).item()
    return PlacementDesign(
        model=model,
        discrete=dsys,
        sample_time_s=T,
        zeta=zeta,
        poles_s=p_s,
        poles_z=p_z,
        observer=observer,
        observer_poles_s=po_s,
        observer_poles_z=np.asarray(po_z),
        K=K,
        L=L,
        N=1.0 / dc,
        measured=tuple(measured),
        kalman_covariances=cov,
    )
