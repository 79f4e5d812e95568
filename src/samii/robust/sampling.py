"""Plant variations for a Monte Carlo robustness study: what the parameters may be, drawn from a seed.

Two sources, combinable:

* **physical spreads** a user gives (``--spread hydraulic.bulk_modulus=20%``): each parameter
  independently normal about its nominal value, standard deviation 20 % of it (or an absolute
  value in the parameter's unit: ``--spread hydraulic.command_delay=0.002``), truncated at ±3σ and,
  for a parameter whose nominal value is positive, above 5 % of it (a bulk modulus, a stiffness or a
  mass cannot reach zero); one whose nominal value is 0 (a delay, a damping, a dead band) stays at or
  above 0, so an absolute spread about 0 is drawn from the half-normal. A quantity whose 0 means
  "none" (a sensor's filter corner, the valve's saturation, a tip body's mass) is spread about a
  value given with ``--set`` and stays above 5 % of it, so the filter or the body is there in every
  plant. The controller's computation delay is spread as ``controller.delay_samples`` (in controller
  samples, about ``--delay-samples``);
* **a calibration's covariance** (``--covariance calibration.json``, written by ``samii calibrate
  --out``): what the data could not pin down. The calibrated parameters jointly normal with their
  standard errors and correlations, about the calibrated values; a draw outside the calibration's
  bounds or the positivity limit above is drawn again.

Every draw is made up front, sample ``i``'s from its own generator (``numpy.random.SeedSequence(seed)``'s
child ``i``), so the same seed gives the same plants whatever engine or number of workers runs them, and
sample ``i`` is the same plant in a study of any size (a worst sample can be run again alone).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from samii.errors import InputError
from samii.json_output import read_json

__all__ = [
    "Spread",
    "Covariance",
    "parse_spread",
    "read_covariance",
    "draw_plants",
    "PlantDraws",
    "sample_seeds",
    "TRUNCATE_SIGMA",
    "MIN_FRACTION",
    "DELAY_SAMPLES",
]

TRUNCATE_SIGMA = 3.0  #: draws beyond this many standard deviations are drawn again
MIN_FRACTION = 0.05  #: a positive parameter stays above this fraction of its nominal value
_MAX_REDRAWS = 1000
_DISCRETE = {
    "beam.n_segments": "the number of beam elements",
    "beam.accel_body_fixed": "a 0/1 switch",
    "beam.pitch_deg": "the beam's orientation",
    "arm.heading_deg": "the arm's heading",
    "timestep_s": "the simulation step",
}
#: 0 means "none" for these: a spread about 0 would switch a filter, a limit or a body on, not perturb it; about a
#: value given with --set they are spread as any positive quantity (above 5 % of it: on in every plant).
_NONE_AT_ZERO = {
    "sensor.accel_lowpass_hz": "a filter corner, 0 for none",
    "sensor.accel_antialias_hz": "a filter corner, 0 for none",
    "sensor.accel_highpass_hz": "a filter corner, 0 for none",
    "hydraulic.valve_saturation": "a limit, 0 for none",
    "beam.tip_body_mass_kg": "a body's mass, 0 for none",
}
#: The controller's computation delay [controller samples], spread by this name about ``--delay-samples``: not a
#: parameter of the plant but of the card that runs the controller (samii.closedloop.card).
DELAY_SAMPLES = "controller.delay_samples"
#: Parameters that may be negative (samii.calibrate's table, and the valve's asymmetry, which the model's own check
#: bounds to -1...<1): not limited below.
_SIGNED = ("beam.accel_offset_m", "arm.heading_deg", "beam.pitch_deg", "hydraulic.valve_asymmetry")


@dataclass(frozen=True)
class Spread:
    """One parameter's independent spread: normal, standard deviation ``relative`` x nominal or ``absolute``."""

    name: str
    relative: float | None = None
    absolute: float | None = None

    def sigma(self, nominal: float) -> float:
        return abs(nominal) * self.relative if self.relative is not None else float(self.absolute)

    def describe(self) -> str:
        return f"{self.name} ±{100 * self.relative:g} % (1σ)" if self.relative is not None else f"{self.name} ±{self.absolute:g} (1σ)"


@dataclass(frozen=True)
class Covariance:
    """Jointly normal parameters: the calibration's values, standard errors and correlations."""

    source: str
    names: tuple[str, ...]
    mean: np.ndarray
    cov: np.ndarray
    bounds: tuple[tuple[float, float], ...]
    nominal: dict = field(default_factory=dict)  #: the calibrated parameter set (SamiiParams.as_dict), the study's nominal plant
    converged: bool | None = None  #: the calibration's own word (None: the file does not say)


def parse_spread(text: str) -> Spread:
    """``NAME=10%`` (relative standard deviation) or ``NAME=VALUE`` (absolute, in the parameter's unit)."""
    name, sep, value = text.partition("=")
    name, value = name.strip(), value.strip()
    if not sep or not name or not value:
        raise InputError(f"--spread {text!r}: expected NAME=P% or NAME=SIGMA, e.g. hydraulic.bulk_modulus=20%")
    rel = value.endswith("%")
    try:
        number = float(value[:-1] if rel else value)
    except ValueError:
        raise InputError(f"--spread {text!r}: {value!r} is not a number (NAME=P% or NAME=SIGMA)") from None
    if not math.isfinite(number) or number <= 0:
        raise InputError(f"--spread {text!r}: expected a positive spread, got {value}")
    if rel and number > 100:
        raise InputError(f"--spread {text!r}: a relative spread above 100 % would put most draws at the positivity limit")
    return Spread(name, relative=number / 100 if rel else None, absolute=None if rel else number)


def read_covariance(path) -> Covariance:
    """The parameters, standard errors and correlations of ``samii calibrate``'s ``calibration.json``."""

    path = Path(path)
    d = read_json(path, "calibration file", missing=f"--covariance {path}: no such file")
    if not isinstance(d, dict):
        raise InputError(f"--covariance {path}: expected samii calibrate's calibration.json (a JSON object)")
    params, corr, nominal = d.get("parameters"), d.get("correlation"), d.get("calibrated_params")
    if not isinstance(params, list) or not params or not isinstance(corr, list) or not isinstance(nominal, dict):
        raise InputError(
            f"--covariance {path}: expected samii calibrate's calibration.json (fields 'parameters', 'correlation', 'calibrated_params')"
        )
    names, mean, se, bounds = [], [], [], []
    for i, p in enumerate(params):
        try:
            names.append(str(p["name"]))
            mean.append(float(p["value"]))
            s = p["stderr"]
            lo, hi = (float(b) for b in p.get("bounds", [-math.inf, math.inf])[:2])
        except (KeyError, TypeError, ValueError, AttributeError):
            raise InputError(f"--covariance {path}: field 'parameters'[{i}] needs a name, a numeric value, stderr and bounds [lo, hi]") from None
        if not math.isfinite(mean[-1]):  # (it was said to disagree with 'calibrated_params')
            raise InputError(
                f"--covariance {path}: field 'parameters'[{i}] ({names[-1]}): value {p['value']!r} is not a finite "
                "number; the file is damaged: calibrate again"
            )
        if names[-1].startswith("gain."):
            raise InputError(
                f"--covariance {path}: parameter {names[-1]} is a measurement gain of the calibration, not a property of the "
                "plant; calibrate without it, or vary the plant with --spread"
            )
        try:
            s = float(s)
        except (TypeError, ValueError):
            s = math.nan
        if not math.isfinite(s) or s <= 0:
            raise InputError(
                f"--covariance {path}: parameter {names[-1]} has no finite positive standard error ({p['stderr']!r}): the "
                "calibration could not determine it; calibrate without it, or give its spread with --spread"
            )
        if not 0.0 < s * s < math.inf:  # (the covariance is built of their products)
            raise InputError(
                f"--covariance {path}: field 'parameters'[{i}] ({names[-1]}): stderr {s:.3g} beside its value "
                f"{mean[-1]:.3g} is no standard error a calibration gives (its square leaves the range of numbers); "
                "the file is damaged: calibrate again, or give its spread with --spread"
            )
        if not lo < hi:
            raise InputError(f"--covariance {path}: parameter {names[-1]} has bounds [{lo:g}, {hi:g}]; expected [LO, HI] with LO < HI")
        se.append(s)
        bounds.append((lo, hi))
    if dup := sorted({n for n in names if names.count(n) > 1}):
        raise InputError(f"--covariance {path}: field 'parameters' names {', '.join(dup)} more than once")
    try:
        c = np.asarray(corr, dtype=float) if all(isinstance(r, list) for r in corr) else np.empty(0)
    except (TypeError, ValueError):  # an entry that is no number (a string, null, a list)
        c = np.empty(0)
    if c.shape != (len(names), len(names)) or not np.all(np.isfinite(c)):
        raise InputError(f"--covariance {path}: field 'correlation' must be a {len(names)}x{len(names)} matrix of finite numbers")
    if np.any(np.abs(np.diag(c) - 1.0) > 1e-6) or np.any(np.abs(c) > 1.0 + 1e-9):
        raise InputError(f"--covariance {path}: field 'correlation' is not a correlation matrix (ones on its diagonal, |r| <= 1)")
    from samii.calibrate.simulator import check_parameter_name  # (lazy: imports mujoco, only when called)
    from samii.sim.model import default_params  # (lazy: imports mujoco, only when called)

    plant = default_params()
    for name in names:
        try:
            check_parameter_name(plant, name)
        except ValueError as exc:
            raise InputError(f"--covariance {path}: field 'parameters': {exc}") from None
    for name, m in zip(names, mean):  # the nominal plant is the calibrated one: the values must agree
        section, _, key = name.partition(".")
        v = nominal.get(section, {}).get(key) if isinstance(nominal.get(section), dict) else None
        if v is None or not math.isclose(float(v), m, rel_tol=1e-9, abs_tol=1e-12):
            raise InputError(f"--covariance {path}: parameter {name} = {m:g} but field 'calibrated_params' holds {v!r}")
    if np.any(np.abs(c - c.T) > 1e-9):
        i, j = np.unravel_index(int(np.argmax(np.abs(c - c.T))), c.shape)
        raise InputError(f"--covariance {path}: field 'correlation' is not symmetric (entry [{i}][{j}] = {c[i, j]:g}, [{j}][{i}] = {c[j, i]:g})")
    # checked on the correlation matrix itself (its eigenvalues are of order 1): on the covariance, standard errors
    # of 1e5 beside 1e-5 scale a negative eigenvalue of the correlation into rounding and it passed (issue 36)
    low = float(np.min(np.linalg.eigvalsh(0.5 * (c + c.T))))
    if low < -1e-9:
        raise InputError(
            f"--covariance {path}: field 'correlation' is not positive semi-definite (its smallest eigenvalue is "
            f"{low:.3g}); no joint distribution has these correlations"
        )
    s = np.asarray(se)
    cov = c * np.outer(s, s)
    cov = 0.5 * (cov + cov.T)
    converged = d.get("converged")
    return Covariance(str(path), tuple(names), np.asarray(mean), cov, tuple(bounds), nominal, converged if isinstance(converged, bool) else None)


@dataclass(frozen=True)
class PlantDraws:
    """The drawn plants: ``values[i, j]`` is parameter ``names[j]`` in sample ``i``."""

    names: tuple[str, ...]
    nominal: np.ndarray
    values: np.ndarray
    sources: tuple[str, ...]  #: how each parameter was drawn (for the report)

    def overrides(self, i: int) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, self.values[i])}


def _lower_limit(nominal: float, name: str = "") -> float:
    """A positive quantity stays above 5 % of its nominal; one nominally 0 (a delay, a damping, a dead band) stays
    non-negative (an absolute spread about 0 becomes a half-normal); a signed one is not limited."""
    if name in _SIGNED:
        return -math.inf
    if nominal > 0:
        return MIN_FRACTION * nominal
    return 0.0 if nominal == 0 else -math.inf


def sample_seeds(seed: int, index: int) -> tuple[np.random.Generator, int]:
    """Sample ``index``'s own generator (for its plant) and its sensor-noise seed, from ``seed``'s child ``index``
    (the same whatever the study's size). The nominal plant is index -1: child ``2**32 - 1``."""
    child = np.random.SeedSequence(seed, spawn_key=(index if index >= 0 else 2**32 - 1,))
    plant, noise = child.spawn(2)
    return np.random.default_rng(plant), int(noise.generate_state(1)[0])


def draw_plants(n: int, seed: int, nominal: dict[str, float], spreads: list[Spread], covariance: Covariance | None) -> PlantDraws:
    """``n`` plants; in each, the covariance's parameters jointly, then each spread's, from the sample's own generator."""
    names: list[str] = []
    sources: list[str] = []
    nominals: list[float] = []
    lows: list[float] = []
    highs: list[float] = []
    if covariance is not None:
        se = np.sqrt(np.diag(covariance.cov))
        for name, m, (b_lo, b_hi), sd in zip(covariance.names, covariance.mean, covariance.bounds, se):
            edge = min(abs(m - b_lo), abs(b_hi - m)) < 1e-6 * max(abs(m), sd)
            names.append(name)
            nominals.append(float(m))
            lows.append(max(b_lo, _lower_limit(m, name), m - TRUNCATE_SIGMA * sd))
            highs.append(min(b_hi, m + TRUNCATE_SIGMA * sd))
            spread = f"±{100 * sd / abs(m):.3g} %" if m != 0 else f"±{sd:.3g}"
            sources.append(
                f"{name} {spread} (1σ, calibration covariance {covariance.source})"
                + (": calibrated on its bound, so drawn on one side of it" if edge else "")
            )
    sigmas: list[float] = []
    for sp in spreads:
        if sp.name in names:
            raise InputError(
                f"--spread {sp.name}: already varied ({'by --covariance' if covariance is not None and sp.name in covariance.names else 'given twice'})"
            )
        if sp.name not in nominal:
            raise InputError(f"--spread {sp.name}: no such parameter (samii params lists them; {DELAY_SAMPLES} is the computation delay)")
        if sp.name in _DISCRETE:
            raise InputError(f"--spread {sp.name}: {_DISCRETE[sp.name]}, not a physical quantity with a spread about its value")
        mu = float(nominal[sp.name])
        if sp.name in _NONE_AT_ZERO and mu == 0:
            raise InputError(
                f"--spread {sp.name}: {_NONE_AT_ZERO[sp.name]}, and it is 0 here: give it a value with --set {sp.name}=VALUE "
                "to spread it about (a spread about 0 would switch it on, not perturb it)"
            )
        sigma = sp.sigma(mu)
        if sigma <= 0:
            raise InputError(f"--spread {sp.describe()}: the nominal value is 0, so a relative spread is 0; give an absolute one")
        names.append(sp.name)
        nominals.append(mu)
        sigmas.append(sigma)
        lows.append(max(mu - TRUNCATE_SIGMA * sigma, _lower_limit(mu, sp.name)))
        highs.append(mu + TRUNCATE_SIGMA * sigma)
        sources.append(sp.describe())
    if not names:
        raise InputError("nothing to vary: give --spread NAME=P% and/or --covariance calibration.json")
    lo, hi = np.array(lows), np.array(highs)
    k = len(covariance.names) if covariance is not None else 0
    if covariance is not None:
        # drawn in the correlation's coordinates, z ~ N(0, R), x = mean + se z: R's eigenvalues are of order 1 whatever
        # the parameters' scales. Decomposed, the covariance itself spans variances of 1e10 (a stiffness) to 1e-30 (a
        # leakage coefficient), its eigenvectors mix them in rounding, and draws of a calibration's own correlations fell
        # outside 5 standard errors every time; a rounding-negative eigenvalue of R (it passed its check) counts as 0
        se_k = np.sqrt(np.diag(covariance.cov))
        corr = covariance.cov / np.outer(se_k, se_k)
        eig, vec = np.linalg.eigh(0.5 * (corr + corr.T))
        root = vec * np.sqrt(np.clip(eig, 0.0, None))  # R = root root^T
    values = np.empty((n, len(names)))
    for i in range(n):
        rng, _ = sample_seeds(seed, i)
        if covariance is not None:
            outside = np.zeros(k, int)
            for _ in range(_MAX_REDRAWS):
                x = covariance.mean + se_k * (root @ rng.standard_normal(k))
                out = (x < lo[:k]) | (x > hi[:k])
                if not out.any():
                    break
                outside += out
            else:
                j = int(np.argmax(outside))
                sd = float(np.sqrt(covariance.cov[j, j]))
                raise InputError(
                    f"--covariance {covariance.source}: no draw within the bounds in {_MAX_REDRAWS} tries; "
                    f"{covariance.names[j]} fell outside {lo[j]:.4g}...{hi[j]:.4g} in {outside[j]} of them (its "
                    f"value {covariance.mean[j]:.4g}, standard error {sd:.3g}: a spread that wide is no "
                    "calibration's; calibrate again, or give its spread with --spread)"
                )
            values[i, :k] = x
        for j, sigma in enumerate(sigmas, start=k):
            for _ in range(_MAX_REDRAWS):  # the interval holds the nominal value: at least half the draws land in it
                x = rng.normal(nominals[j], sigma)
                if lo[j] <= x <= hi[j]:
                    break
            values[i, j] = x
    return PlantDraws(tuple(names), np.asarray(nominals), values, tuple(sources))
