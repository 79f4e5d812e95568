"""Starting points for a fit: the notebook's values, guesses read off the data, perturbations.

Units. Data in samii are SI (theta in rad, acceleration in m/s²); the notebook
does not state its units (theta was most likely in degrees). Frequencies and
damping ratios carry over unchanged, gains (K1, B_k) need not. Every start
here therefore takes only frequencies, damping ratios and tau from its source
and *reads the gains off the data*:

* K1 multiplies theta/v and does not touch its phase, so with the other
  actuator parameters fixed its dB-optimal value is the exponent of the mean of
  ln|H_data| - ln|H_model(K1=1)| (exactly the notebook's cost minimised over K1).
* The base model is linear in B_1..B_N, so with the modes fixed the B's are the
  real least-squares solution of sum_k B_k phi_k(w) / H_data(w) = 1 (a relative,
  i.e. log-like, error).

``notebook_start`` takes frequencies and dampings from eq 1.4 (2 modes) or
eq 9.4 (3 or more modes); ``auto_start`` finds them from the data: the
hydraulic resonance wp and the actuator zero wz as the most prominent peak and
notch of |theta/v| * w (the integrator removed), base modes as the most
prominent peaks of |xdd/theta| / w^n, then a coarse grid search on every
damping ratio and on tau with the gains re-solved at each point.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from samii import notebook as nb
from samii.identify.cost import FitProblem
from samii.identify.structures import ModelStructure

__all__ = ["solve_gains", "notebook_start", "auto_start", "modes_from_total", "scan_modes", "snap_to_peaks", "perturbed_start", "resolvable_damping"]

#: Damping ratios and lag used before the grid search of ``auto_start``
#: (order of eq 9.4: zp 0.14, base modes 0.03-0.05; tau/wp = 158.9/55.3 = 2.9).
_DEFAULT_ZETA_ACT = 0.1
_DEFAULT_ZETA_MODE = 0.04
_DEFAULT_TAU_OVER_WP = 3.0


def _response(st: ModelStructure, x: np.ndarray, w: np.ndarray, channel: str) -> np.ndarray:
    return st.log_responses(x, w, (channel,), derivatives=False)[channel][0]


def _design(problem: FitProblem, x: np.ndarray, channel: str) -> np.ndarray:
    """Columns phi_k(w): the response of ``channel`` with B_k = 1 and the other B's 0."""
    st = problem.structure
    cols = st.modal_columns(x, problem.w)
    return cols * _response(st, x, problem.w, "act")[:, None] if channel == "total" else cols


def solve_gains(problem: FitProblem, x: np.ndarray) -> np.ndarray:
    """Return ``x`` with K1 and B_k read off the data for the other parameters fixed."""
    st = problem.structure
    idx = {n: i for i, n in enumerate(st.param_names)}
    x = np.array(x, float)
    chans = problem.channels
    data = problem.data
    if "act" in chans:
        x[idx["K1"]] = 1.0
        g = _response(st, x, problem.w, "act")
        x[idx["K1"]] = float(np.exp(np.mean(np.log(np.abs(data.response("act") / g)))))
    source = "base" if "base" in chans else ("total" if "total" in chans else None)
    if source is not None:
        phi = _design(problem, x, source) / data.response(source)[:, None]
        a = np.vstack([phi.real, phi.imag])
        b = np.concatenate([np.ones(phi.shape[0]), np.zeros(phi.shape[0])])
        sol, *_ = np.linalg.lstsq(a, b, rcond=None)
        for k in range(st.n_modes):
            x[idx[f"B{k + 1}"]] = sol[k] if sol[k] != 0 else 1e-12
    if "act" not in chans and "base" in chans and "total" in chans:
        x[idx["K1"]] = 1.0
        h = _response(st, x, problem.w, "total")
        x[idx["K1"]] = float(np.exp(np.mean(np.log(np.abs(data.response("total") / h)))))
    return x


def _notebook_modes(values: Mapping[str, float]) -> list[tuple[float, float]]:
    """(w_k, z_k) of a notebook parameter set, mode 2 being (wz, zz)."""
    modes = [(values["w1"], values["z1"]), (values["wz"], values["zz"])]
    k = 3
    while f"w{k}" in values:
        modes.append((values[f"w{k}"], values[f"z{k}"]))
        k += 1
    return modes


def _assemble(problem: FitProblem, act: Mapping[str, float], modes: list[tuple[float, float]]) -> dict[str, float]:
    """Structure parameters from actuator values and a list of (w, z) per mode; gains solved."""
    st = problem.structure
    if len(modes) < st.n_modes:
        raise ValueError(f"no start for {st.n_modes} modes: only {len(modes)} found in the notebook and the data")
    p = {k: float(act[k]) for k in ("K1", "wp", "zp", "wz", "zz", "tau")}
    for k in range(1, st.n_modes + 1):
        wn, zn = st.mode_names(k)
        if wn != "wz":
            p[wn], p[zn] = (float(v) for v in modes[k - 1])
        p[f"B{k}"] = 1.0  # replaced by solve_gains
    return st.params(solve_gains(problem, st.vector(p)))


def notebook_start(problem: FitProblem) -> dict[str, float]:
    """Frequencies, dampings and tau of eq 1.4 (2 modes) or eq 9.4 (3+ modes); gains from the data.

    Modes beyond the third come from the data's base peaks above w3 (see ``auto_start``).
    """
    st = problem.structure
    src = nb.EQ1_4_OPTIMIZED if st.n_modes == 2 else nb.EQ9_4
    modes = _notebook_modes(src)
    if st.n_modes > 3:
        modes += [(w, _DEFAULT_ZETA_MODE) for w in _base_peaks(problem, st.n_modes + 3) if w > 1.2 * src["w3"]]
    return _assemble(problem, src, modes)


def _prominent(logmag: np.ndarray, n: int) -> np.ndarray:
    """Indices of the ``n`` most prominent local maxima of ``logmag``, ascending in frequency."""
    from scipy.signal import find_peaks  # (lazy: imports scipy, only when called)

    peaks, props = find_peaks(logmag, prominence=0.0)
    order = np.argsort(props["prominences"])[::-1][:n]
    return np.sort(peaks[order])


#: Peaks and notches are looked for only where coherence is at least this
#: (random error below 0.4 dB / 2.6 deg for 3 averages, Bendat & Piersol table 9.6).
_PEAK_MIN_COHERENCE = 0.9


def _coherent(problem: FitProblem, channel: str) -> np.ndarray | None:
    """Mask of the points trustworthy enough to pick peaks from (all if no coherence), or None when fewer than 10 are."""
    coh = problem.data.coherence(channel)
    keep = np.ones(problem.w.size, bool) if coh is None else coh >= _PEAK_MIN_COHERENCE
    return keep if keep.sum() >= 10 else None


def _reliable(problem: FitProblem, channel: str) -> np.ndarray:
    """:func:`_coherent`'s mask, or every point when too few are coherent."""
    keep = _coherent(problem, channel)
    return keep if keep is not None else np.ones(problem.w.size, bool)


def _smooth(y: np.ndarray, k: int = 5) -> np.ndarray:
    """Moving average over ``k`` points (edges shortened) so single noisy points are not taken for peaks."""
    k = min(k, y.size)
    c = np.convolve(y, np.ones(k), "same") / np.convolve(np.ones_like(y), np.ones(k), "same")
    return c


def _peaks(st: ModelStructure, w: np.ndarray, base: np.ndarray, n: int) -> list[float]:
    """The ``n`` most prominent resonances [rad/s] of an xdd/theta ``base`` at ``w``, its s^n trend taken out, ascending."""
    return [float(w[i]) for i in _prominent(_smooth(np.log(np.abs(base)) - st.power * np.log(w)), n)]


def _padded(peaks: list[float], n: int) -> list[float]:
    """``peaks`` with the modes beyond them (outside the band) put above the highest, 2.5x apart, to ``n``."""
    peaks = list(peaks)
    while len(peaks) < n:
        peaks.append(peaks[-1] * 2.5)
    return peaks


def _base_peaks(problem: FitProblem, n: int) -> list[float]:
    if "base" not in problem.channels:
        return []
    keep = _reliable(problem, "base")
    return _peaks(problem.structure, problem.w[keep], problem.data.response("base")[keep], n)


def auto_start(problem: FitProblem) -> dict[str, float]:
    """A start read off the data alone (peaks, notches, grid search on dampings and tau).

    What a channel absent from the data cannot show is taken from eq 9.4.
    """
    st = problem.structure
    data, w = problem.data, problem.w
    act = dict(nb.EQ9_4)
    if "act" in problem.channels:
        keep = _reliable(problem, "act")
        g = _smooth(np.log(np.abs(data.response("act")[keep]) * w[keep]))
        iz = _prominent(-g, 1)
        if iz.size:
            act["wz"] = float(w[keep][iz[0]])
        act.update(zp=_DEFAULT_ZETA_ACT, zz=_DEFAULT_ZETA_MODE)
    modes = _notebook_modes(nb.EQ9_4)
    peaks = _base_peaks(problem, st.n_modes)
    if peaks:
        modes = [(wk, _DEFAULT_ZETA_MODE) for wk in _padded(peaks, st.n_modes)]
        if st.tie_mode2:
            act["wz"] = modes[1][0]
    while len(modes) < st.n_modes:
        modes.append((modes[-1][0] * 2.5, _DEFAULT_ZETA_MODE))
    x = st.vector(_assemble(problem, act, modes))
    if "act" in problem.channels:
        x = _scan_wp(problem, x)
    return st.params(_grid_refine(problem, x))


def modes_from_total(problem: FitProblem, params: Mapping[str, float]) -> dict[str, float] | None:
    """``params`` with the base modes read off xdd/v divided by ``params``' theta/v model, or None
    if the data have no xdd/v measured well enough (coherence 0.9 at 10 points or more).

    Above the hydraulic resonance theta/v falls (as 1/w, and 1/w^2 beyond the
    lag tau, in eq 9.1) and a small sweep moves theta less than its sensor noise: xdd/theta, estimated
    with theta in its denominator, is noise there, and so are the peaks
    ``auto_start`` reads off it. xdd/v is not (v is the command, known
    exactly, and the accelerometer sees the base directly). Divided by the
    theta/v *model* (smooth there) it is xdd/theta without theta's noise, and
    its peaks are the base modes, mode 2 included (the actuator zero wz, which
    cancels in xdd/v, is a notch of the model divided out). The dampings and
    tau are grid-refined as in ``auto_start``.
    """
    st, data = problem.structure, problem.data
    if "total" not in data.channels or not {"act", "base"} <= set(problem.channels):
        return None
    keep = _coherent(problem, "total")
    if keep is None:
        return None
    x = st.vector(params)
    w = problem.w[keep]
    peaks = _peaks(st, w, data.response("total")[keep] / _response(st, x, w, "act"), st.n_modes)
    if not peaks:
        return None
    wi, zi = st.mode_index[:2]  # (with eq 9.2's tie, mode 2's frequency is wz)
    x[wi], x[zi] = _padded(peaks, st.n_modes), _DEFAULT_ZETA_MODE
    return st.params(_grid_refine(problem, x))


def _keep_better(problem: FitProblem, trial: np.ndarray, best: np.ndarray, best_cost: float) -> tuple[np.ndarray, float]:
    """``trial`` with its gains re-solved, if its cost is below ``best_cost``; else (best, best_cost)."""
    trial = solve_gains(problem, trial)
    c = problem.cost(trial)
    return (trial, c) if c < best_cost else (best, best_cost)


def _scan_wp(problem: FitProblem, x: np.ndarray, n: int = 40) -> np.ndarray:
    """Global 1-D search for the hydraulic resonance wp over the band (tau = 3 wp, gains re-solved).

    A peak picker is fooled here: the zero pair wz sits just above wp (55 vs
    62 rad/s in eq 9.4) and leaves a shoulder after the notch that looks like a peak.
    """
    st = problem.structure
    iwp, itau = st.param_names.index("wp"), st.param_names.index("tau")
    best, best_cost = x, np.inf
    for wp in np.geomspace(problem.w[0], problem.w[-1], n):
        trial = x.copy()
        trial[iwp], trial[itau] = wp, _DEFAULT_TAU_OVER_WP * wp
        best, best_cost = _keep_better(problem, trial, best, best_cost)
    return best


def resolvable_damping(problem: FitProblem, w: float | None = None) -> float:
    """The least damping ratio a start's search tries for a mode at ``w`` [rad/s]: half the grid's
    local spacing in ln(frequency) there (the median spacing if ``w`` is None; 0 for one point).

    A mode's half-power band is +-zeta around it in ln(frequency). When its width 2 zeta is less than
    the spacing, the cost along the mode's frequency is corrugated: the mode fits best where its
    narrow peak sits on a point, and the cost has a local minimum between each pair of points (eq 9.4
    at 100 points per decade with z3 = 0.0025: five minima within +-6 % of w3, against one with its
    own damping). A local solver started there stays in one of them. (The grid search drove a mode-3
    damping from 0.04 to 0.0025 at 34 Hz, where points lie 0.78 Hz apart, and the solver stayed at
    34 Hz, 1.2 % of cost above the minimum with mode 3 at 30 Hz.) The spacing is the local one, so a
    linear (FFT) grid, coarse in ln f at low frequency, floors a 2 Hz mode by its own spacing there.
    The solver itself may go lower (``fit.BOUNDS``): the floor is on where a start's search moves a
    damping (a start's own value below it, such as the default 0.04 on a log grid coarser than 29
    points per decade, is kept unless a trial above the floor does better; ``perturbed_start`` scales
    the best minimum's dampings without it).
    """
    lw = np.log(problem.w)
    if lw.size < 2:
        return 0.0
    d = np.diff(lw)
    if w is None or not np.isfinite(w) or w <= 0:
        return 0.5 * float(np.median(d))
    return 0.5 * float(np.interp(np.log(w), 0.5 * (lw[:-1] + lw[1:]), d))


def _grid_refine(problem: FitProblem, x: np.ndarray, *, sweeps: int = 2) -> np.ndarray:
    """Coordinate search over a log grid (x/4 ... x*4, 9 points) of each fitted damping ratio and tau;
    damping trials below ``resolvable_damping`` or above 2 are not tried."""
    st = problem.structure
    names = [n for n, free in zip(st.param_names, problem.fitted) if free and (n.startswith("z") or n == "tau")]
    idx = {n: i for i, n in enumerate(st.param_names)}
    factors = np.geomspace(0.25, 4.0, 9)
    # each damping's floor at its mode's frequency (zp -> wp, zz -> wz, z3 -> w3), which this search does not move
    floor = {n: resolvable_damping(problem, x[idx["w" + n[1:]]] if "w" + n[1:] in idx else None) for n in names if n.startswith("z")}
    best = solve_gains(problem, x)
    best_cost = problem.cost(best)
    for _ in range(sweeps):
        for n in names:
            for f in factors:
                trial = best.copy()
                trial[idx[n]] = best[idx[n]] * f
                if n in floor and not floor[n] <= trial[idx[n]] <= 2.0:
                    continue
                best, best_cost = _keep_better(problem, trial, best, best_cost)
    return best


#: Points of the log grid on which ``scan_modes`` tries each mode frequency, and the least ratio between neighbouring modes.
_SCAN_POINTS = 24
_SCAN_SEPARATION = 1.15


def scan_modes(problem: FitProblem, x: np.ndarray, *, points: int = _SCAN_POINTS) -> np.ndarray:
    """``x`` with each fitted base-mode frequency moved to the best point of a global 1-D search.

    The modes are numbered in frequency order (mode 2 is the actuator zero wz in
    the tied structure), so mode k is searched on a log grid between modes k-1
    and k+1 (a factor 1.75 beyond the band's edges for the first and last, whose
    tail alone may be in the data; at least a factor
    ``_SCAN_SEPARATION`` from each neighbour), with damping ratio 0.04 and the
    gains re-solved at every point; the lowest cost is kept, then the damping
    ratios and tau are refined on their grid (``_grid_refine``). A local solver
    cannot move a mode across a neighbour's resonance or out of a noise floor it
    fell into; this search does, in the order of the modes, from mode 1 up.
    """
    st = problem.structure
    best = solve_gains(problem, np.array(x, float))
    best_cost = problem.cost(best)
    lo_w, hi_w = problem.w[0] / _SCAN_SEPARATION**4, problem.w[-1] * _SCAN_SEPARATION**4  # a mode just outside shows its tail
    wi, zi = st.mode_index[:2]
    for k in range(st.n_modes):
        if not problem.fitted[wi[k]]:
            continue
        below = max(best[wi[k - 1]] * _SCAN_SEPARATION if k > 0 else lo_w, lo_w)
        above = min(best[wi[k + 1]] / _SCAN_SEPARATION if k + 1 < st.n_modes else hi_w, hi_w)
        for w in np.geomspace(below, above, points) if above > below else ():
            trial = best.copy()
            trial[wi[k]], trial[zi[k]] = w, _DEFAULT_ZETA_MODE
            best, best_cost = _keep_better(problem, trial, best, best_cost)
    return _grid_refine(problem, best)


def snap_to_peaks(problem: FitProblem, params: Mapping[str, float], *, max_ratio: float = 1.6) -> dict[str, float]:
    """``params`` with each base-mode frequency moved onto the nearest prominent peak of the data.

    A start whose mode frequency misses its resonance by tens of percent puts
    the least-squares solver in the wrong basin (it widens a neighbouring mode
    instead of moving this one). Peaks are matched one to one, nearest in log
    frequency first, and only within a factor ``max_ratio``; gains are re-solved.
    """
    st = problem.structure
    x = st.vector(params)
    peaks = _base_peaks(problem, st.n_modes + 2)
    if not peaks:
        return st.params(x)
    names = [st.mode_names(k)[0] for k in range(1, st.n_modes + 1)]
    idx = [st.param_names.index(n) for n in names]
    pairs = sorted((abs(np.log(x[i] / wpk)), i, j) for i in idx for j, wpk in enumerate(peaks))
    used_modes, used_peaks = set(), set()
    for dist, i, j in pairs:
        if i in used_modes or j in used_peaks or dist > np.log(max_ratio):
            continue
        x[i] = peaks[j]
        used_modes.add(i)
        used_peaks.add(j)
    return st.params(solve_gains(problem, x))


def perturbed_start(problem: FitProblem, params: Mapping[str, float], *, rng: np.random.Generator, scale: float = 0.2) -> dict[str, float]:
    """``params`` with every frequency, damping and tau scaled by exp(scale * N(0,1)), the modes in order; gains re-solved."""
    st = problem.structure
    x = st.vector(params)
    pos = st.positive.copy()
    pos[st.param_names.index("K1")] = False
    x[pos] *= np.exp(scale * rng.standard_normal(int(pos.sum())))
    wi = st.mode_index[0]
    x[wi] = np.sort(x[wi])  # modes keep their order (the solver keeps a start's order)
    return st.params(solve_gains(problem, x))
