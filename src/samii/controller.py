"""Runnable discrete-time controllers: one small interface for the simulator, the tests and the CLI.

A controller is called once per sample: it reads the measurements taken at
``t_k`` and returns the valve command ``v[k]`` [V], which the caller holds
(zero-order hold) until ``t_{k+1}``. Measurement names are those of
DATA_FORMATS.md: ``theta`` [rad, relative to the nominal pose], ``accel``
[m/s²] and ``theta_ref`` [rad] when a reference is used.

Every implementation here is a :class:`LinearController`: a discrete-time
state-space system, discretised explicitly by its designer (the method is
stored in ``method``), evaluated with plain numpy (two matrix-vector
products per step). Designs made on the notebook's own models carry the
notebook's units (theta in degrees, acceleration in ft/s²: samii.closedloop.controllers); the
``input_scale`` converts the caller's SI signals to them, and ``model_units``
says which they are.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal, Protocol, runtime_checkable

import numpy as np

__all__ = [
    "NOTEBOOK_UNITS",
    "Controller",
    "LinearController",
    "unity_theta_controller",
    "mass_damping_controller",
    "from_discrete_tf",
    "from_discrete_zpk",
    "unstable_poles",
]

MEASUREMENTS = ("theta_ref", "theta", "accel")

#: What a design on one of the notebook's fits works in (notebook.py: units not stated in the notebook).
NOTEBOOK_UNITS = "notebook units: theta in degrees, acceleration in ft/s² (samii.closedloop.controllers); v in volts"


def unstable_poles(poles, *, discrete: bool) -> np.ndarray:
    """The poles that are not asymptotically stable: ``Re s >= 0`` (continuous) or ``|z| >= 1`` (discrete).

    A pole on the boundary (an undamped oscillation, an integrator) counts: a
    loop that never settles is not a usable design. Non-finite poles (a root
    at infinity) count too.
    """
    p = np.atleast_1d(np.asarray(poles, complex))
    bad = ~np.isfinite(p) | ((np.abs(p) >= 1.0) if discrete else (p.real >= 0.0))
    return p[bad]


@runtime_checkable
class Controller(Protocol):
    """What the closed-loop simulator needs from a controller."""

    sample_time_s: float
    inputs: tuple[str, ...]

    def reset(self) -> None:
        """Return to the initial (zero) state."""

    def step(self, measurements: Mapping[str, float]) -> float:
        """One sample: measurements at t_k (names in ``inputs``) -> valve command v[k] [V]."""


def _matrix(name: str, value, shape: tuple[int | None, int | None]) -> np.ndarray:
    arr = np.array(value, dtype=float, ndmin=2)
    for got, want, what in zip(arr.shape, shape, ("rows", "columns")):
        if want is not None and got != want:
            raise ValueError(f"LinearController.{name} must have {want} {what}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"LinearController.{name} has a NaN or infinite entry")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class LinearController:
    """``z[k+1] = A z[k] + B w[k]``, ``v[k] = C z[k] + D w[k]``, ``w = scale * measurements[inputs]``.

    Parameters
    ----------
    A, B, C, D : array
        Discrete-time matrices; ``C`` has one row (one valve command).
    sample_time_s : float
        The sample time the matrices were discretised for.
    inputs : tuple of str
        Measurement names read, in the column order of ``B``/``D``.
    input_scale : mapping, optional
        Factor applied to each measurement before use (to the design model's
        units), default 1 for each.
    name, method, model_units : str
        What the controller is, how it was discretised, and the units of the
        model it was designed on.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    sample_time_s: float
    inputs: tuple[str, ...]
    input_scale: Mapping[str, float] | None = None
    name: str = ""
    method: str = ""
    model_units: str = ""
    _scale: np.ndarray = field(init=False, repr=False, compare=False)
    _state: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        A = _matrix("A", self.A, (None, None))
        n = A.shape[0] if A.size else 0
        if A.size and A.shape[0] != A.shape[1]:
            raise ValueError(f"LinearController.A must be square, got shape {A.shape}")
        m = len(self.inputs)
        if m == 0 or len(set(self.inputs)) != m:
            raise ValueError(f"LinearController.inputs must be distinct names, got {self.inputs}")
        unknown = [s for s in self.inputs if s not in MEASUREMENTS]
        if unknown:
            raise ValueError(f"LinearController.inputs {unknown} are not measurements of DATA_FORMATS.md {MEASUREMENTS}")
        object.__setattr__(self, "A", A.reshape(n, n))
        object.__setattr__(self, "B", _matrix("B", self.B, (n, m)) if n else np.zeros((0, m)))
        object.__setattr__(self, "C", _matrix("C", self.C, (1, n)) if n else np.zeros((1, 0)))
        object.__setattr__(self, "D", _matrix("D", self.D, (1, m)))
        if not (np.isfinite(self.sample_time_s) and self.sample_time_s > 0):
            raise ValueError(f"LinearController.sample_time_s must be positive, got {self.sample_time_s}")
        scale = dict(self.input_scale or {})
        extra = set(scale) - set(self.inputs)
        if extra:
            raise ValueError(f"LinearController.input_scale names {sorted(extra)} that are not inputs {self.inputs}")
        object.__setattr__(self, "input_scale", dict(scale))
        object.__setattr__(self, "inputs", tuple(self.inputs))
        object.__setattr__(self, "_scale", np.array([float(scale.get(s, 1.0)) for s in self.inputs]))
        object.__setattr__(self, "_state", np.zeros(n))

    @property
    def n_states(self) -> int:
        return self.A.shape[0]

    def reset(self) -> None:
        self._state[:] = 0.0

    def step(self, measurements: Mapping[str, float]) -> float:
        try:
            w = np.array([measurements[s] for s in self.inputs], dtype=float)
        except KeyError as exc:
            raise KeyError(f"controller {self.name!r} needs measurement {exc.args[0]!r}; it reads {self.inputs}") from None
        if not np.all(np.isfinite(w)):
            bad = [s for s, x in zip(self.inputs, w) if not np.isfinite(x)]
            raise ValueError(f"controller {self.name!r}: measurement {bad} is NaN or infinite")
        w *= self._scale
        z = self._state
        v = float(self.C[0] @ z + self.D[0] @ w)
        z[:] = self.A @ z + self.B @ w
        return v

    def statespace(self):
        """The controller as a discrete-time :class:`control.StateSpace` (input in model units, before scaling)."""
        import control  # (lazy: imports control, only when called)

        return control.ss(self.A, self.B, self.C, self.D, self.sample_time_s, inputs=list(self.inputs), outputs=["v"])


def unity_theta_controller(*, sample_time_s: float, input_scale: Mapping[str, float] | None = None, model_units: str = "") -> LinearController:
    """``v = theta_ref - theta``: the inner position loop alone (the notebook's "no vibration suppression")."""
    return LinearController(
        np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((1, 0)), [[1.0, -1.0]],
        sample_time_s=sample_time_s, inputs=("theta_ref", "theta"), input_scale=input_scale,
        name="unity theta feedback", method="static gain (no discretisation)", model_units=model_units,
    )  # fmt: skip


def from_discrete_tf(num: np.ndarray, den: np.ndarray, *, sample_time_s: float):
    """State-space matrices (A, B, C, D) of a discrete SISO transfer function, via python-control."""
    import control  # (lazy: imports control, only when called)

    ss = control.tf2ss(control.tf(num, den, sample_time_s))
    return np.asarray(ss.A), np.asarray(ss.B), np.asarray(ss.C), np.asarray(ss.D)


def _real_factors(roots: np.ndarray, tol: float = 1e-9) -> list[np.ndarray]:
    """Real polynomials of degree 2 (a conjugate pair or two real roots) and at most one of degree 1 with these roots."""
    roots = np.asarray(roots, complex)
    cplx = [r for r in roots if r.imag > tol * max(abs(r), 1.0)]
    real = sorted(float(r.real) for r in roots if abs(r.imag) <= tol * max(abs(r), 1.0))
    if 2 * len(cplx) + len(real) != len(roots):
        raise ValueError("complex roots must come in conjugate pairs")
    out = [np.array([1.0, -2.0 * r.real, abs(r) ** 2]) for r in cplx]
    for i in range(0, len(real) - 1, 2):
        out.append(np.array([1.0, -(real[i] + real[i + 1]), real[i] * real[i + 1]]))
    if len(real) % 2:
        out.append(np.array([1.0, -real[-1]]))
    return out


def from_discrete_zpk(zeros, poles, dc_gain: float, *, sample_time_s: float):
    """State-space matrices (A, B, C, D) of ``k prod(z - z_i) / prod(z - p_i)`` as a cascade of sections.

    Each section (a real quadratic or linear factor of the numerator over one
    of the denominator) has unit DC gain and ``dc_gain`` multiplies the
    output, so the realisation's DC gain is ``dc_gain`` to round-off. A single
    companion form of the expanded polynomials (:func:`from_discrete_tf`) loses
    digits when poles cluster near ``z = 1``: for the chapter-10 compensator at
    1 ms its DC gain is off by 6e-7 relative. Sections are built and chained
    with python-control (:func:`control.tf2ss`, :func:`control.series`).

    Raises
    ------
    ValueError
        If there are more zeros than poles (not realisable) or a root lies at
        ``z = 1`` (no unit-DC normalisation).
    """
    import control  # (lazy: imports control, only when called)

    nums, dens = _real_factors(zeros), _real_factors(poles)
    if len(zeros) > len(poles):
        raise ValueError(f"{len(zeros)} zeros and {len(poles)} poles: not realisable")
    nums = sorted(nums, key=len, reverse=True)
    dens = sorted(dens, key=len, reverse=True)
    sys = None
    for i, d in enumerate(dens):
        n = nums[i] if i < len(nums) else np.array([1.0])
        n1, d1 = np.polyval(n, 1.0), np.polyval(d, 1.0)
        if n1 == 0 or d1 == 0:
            raise ValueError("a zero or pole at z = 1 has no unit-DC section")
        sec = control.tf2ss(control.tf(n / n1, d / d1, sample_time_s))
        sys = sec if sys is None else control.series(sys, sec)
    if sys is None:
        return np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.array([[float(dc_gain)]])
    return np.asarray(sys.A), np.asarray(sys.B), float(dc_gain) * np.asarray(sys.C), float(dc_gain) * np.asarray(sys.D)


def mass_damping_controller(
    K_a: float,
    filter_tf=None,
    *,
    sample_time_s: float,
    method: Literal["zoh", "tustin", "matched"] = "tustin",
    input_scale: Mapping[str, float] | None = None,
    model_units: str = "",
) -> LinearController:
    """``v = theta_ref + K_a F(z) accel - theta`` (the chapter-2 loop, see :mod:`samii.design.rootlocus`).

    ``filter_tf`` is the continuous filter F(s) (None: F = 1), discretised by
    ``method`` with :func:`control.sample_system`.
    """
    import control  # (lazy: imports control, only when called)

    if filter_tf is None:
        A, B, C, D = np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.array([[1.0]])
        how = "no filter (static gain)"
    else:
        Fd = control.sample_system(control.tf(filter_tf), sample_time_s, method=method)
        A, B, C, D = from_discrete_tf(Fd.num[0][0], Fd.den[0][0], sample_time_s=sample_time_s)
        how = f"filter discretised by {method}"
    n = A.shape[0]
    Bw = np.zeros((n, 3))
    Bw[:, 2:] = B
    Dw = np.array([[1.0, -1.0, K_a * float(np.asarray(D).ravel()[0])]])
    return LinearController(
        A, Bw, K_a * np.asarray(C).reshape(1, n), Dw,
        sample_time_s=sample_time_s, inputs=("theta_ref", "theta", "accel"), input_scale=input_scale,
        name=f"mass-damping acceleration feedback K_a = {K_a:g}", method=how, model_units=model_units,
    )  # fmt: skip
