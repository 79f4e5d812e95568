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

Sample time. ``z = exp(s T)`` maps a pole faithfully only while ``T`` is well
below its period ``2 pi / |s|``: at half the period (Nyquist) complex poles
alias and the placed ``z`` no longer stands for the intended ``s``; well
before that the sampled controller reacts too late to its fastest dynamics.
:func:`design_placement` asks for at least :data:`MIN_SAMPLES_PER_PERIOD`
samples per period of the fastest pole the design involves (the plant's
open-loop poles, the desired poles and, with ``observer="placement"``, the
observer poles): :func:`max_sample_time_s`. Very short sample times crowd
every ``z`` at 1, where placement loses accuracy; the design checks the
poles it achieved (:data:`PLACEMENT_RTOL`) and raises
:class:`PlacementInaccurate` rather than return a controller with other poles.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Literal

import control
import numpy as np
from scipy import linalg
from scipy.optimize import linear_sum_assignment

from samii import notebook as nb
from samii.controller import NOTEBOOK_UNITS, LinearController, unstable_poles

__all__ = [
    "MIN_SAMPLES_PER_PERIOD",
    "PLACEMENT_RTOL",
    "PlacementInaccurate",
    "fastest_pole",
    "max_sample_time_s",
    "desired_poles",
    "unity_feedback_poles",
    "discretize",
    "place_continuous",
    "balance",
    "PlacementDesign",
    "design_placement",
]

ObserverKind = Literal["placement", "kalman"]

#: Samples per period ``2 pi/|s|`` of the fastest pole a design involves (5x Nyquist; the textbook rule
#: samples 10 to 30 times faster than the closed-loop bandwidth).
MIN_SAMPLES_PER_PERIOD = 10

#: Largest relative error ``|s_achieved - s_desired| / |s_desired|`` (``s = log(z)/T``) a design may have.
PLACEMENT_RTOL = 1e-4


class PlacementInaccurate(ValueError):
    """The placed poles are not where they were asked to be (numerically ill-conditioned design)."""

    def __init__(self, message: str, error: float):
        super().__init__(message)
        self.error = error


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
    if not 0 < zeta < 1:  # zeta = 1 makes each pair a double real pole, which one input cannot place
        raise ValueError(f"zeta must be in (0, 1), got {float(zeta):g}")
    out = []
    for p in unity_feedback_poles(sys, theta=theta):
        if abs(p.imag) <= real_tol * max(abs(p), 1.0):
            out.append(complex(p.real, 0.0))
        else:
            out.append(abs(p) * complex(-zeta, np.sign(p.imag) * np.sqrt(1 - zeta**2)))
    return np.array(out)


def fastest_pole(
    sys: control.StateSpace, *, zeta: float = nb.EQ8_3_ZETA, observer: ObserverKind = "placement", observer_factor: float = 2.0
) -> tuple[float, str]:
    """``(|s|, which)`` of the fastest pole a chapter-8 design on ``sys`` involves [rad/s].

    ``which`` is ``"plant"``, ``"controller"`` or ``"observer"``: the model's
    open-loop poles, the desired poles (:func:`desired_poles`, whose magnitudes
    do not depend on ``zeta``) and, for ``observer="placement"``, the
    observer poles at ``observer_factor`` times them. The Kalman filter's
    poles follow from the noise and the sample time, so they are not known
    beforehand.
    """
    sets = {"plant": np.linalg.eigvals(np.asarray(sys.A)), "controller": desired_poles(sys, zeta)}
    if observer == "placement":
        sets["observer"] = observer_factor * sets["controller"]
    which = max(sets, key=lambda k: float(np.max(np.abs(sets[k]))))
    return float(np.max(np.abs(sets[which]))), which


def max_sample_time_s(
    sys: control.StateSpace,
    *,
    zeta: float = nb.EQ8_3_ZETA,
    observer: ObserverKind = "placement",
    observer_factor: float = 2.0,
    samples_per_period: float = MIN_SAMPLES_PER_PERIOD,
) -> float:
    """The longest sample time with ``samples_per_period`` samples per period ``2 pi/|s|`` of :func:`fastest_pole`."""
    w, _ = fastest_pole(sys, zeta=zeta, observer=observer, observer_factor=observer_factor)
    return float(2.0 * np.pi / (samples_per_period * w))


def discretize(sys: control.StateSpace, sample_time_s: float) -> control.StateSpace:
    """Zero-order-hold discretisation (Matlab ``c2d(sys, T, 'zoh')``)."""
    if not (np.isfinite(sample_time_s) and sample_time_s > 0):
        raise ValueError(f"sample_time_s must be a positive number of seconds, got {float(sample_time_s):g}")
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


def _floor_digits(x: float, digits: int) -> float:
    """``x > 0`` rounded down to ``digits`` significant digits (a printed bound that itself satisfies the bound)."""
    q = 10.0 ** (np.floor(np.log10(x)) - digits + 1)
    return float(np.floor(x / q) * q)


def _check_placed(achieved_z: np.ndarray, desired_s: np.ndarray, T: float, what: str) -> None:
    """Raise :class:`PlacementInaccurate` if an achieved pole misses its target by more than :data:`PLACEMENT_RTOL`."""
    s = np.log(np.asarray(achieved_z, complex)) / T
    _, col = linear_sum_assignment(np.abs(desired_s[:, None] - s[None, :]))
    err = float(np.max(np.abs(s[col] - desired_s) / np.abs(desired_s)))
    if not err <= PLACEMENT_RTOL:
        raise PlacementInaccurate(
            f"the {what} poles came out {err:.2g} (relative) from their targets at sample time {T:g} s: every z = exp(s T) "
            f"crowds near 1 (or the targets nearly coincide) and placement loses its accuracy; use a longer sample time",
            err,
        )


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

    def _measured_C(self) -> np.ndarray:
        return np.asarray(self.discrete.C)[[_output_index(self.discrete, m) for m in self.measured]]

    @property
    def achieved_poles_z(self) -> np.ndarray:
        """Eigenvalues of ``Ad - Bd K``: the controller poles as designed, to rounding."""
        return np.linalg.eigvals(np.asarray(self.discrete.A) - np.asarray(self.discrete.B) @ self.K)

    @property
    def achieved_observer_poles_z(self) -> np.ndarray:
        """Eigenvalues of ``Ad - L Cm``: the observer (estimation error) poles."""
        return np.linalg.eigvals(np.asarray(self.discrete.A) - self.L @ self._measured_C())

    @property
    def closed_loop_poles_z(self) -> np.ndarray:
        """Every pole of the sampled loop (plant, observer, held command): controller, observer and ``z = 0``."""
        return np.concatenate([self.achieved_poles_z, self.achieved_observer_poles_z, [0.0]])

    @property
    def unstable_poles_z(self) -> np.ndarray:
        """Closed-loop poles on or outside the unit circle (empty for a usable design)."""

        return unstable_poles(self.closed_loop_poles_z, discrete=True)

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
    min_samples_per_period: float = MIN_SAMPLES_PER_PERIOD,
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
        (model units). The notebook prints none of its values; they must be
        given, and be positive (a zero covariance makes the filter singular or
        blind).
    balanced : bool
        Design on :func:`balance` of the model (same poles and transfer
        functions, well-scaled gains); the design's ``model`` is then the balanced one.
    min_samples_per_period : float
        ``sample_time_s`` may be at most :func:`max_sample_time_s` with this
        many samples per period of the fastest pole (at least 2, Nyquist).

    Raises
    ------
    ValueError
        For a bad argument, including a sample time above :func:`max_sample_time_s`.
    PlacementInaccurate
        If a placed pole misses its target by more than :data:`PLACEMENT_RTOL` (relative, in s).
    """
    if observer not in ("placement", "kalman"):
        raise ValueError(f"observer must be 'placement' or 'kalman', got {observer!r}")
    if not (np.isfinite(observer_factor) and observer_factor > 0):
        raise ValueError(f"observer_factor must be positive, got {float(observer_factor):g}")
    if not min_samples_per_period >= 2:
        raise ValueError(f"min_samples_per_period must be >= 2 (Nyquist), got {float(min_samples_per_period):g}")
    if observer == "kalman":
        if input_noise_std is None or measurement_noise_std is None or len(measurement_noise_std) != len(measured):
            raise ValueError("a Kalman observer needs input_noise_std and one measurement_noise_std per measured output")
        for name, v in [("input_noise_std", input_noise_std)] + [(f"measurement_noise_std[{i}]", x) for i, x in enumerate(measurement_noise_std)]:
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"Kalman {name} must be a positive standard deviation, got {float(v):g}")
    if not (np.isfinite(sample_time_s) and sample_time_s > 0):
        raise ValueError(f"sample_time_s must be a positive number of seconds, got {float(sample_time_s):g}")
    desired_poles(model, zeta)  # checks zeta
    w, which = fastest_pole(model, zeta=zeta, observer=observer, observer_factor=observer_factor)
    t_max = 2.0 * np.pi / (min_samples_per_period * w)
    if sample_time_s > t_max:
        raise ValueError(
            f"sample_time_s {sample_time_s:g} s is too long: the fastest {which} pole (|s| = {w:.4g} rad/s, period "
            f"2 pi/|s| = {2e3 * np.pi / w:.3g} ms) needs at least {min_samples_per_period:g} samples per period, "
            f"i.e. a sample time <= {_floor_digits(t_max * 1e3, 4):g} ms"
        )
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
    _check_placed(np.linalg.eigvals(Ad - Bd @ K), p_s, T, "controller")
    if observer == "placement":
        po_s = observer_factor * p_s
        po_z = np.exp(po_s * T)
        L = _place(Ad.T, Cm.T, po_z).T
        _check_placed(np.linalg.eigvals(Ad - L @ Cm), po_s, T, "observer")
        cov = None
    else:
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
