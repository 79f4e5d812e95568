"""A baseline model with effects, fitted to one or more measured files by weighted least squares.

The residual of a point is the log ratio of data to model,
``e = ln(H_data / H_model)`` (real part: log magnitude, imaginary part: phase),
divided by the point's random error: each part has variance ``var/2``
(:mod:`samii.measure.measured`), so for a right model the weighted residuals
are standard normal and their sum of squares is chi-square.

The baseline is either the notebook's structure with its parameters refitted
with the effects (each file its own parameters: files at different amplitudes
may differ), or a fixed response (a saved fit, the simulator) that only the
effects change. Effects are shared by all files: they are the rig's.

Parameters are optimised transformed: positive ones as logarithms, the base
gains B_k and a mode's residue relative to their start values, a delay in
milliseconds. Standard errors come from the Jacobian at the optimum,
``cov = s^2 (J'J)^-1``, with ``s^2`` the residual variance per degree of freedom
times the correlation length of the noise (neighbouring points that share one
error carry less information than their number says).
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
import scipy.linalg
from scipy.optimize import least_squares

from samii.diagnose.effects import Effect, EffectKind
from samii.forkmap import fork_calls
from samii.frequency_response import FrequencyResponse, interpolate_frf
from samii.identify.fit import fit
from samii.identify.structures import ModelStructure
from samii.measure.frf_variance import MAX_VAR
from samii.notebook import EQ9_4

__all__ = ["Dataset", "Baseline", "Fit", "fit_model", "relabel_modes", "notebook_reference", "scaled_reference", "level_ratio"]


@dataclass(frozen=True, eq=False)
class Dataset:
    """The usable points of one file's channels, prepared for fitting."""

    source: str
    freq_hz: np.ndarray
    data: Mapping[str, np.ndarray]  # channel -> complex (usable points only)
    keep: Mapping[str, np.ndarray]  # channel -> bool mask on freq_hz
    inv_sigma: Mapping[str, np.ndarray]  # channel -> 1/sqrt(var/2), the fit's weights (noise and any model_var)
    known_noise: bool
    corr_length: float
    amplitude_v: float | None
    #: channel -> 1/sqrt(var/2) of the noise alone, where the fit's weights also hold the model's own
    #: approximation (Measured.model_var); None when they are the noise alone
    noise_inv_sigma: Mapping[str, np.ndarray] | None = None
    #: channel -> variance of the systematic floor on its usable points (part of the noise above;
    #: samii.measure.floor), None when the file's has none
    floor_var: Mapping[str, np.ndarray] | None = None
    #: The file's record length [s] (a time series cut into records) and sample rate [Hz], when known.
    record_s: float | None = None
    sample_rate_hz: float | None = None

    @classmethod
    def from_measured(cls, m, channels: Sequence[str] | None = None) -> Dataset:
        """The usable points of ``m``'s channels: by default theta/v and xdd/v (``total``), whose noise is
        independent (theta's noise enters only the first), else theta/v and xdd/theta."""
        if channels is None:
            have = set(m.frf.channels)
            channels = ("act", "total") if {"act", "total"} <= have else ("act", "base")
        frf = m.frf
        data, keep, inv, noise_inv, floor = {}, {}, {}, {}, {}
        extra = m.model_var or {}
        fl = getattr(m.floor, "var", None) or {}
        known = True
        if any(m.var.get(c) is None for c in frf.channels):  # one noise model per file: unknown for all if for one
            m = replace(m, var=dict.fromkeys(frf.channels))
        for ch in channels:
            if ch == "base" and "base" not in frf.channels and {"act", "total"} <= set(frf.channels):
                h = frf.total / frf.act
                va, vt = m.var.get("act"), m.var.get("total")
                var = None if va is None or vt is None else va + vt
                xv = extra["act"] + extra["total"] if {"act", "total"} <= set(extra) else None
                fv = fl["act"] + fl["total"] if {"act", "total"} <= set(fl) else None
            elif ch in frf.channels:
                h = frf.response(ch)
                var = m.var.get(ch)
                xv = extra.get(ch)
                fv = fl.get(ch)
            else:
                continue
            if var is None:
                known = False
                var = np.full(h.shape, 1e-2)
                k = np.ones(h.shape, bool)
            else:
                k = var <= MAX_VAR
            keep[ch] = k
            data[ch] = h[k]
            noise_inv[ch] = 1.0 / np.sqrt(var[k] / 2.0)
            if fv is not None and known:
                floor[ch] = np.asarray(fv)[k]
            inv[ch] = noise_inv[ch] if xv is None else 1.0 / np.sqrt((var[k] + xv[k]) / 2.0)
        if not data:
            raise ValueError(f"{m.source}: no act or base channel to diagnose (has {', '.join(frf.channels)})")
        return cls(
            m.source,
            frf.freq_hz,
            data,
            keep,
            inv,
            known,
            float(m.corr_length),
            m.amplitude_v,
            None if not extra else noise_inv,
            floor if floor and known else None,
            None if getattr(m, "layout", None) is None else float(m.layout.record_s),
            getattr(m, "sample_rate_hz", None),
        )

    def noise_sigma_inv(self, ch: str) -> np.ndarray:
        """1/sqrt(var/2) of the noise alone on channel ``ch``'s usable points (the reported error's scale)."""
        return self.inv_sigma[ch] if self.noise_inv_sigma is None else self.noise_inv_sigma[ch]

    @property
    def n_points(self) -> int:
        return int(sum(v.size for v in self.data.values()))


@dataclass(frozen=True)
class Baseline:
    """The model under test: the notebook's structure (refitted per file) or fixed responses per file."""

    structure: ModelStructure | None = None
    params: tuple[Mapping[str, float], ...] = ()  # per dataset, structure's parameters (start values when free)
    fixed: tuple[Mapping[str, Mapping[str, np.ndarray]], ...] = ()  # per dataset: channel -> {act, base as it needs} on its usable points
    label: str = "notebook"
    #: The model the user holds (eq 9.4, a saved fit): which of the fitted modes are "the baseline's" and
    #: which are extra is decided by nearness to its modes (:func:`relabel_modes`). Default: ``params[0]``.
    reference: Mapping[str, float] | None = None
    #: Per dataset, a factor on the structure's act and base on that dataset's frequency grid (the
    #: simulator's measured-over-linearised response, samii.diagnose.simulator.correction); none if empty.
    correction: tuple = ()
    #: The start of the lag [samples] by which xdd/v's direct feedthrough reaches the data after the rest of it, one
    #: for the files (:func:`feedthrough_term`, fitted with the baseline; samii.diagnose.sampling); None: not modelled.
    feedthrough_lag: float | None = None
    #: Per dataset, its sample rate [Hz] where the feedthrough is modelled (for responses off its data points).
    sample_rates_hz: tuple[float, ...] = ()
    #: Per dataset, the delay [s] of the command's zero-order hold, half a sample, where the measurement holds its
    #: command (samii.diagnose.sampling.with_hold_found): the DAQ's, never an effect of the rig; empty: not modelled.
    hold_s: tuple[float, ...] = ()
    #: The data show the hold (the model found fits better with it by the F-test's level); False: it is kept for
    #: explaining the sampling's delay with fewer effects, as well as without it (samii.diagnose.sampling.with_hold_found).
    hold_seen: bool = False

    def hold(self, i: int) -> float:
        """Dataset ``i``'s hold delay [s] (0 where not modelled)."""
        return float(self.hold_s[i]) if self.hold_s else 0.0

    @property
    def free(self) -> bool:
        return self.structure is not None and not self.fixed

    def factor(self, i: int, freq_hz: np.ndarray, c: str) -> np.ndarray | float:
        """The correction of dataset ``i``'s channel ``c`` at ``freq_hz`` (1 without one)."""
        if not self.correction:
            return 1.0

        corr = self.correction[i]
        f = np.asarray(freq_hz, float)
        if corr.freq_hz.size == f.size and np.array_equal(corr.freq_hz, f):
            return corr.response(c)
        h = interpolate_frf(corr, f)[c]
        return np.where(np.isfinite(h), h, 1.0)


#: The key of the sampled feedthrough's lag [samples] in a fit's per-file baseline parameters.
FEEDTHROUGH_KEY = "feedthrough_lag_samples"


def models_feedthrough(datasets: Sequence[Dataset], baseline: Baseline) -> bool:
    """Whether fits of ``baseline`` to ``datasets`` model the sampled feedthrough (:func:`feedthrough_term`): the
    baseline says so (``feedthrough_lag``, samii.diagnose.sampling), is a structure refitted (a saved fit's or
    the simulator's responses are held as they are), and a file states its sample rate and has xdd in a channel."""
    return (
        baseline.feedthrough_lag is not None
        and baseline.structure is not None
        and not baseline.fixed
        and not baseline.correction
        and any(ds.sample_rate_hz and any(ch in ds.data for ch in ("base", "total")) for ds in datasets)
    )


def start_vectors(fit: Fit) -> list[np.ndarray] | None:
    """``fit``'s per-file baseline vectors as a start for another fit, each with the feedthrough's lag after the
    structure's parameters where the fit has one (fit_model splits it off); None without a structure."""
    st = fit.baseline.structure
    if st is None or not fit.baseline_params:
        return None
    return [np.append(st.vector(p), p[FEEDTHROUGH_KEY]) if FEEDTHROUGH_KEY in p else st.vector(p) for p in fit.baseline_params]


#: The feedthrough's "infinite" frequency, in sample rates: a path whose corners lie above it settles within a
#: sixtieth of a sample (1/(2 pi 10)), so the held command's step reaches the next sample whole through it.
FEEDTHROUGH_AT_FS = 10.0
#: The feedthrough's lag lies within half a sample of the rest's: a DAQ that reads before it writes (+0.5), one
#: that writes first (-0.5), an analogue command (0); a fractional command delay moves it in between.
FEEDTHROUGH_LAG_MAX = 0.5


def feedthrough_term(
    structure, xb, effects, s: np.ndarray, lag_samples: float, sample_rate_hz: float, *, derivatives: bool = False, hold_s: float = 0.0
):
    """The sampling's correction to xdd/v where xdd/v has a direct feedthrough: ``S = D Md (e^{-s lag T} - 1)``.

    Physics. The notebook's theta/v has relative degree 2 and its xdd/theta grows as s^2, so xdd/v tends to a constant
    D at high frequency: a held (zero-order hold) command's steps pass straight into xdd. Sampled, the smooth part of
    xdd/v is the continuous response behind the hold's half-sample delay (within (w T)^2 / 24), but the steps of the
    feedthrough are read whole at the next sample when the DAQ reads its channels before it writes the command (D
    e^{-s T}, a full sample), in the same sample when it writes first (D, none), and as the rest when the command is
    analogue (no hold). So the data's xdd/v is the model's plus ``D Md (e^{-s lag T} - 1)`` with ``lag`` the
    feedthrough's delay beyond the rest in samples (+0.5, -0.5, 0; a command delay that is not a whole number of
    samples moves it between), Md the model's delays (they delay the step too). Near xdd/v's antiresonance, where D and
    the modes cancel, this is decibels at 500 Hz (eq 9.4: -2.8 dB and +16 deg at 20 Hz with lag 0.5; with S the model is
    within 0.2 dB and 2 deg of the exact alias sum from 0.7 Hz up, tests/test_diagnose_sampling.py). Left out here: the
    smooth part's own images (sampled_images, which a baseline carrying the hold adds; there the smooth part carries
    the hold's sinc and the steps, read whole, do not: ``S = D Md (e^{-s lag T} - sinc)``). D is the model (the
    structure and the effects other than delays) at FEEDTHROUGH_AT_FS sample rates: zero behind a low-pass or valve,
    where no step passes. ``hold_s``: the hold's delay where the baseline models it (Baseline.hold_s), one of Md.

    ``effects``: (kind, values) pairs. Returns (S, dlnS/dx_b (n_b,) or None, [dlnS/dp (points, params) per effect] or
    None, dS/dlag).
    """
    d0, d_ln_b, d_ln_e = _feedthrough_gain(structure, xb, effects, sample_rate_hz, derivatives=derivatives)
    md = np.exp(-s * hold_s) * _delays(effects, s) if hold_s else _delays(effects, s)
    period = 1.0 / sample_rate_hz
    shift = np.exp(-s * lag_samples * period)
    # the smooth part carries the hold's sinc (hold_factor); the steps are read whole, without it
    term = d0 * md * (shift - (_sinc(s, hold_s) if hold_s else 1.0))
    d_lag = d0 * md * shift * (-s * period)
    if not derivatives:
        return term, None, None, d_lag
    d_e = []
    for (k, p), d_ln in zip(effects, d_ln_e):  # a delay's at the points (it delays the step), any other's through D
        if d_ln is None:
            da, db, _ = k.derivatives(p, s)
            d_ln = sum(part for part in (da, db) if part is not None)
        d_e.append(np.broadcast_to(d_ln, (s.size, len(k.params))))
    return term, d_ln_b, d_e, d_lag


def _feedthrough_gain(structure, xb, effects, sample_rate_hz: float, *, derivatives: bool = False):
    """D, xdd/v's direct feedthrough: the model (the structure and the effects other than delays) at FEEDTHROUGH_AT_FS
    sample rates (feedthrough_term). Returns (D, d ln D/dx_b (n_b,) or None, [d ln D/dp (params,) per effect, None for
    a delay (D has none: a delay delays the step, at the points)]); the derivatives None without ``derivatives``."""
    s_inf = 1j * np.array([2.0 * np.pi * FEEDTHROUGH_AT_FS * sample_rate_hz])
    with np.errstate(all="ignore"):
        h = structure.log_responses(xb, s_inf.imag, ("act", "base"), derivatives=derivatives)
    smooth = [(k, p) for k, p in effects if k.category != "delay"]
    m_act, m_base, add = _effect_factors(smooth, s_inf)
    hb = h["base"][0]
    base_sum = hb if add is None else hb + add
    d0 = (h["act"][0] * (1.0 if m_act is None else m_act) * base_sum * (1.0 if m_base is None else m_base))[0]
    if not derivatives:
        return d0, None, None
    d_ln_b = None if h["act"][1] is None else h["act"][1][0] + h["base"][1][0] * (hb / base_sum)[0]
    d_ln_e = []
    for k, p in effects:
        if k.category == "delay":
            d_ln_e.append(None)
            continue
        da, db, dA = k.derivatives(p, s_inf)
        d_ln = np.zeros(len(k.params), complex)
        for part in (da, db):
            if part is not None:
                d_ln = d_ln + part[0]
        if dA is not None:
            d_ln = d_ln + dA[0] / base_sum[0]
        d_ln_e.append(d_ln)
    return d0, d_ln_b, d_ln_e


def _delays(effects, s: np.ndarray):
    """The product of the delays' factors on xdd/v at ``s`` (1 without one)."""
    md = 1.0
    for k, p in effects:
        if k.category == "delay":
            ma, mb, _ = k.response(p, s)
            for m in (ma, mb):
                if m is not None:
                    md = md * m
    return md


def _sinc(s: np.ndarray, hold_s: float) -> np.ndarray:
    """The hold's magnitude, sin(w h) / (w h) (h half a sample)."""
    return np.sinc(s.imag * hold_s / np.pi)


def hold_factor(s: np.ndarray, hold_s: float) -> np.ndarray:
    """A zero-order hold of a sample 2 ``hold_s`` long at the points ``s``: e^{-s h} sin(w h) / (w h), the held
    command's response in the band (its images are :func:`sampled_images`)."""
    return np.exp(-s * hold_s) * _sinc(s, hold_s)


#: The images of a held command summed either side of the band (k = +-1 .. +-ALIAS_BANDS; sampled_images).
ALIAS_BANDS = 8


def sampled_images(structure, xb, effects, w: np.ndarray, hold_s: float, *, total: bool, derivatives: bool = False):
    """What sampling adds to the held command's response in the band: the images of the rest of the spectrum.

    Physics. A command held for a sample T = 2 h reaches the rig as ``Z(w) = (1 - e^{-j w T}) / (j w T)`` times the
    samples' spectrum, which repeats every 2 pi / T; the outputs read at the sample instants fold the spectrum back, so
    the data's response is ``sum_k H(j w_k) Z(w_k)``, w_k = w + 2 pi k / T (Franklin, Powell & Workman, Digital
    Control of Dynamic Systems, sec. 6.2: the pulse transfer function). k = 0 is ``H hold_factor``; the rest, the
    images, is what this returns. theta/v rolls off at least as 1/w^2 and its images are a few hundredths of a per cent
    of it; xdd/v rolls off at most as 1/w beyond its constant (behind a first-order accelerometer, 1/w from the
    corner on), and its images are ``(x / sin x)^2 - 1 ~ x^2 / 3`` of the 1/w part, x = w h: 1.7 % at 36 Hz at
    500 Hz (the second rig's 30 Hz roll-off, measured at 500 Hz, left them as a broad base "mode" at 36.7 Hz). Its
    constant D is taken out (its steps are feedthrough_term's, summed exactly there). The terms fall as 1/k^2: the
    first ALIAS_BANDS either side hold all but 7 % of a 1/w tail's images.

    ``total``: also xdd/v's, of (act base - D Md). Returns (theta/v's images, xdd/v's or None, derivatives or None) at
    ``w`` [rad/s]; with ``derivatives``, {"act" | "total": (d/dx_b (points, n_b) or None, [d/dp (points, params) per
    effect])}, of the images themselves (not their logs: they pass through zero)."""
    period = 2.0 * hold_s
    ws = 2.0 * np.pi / period
    ks = np.concatenate([-np.arange(ALIAS_BANDS, 0, -1), np.arange(1, ALIAS_BANDS + 1)])
    w = np.asarray(w, float)
    wk = w[None, :] + ks[:, None] * ws
    flat = wk.ravel()
    sk = 1j * flat
    zk = ((1.0 - np.exp(-1j * w * period))[None, :] / (1j * wk * period)).ravel()

    def fold(x: np.ndarray) -> np.ndarray:  # sum over the bands, each weighted by the hold: (bands x points, ...) -> (points, ...)
        x = x * zk.reshape((-1,) + (1,) * (x.ndim - 1))
        return x.reshape(wk.shape + x.shape[1:]).sum(axis=0)

    with np.errstate(all="ignore"):
        h = structure.log_responses(xb, flat, ("act", "base") if total else ("act",), derivatives=derivatives)
    m_act, m_base, add = _effect_factors(effects, sk)
    act = h["act"][0] if m_act is None else h["act"][0] * m_act
    images_act = fold(act)
    images_total = None
    if total:
        mb = 1.0 if m_base is None else m_base
        base = (h["base"][0] if add is None else h["base"][0] + add) * mb
        d0, d_ln_d0_b, d_ln_d0_e = _feedthrough_gain(structure, xb, effects, 0.5 / hold_s, derivatives=derivatives)
        md = _delays(effects, sk) * np.ones(flat.size)
        images_total = fold(act * base - d0 * md)
    if not derivatives:
        return images_act, images_total, None
    out = {}
    col = lambda x: x[:, None]
    d_b_act = None if h["act"][1] is None else fold(col(act) * h["act"][1])
    d_b_total = None
    if total and h["act"][1] is not None:
        d_b_total = fold(col(act * base) * h["act"][1] + col(act * mb * h["base"][0]) * h["base"][1] - col(d0 * md) * d_ln_d0_b[None, :])
    d_e_act, d_e_total = [], []
    for j, (kind, p) in enumerate(effects):
        da, db, dA = kind.derivatives(p, sk)
        zero = np.zeros((flat.size, len(kind.params)), complex)
        d_e_act.append(fold(zero if da is None else col(act) * da))
        if not total:
            continue
        c = zero
        for part in (da, db):
            if part is not None:
                c = c + col(act * base) * part
        if dA is not None:
            c = c + col(act * mb) * dA
        # D Md: a delay's own factor in Md, any other effect's in D (at FEEDTHROUGH_AT_FS sample rates)
        d_ln_md = sum(part for part in (da, db) if part is not None) if d_ln_d0_e[j] is None else d_ln_d0_e[j][None, :]
        d_e_total.append(fold(c - col(d0 * md) * d_ln_md))
    out["act"] = (d_b_act, d_e_act)
    if total:
        out["total"] = (d_b_total, d_e_total)
    return images_act, images_total, out


@dataclass(frozen=True, eq=False)
class Fit:
    """A fitted baseline + effects."""

    baseline: Baseline
    baseline_params: tuple[dict, ...]  # per dataset (empty for a fixed baseline)
    baseline_stderr: tuple[dict, ...]
    effects: tuple[Effect, ...]
    chi2: float  # sum of squared weighted residuals over all datasets
    n_residuals: int
    n_params: int
    residuals: tuple[dict, ...]  # per dataset: channel -> complex log ratio e = ln(data/model) (usable points)
    #: (value, standard error) of the sampled feedthrough's lag [samples] where it is modelled (error 0 when held)
    feedthrough_lag: tuple[float, float] | None = None
    #: The fit was stopped short of convergence as unable to get below the chi2 it had to beat (``fit_model``'s
    #: ``beat``, :func:`_hopeless`): its chi2 is where it stood, the optimum from its start lies above that chi2
    stopped: bool = False

    @property
    def dof(self) -> int:
        return max(self.n_residuals - self.n_params, 1)


def _effect_factors(effects: Sequence[tuple[EffectKind, np.ndarray]], s: np.ndarray) -> tuple:
    """(M_act, M_base, A_base) of all the effects together at the points ``s``: the products of their factors and
    the sum of their added terms (module docstring of effects), each None where no effect has one."""
    m_act = m_base = add = None
    for kind, p in effects:
        ma, mb, a = kind.response(p, s)
        if ma is not None:
            m_act = ma if m_act is None else m_act * ma
        if mb is not None:
            m_base = mb if m_base is None else m_base * mb
        if a is not None:
            add = a if add is None else add + a
    return m_act, m_base, add


def _apply(effects: Sequence[tuple[EffectKind, np.ndarray]], base: dict[str, np.ndarray], s: np.ndarray) -> dict[str, np.ndarray]:
    """The baseline's act and/or base at the points ``s`` with the effects applied: act M_act, (base + A_base) M_base."""
    m_act, m_base, add = _effect_factors(effects, s)
    out = dict(base)
    if "act" in out and m_act is not None:
        out["act"] = out["act"] * m_act
    if "base" in out:
        b = out["base"] if add is None else out["base"] + add
        out["base"] = b if m_base is None else b * m_base
    return out


class _Layout:
    """The optimiser's vector: baseline parameters per dataset (if free), then each effect's."""

    def __init__(
        self,
        baseline: Baseline,
        n_data: int,
        effects: Sequence[EffectKind],
        starts_b: Sequence[np.ndarray],
        starts_e: Sequence[np.ndarray],
        free_baseline: bool,
        lag_start: float | None = None,
    ):
        self.baseline = baseline
        self.free_baseline = free_baseline
        #: the feedthrough's lag [samples] is a variable (the last) when started (feedthrough_term)
        self.n_lag = 0 if lag_start is None else 1
        self.effects = list(effects)
        st = baseline.structure
        self.nb = len(st.param_names) if (free_baseline and st is not None) else 0
        self.n_data = n_data
        self.pos = st.positive if st is not None else np.zeros(0, bool)
        self.b_scale = [np.where(self.pos, 1.0, np.where(np.abs(b) > 0, np.abs(b), 1.0)) for b in starts_b]
        self.e_scale = []
        for kind, e0 in zip(self.effects, starts_e):
            sc = []
            for p, v in zip(kind.params, e0):
                if p.transform == "log":
                    sc.append(1.0)
                elif p.name == "delay_s":
                    sc.append(1e-3)
                else:
                    sc.append(abs(v) if v != 0 else 1.0)
            self.e_scale.append(np.array(sc))

    def to_z(self, xs_b: Sequence[np.ndarray], xs_e: Sequence[np.ndarray]) -> np.ndarray:
        z = []
        if self.nb:
            for x, sc in zip(xs_b, self.b_scale):
                z.append(np.where(self.pos, np.log(np.where(self.pos, x, 1.0)), x / sc))
        for kind, x, sc in zip(self.effects, xs_e, self.e_scale):
            z.append(np.array([np.log(v) if p.transform == "log" else v / s for p, v, s in zip(kind.params, x, sc)]))
        return np.concatenate(z) if z else np.zeros(0)

    def lag(self, z: np.ndarray) -> float | None:
        """The feedthrough's lag [samples] in ``z`` (None when it is not a variable)."""
        return float(z[-1]) if self.n_lag else None

    def from_z(self, z: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
        xs_b, xs_e = [], []
        i = 0
        if self.nb:
            for sc in self.b_scale:
                zz = z[i : i + self.nb]
                xs_b.append(np.where(self.pos, np.exp(np.where(self.pos, zz, 0.0)), zz * sc))
                i += self.nb
        for kind, sc in zip(self.effects, self.e_scale):
            n = len(kind.params)
            zz = z[i : i + n]
            xs_e.append(np.array([np.exp(v) if p.transform == "log" else v * s for p, v, s in zip(kind.params, zz, sc)]))
            i += n
        return xs_b, xs_e

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = [], []
        if self.nb:
            own = getattr(self.baseline.structure, "log_bounds", None)  # a structure with its own (LocalSimulator)
            for _ in range(self.n_data):
                if own is not None:
                    a, b = own()
                    lo += list(a)
                    hi += list(b)
                    continue
                lo += [np.log(1e-4) if p else -np.inf for p in self.pos]
                hi += [np.log(1e6) if p else np.inf for p in self.pos]
        for kind, sc in zip(self.effects, self.e_scale):
            for p, s in zip(kind.params, sc):
                if p.transform == "log":
                    lo.append(np.log(p.lo))
                    hi.append(np.log(p.hi))
                else:
                    lo.append(p.lo / s)
                    hi.append(p.hi / s)
        if self.n_lag:
            lo.append(-FEEDTHROUGH_LAG_MAX)
            hi.append(FEEDTHROUGH_LAG_MAX)
        return np.array(lo), np.array(hi)


#: Which of the baseline's channels each fitted channel needs.
_NEED = {"act": ("act",), "base": ("base",), "total": ("act", "base")}


@dataclass(frozen=True, eq=False)
class _Block:
    """One channel of one dataset, what its residual needs precomputed."""

    i: int  # dataset
    ch: str
    w: np.ndarray  # angular frequencies of the usable points [rad/s]
    at: np.ndarray  # their indices on the dataset's grid
    #: their positions among the points any block of the dataset uses (_Problem.points), None where they are all of them
    pos: np.ndarray | None
    data: np.ndarray
    inv_sigma: np.ndarray
    fixed: Mapping[str, np.ndarray] | None  # a fixed baseline's responses
    factor: Mapping[str, np.ndarray]  # the baseline's correction on these points (empty: none)


class _Problem:
    """The weighted residual vector of a fit, ``[Re e, Im e] / sigma`` per dataset and channel
    (module docstring), and its Jacobian in the optimiser's variables.

    The Jacobian is analytic: the baseline structure gives ``d ln H / dx`` (eq 9.1/9.2 term by term,
    or the simulator's sensitivity), each effect kind ``d ln M / dp`` and ``dA/dp``
    (:mod:`samii.diagnose.effects`); with the additive term the base is ``(H c + A) M``, so
    ``d ln base / dx = (d ln H / dx) H c / (H c + A)`` and ``d ln base / dp = d ln M / dp + (dA/dp) / (H c + A)``.
    The residual is ``ln data - ln model``: its derivative is minus the model's."""

    def __init__(
        self, datasets: Sequence[Dataset], baseline: Baseline, layout: _Layout, fixed_b: Sequence[np.ndarray], held_lag: float | None = None
    ):
        """``held_lag``: the sampled feedthrough's lag [samples] held (feedthrough_term); it is modelled when that is
        given or the layout frees it, on the datasets that state their sample rate and have xdd in a channel."""
        self.baseline, self.layout, self.fixed_b = baseline, layout, list(fixed_b)
        self.blocks = []
        #: per dataset: its grid [rad/s] and the baseline channels its blocks need (computed once for all of them)
        self.grids: list[tuple[np.ndarray, tuple[str, ...]]] = []
        #: the sampled feedthrough (feedthrough_term): its lag when held, and per dataset its sample rate [Hz] where it is
        #: modelled (None where not: no rate stated, no xdd, a fixed baseline, a held lag of 0)
        self.held_lag = held_lag
        models_ft = baseline.structure is not None and not baseline.fixed and (bool(layout.n_lag) or bool(held_lag))
        self.ft_rate: list[float | None] = [
            float(ds.sample_rate_hz) if models_ft and ds.sample_rate_hz and any(ch in ds.data for ch in ("base", "total")) else None
            for ds in datasets
        ]
        #: per dataset, the command's hold [s] where the baseline models it (Baseline.hold_s; a structure refitted):
        #: its blocks are the sampled response (hold_factor, sampled_images, the feedthrough with its lag or none)
        self.hold = [baseline.hold(i) if baseline.structure is not None and not baseline.fixed else 0.0 for i in range(len(datasets))]
        #: per dataset: the points (s = jw) any of its blocks uses, where the effects are evaluated once for all of them
        self.points: list[np.ndarray] = []
        for i, ds in enumerate(datasets):
            used = np.flatnonzero(np.any([ds.keep[ch] for ch in ds.data], axis=0)) if ds.data else np.zeros(0, int)
            self.points.append(1j * (2.0 * np.pi * ds.freq_hz[used]))
            for ch in ds.data:
                k = ds.keep[ch]
                at = np.flatnonzero(k)
                factor = {}
                if baseline.correction:
                    factor = {c: np.broadcast_to(baseline.factor(i, ds.freq_hz, c), ds.freq_hz.shape)[k] for c in _NEED[ch]}
                fixed = {c: baseline.fixed[i][ch][c] for c in _NEED[ch]} if baseline.fixed else None
                pos = None if at.size == used.size else np.searchsorted(used, at)
                self.blocks.append(_Block(i, ch, 2.0 * np.pi * ds.freq_hz[k], at, pos, ds.data[ch], ds.inv_sigma[ch], fixed, factor))
            need = tuple(c for c in ("act", "base") if any(c in self._need(i, ch) for ch in ds.data))
            self.grids.append((2.0 * np.pi * np.asarray(ds.freq_hz, float), need))
        #: the held baseline's responses per dataset (a fit with the baseline held evaluates them once)
        self._held: dict[int, dict] = {}
        #: (z, Jacobian at z) of the last :meth:`residuals`, for :meth:`jacobian` to give once
        self._last: tuple[np.ndarray, np.ndarray] | None = None

    def _need(self, i: int, ch: str) -> tuple[str, ...]:
        """The baseline channels block ``ch`` of dataset ``i`` needs: xdd/theta with the feedthrough needs act too."""
        return ("act", "base") if ch == "base" and (self.ft_rate[i] is not None or self.hold[i]) else _NEED[ch]

    def _feedthrough(self, blk: _Block, xs_b, z) -> tuple | None:
        """(baseline vector, lag [samples], sample rate [Hz]) of ``blk``'s feedthrough term, None where it has none
        (theta/v; a dataset where it is not modelled)."""
        rate = self.ft_rate[blk.i]
        if blk.ch == "act":
            return None
        if rate is None:  # with the hold the steps are still read, as the rest where no lag is modelled
            return (xs_b[blk.i], 0.0, 0.5 / self.hold[blk.i]) if self.hold[blk.i] else None
        lag = self.layout.lag(z)
        return xs_b[blk.i], self.held_lag if lag is None else lag, rate

    def _all_responses(self, xs_b, derivatives: bool) -> list[dict | None]:
        """:meth:`_responses` of every dataset (None where the baseline is fixed responses)."""
        if self.baseline.fixed or not xs_b:
            return [None] * len(self.grids)
        return [self._responses(i, xb, derivatives) for i, xb in enumerate(xs_b)]

    def _responses(self, i: int, xb, derivatives: bool) -> dict:
        """The baseline's (H, dlogH/dx or None) of dataset ``i`` on its whole grid, for every channel its blocks need:
        one evaluation of the structure per dataset, which its blocks index (theta/v and xdd/v share act, xdd/theta
        and xdd/v share base)."""
        if not self.layout.nb:  # held: its derivatives go unused
            if i not in self._held:
                w, need = self.grids[i]
                with np.errstate(divide="ignore", invalid="ignore"):
                    self._held[i] = self.baseline.structure.log_responses(xb, w, need, derivatives=False)
            return self._held[i]
        w, need = self.grids[i]
        with np.errstate(divide="ignore", invalid="ignore"):  # a point no block uses may sit on a pole
            return self.baseline.structure.log_responses(xb, w, need, derivatives=derivatives)

    def _effects_at(self, i: int, eff, derivatives: bool) -> tuple:
        """The effects at dataset ``i``'s points (:attr:`points`), once for all its blocks: (M_act, M_base, A_base) as
        :func:`_effect_factors`, and with ``derivatives`` each effect's (d ln M_act/dp, d ln M_base/dp, dA/dp)."""
        s = self.points[i]
        return _effect_factors(eff, s), [kind.derivatives(p, s) for kind, p in eff] if derivatives else None

    def _model(self, blk: _Block, resp: dict | None, eff, derivatives: bool, at_points: tuple, ft=None, xb=None):
        """(model, d ln model / d(baseline x) or None, [d ln model / d(effect p)] or None, d ln model / d(lag) or None)
        of one block; ``resp``: its dataset's baseline responses (:meth:`_responses`; None for a fixed baseline);
        ``ft``: its feedthrough (:meth:`_feedthrough`), the term xdd/v and xdd/theta carry; ``xb``: its dataset's
        baseline vector (the sampled images need it); ``at_points``: the effects at its dataset's points
        (:meth:`_effects_at`), which the block picks its own from."""
        need = _NEED[blk.ch] if ft is None else ("act", "base")
        s = 1j * blk.w
        pick = (lambda a: a) if blk.pos is None else (lambda a: None if a is None else a[blk.pos])
        if blk.fixed is not None:
            h = dict(blk.fixed)
            dh = dict.fromkeys(need)
        else:
            h = {c: resp[c][0][blk.at] * blk.factor[c] if blk.factor else resp[c][0][blk.at] for c in need}
            dh = {c: None if resp[c][1] is None else resp[c][1][blk.at] for c in need}
        m_act, m_base, add = (pick(a) for a in at_points[0])
        act = base = base_sum = None
        hold = self.hold[blk.i]
        if "act" in h:
            act = h["act"] if m_act is None else h["act"] * m_act
        if "base" in h:
            base_sum = h["base"] if add is None else h["base"] + add
            base = base_sum if m_base is None else base_sum * m_base
        # the command's hold (Baseline.hold_s): the held command's response in the band, a constant factor, and the
        # images of the rest of the spectrum (sampled_images)
        w_a = 1.0  # d ln(theta/v as sampled) = w_a d ln act + d(images)/act_s
        act_s = act
        images_total = d_images = None
        if hold:
            act = act * hold_factor(s, hold)
            images_act, images_total, d_images = sampled_images(
                self.baseline.structure, xb if ft is None else ft[0], eff, blk.w, hold, total=blk.ch != "act", derivatives=derivatives
            )
            act_s = act + images_act
            w_a = act / act_s
        term = d_lag = None
        if ft is None:
            model = base if act is None else act_s if base is None else act * base
        else:  # xdd/v = act base + S (+ the images); xdd/theta = xdd/v / theta/v
            xb, lag, fs = ft
            term, dt_b, dt_e, d_lag = feedthrough_term(self.baseline.structure, xb, eff, s, lag, fs, derivatives=derivatives, hold_s=hold)
            total = act * base + term
            if images_total is not None:
                total = total + images_total
            model = total if blk.ch == "total" else total / act_s
        if not derivatives:
            return model, None, None, None
        # d ln(act base) = d ln act + d ln base; with the term: w_P d ln(act base) + w_S d ln S (- w_a d ln act for
        # xdd/theta); with the hold each channel's images too: + d(images)/(its response)
        w_p = w_s = None
        if term is not None:
            w_s = term / total
            w_p = act * base / total
        d_b = None
        if blk.fixed is None and self.layout.nb:
            d_act = dh["act"] if "act" in h else 0.0
            d_base = 0.0 if "base" not in h else (dh["base"] if add is None else dh["base"] * (h["base"] / base_sum)[:, None])
            if term is None:
                d_b = d_act + d_base
                if hold and blk.ch == "act":
                    d_b = w_a[:, None] * d_b + d_images["act"][0] / act_s[:, None]
            else:
                d_b = w_p[:, None] * (d_act + d_base) + w_s[:, None] * dt_b[None, :]
                if hold:
                    d_b = d_b + d_images["total"][0] / total[:, None]
                if blk.ch == "base":
                    d_b = d_b - (w_a[:, None] * d_act + d_images["act"][0] / act_s[:, None] if hold else d_act)
        d_e = []
        for j, (kind, _) in enumerate(eff):
            da, db, dA = (pick(a) for a in at_points[1][j])
            col = np.zeros((s.size, len(kind.params)), complex)
            if da is not None and "act" in h:
                col += da
            if "base" in h:
                if db is not None:
                    col += db
                if dA is not None:
                    col += dA / base_sum[:, None]
            if term is not None:
                col = w_p[:, None] * col + w_s[:, None] * dt_e[j]
                if hold:
                    col = col + d_images["total"][1][j] / total[:, None]
                if blk.ch == "base":
                    if da is not None:
                        col = col - (w_a[:, None] * da if hold else da)
                    if hold:
                        col = col - d_images["act"][1][j] / act_s[:, None]
            elif hold and blk.ch == "act":
                col = w_a[:, None] * col + d_images["act"][1][j] / act_s[:, None]
            d_e.append(col)
        dl = None if d_lag is None else d_lag / total
        return model, d_b, d_e, dl

    def _split(self, z):
        xs_b, xs_e = self.layout.from_z(z)
        if not self.layout.nb:
            xs_b = self.fixed_b
        return xs_b, xs_e

    def evaluate(self, z: np.ndarray):
        """(per dataset: channel -> complex residual ln(data/model), baseline vectors, effect vectors) at ``z``."""
        res, xs_b, xs_e, _ = self._evaluate(z, derivatives=False)
        return res, xs_b, xs_e

    def _evaluate(self, z: np.ndarray, derivatives: bool):
        """:meth:`evaluate`'s three and, with ``derivatives``, the Jacobian d(residual vector)/dz (else None): one
        pass over the blocks, the model of each computed once for both (its value does not depend on whether its
        derivatives are asked for)."""
        xs_b, xs_e = self._split(z)
        eff = list(zip(self.layout.effects, xs_e))
        res: list[dict] = [{} for _ in range(max((b.i for b in self.blocks), default=-1) + 1)]
        resp = self._all_responses(xs_b, derivatives)
        at_points = [self._effects_at(i, eff, derivatives) for i in range(len(self.points))]
        dxdz = self._dxdz(xs_b, xs_e) if derivatives else None
        rows = []
        for blk in self.blocks:
            ft, xb = self._feedthrough(blk, xs_b, z), xs_b[blk.i] if xs_b else None
            model, d_b, d_e, d_lag = self._model(blk, resp[blk.i], eff, derivatives, at_points[blk.i], ft, xb)
            e = np.log(blk.data / model)  # one log of the ratio: its phase wrapped to (-pi, pi]
            res[blk.i][blk.ch] = e
            if derivatives:
                d = self._block_jacobian(blk, e, d_b, d_e, d_lag, dxdz, z.size)
                rows += [d.real, d.imag]
        if not derivatives:
            return res, xs_b, xs_e, None
        jac = np.concatenate(rows, axis=0) if rows else np.zeros((0, z.size))
        return res, xs_b, xs_e, jac if np.isfinite(jac).all() else np.where(np.isfinite(jac), jac, 0.0)

    def _dxdz(self, xs_b, xs_e) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """dx/dz of every variable, (baseline's per dataset, effects' per effect): x for a log-transformed one, the
        scale for a linear one."""
        lay = self.layout
        dxdz_b = [np.where(lay.pos, x, sc) for x, sc in zip(xs_b, lay.b_scale)] if lay.nb else []
        dxdz_e = [
            np.array([v if p.transform == "log" else c for p, v, c in zip(k.params, x, sc)]) for k, x, sc in zip(lay.effects, xs_e, lay.e_scale)
        ]
        return dxdz_b, dxdz_e

    def _block_jacobian(self, blk: _Block, e: np.ndarray, d_b, d_e, d_lag, dxdz, n: int) -> np.ndarray:
        """d(weighted residual)/dz of one block (complex: its real and imaginary rows), from :meth:`_model`'s
        derivatives of ln model and :meth:`_dxdz`; zero where its residual ``e`` is not finite."""
        lay = self.layout
        dxdz_b, dxdz_e = dxdz
        d = np.zeros((blk.w.size, n), complex)
        if lay.nb:
            j0 = blk.i * lay.nb
            d[:, j0 : j0 + lay.nb] = d_b * dxdz_b[blk.i]
        j = lay.nb * lay.n_data
        for col, f in zip(d_e, dxdz_e):
            d[:, j : j + f.size] = col * f
            j += f.size
        if lay.n_lag and d_lag is not None:
            d[:, n - 1] = d_lag
        d *= -blk.inv_sigma[:, None]
        d[~np.isfinite(e)] = 0.0
        return d

    def vector(self, res) -> np.ndarray:
        parts = []
        for blk in self.blocks:
            e = res[blk.i][blk.ch]
            parts.append(e.real * blk.inv_sigma)
            parts.append(e.imag * blk.inv_sigma)
        return np.concatenate(parts)

    def residuals(self, z: np.ndarray) -> np.ndarray:
        """The weighted residual vector (non-finite entries as 1e6: a model with a pole on a point).

        Its Jacobian is computed with it and kept for :meth:`jacobian`: the optimiser (scipy's trf) asks for the
        Jacobian at every point whose step it accepts, right after the residuals there, and accepts most."""
        with np.errstate(all="ignore"):
            res, _, _, jac = self._evaluate(z, derivatives=True)
            v = self.vector(res)
        self._last = (np.array(z, float, copy=True), jac)
        return np.where(np.isfinite(v), v, 1e6)

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        """d(residual vector)/dz, analytic (class docstring); rows whose residual is not finite are zero."""
        last, self._last = self._last, None
        if last is not None and np.array_equal(last[0], z):
            return last[1]
        with np.errstate(all="ignore"):
            return self._evaluate(z, derivatives=True)[3]


#: Singular values of the Jacobian below this fraction of the largest are directions the data do not determine.
NULL_RCOND = 1e-8


def _standard_errors(jac: np.ndarray, s2: float) -> np.ndarray:
    """sqrt(diag(s2 (J'J)^-1)) in the determined directions; infinite for a parameter with a share in a
    direction the data do not determine (e.g. the base's parameters when a file has only theta/v)."""

    _, sv, vt = scipy.linalg.svd(jac, full_matrices=False, check_finite=False)
    ok = sv > NULL_RCOND * (sv[0] if sv.size else 0.0)
    inv = np.where(ok, 1.0 / np.where(ok, sv, 1.0) ** 2, 0.0)
    se = np.sqrt(np.clip((vt.T**2) @ inv * s2, 0, None))
    undetermined = np.any(np.abs(vt[~ok]) > 1e-3, axis=0) if np.any(~ok) else np.zeros(jac.shape[1], bool)
    return np.where(undetermined, np.inf, se)


#: The optimiser stops when a step lowers chi2 by less than this fraction of it (or moves the parameters by less
#: than this fraction): with chi2 near the number of residuals (about 700 for a 0.1-40 Hz file) that is 1e-3 of
#: one noise variance, a thousandth of the smallest difference a selection acts on (an F-test's or
#: AMBIGUOUS_CHI2's few variances), and far inside any parameter's standard error. At 1e-8 three of the speed
#: benchmark's files took 10-30 % longer for the same findings and values.
FIT_TOL = 1e-6

#: A fit that matters only if it gets below a chi2 (``fit_model``'s ``beat``: a rival that must beat the model it
#: would replace, the baseline refitted alone from a candidate's baseline, :mod:`samii.diagnose.select`) stops
#: when, after HOPELESS_AFTER iterations, it is still above that chi2 and its last HOPELESS_WINDOW iterations
#: lowered chi2 by less than 1/HOPELESS_PACE of what remains: at that pace it would need more than
#: HOPELESS_WINDOW x HOPELESS_PACE further iterations. Such fits are models that cannot describe the data (the
#: baseline without the 4 ms delay the file has, chi2 11000 against 629 with it), crawling along a valley of
#: two modes with huge opposite gains: on the speed benchmark's 4 ms delay file 26 of the 85 joint fits ran to the
#: 200-evaluation budget (8.8 s of their 10.0 s), ending 6-7 chi2 units above the model they had to beat and still
#: falling by 0.5 a step. Measured on 221 such fits of five benchmark files (2026-11-29): the rule stops 57 of them
#: and saves 56 % of their iterations; none of the 67 that ended below their chi2 is stopped. (Bounding the modes'
#: gains at 20-100x the start's largest does not end the crawl: it goes on along the other parameters.)
HOPELESS_AFTER = 20
HOPELESS_WINDOW = 10
HOPELESS_PACE = 10.0


def _hopeless(beat: float):
    """A least-squares callback that stops the fit by the rule above (its chi2 is twice scipy's cost)."""
    history: list[float] = []

    def callback(intermediate_result) -> None:
        chi2 = 2.0 * float(intermediate_result.cost)
        history.append(chi2)
        k = len(history)
        if k > max(HOPELESS_AFTER, HOPELESS_WINDOW) and chi2 > beat and (history[-1 - HOPELESS_WINDOW] - chi2) * HOPELESS_PACE < chi2 - beat:
            raise StopIteration

    return callback


def noise_level(chi2: float, dof: int) -> float:
    """The noise's level on a fit's chi2 scale (per residual): chi2 per degree of freedom, never below the stated
    noise's 1; the standard errors here and every test of samii.diagnose.select count in it.

    Above 1 the data (or the model) are worse than stated: counted in that, an understated noise does not make
    effects appear. Below 1 the stated noise is larger than the scatter somewhere (a systematic floor,
    samii.measure.floor, on a channel an effect does not touch: a 16-bit encoder's quantisation held theta/v's chi2
    at 0.47 beside xdd/v's 0.78), not smaller where the effect acts: counted in that smaller level a 3-parameter
    "mode" fitted to one rough point of a clean xdd/v passed at p = 10^-4.9 (F 8.6; 5.3 in the stated noise). The
    floors are what the measurement vouches for; the level does not undo them."""
    return max(chi2 / dof, 1.0)


def fit_model(
    datasets: Sequence[Dataset],
    baseline: Baseline,
    effects: Sequence[tuple[EffectKind, np.ndarray]],
    *,
    free_baseline: bool | None = None,
    start_baseline: Sequence[np.ndarray] | None = None,
    max_nfev: int = 200,
    lag_start: float | None = None,
    beat: float | None = None,
) -> Fit:
    """Fit the effects (and the baseline, if free) to the datasets.

    Parameters
    ----------
    effects : sequence of (EffectKind, start values in the kind's parameter order)
    free_baseline : bool, optional
        Refit the baseline's parameters (default: when the baseline is a structure, not fixed responses).
    start_baseline : per-dataset parameter vectors, optional
        Default: ``baseline.params``.
    lag_start : float, optional
        Start the sampled feedthrough's lag [samples] here (:func:`feedthrough_term`), and fit it even when the baseline
        is held. By default it is modelled where the baseline says so (``feedthrough_lag``), started from the
        start vectors' (:func:`start_vectors`) or the baseline's, and free when the baseline is; the result's
        ``feedthrough_lag`` and each file's parameters (``FEEDTHROUGH_KEY``) hold it.
    beat : float, optional
        The fit matters only if its chi2 gets below this: it stops when it cannot (``HOPELESS_AFTER``; the result's
        ``stopped`` says so).
    """
    free = baseline.free if free_baseline is None else (free_baseline and baseline.free)
    st = baseline.structure
    xb0 = (
        list(start_baseline)
        if start_baseline is not None
        else ([st.vector(p) for p in baseline.params] if st is not None and baseline.params else [])
    )
    # the sampled feedthrough's lag (feedthrough_term): free with the baseline, else held; a start vector one longer than
    # the structure's carries it (start_vectors)
    lag0 = None
    if st is not None and xb0 and len(xb0[0]) == len(st.param_names) + 1:
        lag0, xb0 = float(xb0[0][-1]), [np.asarray(x[:-1], float) for x in xb0]
    modelled = models_feedthrough(datasets, baseline) or (lag_start is not None and st is not None and not baseline.fixed)
    if modelled:
        lag0 = lag_start if lag_start is not None else lag0 if lag0 is not None else float(baseline.feedthrough_lag)
    free_lag = modelled and (free or lag_start is not None)
    kinds = [k for k, _ in effects]
    xe0 = [np.clip(np.asarray(v, float), [p.lo for p in k.params], [p.hi for p in k.params]) for k, v in effects]
    layout = _Layout(baseline, len(datasets), kinds, xb0, xe0, free, lag0 if free_lag else None)
    z0 = layout.to_z(xb0, xe0)
    if layout.n_lag:
        z0 = np.append(z0, lag0)
    lo, hi = layout.bounds()
    with np.errstate(invalid="ignore"):
        z0 = np.clip(z0, np.where(np.isfinite(lo), lo + 1e-9 * (np.abs(lo) + 1), lo), np.where(np.isfinite(hi), hi - 1e-9 * (np.abs(hi) + 1), hi))
    problem = _Problem(datasets, baseline, layout, xb0, held_lag=lag0 if modelled and not free_lag else None)
    if z0.size:
        sol = least_squares(
            problem.residuals,
            z0,
            jac=problem.jacobian,
            bounds=(lo, hi),
            method="trf",
            x_scale="jac",
            max_nfev=max_nfev,
            xtol=FIT_TOL,
            ftol=FIT_TOL,
            gtol=1e-8,
            callback=None if beat is None else _hopeless(beat),
        )
        z, jac = sol.x, sol.jac
        stopped = sol.status == -2
    else:
        z, jac, stopped = z0, np.zeros((0, 0)), False
    res, xs_b, xs_e = problem.evaluate(z)
    v = problem.vector(res)
    chi2 = float(v @ v)
    m, n = v.size, z.size
    corr = max(ds.corr_length for ds in datasets)
    # standard errors (transformed space -> values)
    se_z = np.full(n, np.inf)
    if n:
        s2 = noise_level(chi2, max(m - n, 1)) * corr
        try:
            se_z = _standard_errors(jac, s2)
        except np.linalg.LinAlgError:
            pass
    b_params, b_se = [], []
    i = 0
    if layout.nb:
        for x, sc in zip(xs_b, layout.b_scale):
            se = se_z[i : i + layout.nb]
            b_params.append(st.params(x))
            b_se.append({name: float(val * s if p else s * c) for name, val, s, p, c in zip(st.param_names, x, se, layout.pos, sc)})
            i += layout.nb
    elif st is not None and xs_b:
        b_params = [st.params(x) for x in xs_b]
        b_se = [{name: 0.0 for name in st.param_names} for _ in xs_b]
    out_eff = []
    for kind, x, sc in zip(layout.effects, xs_e, layout.e_scale):
        k = len(kind.params)
        se = se_z[i : i + k]
        values = {p.name: float(val) for p, val in zip(kind.params, x)}
        errs = {p.name: float(val * s if p.transform == "log" else s * c) for p, val, s, c in zip(kind.params, x, se, sc)}
        out_eff.append(Effect(kind, values, errs))
        i += k
    lag = None if not modelled else (float(z[-1]), float(se_z[-1])) if layout.n_lag else (float(lag0), 0.0)
    if lag is not None:  # each file's parameters carry it (start_vectors, model_response)
        b_params = [{**p, FEEDTHROUGH_KEY: lag[0]} for p in b_params]
        b_se = [{**e, FEEDTHROUGH_KEY: lag[1]} for e in b_se]
    return Fit(baseline, tuple(b_params), tuple(b_se), tuple(out_eff), chi2, m, n, tuple(res), lag, stopped)


def relabel_modes(datasets: Sequence[Dataset], fit: Fit) -> Fit:
    """The same model with its base modes named as the user would: the ones nearest the reference's
    modes are the baseline's, the others extra.

    A free baseline may move one of its modes onto a mode it lacks and leave its own to an extra
    ``base_mode`` (the modal sum does not care which term is which): then "an extra mode at 25 Hz" is
    reported where the rig has an extra mode at 15 Hz and eq 9.4's 25 Hz mode. The terms are swapped
    (the s^4 modal sum is B s^4/(s^2 + 2 z w s + w^2) either way) and refitted from there, which gives
    the standard errors their new names. For one file the swap is exact and the refit leaves chi2 as it
    was; with several, the baseline mode that becomes the shared extra one starts from the first file's
    values and the refit has to agree. If the refit ends worse (also when a moved term falls outside its
    bounds, a damping above 0.5 or a frequency beyond the band) the fit is kept as it was, names
    unchanged. Modes tied to the actuator (mode 2 = wz) stay where they are.
    """

    bl = fit.baseline
    st = bl.structure
    ref = bl.reference if bl.reference is not None else (bl.params[0] if bl.params else None)
    extras = [j for j, e in enumerate(fit.effects) if e.kind.kind == "base_mode"]
    if st is None or not bl.free or st.power != 4 or ref is None or not extras or not fit.baseline_params:
        return fit
    free = [k for k in range(1, st.n_modes + 1) if not (k == 2 and st.tie_mode2)]
    two_pi = 2.0 * np.pi
    p0 = fit.baseline_params[0]
    pool = [("b", k, p0[f"w{k}"] / two_pi) for k in free] + [("e", j, fit.effects[j].values["freq_hz"]) for j in extras]
    ref_hz = [ref[f"w{k}"] / two_pi for k in free]

    def cost(assign):
        return sum(abs(np.log(pool[a][2] / f)) for a, f in zip(assign, ref_hz))

    identity = tuple(range(len(free)))
    best = min(itertools.permutations(range(len(pool)), len(free)), key=lambda a: (cost(a), a != identity))
    if best == identity:
        return fit

    def gain_factor(w):
        return w * w if st.w2_factors else 1.0

    new_b = []
    for p in fit.baseline_params:
        q = dict(p)
        for slot, a in zip(free, best):
            src, idx, _ = pool[a]
            if src == "b":
                w, z, b = p[f"w{idx}"], p[f"z{idx}"], p[f"B{idx}"]
            else:
                v = fit.effects[idx].values
                w, z = two_pi * v["freq_hz"], v["zeta"]
                b = v["residue"] / gain_factor(w)
            q[f"w{slot}"], q[f"z{slot}"], q[f"B{slot}"] = w, z, b
        new_b.append(np.append(st.vector(q), q[FEEDTHROUGH_KEY]) if FEEDTHROUGH_KEY in q else st.vector(q))
    left = sorted((pool[a] for a in range(len(pool)) if a not in best), key=lambda t: t[2])
    moved = []
    for src, idx, _ in left:
        if src == "b":
            w = p0[f"w{idx}"]
            moved.append(np.array([w / two_pi, p0[f"z{idx}"], p0[f"B{idx}"] * gain_factor(w)]))
        else:
            v = fit.effects[idx].values
            moved.append(np.array([v["freq_hz"], v["zeta"], v["residue"]]))
    effects = []
    for e in fit.effects:
        x = moved.pop(0) if e.kind.kind == "base_mode" else np.array([e.values[p.name] for p in e.kind.params])
        effects.append((e.kind, x))
    again = fit_model(datasets, bl, effects, start_baseline=new_b)
    return again if again.chi2 <= fit.chi2 * (1.0 + 1e-6) + 1e-9 else fit


def notebook_reference() -> dict[str, float]:
    """Eq 9.4 in SI (theta in rad: K1 x pi/180, B_k x 180/pi): the notebook's model, the default baseline."""

    deg = np.pi / 180.0
    return {k: (v * deg if k == "K1" else v / deg if k.startswith("B") else v) for k, v in EQ9_4.items()}


def level_ratio(data: np.ndarray, model: np.ndarray) -> float | None:
    """The data's level over a model's: the geometric median of |data / model| over the points where it is finite and
    positive (None without one): a gain the resonances either side of a misplaced mode do not move."""
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.log(np.abs(np.asarray(data)) / np.abs(np.asarray(model)))
    r = r[np.isfinite(r)]
    return float(np.exp(np.median(r))) if r.size else None


def scaled_reference(ds: Dataset, structure: ModelStructure, ref: Mapping[str, float]) -> dict[str, float]:
    """``ref`` with its gains scaled to ``ds``'s data: K1 by the geometric median of |theta/v| over ref's, each B_k by
    that of |xdd/theta| (from xdd/v over theta/v where the file has no xdd/theta). Only the gains move: the frequencies
    and dampings are ref's. A start from the notebook's rig must not depend on the units or the sensors' gains of the
    file it starts on: theta in mrad made eq 9.4's K1 a thousand times too small and its B_k too large, a start from
    another basin than the same data in rad (a different diagnosis). A channel the file lacks, or without one finite
    ratio, keeps ref's gains."""
    out = dict(ref)
    f = ds.freq_hz

    def ratio(ch: str) -> float | None:
        return level_ratio(ds.data[ch], structure.response(ref, f[ds.keep[ch]], ch)) if ch in ds.data else None

    act = ratio("act")
    base = ratio("base")
    if base is None and act is not None and (total := ratio("total")) is not None:
        base = total / act
    for name in structure.param_names:
        if name == "K1" and act is not None:
            out[name] = ref[name] * act
        elif name.startswith("B") and base is not None:
            out[name] = ref[name] * base
    return out


def start_params(m, structure: ModelStructure, *, rng_seed: int = 0) -> dict[str, float]:
    """Baseline parameters to start the weighted fit from: the better (by weighted chi-square, after
    :func:`fit_model`) of samii's fit of the file and, for the notebook's 3-mode structure, eq 9.4
    in SI (theta in rad: K1 x pi/180, B_k x 180/pi) with its gains scaled to the file (:func:`scaled_reference`).
    A swept sine's noisy ends can lead the
    first into a basin that loses a mode; the notebook's own model rarely is far from a rig like it.
    """

    ref = notebook_reference()
    ds = Dataset.from_measured(m)

    def fitted(p: dict) -> tuple[float, dict]:
        f = fit_model([ds], Baseline(structure=structure, params=(p,)), [])
        return f.chi2, dict(f.baseline_params[0])

    def from_samii_fit() -> tuple[float, dict]:
        # parameters samii's fit leaves out (no xdd in a theta/v-only file) start at eq 9.4's values; the weighted
        # fit then leaves them there, with an infinite standard error
        return fitted({k: (v if np.isfinite(v) else ref.get(k, v)) for k, v in _fitted_start(m, structure, rng_seed=rng_seed).items()})

    jobs = [from_samii_fit]
    if structure == ModelStructure.notebook_3mode():
        jobs.append(lambda: fitted(scaled_reference(ds, structure, {k: v for k, v in ref.items() if k in structure.param_names})))
    results = fork_calls(jobs)  # the two starts at once (samii.forkmap)
    return min(results, key=lambda r: r[0])[1]  # the better (the first of equals)


def _fitted_start(m, structure: ModelStructure, *, rng_seed: int = 0) -> dict[str, float]:
    """The structure fitted to one file by samii's fit (the notebook's cost), each point weighted by its random error.

    The file's variances are passed as the coherence they imply with 3 averages,
    ``g = 1/(1 + 3 var)``, so that noise-dominated points (a weak xdd at 0.1 Hz)
    weigh nothing; the result starts the weighted fit of :func:`fit_model`.
    """

    frf = m.frf
    kw = {}
    for ch in frf.channels:
        kw[ch] = frf.response(ch)
        var = m.var.get(ch)
        kw[f"{ch}_coh"] = np.ones(frf.freq_hz.size) if var is None else 1.0 / (1.0 + 3.0 * np.minimum(var, 1e6))
    data = FrequencyResponse(frf.freq_hz, metadata={}, **kw)
    weighted = all(m.var.get(ch) is not None for ch in frf.channels)
    res = fit(
        data,
        structure,
        phase_weight=0.1,
        weighting="coherence" if weighted else "none",
        rng=np.random.default_rng(rng_seed),
        n_averages=3,
        profile=False,
    )  # a start: only its parameters are read
    return dict(res.params)
