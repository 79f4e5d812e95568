"""Plant variations for a Monte Carlo robustness study: what the parameters may be, drawn from a seed.

Two sources, combinable:

* **physical spreads** a user gives (``--spread hydraulic.bulk_modulus=20%``): each parameter
  independently normal about its nominal value, standard deviation 20 % of it (or an absolute
  value in the parameter's unit: ``--spread hydraulic.command_delay=0.002``), truncated at ±3σ and,
  for a parameter whose nominal value is positive, above 5 % of it (a bulk modulus, a stiffness or a
  mass cannot reach zero); one whose nominal value is 0 (a delay, a damping, a dead band) stays at or
  above 0, so an absolute spread about 0 is drawn from the half-normal;
* **a calibration's covariance** (``--covariance calibration.json``, written by ``samii calibrate
  --out``): what the data could not pin down. The calibrated parameters jointly normal with their
  standard errors and correlations, about the calibrated values; a draw outside the calibration's
  bounds or the positivity limit above is drawn again.

Every draw is made up front from one ``numpy`` generator seeded with ``--seed``, in sample order,
so the same seed gives the same plants whatever engine or number of workers runs them.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from samii.errors import InputError

__all__ = ["Spread", "Covariance", "parse_spread", "read_covariance", "draw_plants", "PlantDraws", "TRUNCATE_SIGMA", "MIN_FRACTION"]

TRUNCATE_SIGMA = 3.0  #: draws beyond this many standard deviations are drawn again
MIN_FRACTION = 0.05  #: a positive parameter stays above this fraction of its nominal value
_MAX_REDRAWS = 1000
_DISCRETE = {"beam.n_segments": "the number of beam elements", "beam.accel_body_fixed": "a 0/1 switch", "beam.pitch_deg": "the beam's orientation",
             "arm.heading_deg": "the arm's heading", "timestep_s": "the simulation step"}


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
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"--covariance {path}: no such file") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"--covariance {path}: not readable JSON ({exc})") from None
    params, corr, nominal = d.get("parameters"), d.get("correlation"), d.get("calibrated_params")
    if not isinstance(params, list) or not params or not isinstance(corr, list) or not isinstance(nominal, dict):
        raise InputError(f"--covariance {path}: expected samii calibrate's calibration.json (fields 'parameters', 'correlation', "
                         "'calibrated_params')")
    names, mean, se, bounds = [], [], [], []
    for i, p in enumerate(params):
        try:
            names.append(str(p["name"]))
            mean.append(float(p["value"]))
            s = p["stderr"]
            lo, hi = (float(b) for b in p.get("bounds", [-math.inf, math.inf])[:2])
        except (KeyError, TypeError, ValueError):
            raise InputError(f"--covariance {path}: field 'parameters'[{i}] lacks a name, value, stderr or bounds") from None
        if s is None or not math.isfinite(float(s)) or float(s) <= 0:
            raise InputError(f"--covariance {path}: parameter {names[-1]} has no finite standard error ({s!r}): the calibration could not "
                             "determine it; calibrate without it, or give its spread with --spread")
        se.append(float(s))
        bounds.append((lo, hi))
    c = np.asarray(corr, dtype=float) if all(isinstance(r, list) for r in corr) else np.empty(0)
    if c.shape != (len(names), len(names)) or not np.all(np.isfinite(c)):
        raise InputError(f"--covariance {path}: field 'correlation' must be a finite {len(names)}x{len(names)} matrix")
    s = np.asarray(se)
    cov = c * np.outer(s, s)
    cov = 0.5 * (cov + cov.T)
    if np.min(np.linalg.eigvalsh(cov)) < -1e-9 * np.max(np.abs(np.diag(cov))):
        raise InputError(f"--covariance {path}: the correlation matrix is not positive semi-definite")
    return Covariance(str(path), tuple(names), np.asarray(mean), cov, tuple(bounds), nominal)


@dataclass(frozen=True)
class PlantDraws:
    """The drawn plants: ``values[i, j]`` is parameter ``names[j]`` in sample ``i``."""

    names: tuple[str, ...]
    nominal: np.ndarray
    values: np.ndarray
    sources: tuple[str, ...]  #: how each parameter was drawn (for the report)

    def overrides(self, i: int) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, self.values[i])}


def _lower_limit(nominal: float) -> float:
    """A positive quantity stays above 5 % of its nominal; one nominally 0 (a delay, a damping, a dead band) stays
    non-negative (an absolute spread about 0 becomes a half-normal); a negative one is not limited."""
    if nominal > 0:
        return MIN_FRACTION * nominal
    return 0.0 if nominal == 0 else -math.inf


def draw_plants(n: int, seed: int, nominal: dict[str, float], spreads: list[Spread], covariance: Covariance | None) -> PlantDraws:
    """``n`` plants: the covariance's parameters jointly, then each spread's, in that order, from one generator."""
    rng = np.random.default_rng(seed)
    names: list[str] = []
    cols: list[np.ndarray] = []
    sources: list[str] = []
    nominals: list[float] = []
    if covariance is not None:
        lo = np.array([max(b[0], _lower_limit(m)) for b, m in zip(covariance.bounds, covariance.mean)])
        hi = np.array([b[1] for b in covariance.bounds])
        se = np.sqrt(np.diag(covariance.cov))
        out = np.empty((n, len(covariance.names)))
        for i in range(n):
            for _ in range(_MAX_REDRAWS):
                x = rng.multivariate_normal(covariance.mean, covariance.cov, method="eigh")
                if np.all(x >= lo) and np.all(x <= hi) and np.all(np.abs(x - covariance.mean) <= TRUNCATE_SIGMA * se):
                    break
            else:
                raise InputError(f"--covariance {covariance.source}: no draw within the bounds in {_MAX_REDRAWS} tries")
            out[i] = x
        names += covariance.names
        cols += list(out.T)
        for m, (b_lo, b_hi), sd in zip(covariance.mean, covariance.bounds, se):
            edge = min(abs(m - b_lo), abs(b_hi - m)) < 1e-6 * max(abs(m), sd)
            sources.append(f"calibration covariance ({covariance.source})" + (": calibrated on its bound, so drawn on one side of it" if edge else ""))
        nominals += list(covariance.mean)
    for sp in spreads:
        if sp.name in names:
            raise InputError(f"--spread {sp.name}: already varied ({'given twice' if sp.name in [s.name for s in spreads[:spreads.index(sp)]] else 'by --covariance'})")
        if sp.name not in nominal:
            raise InputError(f"--spread {sp.name}: no such parameter (samii params lists them)")
        if sp.name in _DISCRETE:
            raise InputError(f"--spread {sp.name}: a discrete setting ({_DISCRETE[sp.name]}), not a physical quantity with a spread")
        mu = float(nominal[sp.name])
        sigma = sp.sigma(mu)
        if sigma <= 0:
            raise InputError(f"--spread {sp.describe()}: the nominal value is 0, so a relative spread is 0; give an absolute one")
        low = max(mu - TRUNCATE_SIGMA * sigma, _lower_limit(mu))
        col = np.empty(n)
        for i in range(n):
            for _ in range(_MAX_REDRAWS):
                x = rng.normal(mu, sigma)
                if low <= x <= mu + TRUNCATE_SIGMA * sigma:
                    break
            col[i] = x
        names.append(sp.name)
        cols.append(col)
        sources.append(sp.describe())
        nominals.append(mu)
    if not names:
        raise InputError("nothing to vary: give --spread NAME=P% and/or --covariance calibration.json")
    return PlantDraws(tuple(names), np.asarray(nominals), np.column_stack(cols), tuple(sources))
