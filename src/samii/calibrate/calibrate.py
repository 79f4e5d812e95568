"""Frequency-domain calibration of the simulator's physical parameters to FRF data.

``calibrate(data, names)`` adjusts the named physical parameters (the ``--set``
names) so that the linearised simulator's FRF matches ``data`` in the
notebook's weighted cost (dB^2 + (pw deg)^2 per point, optional coherence
weighting): the same ``FitProblem`` that ``samii fit`` minimises, with
``SimulatorFRF`` in place of a transfer-function structure. ``mujoco.sysid``
calibrates in the time domain; a swept-sine rig hands over Bode data, so this
works where the data are.

Solver: ``scipy.optimize.least_squares`` (trust-region reflective) in the
logarithms of the positive parameters (the solver takes relative steps) and in
scaled units of the few that may be zero or negative (``SIGNED``: the
accelerometer's position), inside bounds. Bounds: hard physical limits where
physics gives them (``PHYSICAL_LIMITS``, each with its reason), otherwise a
factor ``span`` (default 10) either side of the start; the user's bounds win.

Uncertainty, identifiability warnings and lack of fit are those of ``samii fit``
(``samii.identify.fit``: sandwich covariance from the Jacobian with the
coherence noise profile; directions the data do not determine; parameters
correlated beyond 0.99; bands where the residual exceeds the random error the
coherence predicts). A parameter that ends on a bound is a warning, and the
result is then not called converged.

Optionally (``confirm``) the calibrated model is measured like the rig (a
simulated swept sine) and the cost of that measurement against the data is
reported beside the linearised one: the nonlinear simulator's agreement, not
only the linearisation's.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import numpy as np

from samii.calibrate.simulator import GAIN_PREFIX, SIGNED, SimulatorFRF, check_parameter_name, parameter_value
from samii.frequency_response import Channel, FrequencyResponse
from samii.identify.cost import FitProblem, Weighting
from samii.identify.fit import _covariance, resolve_weighting
from samii.identify.lack_of_fit import LackOfFit, lack_of_fit, refuse_noise
from samii.json_output import dumps
from samii.sim.mjcf import SamiiParams

__all__ = ["MODE_KNOBS", "PHYSICAL_LIMITS", "CalibrationResult", "calibrate", "default_bounds"]

#: Six physical parameters that set the simulator's three base modes, their damping and the
#: hydraulic pole pair: what a calibration to a Bode test usually frees (the calibration test and
#: benchmarks/calibrate_speed.py recover them from data started 20 % off).
MODE_KNOBS: tuple[str, ...] = (
    "beam.clamp_stiffness_Nm_rad",
    "arm.joint1_stiffness_Nm_rad",
    "beam.clamp_maxwell_stiffness_Nm_rad",
    "arm.joint1_damping_Nms_rad",
    "hydraulic.total_volume",
    "hydraulic.leakage_coefficient",
)

#: Hard limits of parameters whose physics bounds them: (lo, hi, reason).
PHYSICAL_LIMITS: Mapping[str, tuple[float, float, str]] = MappingProxyType(
    {
        "hydraulic.bulk_modulus": (
            1.0e8,
            2.0e9,
            "effective bulk modulus of mineral oil: ~0.1 GPa with much entrained air and hose compliance, <= ~1.8-2 GPa for pure oil",
        ),
        "hydraulic.supply_pressure": (1.0e6, 3.5e7, "industrial hydraulic supplies run 1-35 MPa"),
        "hydraulic.valve_time_constant": (2.0e-4, 0.05, "servo/proportional valves: bandwidths from ~3 Hz to ~800 Hz"),
        "beam.length_m": (3.0, 4.6482, "free length: at most the beam's 4.6482 m (TMM), less if the clamp grips part of it"),
        "beam.EI_Nm2": (1.0e4, 1.0e6, "steel at the public 5.73 kg/m: from a solid square bar (~1e4) to a 0.2 m thin-walled tube (~1e6)"),
        "beam.mass_per_length_kg_m": (2.0, 12.0, "within a factor of about 2 of the public 5.7281 kg/m"),
        "beam.accel_offset_m": (-0.5, 0.45, "on the beam's last half element or on the mount post l0 (0.33 m) above the beam's end"),
        "gain.act": (1e-6, 1e6, "sensor unit unknown: any positive factor"),
        "gain.base": (1e-6, 1e6, "sensor unit unknown: any positive factor"),
    }
)

#: A parameter within this relative distance of a bound is "on the bound".
_ON_BOUND = 1e-3
#: Residual returned for a trial point where the model cannot be built (rejected by the solver).
_PENALTY = 1e4


def default_bounds(name: str, start: float, *, span: float = 10.0) -> tuple[float, float, str]:
    """(lo, hi, source) for parameter ``name`` starting at ``start``."""
    if name.startswith(GAIN_PREFIX) or name in SIGNED:
        if name not in PHYSICAL_LIMITS:
            raise ValueError(f"parameter {name!r} has no default bounds: give them (--bound {name}=LO:HI)")
        plo, phi, why = PHYSICAL_LIMITS[name]
        return plo, phi, f"physics: {why}"
    lo, hi = start / span, start * span
    if name in PHYSICAL_LIMITS:
        plo, phi, why = PHYSICAL_LIMITS[name]
        lo, hi = max(lo, plo), min(hi, phi)
        if not lo < hi or not lo <= start <= hi:
            lo, hi = plo, phi
        return lo, hi, f"physics: {why}"
    return lo, hi, f"a factor {span:g} either side of the start"


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class CalibrationResult:
    """What ``calibrate`` found. Values in SI (the parameter's own unit)."""

    names: tuple[str, ...]
    start: Mapping[str, float]
    values: Mapping[str, float]
    stderr: Mapping[str, float]
    correlation: np.ndarray
    bounds: Mapping[str, tuple[float, float, str]]
    cost_start: float
    cost: float
    rms_start: Mapping[str, tuple[float, float]]  #: channel -> (dB, deg) RMS error at the start
    rms: Mapping[str, tuple[float, float]]  #: channel -> (dB, deg) RMS error calibrated
    converged: bool
    status: str
    nfev: int
    elapsed_s: float
    warnings: tuple[str, ...]
    lack_of_fit: LackOfFit
    params: SamiiParams  #: the full calibrated parameter set
    phase_weight: float
    band_hz: tuple[float, float]
    channels: tuple[str, ...]
    weighting: str
    data_source: str = ""
    confirmation: Mapping[str, object] | None = None
    frf_start: FrequencyResponse | None = field(default=None, repr=False)
    frf: FrequencyResponse | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        def num(v):
            v = float(v)
            return v if math.isfinite(v) else None

        return {
            "data": self.data_source,
            "settings": {
                "phase_weight": self.phase_weight,
                "band_hz": list(self.band_hz),
                "channels": list(self.channels),
                "weighting": self.weighting,
            },
            "parameters": [
                {
                    "name": n,
                    "start": self.start[n],
                    "value": self.values[n],
                    "stderr": num(self.stderr[n]),
                    "change_pct": 100.0 * (self.values[n] / self.start[n] - 1.0) if self.start[n] != 0 else None,
                    "bounds": [self.bounds[n][0], self.bounds[n][1]],
                    "bounds_source": self.bounds[n][2],
                }
                for n in self.names
            ],
            "correlation": [[num(v) for v in row] for row in self.correlation],
            "cost": {"start": self.cost_start, "calibrated": self.cost},
            "rms_error": {
                c: {"start_db": self.rms_start[c][0], "start_deg": self.rms_start[c][1], "db": self.rms[c][0], "deg": self.rms[c][1]}
                for c in self.channels
            },
            "converged": self.converged,
            "status": self.status,
            "nfev": self.nfev,
            "elapsed_s": self.elapsed_s,
            "warnings": list(self.warnings),
            "lack_of_fit": self.lack_of_fit.to_dict(),
            "confirmation": dict(self.confirmation) if self.confirmation is not None else None,
            "calibrated_params": self.params.as_dict(),
        }

    def to_json(self, **kwargs) -> str:
        return dumps(self.to_dict(), **kwargs)

    def table(self) -> str:
        """Parameters, start, calibrated value, standard error."""
        lines = [f"{'parameter':38s} {'start':>12s} {'calibrated':>12s} {'std err':>10s} {'change':>8s}"]
        for n in self.names:
            se = self.stderr[n]
            se_txt = f"{100 * se / abs(self.values[n]):9.2f}%" if math.isfinite(se) else "      n/a"
            change = f"{100 * (self.values[n] / self.start[n] - 1):+7.1f}%" if self.start[n] != 0 else f"{self.values[n] - self.start[n]:+8.3g}"
            lines.append(f"{n:38s} {self.start[n]:12.5g} {self.values[n]:12.5g} {se_txt:>10s} {change}")
        return "\n".join(lines)

    def write_params(self, path, *, overwrite: bool = False) -> Path:
        """The calibrated parameter set as a parameter file that ``load_model`` and ``--model`` accept."""
        from samii.formats import write_text  # (lazy: this module is imported at samii's start-up, that one is not needed there)

        note = f"written by samii calibrate from {self.data_source or 'FRF data'}: " + ", ".join(
            f"{n} = {self.values[n]:.6g}" for n in self.names if not n.startswith(GAIN_PREFIX)
        )
        text = json.dumps({"note": note, "params": self.params.as_dict()}, indent=2) + "\n"
        return write_text(path, text, overwrite=overwrite)


def _gain_starts(data: FrequencyResponse, base: SamiiParams, names: tuple[str, ...], x0: np.ndarray, gains: list[int], band_hz) -> np.ndarray:
    """Start of each channel gain: the geometric mean of |data / model| over the band (gain.act
    from theta/v; gain.base from xdd/theta, else from xdd/v)."""
    d = data.band(*band_hz) if band_hz is not None else data
    h = SimulatorFRF(base, names).frf(x0, d.freq_hz)  # gains at 1 unless given
    out = []
    for i in gains:
        ch = names[i][len(GAIN_PREFIX) :]
        c = ch if ch in d.channels else ("total" if ch == "base" and "total" in d.channels else None)
        if c is None:
            raise ValueError(f"{names[i]}: the data have no {ch} channel to set its level")
        ratio = np.abs(d.response(c) / h.response(c))
        out.append(float(np.exp(np.median(np.log(ratio)))) * x0[i])
    return np.array(out)


def _rms(errors: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> dict[str, tuple[float, float]]:
    return {c: (float(np.sqrt(np.mean(db**2))), float(np.sqrt(np.mean(deg**2)))) for c, (db, deg) in errors.items()}


def calibrate(
    data: FrequencyResponse,
    names: Sequence[str],
    *,
    base: SamiiParams | None = None,
    start: Mapping[str, float] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    span: float = 10.0,
    phase_weight: float = 0.1,
    band_hz: tuple[float, float] | None = None,
    channels: tuple[Channel, ...] | None = None,
    weighting: Weighting = "none",
    max_nfev: int = 60,
    confirm: object | None = None,
    data_source: str = "",
) -> CalibrationResult:
    """Calibrate the simulator's parameters ``names`` to ``data``.

    Parameters
    ----------
    data : FrequencyResponse
        Measured (or model) FRF: act = theta/v [rad/V], base = xdd/theta [(m/s²)/rad].
    names : sequence of str
        Dotted parameter names (``beam.clamp_stiffness_Nm_rad``, ``hydraulic.total_volume``,
        ..., or ``gain.base`` for an accelerometer of unknown unit).
    base : SamiiParams, optional
        The other parameters (default: the embedded model's).
    start : mapping, optional
        Starting values (default: the values in ``base``; gains 1).
    bounds : mapping name -> (lo, hi), optional
        Overrides of :func:`default_bounds`.
    span : float
        Default bound factor either side of the start, where physics gives none.
    phase_weight, band_hz, channels, weighting
        The cost, as in ``samii fit`` (``samii.identify.cost.FitProblem``); ``weighting="auto"``
        is coherence weighting when every channel in the cost has coherence, else none.
    max_nfev : int
        Largest number of solver iterations (each costs 2 n + 1 linearisations).
    confirm : samii.measure.excitation.SweptSine, optional
        Also measure the calibrated model with this swept sine in the nonlinear simulator
        and report that measurement's cost against the data.
    data_source : str
        Where the data came from (for the report).
    """
    from scipy.optimize import least_squares  # (lazy: imports scipy, only when called)

    from samii.sim.model import default_params  # (lazy: this module is imported at samii's start-up, that one is not needed there)

    t0 = time.perf_counter()
    base = default_params() if base is None else base
    names = tuple(names)
    if not names:
        raise ValueError("name at least one parameter to calibrate")
    for n in names:
        check_parameter_name(base, n)
    start = dict(start or {})
    unknown = sorted(set(start) - set(names))
    if unknown:
        raise ValueError(f"start values given for {unknown}, which are not calibrated ({list(names)})")
    x0 = np.array([float(start.get(n, parameter_value(base, n))) for n in names])
    gains = [i for i, n in enumerate(names) if n.startswith(GAIN_PREFIX) and n not in start]
    if gains:  # an unknown sensor unit: start from the data's level against the model's
        x0[gains] = _gain_starts(data, base, names, x0, gains, band_hz)
    for n, v in zip(names, x0):
        if not math.isfinite(v) or (n not in SIGNED and not v > 0):
            raise ValueError(
                f"parameter {n}: start {float(v):g} must be finite and > 0 (positive parameters are calibrated as logarithms); give --start {n}=VALUE"
            )
    user_bounds = dict(bounds or {})
    unknown = sorted(set(user_bounds) - set(names))
    if unknown:
        raise ValueError(f"bounds given for {unknown}, which are not calibrated ({list(names)})")
    bnds: dict[str, tuple[float, float, str]] = {}
    for n, v in zip(names, x0):
        if n in user_bounds:
            lo, hi = (float(b) for b in user_bounds[n])
            if not (lo < hi and math.isfinite(lo) and math.isfinite(hi)) or (n not in SIGNED and lo <= 0):
                raise ValueError(f"bounds of {n}: expected {'' if n in SIGNED else '0 < '}lo < hi, finite, got ({lo}, {hi})")
            bnds[n] = (lo, hi, "given")
        else:
            bnds[n] = default_bounds(n, float(v), span=span)
        lo, hi, _ = bnds[n]
        if not lo <= v <= hi:
            raise ValueError(f"parameter {n}: start {v:.6g} lies outside its bounds [{lo:.6g}, {hi:.6g}]")

    weighting = resolve_weighting(data, channels, weighting)
    structure = SimulatorFRF(base, names)
    problem = FitProblem(data, structure, phase_weight=phase_weight, band_hz=band_hz, channels=channels, weighting=weighting)
    refuse_noise(problem.data, problem.channels, "calibrate against")
    free = problem.fitted
    if not np.all(free):
        idle = [n for n, f in zip(names, free) if not f]
        raise ValueError(f"{idle} do not act on the fitted channels {problem.channels}")

    # solver coordinates: log x for positive parameters, x / scale for signed ones
    signed = np.array([n in SIGNED for n in names])
    scale = np.array([(bnds[n][1] - bnds[n][0]) / 10 if n in SIGNED else 1.0 for n in names])

    def to_z(x):
        return np.where(signed, np.asarray(x, float) / scale, np.log(np.where(signed, 1.0, x)))

    def to_x(z):
        return np.where(signed, z * scale, np.exp(np.where(signed, 0.0, z)))

    lo = to_z([bnds[n][0] for n in names])
    hi = to_z([bnds[n][1] for n in names])
    z0 = to_z(x0)
    failures: list[str] = []

    def fun(z):
        try:
            r = problem.residuals(to_x(z))
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            failures.append(str(exc))
            return np.full(problem.n_residuals, _PENALTY)
        if not np.all(np.isfinite(r)):
            return np.full(problem.n_residuals, _PENALTY)
        return r

    def jac(z):
        x = to_x(z)
        try:
            J = problem.jacobian(x)
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            failures.append(str(exc))
            return np.zeros((problem.n_residuals, z.size))
        return np.nan_to_num(J * np.where(signed, scale, x)[None, :])  # dx/dz

    r0 = fun(z0)
    if r0[0] == _PENALTY and np.all(r0 == _PENALTY):
        raise ValueError(f"the simulator cannot be built at the start: {failures[-1] if failures else 'non-finite response'}")
    sol = least_squares(fun, z0, jac=jac, bounds=(lo, hi), method="trf", x_scale=1.0, xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=max_nfev)
    x = to_x(sol.x)
    r, J = problem.residuals_and_jacobian(x)
    cost = float(r @ r)
    _, se, corr, warnings = _covariance(problem, x, (r, J))
    warnings = list(warnings)
    on_bound = []
    for i, n in enumerate(names):
        if min(abs(sol.x[i] - lo[i]), abs(hi[i] - sol.x[i])) < _ON_BOUND * (10 if signed[i] else 1):
            on_bound.append(n)
            warnings.append(
                f"{n} = {x[i]:.6g} ended on its bound [{bnds[n][0]:.6g}, {bnds[n][1]:.6g}] ({bnds[n][2]}): the data want it further; "
                "check the structure (a missing effect) or widen the bound with --bound"
            )
    if failures:
        warnings.append(f"{len(failures)} trial point(s) could not be simulated and were rejected (e.g. {failures[-1]})")
    if "unit unknown" in str(data.metadata.get("source", "")) and "gain.base" not in names and any(c in ("base", "total") for c in problem.channels):
        warnings.append(
            "the data's acceleration unit is unknown (notebook curves) but gain.base is not calibrated: the physical "
            "parameters absorb the unit; add --param gain.base"
        )
    converged = bool(sol.status > 0 and not on_bound)
    status = {0: "stopped at max_nfev", 1: "gradient small", 2: "cost change small", 3: "step small", 4: "cost and step small"}.get(
        sol.status, f"status {sol.status}"
    )
    lof = lack_of_fit(problem, x)
    warnings.extend(lof.warnings())
    w0 = problem.errors(x0)
    result_errors = problem.errors(x)
    values = {n: float(v) for n, v in zip(names, x)}
    elapsed = time.perf_counter() - t0
    confirmation = None
    if confirm is not None:
        t1 = time.perf_counter()
        confirmation = _confirm(structure, x, problem, confirm)
        confirmation["elapsed_s"] = time.perf_counter() - t1
    return CalibrationResult(
        names=names,
        start={n: float(v) for n, v in zip(names, x0)},
        values=values,
        stderr={n: float(v) for n, v in zip(names, se)},
        correlation=corr,
        bounds=bnds,
        cost_start=float(r0 @ r0),
        cost=cost,
        rms_start=_rms(w0),
        rms=_rms(result_errors),
        converged=converged,
        status=status,
        nfev=int(sol.nfev),
        elapsed_s=elapsed,
        warnings=tuple(warnings),
        lack_of_fit=lof,
        params=structure.samii_params(x),
        phase_weight=float(phase_weight),
        band_hz=(float(problem.data.freq_hz[0]), float(problem.data.freq_hz[-1])),
        channels=tuple(problem.channels),
        weighting=weighting,
        data_source=data_source,
        confirmation=confirmation,
        frf_start=structure.frf(x0, problem.data.freq_hz),
        frf=structure.frf(x, problem.data.freq_hz),
    )


def _confirm(structure: SimulatorFRF, x: np.ndarray, problem: FitProblem, sweep) -> dict:
    """Measure the calibrated model with ``sweep`` in the nonlinear simulator (noise-free DAQ)
    and compare that measurement and the linearisation with the data (unweighted RMS errors)."""
    from samii.measure.campaign import record  # (lazy: this module is imported at samii's start-up, that one is not needed there)
    from samii.measure.frf import estimate_frf  # (lazy: this module is imported at samii's start-up, that one is not needed there)

    f = problem.data.freq_hz
    inside = (f >= sweep.start_hz) & (f <= sweep.stop_hz)
    if not np.any(inside):
        raise ValueError(f"the confirming sweep {sweep.start_hz:g}-{sweep.stop_hz:g} Hz covers none of the data's frequencies")
    f = f[inside]
    _, ts = record(structure.model(x), sweep)
    meas = estimate_frf(ts, record_s=sweep.record_s, baseline_s=sweep.lead_s, freqs_hz=f, record_signs=sweep.record_signs)
    measured = structure.with_gains(x, meas)
    linear = structure.frf(x, f)

    def rms(h, c):
        q = h / problem.data.response(c)[inside]
        return {"db": float(np.sqrt(np.mean((20 * np.log10(np.abs(q))) ** 2))), "deg": float(np.sqrt(np.mean(np.degrees(np.angle(q)) ** 2)))}

    return {
        "method": f"swept sine {sweep.start_hz:g}-{sweep.stop_hz:g} Hz, {sweep.amplitude_v:g} V, {sweep.repetitions} records, in the nonlinear simulator (no sensor noise)",
        "points": int(f.size),
        "rms_error_measured": {c: rms(measured[c], c) for c in problem.channels},
        "rms_error_linearised": {c: rms(linear.response(c), c) for c in problem.channels},
    }
