"""A model's residuals against measured data, per channel: the layer the diagnosis (:mod:`samii.diagnose.diagnosis`),
its attribution (:mod:`samii.diagnose.attribution`) and the simulator baseline (:mod:`samii.diagnose.simulator`) share.

Error per channel (``act`` theta/v, ``base`` xdd/theta, ``total`` xdd/v), pooled over the files: the residual
``e = ln(H_data/H_model)`` as rms dB (20 log10 e^Re e) and rms deg (Im e), and ``chi2``: the mean of the squared
residual over its predicted random error, per real residual (1 when the model is right and the noise estimate too).
Unexplained bands: :func:`unexplained_bands` (the test is described in :mod:`samii.diagnose.diagnosis`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np
from scipy import stats

from samii.diagnose.model import FEEDTHROUGH_KEY, Dataset, Fit, _apply, feedthrough_term, hold_factor, sampled_images
from samii.diagnose.select import ALPHA
from samii.frequency_response import CHANNELS
from samii.identify.cost import DB_PER_NEPER, DEG_PER_RAD

__all__ = [
    "BAND_POINTS",
    "ChannelError",
    "Band",
    "model_response",
    "full_residuals",
    "channel_errors",
    "errors_from_residuals",
    "unexplained_bands",
    "EVEN_MISFIT_RATIO",
    "even_misfit",
    "band_tested",
    "runs",
]

#: Points averaged when looking for a band the final model leaves unexplained.
BAND_POINTS = 9


@dataclass(frozen=True)
class ChannelError:
    """Residual of one channel over the usable points of every file."""

    rms_db: float
    rms_deg: float
    chi2: float | None  # mean squared normalised residual per real residual (1 at the noise); None when the noise is unknown
    n_points: int

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Band:
    """A frequency band where a significant residual remains."""

    source: str
    channel: str
    lo_hz: float
    hi_hz: float
    chi2: float
    n_points: int
    #: "residual": the final model's residual beyond the noise; "records differ": the file's records are not repeats
    #: there (samii.diagnose.stationarity: the rig changed during the file)
    why: str = "residual"

    def to_dict(self) -> dict:
        return asdict(self)


def model_response(fit: Fit, i: int, freq_hz: np.ndarray, *, sampled: bool = True) -> dict[str, np.ndarray]:
    """act, base and total of ``fit``'s model for file ``i`` at ``freq_hz`` (the baseline's structure with the effects),
    as the file's DAQ samples it (the command's hold and the feedthrough's lag, samii.diagnose.sampling) or,
    ``sampled=False``, the rig's alone."""
    st = fit.baseline.structure
    f = np.asarray(freq_hz, float)
    if st is None or not fit.baseline_params:
        raise ValueError("the baseline has no structure to evaluate off its data points")
    p = fit.baseline_params[i]
    base = {c: st.response(p, f, c) * fit.baseline.factor(i, f, c) for c in ("act", "base")}
    eff = [(e.kind, np.array([e.values[q.name] for q in e.kind.params])) for e in fit.effects]
    s = 2j * np.pi * f
    out = _apply(eff, base, s)
    hold = fit.baseline.hold(i) if sampled and not fit.baseline.fixed else 0.0
    lag, rate = p.get(FEEDTHROUGH_KEY), fit.baseline.sample_rates_hz
    if hold:  # the command's hold, its images and the steps (samii.diagnose.sampling, model._Problem._model)
        images_act, images_total, _ = sampled_images(st, st.vector(p), eff, 2.0 * np.pi * f, hold, total=True)
        act = out["act"] * hold_factor(s, hold)
        term, _, _, _ = feedthrough_term(st, st.vector(p), eff, s, lag or 0.0, 0.5 / hold, hold_s=hold)
        out["total"] = act * out["base"] + term + images_total
        out["act"] = act + images_act
        out["base"] = out["total"] / out["act"]
        return out
    out["total"] = out["act"] * out["base"]
    if sampled and lag and rate and rate[i]:  # the sampled feedthrough (samii.diagnose.sampling)
        term, _, _, _ = feedthrough_term(st, st.vector(p), eff, s, lag, rate[i])
        out["total"] = out["total"] + term
        out["base"] = out["total"] / out["act"]
    return out


def full_residuals(ds: Dataset, res: dict, *, noise_only: bool = True) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """act, base and total residuals on ``ds``'s whole grid (NaN where a channel is not usable), any one derived from
    the other two; the variance the noise's alone, or with ``noise_only=False`` the fit's (with the distortion's
    and any describing function's approximation, Measured.model_var)."""
    n = ds.freq_hz.size
    e, var = {}, {}
    for ch, r in res.items():
        full = np.full(n, complex(np.nan, np.nan))
        full[ds.keep[ch]] = r
        v = np.full(n, np.nan)
        v[ds.keep[ch]] = 2.0 / (ds.noise_sigma_inv(ch) if noise_only else ds.inv_sigma[ch]) ** 2
        e[ch], var[ch] = full, v
    if "base" not in e and {"act", "total"} <= set(e):
        e["base"], var["base"] = e["total"] - e["act"], var["total"] + var["act"]
    if "total" not in e and {"act", "base"} <= set(e):
        e["total"], var["total"] = e["act"] + e["base"], var["act"] + var["base"]
    return {ch: (e[ch], var[ch]) for ch in CHANNELS if ch in e}


def channel_errors(datasets: Sequence[Dataset], fit: Fit) -> dict[str, ChannelError]:
    """Error of ``fit`` per channel over the usable points of every dataset."""
    return errors_from_residuals(datasets, fit.residuals)


def errors_from_residuals(datasets: Sequence[Dataset], residuals: Sequence[Mapping[str, np.ndarray]]) -> dict[str, ChannelError]:
    """Error per channel from each dataset's residuals log(data/model) on its usable points."""
    pooled: dict[str, list] = {}
    known = all(ds.known_noise for ds in datasets)
    for ds, res in zip(datasets, residuals):
        for ch, (e, v) in full_residuals(ds, res).items():
            ok = np.isfinite(e) & np.isfinite(v)
            pooled.setdefault(ch, []).append((e[ok], v[ok]))
    out = {}
    for ch in CHANNELS:
        if ch not in pooled:
            continue
        e = np.concatenate([p[0] for p in pooled[ch]])
        v = np.concatenate([p[1] for p in pooled[ch]])
        if e.size == 0:
            continue
        out[ch] = ChannelError(
            rms_db=float(DB_PER_NEPER * np.sqrt(np.mean(e.real**2))),
            rms_deg=float(DEG_PER_RAD * np.sqrt(np.mean(e.imag**2))),
            chi2=float(np.mean(np.abs(e) ** 2 / v)) if known else None,
            n_points=int(e.size),
        )
    return out


def unexplained_bands(
    datasets: Sequence[Dataset], residuals: Sequence[Mapping[str, np.ndarray]], *, alpha: float = ALPHA, points: int = BAND_POINTS
) -> list[Band]:
    """Bands of each channel where a model's residual (per dataset: channel -> log(data/model) on its usable
    points, as ``Fit.residuals``) exceeds the noise (module docstring).

    xdd/v is tested too: where theta is noise-dominated (theta/v above some 9 Hz at 0.1 V) xdd/theta
    is not usable, and a misfit there shows only in xdd/v."""
    out = []
    for ds, res in zip(datasets, residuals):
        full = full_residuals(ds, res, noise_only=False)  # a describing function's approximation is no miss
        for ch in CHANNELS:
            if ch not in full:
                continue
            e, v = full[ch]
            ok = np.isfinite(e) & np.isfinite(v)
            if ok.sum() < 2 * points:
                continue
            f = ds.freq_hz[ok]
            z2 = np.abs(e[ok]) ** 2 / v[ok] * 2.0  # ~ chi2(2) per point
            scale = float(np.median(z2)) / (2.0 * np.log(2.0))
            if ds.known_noise:  # never judge against less noise than the data show
                scale = max(1.0, scale)
            win = np.convolve(z2 / scale, np.ones(points), mode="valid") / (2.0 * points)  # mean per real residual
            dof = 2.0 * points / max(ds.corr_length, 1.0)
            limit = stats.chi2.isf(alpha / win.size, dof) / dof
            flag = np.zeros(f.size, bool)
            for j in np.flatnonzero(win > limit):
                flag[j : j + points] = True
            for a, b in runs(flag):
                out.append(Band(ds.source, ch, float(f[a]), float(f[b - 1]), float(np.mean(z2[a:b] / scale) / 2.0), int(b - a)))
    return out


#: A channel's chi2 per residual above this is a misfit a reader would see, when chance cannot make it either
#: (:func:`even_misfit`): a residual twice the noise's rms. (At the noise chi2 per residual is about 1.2 from 3 records'
#: spread and about 2 from a 3-average coherence, which runs high: the rule must clear both.)
EVEN_MISFIT_RATIO = 4.0


def even_misfit(errors: Mapping[str, ChannelError], *, alpha: float = ALPHA) -> dict[str, float]:
    """Channels whose residual stays above their noise as a whole: chi2 per residual above ``EVEN_MISFIT_RATIO`` and
    above what chance gives its 2 n real residuals at ``alpha``. :func:`unexplained_bands` judges each band against its
    channel's own median (a noise stated too small is no finding there), so a misfit spread evenly over the band, or
    on too few points for a band, shows only here: a verdict of none must not call it "within their noise"."""
    out = {}
    for ch, e in errors.items():
        if e.chi2 is None or e.n_points < 1:
            continue
        dof = 2 * e.n_points
        if e.chi2 > max(EVEN_MISFIT_RATIO, float(stats.chi2.isf(alpha, dof)) / dof):
            out[ch] = e.chi2
    return out


def band_tested(errors: Mapping[str, ChannelError]) -> bool:
    """Some channel has the points :func:`unexplained_bands` needs to look for a band of misfit (2 x BAND_POINTS)."""
    return any(e.n_points >= 2 * BAND_POINTS for e in errors.values())


def runs(flag: np.ndarray) -> list[tuple[int, int]]:
    edges = np.diff(np.concatenate([[0], flag.astype(int), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))
