"""Bounded least-squares fit of the notebook's models, with uncertainty and honest convergence.

The residual vector and its analytic Jacobian come from ``FitProblem``
(the notebook's cost); it is minimised from several starts by
Levenberg-Marquardt on the normal equations (``_levenberg_marquardt``:
MINPACK's scaling and stopping tests, without its QR of the tall Jacobian,
which dominated the fit time), or by ``scipy.optimize.least_squares``'s
trust-region reflective method with the box ``BOUNDS`` when LM's answer leaves it. Internally positive parameters are
optimised as logarithms (positive by construction; the solver works in
relative steps) and gains as multiples of their start. Every start is first
moved onto the data's resonance peaks (``starts.snap_to_peaks``): a mode
frequency tens of percent off otherwise leads into the wrong basin.

Many points (an FFT's thousands of lines): the starts are searched on every
k-th point, at most ``SEARCH_POINTS`` = 1000 (``FitProblem.thinned``), and the
best is refined on all points, so a fit's time grows linearly with the points
(benchmarks/fit_scale.py). Convergence, uncertainty and lack of fit are those of
all points.

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
Checked by seeded trials (tests/test_identify_fit.py, fits started 30 % off
the truth under 3-average swept-sine noise): the 95 % intervals covered the
truth at a rate of 0.965 for eq 9.4 (502 of 40 trials x 13 parameters) and
0.953 for eq 1.4 over 1-12 Hz (381 of 40 x 10); nominal 0.95.

Lack of fit: a converged fit can still miss the data. ``FitResult.lack_of_fit``
compares the residuals with the random error the coherence predicts and names
the bands where they are many times larger (``samii.identify.lack_of_fit``);
each band is also a warning.

Channels: only the parameters the fitted channels depend on are fitted
(``FitProblem.fitted``); with theta/v alone the base's modes and gains are
reported as not fitted (NaN here, null in JSON), with xdd/theta alone K1, wp,
zp and tau.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Literal

import numpy as np

from samii.frequency_response import Channel, FrequencyResponse
from samii.identify.concerns import Finding
from samii.identify.cost import FitProblem, Weighting, thinning_step
from samii.identify.lack_of_fit import (
    MIN_COHERENCE,
    ROUGHNESS_LAG,
    LackOfFit,
    averages_from_metadata,
    lack_of_fit,
    noise_only,
    refuse_noise,
    roughness_variance,
)
from samii.identify.notebook_loop import NOTEBOOK_TOL_PCT, PercentChange, percent_change
from samii.identify.profile import Profile, interval_text, profile_scan
from samii.identify.starts import auto_start, modes_from_total, notebook_start, perturbed_start, scan_modes, snap_to_peaks
from samii.identify.structures import ModelStructure
from samii.json_output import dumps
from samii.progress import SILENT, Progress, part

__all__ = ["FitResult", "check_not_noise", "fit", "fit_problem", "profile_names", "resolve_weighting", "BOUNDS"]

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

#: Starts are searched on at most this many frequency points (every k-th point of larger data,
#: ``FitProblem.thinned``); the best is then refined on all points. Keeps a fit's cost linear in
#: the number of points (the searches cost as much as for 1000 points, the refinement a few
#: iterations on all of them) and the peak-picking of the starts at the resolution it was made for.
SEARCH_POINTS = 1000
#: Relative tolerance of a profile point's solve: its cost, about m squared standard errors (m
#: residuals), is then known to a small fraction of one (``samii.identify.profile``).
PROFILE_TOL = 1e-6
#: A profile that finds a cost this many squared standard errors below the fit's (the 0.999 quantile of chi-square
#: on one degree of freedom) shows that the fit's value lies outside its own 99.9 % profile interval: the fit is not
#: the minimum of its cost along that parameter, and its parameters are not to be used (a concern). Less is a
#: warning: the estimate is off by less than its uncertainty. A rig-era .mat of theta/v alone without coherence,
#: fitted by the notebook's unweighted cost, ended at wp 19.5 Hz (the rig's: 8.3) with its profile 92 lower at 34 Hz
#: and was called "a sound fit with caveats".
PROFILE_BELOW_CONCERN = 10.83  # scipy.stats.chi2.isf(1e-3, 1) = 10.828 (tests/test_identify_profile.py)
#: The level of a 3-standard-error interval, erf(3 / sqrt(2)): the fit's JSON gives each profile's interval at it and at 95 %.
PROFILE_3SIGMA = math.erf(3 / math.sqrt(2))


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
        solver's last two iterates. Says nothing about whether the model describes
        the data: see ``lack_of_fit``.
    message : str
    warnings : tuple of str
        Lack-of-fit, identifiability and bound warnings.
    lack_of_fit : LackOfFit or None
        Bands where the residuals exceed the data's random error (``samii.identify.lack_of_fit``).
    not_fitted : tuple of str
        Parameters no fitted channel depends on: NaN in ``params`` and ``stderr``.
    starts : tuple of (label, start cost, final cost)
        Every start solved; on data thinned for the search (more than
        ``SEARCH_POINTS`` points) the costs are those of the search points.
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
    lack_of_fit: LackOfFit | None = None
    not_fitted: tuple[str, ...] = ()
    #: Why the fit's parameters should not be used even if converged, each with what to try (a
    #: parameter put where no reading of the data would: a damping on its bound, modes out of their
    #: order, two modes on one resonance, a mode in the noise below modes the data place), as
    #: :class:`samii.identify.concerns.Finding` (a code, its figures, what to try; ``.text`` words it).
    concerns: tuple[Finding, ...] = ()
    #: What to know before using them, each with what to try: a mode the data do not determine
    #: (outside the band, in the noise above the modes the data place, no resonant peak: its
    #: parameters are in ``undetermined``), residuals far above the noise in bands (the structure
    #: misses an effect there). :class:`samii.identify.concerns.Finding` as ``concerns``.
    caveats: tuple[Finding, ...] = ()
    #: Parameters the data do not determine (named in ``caveats``): not to be used.
    undetermined: tuple[str, ...] = ()
    #: Profiles of the frequencies (``samii.identify.profile``): each held away from its estimate with
    #: the others re-solved; ``interval`` reads its intervals from them.
    profiles: Mapping[str, Profile] = field(default_factory=dict)

    @property
    def sound(self) -> bool:
        """Converged and nothing in ``concerns``: the parameters can be used (but ``undetermined``)."""
        return self.converged and not self.concerns

    @property
    def verdict(self) -> str:
        """``"sound"``, ``"caveats"`` (sound, with caveats to read) or ``"not sound"`` (converged or not:
        the parameters should not be used)."""
        return "not sound" if not self.sound else ("caveats" if self.caveats else "sound")

    def __post_init__(self) -> None:
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))
        object.__setattr__(self, "stderr", MappingProxyType(dict(self.stderr)))
        object.__setattr__(self, "rms_mag_db", MappingProxyType(dict(self.rms_mag_db)))
        object.__setattr__(self, "rms_phase_deg", MappingProxyType(dict(self.rms_phase_deg)))
        object.__setattr__(self, "metadata", MappingProxyType(dict(self.metadata)))
        object.__setattr__(self, "profiles", MappingProxyType(dict(self.profiles)))
        for a in ("covariance", "correlation"):
            v = np.array(getattr(self, a), float)
            v.setflags(write=False)
            object.__setattr__(self, a, v)

    # -- use ------------------------------------------------------------------------
    def _params_for(self, channel: Channel) -> dict[str, float]:
        """Parameters to evaluate ``channel`` with; ValueError if it needs a parameter not fitted."""
        missing = [n for n in self.structure.channel_params((channel,)) if n in self.not_fitted]
        if missing:
            raise ValueError(
                f"channel {channel!r} cannot be evaluated: {', '.join(missing)} were not fitted (the fit saw only {', '.join(self.channels)})"
            )
        return {n: (1.0 if n in self.not_fitted else v) for n, v in self.params.items()}  # placeholders never enter the channel

    def response(self, freq_hz: np.ndarray, channel: Channel) -> np.ndarray:
        """Complex response of the fitted model."""
        return self.structure.response(self._params_for(channel), freq_hz, channel)

    def tf(self, channel: Channel = "total"):
        """python-control TransferFunction of the fitted model."""
        return self.structure.to_tf(self._params_for(channel), channel)

    def ss(self, channel: Channel = "total"):
        """python-control StateSpace (minimal) of the fitted model."""
        return self.structure.to_ss(self._params_for(channel), channel)

    def interval(self, name: str, level: float = 0.95) -> tuple[float, float]:
        """Confidence interval of one parameter: its profile's where it was profiled (``profiles``;
        lopsided where the cost is, ending at the scan's end where the data do not bound it), else
        ``value +- z SE`` (normal approximation)."""
        from scipy.stats import norm  # (lazy: imports scipy, only when called)

        if name in self.profiles:
            return self.profiles[name].interval(level)

        z = norm.ppf(0.5 + level / 2)
        return self.params[name] - z * self.stderr[name], self.params[name] + z * self.stderr[name]

    # -- report -----------------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-ready summary; the first keys are those of ``samii fit --json``.

        A number that is not defined is None (null in JSON): ``params`` and
        ``stderr`` of a parameter not fitted, the ``stderr`` of a parameter the
        data do not determine (infinite; a warning names it), a correlation
        with such a parameter. ``to_json`` makes every other non-finite number null too.
        """

        def num(v: float):
            return float(v) if np.isfinite(v) else None

        names = self.structure.param_names
        return {
            "params": {k: num(v) for k, v in self.params.items()},
            "stderr": {k: num(v) for k, v in self.stderr.items()},
            "cost": num(self.cost),
            "rms_mag_db": {k: float(v) for k, v in self.rms_mag_db.items()},
            "rms_phase_deg": {k: float(v) for k, v in self.rms_phase_deg.items()},
            "converged": bool(self.converged),
            "sound": bool(self.sound),
            "verdict": self.verdict,
            "concerns": [c.text for c in self.concerns],
            "caveats": [c.text for c in self.caveats],
            "findings": {"concerns": [c.to_dict() for c in self.concerns], "caveats": [c.to_dict() for c in self.caveats]},
            "undetermined": list(self.undetermined),
            "profile_intervals": {k: p.to_dict((0.95, PROFILE_3SIGMA)) for k, p in self.profiles.items()},
            "message": self.message,
            "warnings": list(self.warnings),
            "not_fitted": list(self.not_fitted),
            "lack_of_fit": None if self.lack_of_fit is None else self.lack_of_fit.to_dict(),
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
        """Strict JSON of ``to_dict`` (RFC 8259: non-finite numbers are null, never NaN or Infinity)."""

        return dumps(self.to_dict(), **kwargs)

    def table(self) -> str:
        """Plain-text parameter table: value, standard error, relative error and, for a profiled
        parameter, its 95 % profile interval (``profile.interval_text``: an open side, which the data
        do not bound, as ``≥ lo`` or ``≤ hi``); a frequency (rad/s inside, in ``params``) shown in Hz as
        ``w/2pi``, as every user-facing number in samii is."""
        units = self.structure.units()
        profiled = bool(self.profiles)
        lines = [f"{'name':>8} {'value':>13} {'stderr':>11} {'rel':>8}  " + (f"{'95 % profile interval':>23}  " if profiled else "") + "unit"]
        for n in self.structure.param_names:
            v, e, unit, name = self.params[n], self.stderr[n], units[n], n
            if n in self.not_fitted:
                lines.append(f"{name:>8} {'not fitted':>13}")
                continue
            rel = abs(e / v) if v != 0 else np.inf
            k = 2 * np.pi if unit == "rad/s" else 1.0
            if unit == "rad/s":
                v, e, unit, name = v / k, e / k, "Hz", f"{n}/2pi"
            cell = ""
            if n in self.profiles:
                (lo, hi), (blo, bhi) = self.profiles[n].interval(0.95), self.profiles[n].bounded(0.95)
                cell = interval_text(lo / k if blo else None, hi / k if bhi else None)
            lines.append(f"{name:>8} {v:13.6g} {e:11.3g} {100 * rel:7.3g}%  " + (f"{cell:>23}  " if profiled else "") + unit)
        return "\n".join(lines)


def _to_z(pos: np.ndarray, x: np.ndarray, scale: np.ndarray) -> np.ndarray:
    return np.where(pos, np.log(np.where(pos, x, 1.0)), x / scale)


def _from_z(pos: np.ndarray, z: np.ndarray, scale: np.ndarray) -> np.ndarray:
    return np.where(pos, np.exp(np.where(pos, z, 0.0)), z * scale)


#: Messages of the solver's stopping tests (worded as scipy.optimize.least_squares words them).
_TERMINATION = {
    -1: "No step could be computed (damping overflowed).",
    0: "The maximum number of function evaluations is exceeded.",
    1: "`gtol` termination condition is satisfied.",
    2: "`ftol` termination condition is satisfied.",
    3: "`xtol` termination condition is satisfied.",
    4: "Both `ftol` and `xtol` termination conditions are satisfied.",
}


@dataclass(frozen=True, eq=False)
class _Solution:
    """What ``_levenberg_marquardt`` returns (the fields of scipy's OptimizeResult that are used)."""

    x: np.ndarray
    fun: np.ndarray
    status: int
    message: str
    nfev: int


def _levenberg_marquardt(
    evaluate, z0: np.ndarray, *, ftol: float, xtol: float, gtol: float, max_nfev: int, on_accept=None, small_step=None
) -> _Solution:
    """Levenberg-Marquardt on the normal equations, with MINPACK's scaling and stopping tests.

    ``evaluate(z) -> (r, J'J, J'r, ...)``: the solver needs the Jacobian J only
    through these (n x n and n), so the caller may form them without keeping a
    scaled copy of J. Each step solves ``(J'J + mu D) h = -J'r``
    with ``D`` the running maximum of diag(J'J) (MINPACK's scaling, so the
    step does not depend on the units of z); ``mu`` follows Nielsen's update
    (Madsen, Nielsen & Tingleff, *Methods for non-linear least squares
    problems*, 2004, sec. 3.2). Stopping tests as MINPACK ``lmder`` (Moré et
    al. 1980): ``ftol`` on the actual and predicted relative reduction of the
    cost, ``xtol`` on the scaled step relative to the scaled z, ``gtol`` on the
    largest cosine between r and a column of J. Forming J'J (n x n) costs
    O(m n^2) in BLAS, against MINPACK's unblocked QR of the m x n Jacobian at
    every iteration, which dominated the fit time (m = 1600, n = 13).
    ``on_accept(z, cost)`` is called at every accepted iterate, the start included.
    ``small_step(z_old, z_new)``, if given, must also hold for the last accepted
    step before the ``ftol`` and ``xtol`` tests may stop (the notebook's
    percent-change test: a direction the data barely determine can still move
    after the cost has settled).
    """
    z = np.array(z0, float)
    r, A, g = evaluate(z)[:3]
    nfev = 1
    cost = float(r @ r)
    if on_accept:
        on_accept(z, cost)
    D = np.maximum(np.diag(A).copy(), np.finfo(float).tiny)
    mu, nu = 1e-3, 2.0
    status = 0
    last_small = True  # the last accepted step met small_step (no step yet: the start vs itself)
    while nfev < max_nfev:
        col = np.sqrt(np.diag(A))
        with np.errstate(divide="ignore", invalid="ignore"):
            gcos = np.where(col > 0, np.abs(g) / (col * np.sqrt(cost)), 0.0) if cost > 0 else np.zeros_like(g)
        if np.max(gcos, initial=0.0) <= gtol:
            status = 1
            break
        M = A.copy()
        M[np.diag_indices_from(M)] += mu * D
        try:
            with np.errstate(all="ignore"):
                h = np.linalg.solve(M, -g)
        except np.linalg.LinAlgError:
            h = np.full_like(g, np.nan)
        if not np.all(np.isfinite(h)):
            if mu > 1e300 or not np.isfinite(mu):
                status = -1
                break
            mu, nu = mu * nu, nu * 2
            continue
        dn = np.sqrt(D)
        step_small = np.linalg.norm(dn * h) <= xtol * (np.linalg.norm(dn * z) + xtol)
        z_new = z + h
        r_new, A_new, g_new = evaluate(z_new)[:3]
        nfev += 1
        cost_new = float(r_new @ r_new)
        pred = float(-(2 * h @ g + h @ A @ h))  # cost - |r + J h|^2
        actual = cost - cost_new
        rho = actual / pred if pred > 0 else -1.0
        f_small = pred <= ftol * cost and abs(actual) <= ftol * cost and rho <= 2
        if rho > 0:
            last_small = small_step is None or small_step(z, z_new)
            z, r, A, g, cost = z_new, r_new, A_new, g_new, cost_new
            if on_accept:
                on_accept(z, cost)
            D = np.maximum(D, np.diag(A))
            mu *= max(1 / 3, 1 - (2 * rho - 1) ** 3)
            nu = 2.0
        else:
            mu, nu = mu * nu, nu * 2
        if (f_small or step_small) and (last_small or (rho <= 0 and step_small)):
            # a rejected step below xtol: no further progress is possible, stop whatever small_step says
            status = 4 if (f_small and step_small) else (2 if f_small else 3)
            break
    return _Solution(z, r, status, _TERMINATION[status], nfev)


def _solve(
    problem: FitProblem,
    x0: np.ndarray,
    *,
    max_nfev: int,
    on_evaluation: Callable[[int], None] | None = None,
    hold: Sequence[str] = (),
    tol: float = _TOL,
) -> tuple[np.ndarray, object, tuple[np.ndarray, float], tuple[np.ndarray, np.ndarray]]:
    """Levenberg-Marquardt (``_levenberg_marquardt``) in log/scaled variables; scipy's
    trust-region reflective with the box ``BOUNDS`` if the unbounded answer leaves it
    (positivity already holds through the logs).

    Only the parameters in ``problem.fitted`` move; the others keep their values in ``x0``.
    LM first because its per-iteration overhead is a fraction of TRF's on these
    small dense problems; the bounds are still enforced. LM stops on ``ftol`` or
    ``xtol`` only once its step also meets the notebook's percent-change test
    (with a factor 2 of margin). Also returns the last
    accepted iterate before the answer, with its cost (the solvers evaluate the
    Jacobian at every accepted point), for the notebook's percent-change test,
    and the residuals and Jacobian (fitted columns) at the answer.
    ``on_evaluation(k)`` is called before the k-th evaluation of the model (progress of long solves).
    ``hold``: names of fitted parameters kept at their values in ``x0`` too (a profile's fixed parameter).
    ``tol``: the relative tolerances of cost, step and gradient; above ``_TOL`` (a profile's points, whose
    cost is read to a fraction of a squared standard error) the notebook's percent-change test is not applied.
    """
    from scipy.optimize import least_squares  # (lazy: imports scipy, only when called)

    st = problem.structure
    free = problem.fitted & ~np.isin(st.param_names, list(hold))
    x0 = np.asarray(x0, float)
    pos = st.positive[free]
    xf0 = x0[free]
    scale = np.where(pos, 1.0, np.where(xf0 != 0, np.abs(xf0), 1.0))
    lo, hi = (b[free] for b in _bounds(st))
    z0 = np.clip(_to_z(pos, xf0, scale), lo + 1e-9, hi - 1e-9)
    cache: dict = {}

    def full(z):
        x = x0.copy()
        x[free] = _from_z(pos, z, scale)
        return x

    ix = np.ix_(free, free)
    n_eval = [0]
    # the modes keep their order (mode k below mode k+1; mode 2 of the tied structure is the actuator zero):
    # a step that would carry one across another is rejected like one where the model overflows, so a mode
    # cannot leave the resonance it was started on for a floor of unmodelled response below the others
    order = st.mode_index[0][free[st.mode_index[0]]]
    keep_order = order.size > 1 and bool(np.all(np.diff(x0[order]) > 0))

    def evaluate(z):
        """(r, J'J, J'r) in the solver's variables z, the Jacobian J in x (all columns), dx/dz and whether the model was finite at ``z``.

        J'J and J'r are formed from J in x and scaled afterwards (n x n work instead of a scaled
        m x n copy): with many points the passes over J dominate a fit's time.
        """
        key = z.tobytes()
        if key not in cache:
            cache.clear()
            n_eval[0] += 1
            if on_evaluation is not None:
                on_evaluation(n_eval[0])
            with np.errstate(all="ignore"):  # a trial step far outside: penalised below, step rejected
                x = full(z)
                r, jx = problem.residuals_and_jacobian(x)
                d = np.where(pos, x[free], scale)  # dx/dz of the fitted parameters
                A = (jx.T @ jx)[ix] * np.outer(d, d)
                g = (jx.T @ r)[free] * d
            ok = bool(np.all(np.isfinite(r)) and np.all(np.isfinite(A)) and np.all(np.isfinite(g)))
            ok = ok and not (keep_order and np.any(np.diff(x[order]) <= 0))
            if not ok:
                r, A, g = np.full_like(r, _PENALTY), np.zeros_like(A), np.zeros_like(g)
            cache[key] = (r, A, g, jx, d, ok)
        return cache[key]

    def fun(z):
        return evaluate(z)[0]

    iterates: list[tuple[bytes, np.ndarray, float]] = []

    def jac(z):
        r, _, _, jx, d, ok = evaluate(z)
        iterates.append((z.tobytes(), full(z), float(r @ r)))
        return jx[:, free] * d[None, :] if ok else np.zeros((r.size, d.size))

    strict = tol <= _TOL
    tol = dict(ftol=tol, xtol=tol, gtol=tol, max_nfev=max_nfev)

    def small_step(za, zb):
        # the notebook's coefficient test (percent_change) on a step, with a factor 2 of margin, written
        # directly in the solver's variables (exp(h) - 1 for log parameters, h / z for scaled gains) so
        # that the inner loop builds no parameter vectors
        h = zb - za
        with np.errstate(all="ignore"):
            rel = np.where(pos, np.abs(np.expm1(h)), np.abs(h) / np.abs(za))
        return bool(100.0 * np.max(rel) < NOTEBOOK_TOL_PCT / 2)

    sol = _levenberg_marquardt(
        evaluate, z0, on_accept=lambda z, c: iterates.append((z.tobytes(), full(z), c)), small_step=small_step if strict else None, **tol
    )
    if np.any(sol.x < lo) or np.any(sol.x > hi) or np.any(sol.fun == _PENALTY):
        iterates.clear()
        sol = least_squares(fun, z0, jac=jac, bounds=(lo, hi), method="trf", **tol)
    before = [(x, c) for key, x, c in iterates if key != sol.x.tobytes()]
    previous = before[-1] if before else (x0, problem.cost(x0))
    r, _, _, jx, _, _ = evaluate(sol.x)  # cached: the solver's last evaluation is normally its answer
    return full(sol.x), sol, previous, (r, jx[:, free])


def _undetermined_warning(involved: Sequence[str], singular_value: float) -> str:
    """Warning for a direction of parameter space the data do not determine."""
    if len(involved) == 1:
        what = f"{involved[0]} is not determined by the data in the band"
    else:
        what = f"only a combination of {', '.join(involved)} is determined"
    return f"not identifiable from these data: {what} (relative singular value {singular_value:.1e})"


def _covariance(problem: FitProblem, x: np.ndarray, rj: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """Sandwich covariance, standard errors, correlations and identifiability warnings (``_sandwich``'s first four)."""
    return _sandwich(problem, x, rj)[:4]


def _sandwich(
    problem: FitProblem, x: np.ndarray, rj: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str], np.ndarray]:
    """Sandwich covariance, standard errors, correlations, identifiability warnings, and each parameter's
    profile scale: the cost's rise per squared standard error, ``SE_k^2 / [(J'J)^-1]_kk``
    (``samii.identify.profile``; with exact weights the residual variance ``s^2``), NaN where the
    standard error is not finite.

    ``rj``: residuals and Jacobian (fitted columns) at ``x``.
    Rows and columns of parameters not fitted are NaN.
    """
    st = problem.structure
    free = problem.fitted
    names = [n for n, f in zip(st.param_names, free) if f]
    r, J = rj
    xf = x[free]
    m, n = J.shape
    N = len(st.param_names)
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(r))):  # the model overflows at the answer: no uncertainty to give
        se_full = np.where(free, np.inf, np.nan)
        corr_full = np.full((N, N), np.nan)
        corr_full[np.ix_(free, free)] = np.eye(n)
        return (
            np.full((N, N), np.nan),
            se_full,
            corr_full,
            ["the model cannot be evaluated at the answer (it overflows): no standard errors"],
            np.full(N, np.nan),
        )
    d = np.where(xf != 0, np.abs(xf), 1.0)
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
        involved = [names[i] for i in np.argsort(np.abs(v))[::-1] if abs(v[i]) > 0.3] or [names[int(np.argmax(np.abs(v)))]]
        warnings.append(_undetermined_warning(involved, s[k]))
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
        if np.isfinite(stderr[i]) and xf[i] != 0 and stderr[i] / abs(xf[i]) > REL_STDERR_WARN:
            warnings.append(f"{p} = {xf[i]:.4g} is poorly determined (standard error {100 * stderr[i] / abs(xf[i]):.0f} %)")
    # the profile scale, SE^2 / [(J'J)^-1]_kk: in the relative variables both carry the same d_k^2
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(np.isfinite(stderr) & (np.diag(A) > 0), np.diag(cov_s) / np.diag(A), np.nan)
    # embed in the full parameter order, NaN where not fitted
    cov_full, corr_full, se_full, scale_full = np.full((N, N), np.nan), np.full((N, N), np.nan), np.full(N, np.nan), np.full(N, np.nan)
    ix = np.ix_(free, free)
    cov_full[ix], corr_full[ix], se_full[free], scale_full[free] = cov, corr, stderr, scale
    return cov_full, se_full, corr_full, warnings, scale_full


def profile_names(structure: ModelStructure) -> tuple[str, ...]:
    """The frequencies a fit profiles by default: wp, the zero and every base mode, in the structure's order."""
    return tuple(n for n in structure.param_names if n.startswith("w"))


def _profiles(
    problem: FitProblem, x: np.ndarray, cost: float, stderr: np.ndarray, scale: np.ndarray, names: Sequence[str], *, max_nfev: int
) -> tuple[dict[str, Profile], list[str], list[str]]:
    """Profiles of ``names`` at the minimum ``x`` of ``problem`` (its ``cost``; ``stderr`` and the profile
    ``scale`` of ``_sandwich``), a warning for each that found a lower cost, and a concern for each that found one
    more than PROFILE_BELOW_CONCERN squared standard errors lower (not beside another mode: a minimum the fit does
    not take).

    Scanned on all points: on data thinned as the search is, the thinned cost's own minimum lies
    about sqrt(k) standard errors from the full one's (it has 1/k of the information), and the
    profile read off it was up to 17 times too wide on 12,000 points (k = 12). A mode frequency
    stays between its neighbouring modes (the solver keeps them in order), every frequency within
    ``BOUNDS``. A parameter with no finite standard error is scanned at the
    residual variance ``cost / (m - n)``.
    """
    st = problem.structure
    free = problem.fitted
    s2 = cost / max(problem.n_residuals - int(free.sum()), 1)
    order = list(st.mode_index[0])
    wlo, whi = BOUNDS["w"]
    out, warnings, concerns = {}, [], []
    for name in names:
        i = st.param_names.index(name)
        if not free[i] or not np.isfinite(x[i]):
            continue

        def limits(xc: np.ndarray, i: int = i) -> tuple[float, float]:
            lo, hi = wlo, whi
            if i in order:
                j = order.index(i)
                lo = max(lo, xc[order[j - 1]] * 1.001) if j > 0 else lo
                hi = min(hi, xc[order[j + 1]] / 1.001) if j + 1 < len(order) else hi
            return lo, hi

        def solve(x0: np.ndarray, name: str = name) -> tuple[np.ndarray, float]:
            xs, sol, _, (r, _) = _solve(problem, x0, max_nfev=max_nfev, hold=(name,), tol=PROFILE_TOL)
            return xs, (float(r @ r) if np.all(r != _PENALTY) else np.nan)

        sigma2 = scale[i] if np.isfinite(scale[i]) and scale[i] > 0 else s2
        out[name] = p = profile_scan(name, x, i, cost, sigma2, float(stderr[i]), solve, limits)
        if p.lowest < -1.0:
            f_hz = p.lowest_at / (2 * np.pi)
            beside = [st.param_names[j] for j in order if j != i and abs(np.log(p.lowest_at / x[j])) < 0.02]
            where = (
                f" beside {beside[0]} = {x[st.param_names.index(beside[0])] / (2 * np.pi):.4g} Hz: two modes on one resonance, "
                "a minimum the fit does not take"
                if beside
                else f": the fit's minimum is not the lowest along {name}"
            )
            warnings.append(
                f"holding {name} at {f_hz:.4g} Hz, its profile found a cost {-p.lowest:.3g} squared standard errors below the fit's{where}"
            )
            if not beside and -p.lowest > PROFILE_BELOW_CONCERN:
                said = {"param": name, "held_hz": f_hz, "fit_hz": x[i] / (2 * np.pi), "below": -p.lowest}
                concerns.append(Finding("not_lowest", "start", said, (name,), ("other_starts",)))
    return out, warnings, concerns


def _band_warnings(problem: FitProblem, params: Mapping[str, float]) -> list[str]:
    lo, hi = problem.data.freq_hz[0], problem.data.freq_hz[-1]
    params = {n: v for n, v in params.items() if np.isfinite(v)}
    out = []
    for n, v in params.items():
        if (n.startswith("w") or n == "tau") and not lo <= v / (2 * np.pi) <= hi:
            out.append(f"{n}/2pi = {v / (2 * np.pi):.3g} Hz lies outside the fitted band {lo:.3g}-{hi:.3g} Hz: only its tail is seen")
    lz, hz = BOUNDS["z"]
    for n, v in params.items():
        if n.startswith("z") and (v < 1.01 * lz or v > 0.99 * hz):
            out.append(f"{n} = {v:.4g} is at its bound {BOUNDS['z']}")
    return out


#: Channels whose coherence tells whether a base mode was measured (the best of those fitted).
_MODE_CHANNELS = ("base", "total")


def _roughness_coherence(problem: FitProblem, params: Mapping[str, float]) -> dict[str, np.ndarray]:
    """For each fitted mode channel without coherence: the coherence a single estimate with the data's scatter about
    the fitted model would have, ``1/(1 + var)``, ``var`` the relative variance read off the roughness of the log
    residual (samii.identify.lack_of_fit.roughness_variance). A point whose scatter is as large
    as the response itself (var 1) reads 0.5, MIN_COHERENCE: there the data are noise. Without it a file without
    coherence (a rig-era .mat, a CSV without *_coh, one average) had no check of where its modes sit: a fit that put
    base mode 1 at 0.12 Hz in xdd/theta's noise and the hydraulic pair on mode 1 was called sound."""
    data = problem.data
    out = {}
    for c in _MODE_CHANNELS:
        if c not in problem.channels or data.coherence(c) is not None:
            continue
        with np.errstate(all="ignore"):
            e = np.log(data.response(c) / problem.structure.response(params, data.freq_hz, c))
        if e.size <= ROUGHNESS_LAG or not np.all(np.isfinite(e)):
            continue
        out[c] = 1.0 / (1.0 + roughness_variance(e))
    return out


def _resonance_coherence(
    problem: FitProblem, w: float, zeta: float, n_averages: int | None, rough: Mapping[str, np.ndarray] | None = None
) -> tuple[float, str, str] | None:
    """The best fitted channel's coherence over a base mode's half-power band, that channel, and where the coherence
    came from: "coherence" (the file's), "scatter" (a channel without one: ``rough``, :func:`_roughness_coherence`).

    A resonance the data measured raises the response, so the coherence around
    it is high. The band is +-zeta, at least +-10 % (8 points on a 100-per-decade
    grid: one point's coherence scatters too much to judge) and at most +-30 % (a
    broad term is judged near its centre). Where the response is noise alone, an
    estimate from n records is not 0 but Beta(1, n - 1) distributed (mean 1/n;
    above 0.9 at one point in a hundred for n = 3), and a fit that weights points
    by it is drawn to where it happens to be high. So the band's mean is
    corrected for that bias to first order, (n g - 1) / (n - 1), clipped at 0: 0
    for noise, 1 for a noise-free response (``n_averages`` None: as given).
    Only the channels the fit used count: a mode the accelerometer saw (high
    coherence in xdd/v) but theta did not (xdd/theta noise above the hydraulic
    resonance) is not determined by a fit of theta/v and xdd/theta.
    """
    data = problem.data
    f = data.freq_hz
    fz = w / (2 * np.pi)
    half = min(max(zeta if np.isfinite(zeta) else 0.0, 0.1), 0.3)
    dist = np.abs(np.log(f / fz))
    near = dist <= half
    if not near.any():
        near = dist == dist.min()
    g = {}
    for c in _MODE_CHANNELS:
        coh = data.coherence(c) if c in problem.channels else None
        if coh is not None:
            m = float(np.mean(coh[near]))
            g[c] = max((n_averages * m - 1) / (n_averages - 1), 0.0) if n_averages and n_averages > 1 else m
        elif rough and c in rough:  # (no averages behind it: no bias to correct)
            g[c] = float(np.mean(rough[c][near]))
    if not g:
        return None
    best = max(g, key=g.get)
    return g[best], best, "scatter" if rough and best in rough else "coherence"


def _unresolved_pairs(params: Mapping[str, float], structure: ModelStructure) -> list[tuple[str, str]]:
    """Pairs of base modes closer than the narrower one's half-power half-width (zeta w): one resonance, two modes.

    (Not the sum of the half-widths: a broad, heavily damped term beside a resonance is a shape the fit chose,
    not a second mode on the same peak.)"""
    modes = sorted((params[wn], params[zn], wn) for wn, zn in _mode_names(structure) if np.isfinite(params[wn]) and np.isfinite(params[zn]))
    return [(a[2], b[2]) for a, b in zip(modes, modes[1:]) if b[0] - a[0] < min(a[1] * a[0], b[1] * b[0])]


def _mode_names(structure: ModelStructure) -> list[tuple[str, str]]:
    """(frequency, damping) names of every base mode, mode 1 first."""
    return [structure.mode_names(k) for k in range(1, structure.n_modes + 1)]


#: A second-order mode with a damping ratio above 1/sqrt(2) has no resonant peak.
OVERDAMPED = 1 / np.sqrt(2)


def _defects(
    problem: FitProblem, params: Mapping[str, float], n_averages: int | None = None, model: Mapping[str, float] | None = None
) -> list[Finding]:
    """Reasons the parameters of a minimum should not be used.

    ``"misplaced"``: a damping ratio on its bound, modes out of their order
    (mode 2 of the tied structure is the second base mode), two modes on one
    resonance, a mode in the noise below a base mode the data place (the lowest
    modes are the lowest resonances: one below them fits a floor of unmodelled
    response, such as the tilt an accelerometer sees below 1 Hz): the solver put
    a parameter where no reading of the data would. ``"unmeasured"``: a mode
    outside the band (only its tail is seen) or where the fitted channels are
    noise above the modes the data place, or that has no resonant peak (damping
    above 1/sqrt(2)), and the damping of such a mode on its bound: the data do
    not determine it wherever it is put. The fit keeps the lowest minimum among
    those with the fewest misplaced parameters (``fit_problem``); unmeasured
    ones are said, not ranked (where the data are noise no place is better than
    another).
    """

    data = problem.data
    lo, hi = data.freq_hz[0], data.freq_hz[-1]
    st = problem.structure
    weighable = problem.weighting == "none" and all(data.coherence(c) is not None for c in problem.channels)
    reweigh = ("weigh_by_coherence",) if weighable else ()
    fewer = ("fewer_modes",) if st.n_modes > 1 else ()  # advice never names what cannot be done
    out: list[Finding] = []
    undetermined: set[str] = set()  # modes the data do not determine
    noise: list[tuple[float, tuple[str, str], dict]] = []  # modes where the fitted channels are noise: (w, names, values)
    placed: list[float] = []  # base modes the data place
    rough = _roughness_coherence(problem, params if model is None else model)  # channels without coherence
    # wp and wz are not read off a resonance of their own: wp sits where theta/v starts to roll off into the noise
    # (its place is read from the phase below it), wz at theta/v's zero, which makes theta, and so both fitted
    # channels, small exactly there (its place is read from the slopes on either side)
    named = [("wp", "zp")] + _mode_names(st) + ([] if st.tie_mode2 else [("wz", "zz")])
    for wn, zn in named:
        v, zeta = params.get(wn, np.nan), params.get(zn, np.nan)
        if not np.isfinite(v):
            continue
        fz = v / (2 * np.pi)
        if not lo <= fz <= hi:
            undetermined.add(wn)
            out.append(
                Finding(
                    "outside_band",
                    "unmeasured",
                    {"mode": wn, "freq_hz": float(fz), "band_hz": (float(lo), float(hi))},
                    (wn, zn),
                    ("widen_band", *fewer),
                )
            )
        elif wn == "wz":
            placed += [v] if st.tie_mode2 else []
        elif wn == "wp":
            pass
        elif zeta > OVERDAMPED:
            undetermined.add(wn)
            out.append(
                Finding(
                    "overdamped",
                    "unmeasured",
                    {"mode": wn, "freq_hz": fz, "damping": zn, "zeta": zeta},
                    (wn, zn),
                    (*reweigh, "band_where_holds", *fewer),
                )
            )
        elif (found := _resonance_coherence(problem, v, zeta, n_averages, rough)) is not None and found[0] < MIN_COHERENCE:
            undetermined.add(wn)
            read_from = "coherence" if found[2] == "coherence" and problem.coherence_from == "data" else "scatter"
            said = {"mode": wn, "freq_hz": fz, "coherence": found[0], "channel": found[1], "read_from": read_from, "averages": n_averages}
            noise.append((v, (wn, zn), said))
        else:
            placed.append(v)
    for v, names, said in noise:
        out.append(
            Finding(
                "in_noise",
                "misplaced" if any(p > v for p in placed) else "unmeasured",
                said,
                names,
                (*reweigh, "more_excitation_there", "band_where_coherent", *fewer),
            )
        )
    lz, hz = BOUNDS["z"]
    owner = {zn: wn for wn, zn in named}
    for n, v in params.items():
        if n.startswith("z") and np.isfinite(v) and (v < 1.01 * lz or v > 0.99 * hz):
            # the damping of a mode the data do not determine follows the noise: said, not held against the minimum
            out.append(
                Finding(
                    "damping_on_bound",
                    "unmeasured" if owner.get(n) in undetermined else "misplaced",
                    {"damping": n, "zeta": v, "bounds": BOUNDS["z"]},
                    (owner.get(n, n), n),
                    ("narrower_band", *fewer),
                )
            )
    order = [(params[wn], wn) for wn, _ in _mode_names(st) if np.isfinite(params[wn])]
    for (wa, a), (wb, b) in zip(order, order[1:]):
        if not wb > wa:
            out.append(
                Finding(
                    "out_of_order",
                    "misplaced",
                    {"lower": a, "lower_hz": wa / (2 * np.pi), "upper": b, "upper_hz": wb / (2 * np.pi), "tied": st.tie_mode2},
                    (a, b),
                    ("narrower_band", *fewer),
                )
            )
    for a, b in _unresolved_pairs(params, st):
        out.append(
            Finding(
                "unresolved_pair",
                "misplaced",
                {"lower": a, "lower_hz": params[a] / (2 * np.pi), "upper": b, "upper_hz": params[b] / (2 * np.pi)},
                (a, b),
                ("try_fewer_modes",),
            )
        )
    return out


def _assess(
    problem: FitProblem, params: Mapping[str, float], lof: LackOfFit, n_averages: int | None, defects: list[Finding] | None = None
) -> tuple[list[Finding], list[Finding], tuple[str, ...]]:
    """``(concerns, caveats, undetermined)`` of a converged minimum, each reason with what to try (``defects``: its
    ``_defects``, where the caller has them already).

    A concern: a parameter the solver put where no reading of the data would (``_defects``'
    "misplaced"): the fit's parameters should not be used. A caveat: a mode the data do not determine
    ("unmeasured": its parameters, listed in ``undetermined``, are not to be used, the others are),
    or residuals far above the noise in bands (the structure misses an effect there, such as the
    arm's own dynamics above 30 Hz in the simulator's data: the parameters are the structure's
    best compromise, usable where it holds).
    """
    defects = _defects(problem, params, n_averages) if defects is None else defects
    concerns = [d for d in defects if d.kind == "misplaced"]
    if (best := noise_only(problem.data, problem.channels)) is not None:  # a minimum of noise (it said "a sound fit")
        concerns.insert(0, Finding("noise_only", "noise", {"min_coherence": MIN_COHERENCE, "highest": best}, (), ("more_excitation",)))
    caveats = [d for d in defects if d.kind == "unmeasured"]
    undetermined = tuple(dict.fromkeys(n for d in defects if d.kind == "unmeasured" for n in d.names))
    if lof.found:
        said = {"bands": [(b.channel, b.f_lo_hz, b.f_hi_hz) for b in lof.bands], "noise_ratio": dict(lof.noise_ratio)}
        caveats.append(Finding("misfit_bands", "structure", said, (), ("band_where_holds", "look_at_bands")))
    return concerns, caveats, undetermined


def _build_starts(problem: FitProblem, start: StartSpec) -> tuple[list[tuple[str, dict]], list[str]]:
    """The starts asked for, each snapped onto the data's peaks; a start that cannot be built is
    skipped with a note, and if none can, the automatic start (which pads missing modes) is used."""
    st = problem.structure
    builders: dict = {
        "notebook": lambda: snap_to_peaks(problem, notebook_start(problem)),
        "auto": lambda: auto_start(problem),
    }
    if isinstance(start, str):
        if start not in ("notebook", "auto", "both"):
            raise ValueError(f"start must be 'notebook', 'auto', 'both' or a parameter mapping, got {start!r}")
        labels = ["notebook", "auto"] if start == "both" else [start]
    else:
        given = dict(start)
        builders["given"] = lambda: snap_to_peaks(problem, st.params(st.vector(given)))
        labels = ["given"]
    starts, notes = [], []
    for label in labels:
        try:
            starts.append((label, builders[label]()))
        except ValueError as exc:
            notes.append(f"{label} start skipped ({exc})")
    auto = next((p for label, p in starts if label == "auto"), None)
    if auto is not None and (through := modes_from_total(problem, auto)) is not None:
        starts.append(("auto, modes from xdd/v", through))
    if not starts and "auto" not in labels:
        notes.append("falling back to the automatic start (modes beyond the data's peaks padded above the highest)")
        starts.append(("auto", builders["auto"]()))
    return starts, notes


def fit_problem(
    problem: FitProblem,
    *,
    start: StartSpec = "both",
    n_perturbed: int = 2,
    mode_scan: bool = True,
    rng: np.random.Generator | None = None,
    max_nfev: int = 200,
    n_averages: int | None = None,
    progress: Progress | None = None,
    profile: bool | Literal["auto"] | Sequence[str] = "auto",
) -> FitResult:
    """Fit a prepared ``FitProblem``; see ``fit``."""
    st = problem.structure
    if isinstance(profile, str) and profile != "auto":
        raise ValueError(f"profile must be True, False, 'auto' or a sequence of frequency names, got {profile!r}")
    auto_off = isinstance(profile, str) and problem.n_points > SEARCH_POINTS
    if isinstance(profile, str):
        profile = not auto_off
    names = profile_names(st) if profile is True else tuple(profile or ())
    bad = [n for n in names if n not in profile_names(st)]
    if bad:
        raise ValueError(f"profile: {', '.join(map(str, bad))} not among the structure's frequencies {', '.join(profile_names(st))}")
    free = problem.fitted
    search = problem.thinned(SEARCH_POINTS)
    thinned = search is not problem
    n_labels = 1 if not isinstance(start, str) else (2 if start == "both" else 1)
    scan = mode_scan and isinstance(start, str) and bool(free[st.mode_index[0]].any())
    total = (
        n_labels + int(bool(scan)) + n_perturbed + int(thinned) + 1 + int(bool(names))
    )  # starts, scan, perturbed starts, refinement, diagnosis, profiles
    progress = progress or SILENT

    def done(what: str) -> None:
        progress.stage(what)
        progress.advance()

    starts, notes = _build_starts(search, start)
    averages = n_averages if n_averages is not None else averages_from_metadata(problem.data.metadata)
    total += len(starts) - n_labels  # a start skipped, or the fallback added
    progress.expect(total)
    runs = []

    def run(label: str, p: Mapping[str, float]) -> None:
        x0 = st.vector(p)
        x, sol, prev, (r, jx) = _solve(search, x0, max_nfev=max_nfev)
        misplaced = [d for d in _defects(search, st.params(np.where(free, x, np.nan)), averages, st.params(x)) if d.kind == "misplaced"]
        runs.append((label, search.cost(x0), float(r @ r), x, sol, prev, (r, jx), misplaced))
        done(f"start {label}")

    def best_run():
        """The lowest minimum among those with the fewest misplaced parameters (``_defects``)."""
        return min(runs, key=lambda r: (len(r[7]), r[2]))

    for label, p in starts:
        run(label, p)
    if scan:
        best = best_run()
        run(f"modes scanned from {best[0]}", st.params(scan_modes(search, best[3])))
    if n_perturbed:
        rng = rng if rng is not None else np.random.default_rng(0)
        best = best_run()
        for k in range(n_perturbed):
            run(f"perturbed {k + 1} of {best[0]}", perturbed_start(search, st.params(best[3]), rng=rng))
    chosen = best_run()
    label, _, cost, x, sol, (x_prev, cost_prev), rj, _ = chosen
    discarded = [r for r in runs if r[2] < cost * (1 - 1e-6)]
    nfev = sum(int(r[4].nfev) for r in runs)
    agree = sum(1 for r in runs if r[2] <= cost * (1 + 1e-6) + 1e-12)
    if thinned:
        refining = f"refining on all {problem.n_points} points"
        x, sol, (x_prev, cost_prev), rj = _solve(problem, x, max_nfev=max_nfev, on_evaluation=lambda k: progress.stage(f"{refining}, evaluation {k}"))
        cost = float(rj[0] @ rj[0])
        nfev += int(sol.nfev)
        done(f"refined on all {problem.n_points} points")
    # the notebook's criterion, for comparison, between the solver's last two iterates (the
    # notebook compared successive 500-iteration loops); rounding floor of the cost: an RMS
    # residual of 1e-6 dB (or weighted deg), i.e. an exact fit to data stored with ~10 digits
    crit = percent_change(x_prev[free], x[free], cost_prev, cost, cost_floor=1e-12 * problem.n_residuals)
    solver_ok = bool(sol.status > 0)
    converged = solver_ok and crit.met and np.isfinite(cost)
    errs = problem.errors(x)
    lof = lack_of_fit(problem, x, n_averages=n_averages, errors=errs)
    not_fitted = tuple(n for n, f in zip(st.param_names, free) if not f)
    if thinned:
        where = (
            f"{len(runs)} starts searched on 1 point in {thinning_step(problem.n_points, SEARCH_POINTS)} ({search.n_points} of {problem.n_points}), "
            f"the best ({label}; {agree} reached it) refined on all {problem.n_points} points"
        )
    else:
        where = f"best of {len(runs)} starts ({label}; {agree} reached it)"
    parts = [f"{where}: solver: {sol.message} {crit.describe()}."]
    if discarded:
        low = min(discarded, key=lambda r: r[2])
        parts.append(
            f"{len(discarded)} lower minim{'um' if len(discarded) == 1 else 'a'} discarded, the lowest ({low[0]}, cost {low[2]:.4g}) because "
            f"{low[7][0].finding}."
        )
    parts += [f"{n}." for n in notes]
    if not_fitted:
        parts.append(
            f"Not fitted (the fitted channel{'s' if len(problem.channels) > 1 else ''} {', '.join(problem.channels)} do not depend on them): {', '.join(not_fitted)}."
        )
    if auto_off:
        parts.append(
            f"No profile intervals on {problem.n_points} points (profile='auto' computes them on at most {SEARCH_POINTS}; "
            "samii fit --profiles on): the intervals are the standard errors' normal ones."
        )
    if lof.found:
        parts.append(f"LACK OF FIT: the model misses the data in {len(lof.bands)} band(s) ({lof.summary()}): see warnings.")
    cov, stderr, corr, warnings, scale = _sandwich(problem, x, rj)
    x_report = np.where(free, x, np.nan)
    params = dict(zip(st.param_names, map(float, x_report)))
    warnings = lof.warnings() + warnings + _band_warnings(problem, params)
    concerns, caveats, undetermined = _assess(problem, params, lof, averages)
    done("uncertainty and lack of fit")
    profiles, lower, not_lowest = _profiles(problem, x, cost, stderr, scale, names, max_nfev=max_nfev) if names else ({}, [], [])
    warnings += lower
    concerns += not_lowest
    if names:
        done(f"profiles of {', '.join(profiles)}")
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
        message=" ".join(parts),
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
        lack_of_fit=lof,
        not_fitted=not_fitted,
        concerns=tuple(concerns),
        caveats=tuple(caveats),
        undetermined=undetermined,
        profiles=profiles,
    )


#: A coherence this close to 1 at every point of every fitted channel holds no information on the noise: what an
#: analyser writes for a single average (its coherence is 1 whatever the noise), or a placeholder column.
COHERENCE_NO_INFORMATION = 1.0 - 1e-9


def informative_coherence(data: FrequencyResponse, channels: Sequence[Channel]) -> bool:
    """Every channel has coherence, and not 1 at every point of all of them (:data:`COHERENCE_NO_INFORMATION`). A file
    of one noisy average with its coherence written as 1 was weighted uniformly as "coherence" and its wrong-basin
    fit (base mode 1 at 0.16 Hz) called sound with caveats; read as none, it is judged by its scatter. (A noise-free
    simulation's coherence is below 1 somewhere: the default's xdd/theta reaches 0.956.)"""
    cohs = [data.coherence(c) for c in channels]
    if not cohs or any(c is None for c in cohs):
        return False
    return not all(bool(np.all(np.asarray(c) >= COHERENCE_NO_INFORMATION)) for c in cohs)


def resolve_weighting(data: FrequencyResponse, channels: Sequence[Channel] | None, weighting: str) -> Weighting:
    """``"auto"``: ``"coherence"`` when every fitted channel carries coherence that says something
    (:func:`informative_coherence`), else ``"none"``."""
    if weighting != "auto":
        return weighting  # type: ignore[return-value]
    return "coherence" if informative_coherence(data, _fitted_channels(data, channels)) else "none"


def _fitted_channels(data: FrequencyResponse, channels: Sequence[Channel] | None) -> list[Channel]:
    """The channels a fit uses: those given, else act and base (total in place of a missing base), as FitProblem."""
    if channels is not None:
        return list(channels)
    out = [c for c in ("act", "base") if c in data.channels]
    if "base" not in out and "total" in data.channels:
        out.append("total")
    return out


def check_not_noise(
    data: FrequencyResponse,
    structure: ModelStructure | None = None,
    *,
    band_hz: tuple[float, float] | None = None,
    channels: Sequence[Channel] | None = None,
) -> None:
    """ValueError when every channel a fit of ``data`` would use is noise (``lack_of_fit.refuse_noise``): for the
    commands that refuse such data before any work (:func:`fit` itself returns a fit that is not sound)."""
    problem = FitProblem(data, structure or ModelStructure.notebook_3mode(), band_hz=band_hz, channels=None if channels is None else tuple(channels))
    refuse_noise(problem.data, problem.channels, "fit")


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
    n_averages: int | None = None,
    progress: Progress | None = None,
    profile: bool | Literal["auto"] | Sequence[str] = "auto",
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
        Default ``("act", "base")`` as the notebook (``total`` in place of a missing
        ``base``). Parameters the channels do not depend on are not fitted (NaN).
    weighting : {"none", "coherence", "auto"}
        ``"none"`` is the notebook's cost; ``"coherence"`` weights points by their
        expected random error (see ``samii.identify.cost``); ``"auto"`` (the CLI's
        default) is ``"coherence"`` when every fitted channel has coherence, else ``"none"``.
    start : "notebook", "auto", "both" or mapping
        Where the solver starts (``samii.identify.starts``): notebook frequencies
        and dampings with gains read off the data, a start read off the data
        alone, both, or given parameters. A start that cannot be built (the
        notebook's for more modes than the data show) is skipped, said so in the
        message; if no start remains, the automatic one is used.
    n_perturbed : int
        Extra starts around the best result so far (frequencies, dampings and tau
        scaled by exp(0.2 N(0,1)), modes kept in order, gains re-solved). Before
        them, unless ``start`` is a mapping, a start whose every base-mode
        frequency is moved by a global scan between its neighbours
        (``starts.scan_modes``). The solver keeps the modes in their order. Of all
        minima the lowest among those with the fewest misplaced parameters is
        kept (a damping on its bound, modes out of order, two modes on one
        resonance, a mode in the noise below a mode the data place); the message
        says which lower minimum was discarded and why.
    rng : numpy Generator, optional
        For the perturbed starts (default: seed 0, so a fit is reproducible).
    n_averages : int, optional
        Averages behind the coherence, for the lack-of-fit test; default from the
        metadata ``frf_records``, else 3 (stated in the result).
    progress : samii.progress.Progress, optional
        Told the fit's stages (``expect``: its starts, the scan, the refinement, the diagnosis, the profiles), then
        each as it is done (``stage``, ``advance``); a second reading weighted by the scatter says its stages only.
    profile : "auto", bool or sequence of names
        Frequencies to profile (``samii.identify.profile``: each held at values stepped away from
        its estimate, the others re-solved; ``FitResult.interval`` then reads the interval off the
        profile, lopsided or open where the data leave it so). ``True``: every fitted frequency
        (``profile_names``: wp, the modes, the zero); ``False``: none (normal intervals from the
        standard errors only); ``"auto"`` (default): ``True`` on data of at most ``SEARCH_POINTS``
        points in the band, where they cost about as much as the fit, ``False`` on more (each
        profile value is a solve on all points: about 1 s on 10,000, 6 s on 100,000; the message
        says they were not computed).

    Data with more than ``SEARCH_POINTS`` frequency points in the band are fitted
    in two steps, so that the time grows linearly with the points: the starts
    are searched on every k-th point (``FitProblem.thinned``), then the best is
    refined on all points; convergence, uncertainty and lack of fit are those of
    all points, the costs in ``FitResult.starts`` those of the search points.

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
    requested = weighting
    fitted = _fitted_channels(data, channels)
    blank = requested == "auto" and all(data.coherence(c) is not None for c in fitted) and not informative_coherence(data, fitted)
    if blank:  # a coherence of 1 everywhere says nothing of the noise: read as none (judged by the data's scatter)
        data = dataclasses.replace(data, act_coh=None, base_coh=None, total_coh=None)
    weighting = resolve_weighting(data, channels, weighting)
    problem = FitProblem(
        data, structure, phase_weight=phase_weight, band_hz=band_hz, channels=None if channels is None else tuple(channels), weighting=weighting
    )
    result = fit_problem(
        problem, start=start, n_perturbed=n_perturbed, rng=rng, max_nfev=max_nfev, n_averages=n_averages, progress=progress, profile=profile
    )
    if requested == "auto" and weighting == "none" and (not result.sound or result.caveats) and isinstance(start, str):
        try:
            # (its progress said as a second reading, the bar at the end of the first: 3-5 s more showed nothing)
            second = part(progress, 0, prefix="second reading, weighted by the data's scatter: ")
            mended = _weighted_by_scatter(problem, result, n_perturbed=n_perturbed, rng=rng, max_nfev=max_nfev, profile=profile, progress=second)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError):
            mended = None  # (a second reading that fails leaves the first as it was)
        if mended is not None:
            result = mended
    if blank:
        result = dataclasses.replace(
            result,
            message=result.message + " The file's coherence is 1 at every point (one average, or a "
            "placeholder): it says nothing of the noise and was read as none.",
        )
    return result


def _finite(params: Mapping[str, float]) -> dict[str, float]:
    """``params`` with the NaN of parameters the fitted channels do not depend on (a result's) set to 1: any finite
    value stands for them in a response or a residual."""
    return {k: (v if np.isfinite(v) else 1.0) for k, v in params.items()}


def _weighted_by_scatter(
    problem: FitProblem,
    unweighted: FitResult,
    *,
    n_perturbed: int,
    rng: np.random.Generator | None,
    max_nfev: int,
    profile,
    progress: Progress | None = None,
) -> FitResult | None:
    """Data without coherence whose fit by the notebook's unweighted cost is not sound, or sound with caveats, fitted
    again weighted by their scatter; the result if it is sound by both readings of the noise (and, where the
    unweighted fit was sound, leaves fewer modes undetermined or fewer bands of misfit), else None (the unweighted
    fit stands, said).

    Without coherence every point counts alike in the notebook's cost, and where a channel is noise (xdd/theta
    below 0.3 Hz at 0.1 V) the noise draws the modes to it: a rig-era .mat file of the default simulator's
    measurement put base mode 1 at 0.16 Hz and the hydraulic pair on mode 1 (NOT A SOUND FIT, rightly). The noise of
    each point is read off the roughness of the log residual (:func:`samii.identify.lack_of_fit.roughness_variance`)
    about each of the unweighted fit and the starts; a misfit only adds to the scatter, so the smallest reading of
    each point is kept. As a coherence of one estimate, ``1/(1 + var)`` (``(1 - g)/g = var``, one average), it
    weighs a fit from every start. A weighting read off a fit can favour that fit's basin, so the weighted result is
    kept only if it is sound both by its own weights and by the scatter about itself, as an unweighted fit is
    judged (:func:`_assess`); on one noisy average (samii measure --averages 1 --noise) neither reading places
    mode 1, and the unweighted fit's "not sound" stands."""
    data, st = problem.data, problem.structure
    starts, _ = _build_starts(problem, "both")
    candidates = [_finite(unweighted.params)] + [p for _, p in starts]
    coh: dict[str, np.ndarray] = {}
    for c in problem.channels:
        scatter = []
        for p in candidates:
            with np.errstate(all="ignore"):
                e = np.log(data.response(c) / st.response(p, data.freq_hz, c))
            if e.size > ROUGHNESS_LAG and np.all(np.isfinite(e)):
                scatter.append(roughness_variance(e))
        if not scatter:
            return None
        coh[f"{c}_coh"] = 1.0 / (1.0 + np.min(scatter, axis=0))
    weighted = FitProblem(
        dataclasses.replace(data, **coh),
        st,
        phase_weight=problem.phase_weight,
        channels=tuple(problem.channels),
        weighting="coherence",
        coherence_from="scatter",
    )
    res = fit_problem(weighted, start="both", n_perturbed=n_perturbed, rng=rng, max_nfev=max_nfev, n_averages=1, profile=profile, progress=progress)
    lof = lack_of_fit(problem, st.vector(_finite(res.params)))
    defects = _defects(problem, res.params, None)
    concerns, _, undetermined = _assess(problem, res.params, lof, None, defects=defects)
    if not res.sound or concerns:
        return None
    if unweighted.sound:
        # sound already, with caveats: the weighted fit is kept only where, read as the unweighted fit is (the scatter
        # about each), it leaves fewer modes undetermined or fewer bands of misfit and more of neither
        fewer = (len(set(res.undetermined) | set(undetermined)), len(lof.bands))
        before = (len(unweighted.undetermined), len(unweighted.lack_of_fit.bands))
        if not (fewer[0] <= before[0] and fewer[1] <= before[1] and fewer != before):
            return None
    why = f"not sound ({unweighted.concerns[0].text})" if unweighted.concerns else f"sound with caveats ({unweighted.caveats[0].text})"
    # the scatter about the weighted fit read as the unweighted fit is: its modes undetermined that the weighted fit's
    # own findings do not name (one "mode w3 ... sits where the data are noise", not two with 0.30 and 0.31)
    own = [d for d in defects if d.kind == "unmeasured" and not set(d.names) <= set(res.undetermined)]
    return dataclasses.replace(
        res,
        weighting="scatter",
        caveats=tuple(res.caveats) + tuple(own),
        undetermined=tuple(dict.fromkeys(res.undetermined + tuple(undetermined))),
        message=res.message + f" Weighted by the data's scatter (no coherence in the file): the notebook's unweighted "
        f"cost gave a fit that was {why}.",
    )
