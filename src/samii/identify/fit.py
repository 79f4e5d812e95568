"""Bounded least-squares fit of the notebook's models, with uncertainty and honest convergence.

The residual vector and its analytic Jacobian come from ``FitProblem``
(the notebook's cost); ``scipy.optimize.least_squares`` minimises it from
several starts: Levenberg-Marquardt, or trust-region reflective with the box
``BOUNDS`` when LM's answer leaves it. Internally positive parameters are
optimised as logarithms (positive by construction; the solver works in
relative steps) and gains as multiples of their start. Every start is first
moved onto the data's resonance peaks (``starts.snap_to_peaks``): a mode
frequency tens of percent off otherwise leads into the wrong basin.

Convergence is reported as the solver's status together with the notebook's
own test (every coefficient and the cost changing by less than 0.01 %),
applied to the solver's last two iterates, and with how many starts reached
the best cost.

Uncertainty: the covariance is the sandwich ``A J' V J A`` with
``A = (J'J)^-1``, which is right for the notebook's unweighted cost when the
noise is not the same at every point: ``V`` is the noise profile of
``FitProblem.noise_profile`` (from coherence where the data have it) scaled by
one factor estimated from the residuals, ``sum(r^2 / profile) / (m - n)``.
With exact weighting this reduces to the textbook ``s^2 (J'J)^-1``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Literal, Mapping, Sequence

import numpy as np

from samii.frequency_response import Channel, FrequencyResponse
from samii.identify.cost import FitProblem, Weighting
from samii.identify.notebook_loop import PercentChange, percent_change
from samii.identify.starts import auto_start, notebook_start, perturbed_start, snap_to_peaks
from samii.identify.structures import ModelStructure

__all__ = ["FitResult", "fit", "fit_problem", "BOUNDS"]

#: Physical sanity bounds (rad/s for frequencies and tau). Damping up to 5:
#: the notebook's own pw=0.5 fit reached z1 = 0.82 (eq 9.12), so it must be allowed.
BOUNDS = {"w": (1e-3, 1e6), "z": (1e-4, 5.0), "tau": (1e-2, 1e6)}
#: Thresholds of the identifiability warnings.
CORR_WARN = 0.99
REL_STDERR_WARN = 0.5
COND_WARN = 1e-7  # singular value / largest of the column-equilibrated relative-sensitivity Jacobian

#: Residual returned for a trial point where the model overflows (rejected by the solver).
_PENALTY = 1e8
#: Relative tolerances of the solver (cost, step, gradient).
_TOL = 1e-10

StartSpec = Literal["notebook", "auto", "both"] | Mapping[str, float]


def _bounds(structure: ModelStructure) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = [], []
    for n in structure.param_names:
        if n.startswith("B") or n == "K1":
            b = (-np.inf, np.inf)  # K1 is a log variable: positive without a bound
        elif n == "tau":
            b = tuple(np.log(BOUNDS["tau"]))
        elif n.startswith("z"):
            b = tuple(np.log(BOUNDS["z"]))
        else:
            b = tuple(np.log(BOUNDS["w"]))
        lo.append(b[0])
        hi.append(b[1])
    return np.array(lo), np.array(hi)


@dataclass(frozen=True, eq=False)  # holds arrays: compare by identity
class FitResult:
    """A fitted model with its uncertainty, quality and convergence report.

    Attributes
    ----------
    structure : ModelStructure
    params, stderr : mapping name -> float
        Estimates and standard errors (inf where not identifiable), notebook names.
    covariance, correlation : (n, n) arrays, ``structure.param_names`` order.
    cost : float
        The notebook's ``errout`` at the optimum (with the chosen weighting).
    rms_mag_db, rms_phase_deg : mapping channel -> float
        RMS model - data error per channel over the band (unweighted).
    converged : bool
        Solver status ok *and* the notebook's percent-change criterion met between the
        solver's last two iterates.
    message : str
    warnings : tuple of str
        Identifiability and bound warnings.
    """

    structure: ModelStructure
    params: Mapping[str, float]
    stderr: Mapping[str, float]
    covariance: np.ndarray
    correlation: np.ndarray
    cost: float
    rms_mag_db: Mapping[str, float]
    rms_phase_deg: Mapping[str, float]
    converged: bool
    message: str
    phase_weight: float
    band_hz: tuple[float, float]
    channels: tuple[str, ...]
    weighting: str
    n_points: int
    nfev: int
    starts: tuple[tuple[str, float, float], ...]
    notebook_criterion: PercentChange
    warnings: tuple[str, ...] = ()
    metadata: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))
        object.__setattr__(self, "stderr", MappingProxyType(dict(self.stderr)))
        object.__setattr__(self, "rms_mag_db", MappingProxyType(dict(self.rms_mag_db)))
        object.__setattr__(self, "rms_phase_deg", MappingProxyType(dict(self.rms_phase_deg)))
        object.__setattr__(self, "metadata", MappingProxyType(dict(self.metadata)))
        for a in ("covariance", "correlation"):
            v = np.array(getattr(self, a), float)
            v.setflags(write=False)
            object.__setattr__(self, a, v)

    # -- use ------------------------------------------------------------------------
    def response(self, freq_hz: np.ndarray, channel: Channel) -> np.ndarray:
        """Complex response of the fitted model."""
        return self.structure.response(self.params, freq_hz, channel)

    def tf(self, channel: Channel = "total"):
        """python-control TransferFunction of the fitted model."""
        return self.structure.to_tf(self.params, channel)

    def ss(self, channel: Channel = "total"):
        """python-control StateSpace (minimal) of the fitted model."""
        return self.structure.to_ss(self.params, channel)

    def interval(self, name: str, level: float = 0.95) -> tuple[float, float]:
        """Normal-approximation confidence interval of one parameter."""
        from scipy.stats import norm

        z = norm.ppf(0.5 + level / 2)
        return self.params[name] - z * self.stderr[name], self.params[name] + z * self.stderr[name]

    # -- report -----------------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-ready summary; the first keys are those of ``samii fit --json``."""

        def num(v: float):
            return float(v) if np.isfinite(v) else None

        names = self.structure.param_names
        return {
            "params": {k: float(v) for k, v in self.params.items()},
            "stderr": {k: num(v) for k, v in self.stderr.items()},
            "cost": float(self.cost),
            "rms_mag_db": {k: float(v) for k, v in self.rms_mag_db.items()},
            "rms_phase_deg": {k: float(v) for k, v in self.rms_phase_deg.items()},
            "converged": bool(self.converged),
            "message": self.message,
            "warnings": list(self.warnings),
            "structure": self.structure.to_dict(),
            "phase_weight": float(self.phase_weight),
            "band_hz": [float(b) for b in self.band_hz],
            "channels": list(self.channels),
            "weighting": self.weighting,
            "n_points": int(self.n_points),
            "nfev": int(self.nfev),
            "starts": [{"label": s[0], "start_cost": float(s[1]), "final_cost": float(s[2])} for s in self.starts],
            "notebook_criterion": {
                "max_param_pct": float(self.notebook_criterion.max_param_pct),
                "cost_pct": float(self.notebook_criterion.cost_pct),
                "met": self.notebook_criterion.met,
            },
            "correlation": {"names": list(names), "matrix": [[num(v) for v in row] for row in self.correlation]},
            "metadata": dict(self.metadata),
        }

    def to_json(self, **kwargs) -> str:
        return json.dumps(self.to_dict(), **kwargs)

    def table(self) -> str:
        """Plain-text parameter table: value, standard error, relative error."""
        lines = [f"{'name':>5} {'value':>13} {'stderr':>11} {'rel':>8}"]
        for n in self.structure.param_names:
            v, e = self.params[n], self.stderr[n]
            rel = abs(e / v) if v != 0 else np.inf
            lines.append(f"{n:>5} {v:13.6g} {e:11.3g} {100 * rel:7.3g}%")
        return "\n".join(lines)


def _to_z(structure: ModelStructure, x: np.ndarray, scale: np.ndarray) -> np.ndarray:
    pos = structure.positive
    return np.where(pos, np.log(np.where(pos, x, 1.0)), x / scale)


def _from_z(structure: ModelStructure, z: np.ndarray, scale: np.ndarray) -> np.ndarray:
    pos = structure.positive
    return np.where(pos, np.exp(np.where(pos, z, 0.0)), z * scale)


def _solve(problem: FitProblem, x0: np.ndarray, *, max_nfev: int) -> tuple[np.ndarray, object, tuple[np.ndarray, float]]:
    """Levenberg-Marquardt (MINPACK) in log/scaled variables; trust-region reflective with the
    box ``BOUNDS`` if the unbounded answer leaves it (positivity already holds through the logs).

    LM first because its per-iteration overhead is a fraction of TRF's on these
    small dense problems; the bounds are still enforced. Also returns the last
    accepted iterate before the answer, with its cost (the solvers evaluate the
    Jacobian at every accepted point), for the notebook's percent-change test.
    """
    from scipy.optimize import least_squares

    st = problem.structure
    scale = np.where(st.positive, 1.0, np.where(x0 != 0, np.abs(x0), 1.0))
    dxdz_pos = st.positive
    lo, hi = _bounds(st)
    z0 = np.clip(_to_z(st, x0, scale), lo + 1e-9, hi - 1e-9)
    cache: dict = {}

    def evaluate(z):
        key = z.tobytes()
        if key not in cache:
            cache.clear()
            with np.errstate(all="ignore"):  # a trial step far outside: penalised below, step rejected
                x = _from_z(st, z, scale)
                r, j = problem.residuals_and_jacobian(x)
                j = j * np.where(dxdz_pos, x, scale)[None, :]
            if not (np.all(np.isfinite(r)) and np.all(np.isfinite(j))):
                r, j = np.full_like(r, _PENALTY), np.zeros_like(j)
            cache[key] = (r, j)
        return cache[key]

    def fun(z):
        return evaluate(z)[0]

    iterates: list[tuple[bytes, np.ndarray, float]] = []

    def jac(z):
        r, j = evaluate(z)
        iterates.append((z.tobytes(), _from_z(st, z, scale), float(r @ r)))
        return j

    tol = dict(ftol=_TOL, xtol=_TOL, gtol=_TOL, max_nfev=max_nfev)
    sol = least_squares(fun, z0, jac=jac, method="lm", **tol)
    if np.any(sol.x < lo) or np.any(sol.x > hi) or np.any(sol.fun == _PENALTY):
        iterates.clear()
        sol = least_squares(fun, z0, jac=jac, bounds=(lo, hi), method="trf", **tol)
    before = [(x, c) for key, x, c in iterates if key != sol.x.tobytes()]
    previous = before[-1] if before else (x0, problem.cost(x0))
    return _from_z(st, sol.x, scale), sol, previous


def _covariance(problem: FitProblem, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """Sandwich covariance, standard errors, correlations and identifiability warnings."""
    st = problem.structure
    names = st.param_names
    r, J = problem.residuals_and_jacobian(x)
    m, n = J.shape
    d = np.where(x != 0, np.abs(x), 1.0)
    Js = J * d[None, :]  # sensitivity to relative changes
    # eigen-decomposition of the small normal matrix, columns equilibrated first
    # (cheaper than an SVD of the tall Jacobian; the ratio test below is on singular values)
    cn = np.linalg.norm(Js, axis=0)
    cn = np.where(cn > 0, cn, 1.0)
    lam, V = np.linalg.eigh((Js / cn).T @ (Js / cn))
    lam = np.clip(lam, 0.0, None)
    s = np.sqrt(lam / lam[-1])
    warnings: list[str] = []
    ok = s > COND_WARN
    A = ((V[:, ok] / lam[ok]) @ V[:, ok].T) / np.outer(cn, cn)  # pseudo-inverse of Js'Js
    profile = problem.noise_profile()
    c = float(np.sum(r**2 / profile) / max(m - n, 1))
    meat = (Js * (c * profile)[:, None]).T @ Js
    cov_s = A @ meat @ A
    cov = cov_s * np.outer(d, d)
    stderr = np.sqrt(np.clip(np.diag(cov), 0, None))
    for k in np.flatnonzero(~ok):
        v = V[:, k]
        involved = [names[i] for i in np.argsort(np.abs(v))[::-1] if abs(v[i]) > 0.3]
        warnings.append(f"not identifiable from these data: only a combination of {', '.join(involved)} is determined (relative singular value {s[k]:.1e})")
        stderr[[names.index(p) for p in involved]] = np.inf
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(stderr, stderr)
    corr[~np.isfinite(corr)] = np.nan
    np.fill_diagonal(corr, 1.0)
    for i in range(n):
        for j in range(i + 1, n):
            if np.isfinite(corr[i, j]) and abs(corr[i, j]) > CORR_WARN:
                warnings.append(f"{names[i]} and {names[j]} are strongly correlated (r = {corr[i, j]:+.4f}): the band barely separates them")
    for i, p in enumerate(names):
        if np.isfinite(stderr[i]) and x[i] != 0 and stderr[i] / abs(x[i]) > REL_STDERR_WARN:
            warnings.append(f"{p} = {x[i]:.4g} is poorly determined (standard error {100 * stderr[i] / abs(x[i]):.0f} %)")
    return cov, stderr, corr, warnings


def _band_warnings(problem: FitProblem, params: Mapping[str, float]) -> list[str]:
    lo, hi = problem.data.freq_hz[0], problem.data.freq_hz[-1]
    out = []
    for n, v in params.items():
        if (n.startswith("w") or n == "tau") and not lo <= v / (2 * np.pi) <= hi:
            out.append(f"{n} = {v:.4g} rad/s ({v / (2 * np.pi):.3g} Hz) lies outside the fitted band {lo:.3g}-{hi:.3g} Hz: only its tail is seen")
    lz, hz = BOUNDS["z"]
    for n, v in params.items():
        if n.startswith("z") and (v < 1.01 * lz or v > 0.99 * hz):
            out.append(f"{n} = {v:.4g} is at its bound {BOUNDS['z']}")
    return out


def fit_problem(problem: FitProblem, *, start: StartSpec = "both", n_perturbed: int = 2, rng: np.random.Generator | None = None, max_nfev: int = 200) -> FitResult:
    """Fit a prepared ``FitProblem``; see ``fit``."""
    st = problem.structure
    starts: list[tuple[str, dict]] = []
    if isinstance(start, str):
        if start not in ("notebook", "auto", "both"):
            raise ValueError(f"start must be 'notebook', 'auto', 'both' or a parameter mapping, got {start!r}")
        if start in ("notebook", "both"):
            starts.append(("notebook", snap_to_peaks(problem, notebook_start(problem))))
        if start in ("auto", "both"):
            starts.append(("auto", auto_start(problem)))
    else:
        starts.append(("given", snap_to_peaks(problem, st.params(st.vector(start)))))
    runs = []
    for label, p in starts:
        x0 = st.vector(p)
        x, sol, prev = _solve(problem, x0, max_nfev=max_nfev)
        runs.append((label, problem.cost(x0), problem.cost(x), x, sol, prev))
    if n_perturbed:
        rng = rng if rng is not None else np.random.default_rng(0)
        best = min(runs, key=lambda r: r[2])
        for k in range(n_perturbed):
            p = perturbed_start(problem, st.params(best[3]), rng=rng)
            x0 = st.vector(p)
            x, sol, prev = _solve(problem, x0, max_nfev=max_nfev)
            runs.append((f"perturbed {k + 1} of {best[0]}", problem.cost(x0), problem.cost(x), x, sol, prev))
    label, _, cost, x, sol, (x_prev, cost_prev) = min(runs, key=lambda r: r[2])
    nfev = sum(int(r[4].nfev) for r in runs)
    # the notebook's criterion, for comparison, between the solver's last two iterates (the
    # notebook compared successive 500-iteration loops); rounding floor of the cost: an RMS
    # residual of 1e-6 dB (or weighted deg), i.e. an exact fit to data stored with ~10 digits
    crit = percent_change(x_prev, x, cost_prev, cost, cost_floor=1e-12 * problem.n_residuals)
    agree = sum(1 for r in runs if r[2] <= cost * (1 + 1e-6) + 1e-12)
    solver_ok = bool(sol.status > 0)
    converged = solver_ok and crit.met and np.isfinite(cost)
    message = f"best of {len(runs)} starts ({label}; {agree} reached it): solver: {sol.message} {crit.describe()}."
    cov, stderr, corr, warnings = _covariance(problem, x)
    params = st.params(x)
    warnings += _band_warnings(problem, params)
    errs = problem.errors(x)
    rms_m = {c: float(np.sqrt(np.mean(e[0] ** 2))) for c, e in errs.items()}
    rms_p = {c: float(np.sqrt(np.mean(e[1] ** 2))) for c, e in errs.items()}
    f = problem.data.freq_hz
    return FitResult(
        structure=st,
        params=params,
        stderr=dict(zip(st.param_names, map(float, stderr))),
        covariance=cov,
        correlation=corr,
        cost=float(cost),
        rms_mag_db=rms_m,
        rms_phase_deg=rms_p,
        converged=bool(converged),
        message=message,
        phase_weight=float(problem.phase_weight),
        band_hz=(float(f[0]), float(f[-1])),
        channels=tuple(problem.channels),
        weighting=problem.weighting,
        n_points=int(f.size),
        nfev=nfev,
        starts=tuple((r[0], float(r[1]), float(r[2])) for r in runs),
        notebook_criterion=crit,
        warnings=tuple(warnings),
        metadata=dict(problem.data.metadata),
    )


def fit(
    data: FrequencyResponse,
    structure: ModelStructure | None = None,
    *,
    phase_weight: float = 0.1,
    band_hz: tuple[float, float] | None = None,
    channels: Sequence[Channel] | None = None,
    weighting: Weighting = "none",
    start: StartSpec = "both",
    n_perturbed: int = 2,
    rng: np.random.Generator | None = None,
    max_nfev: int = 200,
) -> FitResult:
    """Fit one of the notebook's model structures to frequency-response data.

    Parameters
    ----------
    data : FrequencyResponse
    structure : ModelStructure, optional
        Default: the 3-mode s^4 model of eq 9.1/9.2.
    phase_weight : float
        Weight of the phase error in degrees (chapter 9; 0.1 gave eq 9.4).
    band_hz : (lo, hi), optional
        Fit band (eq 1.4 used 1-12 Hz). Default: all points.
    channels : sequence, optional
        Default ``("act", "base")`` as the notebook.
    weighting : {"none", "coherence"}
        ``"none"`` is the notebook's cost; ``"coherence"`` weights points by their
        expected random error (see ``samii.identify.cost``).
    start : "notebook", "auto", "both" or mapping
        Where the solver starts (``samii.identify.starts``): notebook frequencies
        and dampings with gains read off the data, a start read off the data
        alone, both, or given parameters.
    n_perturbed : int
        Extra starts around the best result so far (frequencies, dampings and tau
        scaled by exp(0.2 N(0,1)), gains re-solved).
    rng : numpy Generator, optional
        For the perturbed starts (default: seed 0, so a fit is reproducible).

    Returns
    -------
    FitResult

    Examples
    --------
    >>> import numpy as np
    >>> from samii import notebook as nb
    >>> from samii.identify import ModelStructure, fit, synthesize
    >>> st = ModelStructure.notebook_3mode()
    >>> f = np.geomspace(0.1, 40, 300)
    >>> data = synthesize(f, {c: st.response(nb.EQ9_4, f, c) for c in ("act", "base")}, noise=None)
    >>> res = fit(data, st, phase_weight=0.1)
    >>> round(res.params["w1"], 3)
    10.886
    """
    structure = structure or ModelStructure.notebook_3mode()
    problem = FitProblem(data, structure, phase_weight=phase_weight, band_hz=band_hz, channels=None if channels is None else tuple(channels), weighting=weighting)
    return fit_problem(problem, start=start, n_perturbed=n_perturbed, rng=rng, max_nfev=max_nfev)
