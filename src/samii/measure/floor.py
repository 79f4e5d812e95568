"""The systematic floor of a measured frequency response: what repeats in every record.

The record-to-record spread (:mod:`samii.measure.frf_variance`) sees only what
changes from one record to the next. What is the same in every record passes
it unseen, and a diagnosis that weighs residuals against the spread alone
then calls it an effect. Three such errors are added to each point's
variance, as the *floor*:

* **The FRF estimator's own bias.** The estimator takes each record as a
  transient from rest to rest; where a record does not end at rest (no rest
  between sweeps, a lightly damped mode still ringing, the position loop's
  slow pole) the next one starts with the last one's tail, the same in every
  record. Measured by doing it: the file's own excitation ``r`` is pushed
  through a linear model of the loop (the notebook's structure fitted to the
  file, closed by the controller read off the file, :func:`controller_fir`),
  the result is cut into the same records and estimated the same way, and what
  comes back different from the model is the bias (:func:`estimator_bias`).
  Its square, pooled over neighbouring points as the spread is, is the floor.
* **Quantisation.** An encoder or converter without dither rounds the same
  motion the same way in every record. A column whose values lie on a lattice
  (:func:`quantisation_step`) adds the rounding error's variance ``q^2/12`` per
  sample, relative to the signal's power at the point, and not divided by the
  number of records: it does not average out.
* **A stated relative floor**, ``REL_FLOOR``: what a calibrated data
  acquisition can vouch for at best. A DAQ channel's gain error is typically
  0.05-0.2 % (16-bit cards), an accelerometer's linearity 0.5-1 % of its range,
  the channels' anti-alias filters match to a few tenths of a degree: 0.5 %
  (of the complex relative error: 0.031 dB and 0.20 deg each) is the least error a point is granted.

The floor is part of each point's variance (fit weights, chi2, bands), and a
finding must also change the response by more than ``PRACTICAL_FACTOR`` times
the floor's standard deviation somewhere (:mod:`samii.diagnose.select`): an
effect the floor could produce is not one the data show.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace

import numpy as np
import scipy.fft

from samii.measure.frf import CHANNEL_PAIRS
from samii.measure.frf_variance import MAX_VAR, POOL, pool_mean, spectra_at, timeseries_frf
from samii.timeseries import TimeSeries

__all__ = ["REL_FLOOR", "PRACTICAL_FACTOR", "Floor", "quantisation_step", "controller_fir", "estimator_bias", "with_floor"]

#: The least relative error a point is granted (module docstring): 0.5 % complex, 0.031 dB and 0.20 deg each.
REL_FLOOR = 5e-3
#: A finding must change the response by more than this many of the floor's standard deviations at some points.
PRACTICAL_FACTOR = 3.0
#: Lags of theta in the controller read off a file (v = r - sum_j c_j theta[k - j]): a proportional loop, a digital one
#: that acts on the last sample, a short filter.
CONTROLLER_LAGS = 4
#: The controller read off a file is used when it explains at least this fraction of the variance of r - v.
CONTROLLER_EXPLAINED = 0.98
#: A column is quantised when its values take few levels (under a tenth of the samples) that all lie within this
#: fraction of a step of the lattice (quantisation_step).
_LATTICE_TOL = 0.02


@dataclass(frozen=True)
class Floor:
    """The systematic floor of one file: per channel the variance of the complex relative error of every point
    (on the FRF's grid), and what it is made of."""

    var: Mapping[str, np.ndarray]
    bias_var: Mapping[str, np.ndarray] | None  # the estimator's bias, squared and pooled; None when not measured
    quant_steps: Mapping[str, float]  # column -> lattice step found
    how: str
    #: The model's noise-free response to the file's own r, as the file was recorded (the bias was measured on it);
    #: None when not measured. The records of a run that does not rest between sweeps differ by the tails they
    #: inherit, and this says by how much (samii.diagnose.stationarity)
    simulated: TimeSeries | None = None
    #: The records repeat to within 1 % of the floor at most points (a simulation without noise): the data are
    #: judged against the floor alone, which the diagnosis says first
    noise_free: bool = False


def quantisation_step(x: np.ndarray) -> float | None:
    """The step of the lattice ``x``'s values lie on (an encoder's count, a converter's LSB), or None.

    Quantised when the values take few distinct levels (under a tenth of the samples) and all lie, within 2 % of
    the step, on multiples of the smallest difference between neighbouring levels away from an offset."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size < 100:
        return None
    levels = np.unique(x)
    if levels.size < 3 or levels.size > 0.1 * x.size:
        return None
    d = np.diff(levels)
    q = float(np.min(d))
    if not q > 0:
        return None
    k = (levels - levels[0]) / q
    if np.max(np.abs(k - np.round(k))) > _LATTICE_TOL:
        return None
    return q


def controller_fir(theta: np.ndarray, v: np.ndarray, r: np.ndarray, fs: float, lags: int = CONTROLLER_LAGS) -> tuple[np.ndarray, float]:
    """The position loop read off the data: ``r - v = sum_j c_j theta[k - j]`` (a proportional gain is c_0; a
    digital loop acting on the last reading, c_1), by least squares on the frequencies ``r`` excites (within
    20 dB of its peak): white noise on theta outside them would pull the gains (errors in the variables), and
    more lags than the loop has would spread a gain over them. The fewest lags (up to ``lags``) whose misfit
    is within 10 % of the longest filter's. Returns (c, the fraction of r - v's power at those frequencies it explains)."""
    u = np.asarray(r, float) - np.asarray(v, float)
    U = np.fft.rfft(u - u.mean())
    TH = np.fft.rfft(np.asarray(theta, float) - float(np.mean(theta)))
    R = np.fft.rfft(np.asarray(r, float) - float(np.mean(r)))
    mag = np.abs(R)
    use = mag > 0.1 * mag.max() if mag.max() > 0 else np.zeros(mag.size, bool)
    if not use.any():
        return np.zeros(1), 0.0
    w = 2.0 * np.pi * np.fft.rfftfreq(u.size, 1.0 / fs)[use]
    basis = TH[use, None] * np.exp(-1j * np.outer(w / fs, np.arange(lags)))
    y = U[use]
    tot = float(np.sum(np.abs(y) ** 2))
    if tot <= 1e-12 * float(np.sum(mag[use] ** 2)):
        return np.zeros(1), 1.0  # v is r: no loop (open loop), exactly
    a = np.concatenate([basis.real, basis.imag])
    b = np.concatenate([y.real, y.imag])
    fits = []
    for k in range(1, lags + 1):
        c, *_ = np.linalg.lstsq(a[:, :k], b, rcond=None)
        res = b - a[:, :k] @ c
        fits.append((c, float(res @ res)))
    best = fits[-1][1]
    c, ss = next((c, ss) for c, ss in fits if ss <= 1.1 * best + 1e-12 * tot)
    return c, 1.0 - ss / tot


def estimator_bias(
    m, model: Callable[[np.ndarray], Mapping[str, np.ndarray]], *, keep: list | None = None
) -> tuple[dict[str, np.ndarray] | None, str]:
    """The estimator's relative bias ``H_est/H - 1`` of each channel on ``m``'s grid, for a model of the rig
    (``model(freq_hz) -> {"act": theta/v, "base": xdd/theta}``), or None with the reason it could not be measured.

    The file's ``r`` drives the model's loop closed by the controller read off the file (:func:`controller_fir`);
    the whole run is computed at once in the frequency domain (zero-padded 2x: an exact linear convolution for a
    loop whose response dies out within the run), cut into ``m``'s records and estimated as ``m`` was. The simulated
    time series is appended to ``keep`` when given."""

    ts, layout = m.timeseries, m.layout
    if ts is None or layout is None or ts.r is None:
        return None, "not a time series"
    if layout.n_records < 2:
        return None, "one record"
    c, explained = controller_fir(ts.theta, ts.v, ts.r, ts.sample_rate_hz)
    if explained < CONTROLLER_EXPLAINED:
        return None, (
            f"the position loop is not a short filter of theta (it explains {100 * explained:.1f} % of r - v): the loop could not be modelled"
        )
    fs = ts.sample_rate_hz
    n = len(ts)
    nfft = scipy.fft.next_fast_len(2 * n, real=True)
    f = np.fft.rfftfreq(nfft, 1.0 / fs)
    f_eval = f.copy()
    f_eval[0] = f[1] * 1e-3  # (theta/v integrates: its closed loop is finite at 0, the model is not)
    with np.errstate(all="ignore"):
        h = model(f_eval)
        act, base = np.asarray(h["act"], complex), np.asarray(h["base"], complex)
        ctrl = np.exp(-2j * np.pi * np.outer(f_eval / fs, np.arange(c.size))) @ c
        s_rv = 1.0 / (1.0 + ctrl * act)
        s_rt = act * s_rv
        s_ra = base * s_rt
    if not all(np.all(np.isfinite(x)) for x in (s_rv, s_rt, s_ra)):
        return None, "the model's loop is not finite at every frequency"
    R = scipy.fft.rfft(np.asarray(ts.r, float), nfft)  # (at DC the closed loop is finite: theta -> r/C(0), v -> 0)
    sig = {k: scipy.fft.irfft(R * g, nfft) for k, g in (("v", s_rv), ("theta", s_rt), ("accel", s_ra))}
    # the loop must have died out within the padding: else the convolution wrapped around (an unstable model loop)
    for k, y in sig.items():
        peak = float(np.max(np.abs(y[:n]))) or 1.0
        if float(np.max(np.abs(y[nfft - n // 4 :]))) > 1e-3 * peak:
            return None, f"the model's loop does not settle within the run ({k} still moves at its end)"
    sim = TimeSeries(t=np.asarray(ts.t), r=np.asarray(ts.r), v=sig["v"][:n], theta=sig["theta"][:n], accel=sig["accel"][:n], metadata=ts.metadata)
    if keep is not None:
        keep.append(sim)
    band = m.band_hz or (float(m.frf.freq_hz[0]), float(m.frf.freq_hz[-1]))
    frf, _, _, _ = timeseries_frf(sim, layout, band_hz=band)
    if frf.freq_hz.size != m.frf.freq_hz.size or not np.allclose(frf.freq_hz, m.frf.freq_hz, rtol=1e-9):
        return None, "the estimate's grid differs from the file's"
    truth = model(m.frf.freq_hz)
    truth = {"act": truth["act"], "base": truth["base"], "total": truth["act"] * truth["base"]}
    with np.errstate(all="ignore"):
        out = {ch: np.asarray(frf.response(ch) / truth[ch] - 1.0) for ch in m.frf.channels if ch in truth}
    out = {ch: np.where(np.isfinite(b), b, np.nan) for ch, b in out.items()}
    ctrl_text = ", ".join(f"{x:.4g}" for x in c)
    return out, f"the loop closed by v = r - ({ctrl_text}) x theta[k - j], read off the file"


#: The rounding of a sine of amplitude A to a step q has, at its own frequency and its harmonics, components of
#: at most 0.53 q sqrt(q/A) (samii.diagnose.nonlinear.QUANT_HARMONIC): relative to the sine, 0.53 (q/A)^1.5.
QUANT_FUNDAMENTAL = 0.53


def _quantisation_var(m, steps: Mapping[str, float]) -> dict[str, np.ndarray]:
    """Variance of each channel's relative error from the columns' rounding, per signal the sum of

    * its broadband part, ``(q^2/12) N / |Y_k(f)|^2`` (N samples a record, Y_k a record's spectrum, averaged in
      power over the records, not divided by their number: it repeats), and
    * its part at the sweep's own frequency: a sine of amplitude A rounded to q is a sine of another amplitude
      and phase, off by up to ``QUANT_FUNDAMENTAL (q/A)^1.5`` relative (A from the signal's response to r at f
      times r's peak). With Kp = 1 V/deg a 0.1 V sweep moves theta by 1.7 mrad, 18 counts of a 16-bit encoder:
      0.7 %; beyond the loop's bandwidth a few counts, 20 % and more (the second rig's clean files).

    In the loop, theta's rounding enters the command too, but theta/v's error is still the rounding over theta
    (``dTheta/Theta - dV/V = E_q / Theta`` with v = r - C theta_q), and xdd/v has none of it."""

    spec, r_records = spectra_at(m.timeseries, m.layout, m.frf.freq_hz)
    n_rec = r_records.shape[1]
    R = np.abs(spec["r"])
    r_peak = float(np.max(np.abs(r_records)))
    rel = {}
    for sig, q in steps.items():
        Y = np.abs(spec[sig])
        with np.errstate(divide="ignore", invalid="ignore"):
            broadband = q * q / 12.0 * n_rec / np.maximum(np.mean(Y**2, axis=0), 1e-300)
            amp = np.mean(Y / np.maximum(R, 1e-300), axis=0) * r_peak  # the signal's amplitude as the sweep passes f
            own = QUANT_FUNDAMENTAL**2 * (q / np.maximum(amp, 0.25 * q)) ** 3
        rel[sig] = pool_mean(np.nan_to_num(broadband + own, nan=1.0, posinf=1.0), POOL)
    out = {}
    for ch, (num, den) in CHANNEL_PAIRS.items():
        if ch in m.frf.channels:
            out[ch] = rel.get(num, 0.0) + rel.get(den, 0.0) + np.zeros(m.frf.freq_hz.size)
    return out


def with_floor(m, model: Callable[[np.ndarray], Mapping[str, np.ndarray]] | None = None):
    """``m`` with the floor (module docstring) added to every point's variance, and ``m.floor`` set.

    ``model`` (freq_hz -> act, base) measures the estimator's bias on a time series; without it, or for an FRF
    file, the floor is the quantisation's and the stated relative one."""

    if m.var is None or any(m.var.get(ch) is None for ch in m.frf.channels):
        return m  # the noise is unknown: nothing to add a floor to (a roughness estimate, set earlier, gets the relative one)
    size = m.frf.freq_hz.size
    floor = {ch: np.full(size, REL_FLOOR**2) for ch in m.frf.channels}
    parts = [f"a relative floor of {100 * REL_FLOOR:g} % (what a calibrated DAQ vouches for)"]
    steps: dict[str, float] = {}
    bias_var, sims = None, []
    if m.timeseries is not None and m.layout is not None:
        for sig in ("theta", "accel"):  # (v is what the valve got: a DAC's rounding of it is no error of the record)
            q = quantisation_step(getattr(m.timeseries, sig))
            if q is not None:
                steps[sig] = q
        if steps:
            qv = _quantisation_var(m, steps)
            for ch in floor:
                floor[ch] = floor[ch] + qv.get(ch, 0.0)
            parts.append("quantisation of " + ", ".join(f"{k} (step {q:.3g})" for k, q in steps.items()))
        if model is not None:
            try:
                bias, how = estimator_bias(m, model, keep=sims)
            except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:  # (a model the loop cannot be closed with)
                bias, how = None, f"{type(exc).__name__}: {exc}"
                sims.clear()
            if bias is None:
                parts.append(f"the estimator's bias not measured ({how})")
            else:
                bias_var = {ch: np.nan_to_num(pool_mean(np.abs(np.nan_to_num(b)) ** 2, POOL)) for ch, b in bias.items()}
                for ch in floor:
                    floor[ch] = floor[ch] + bias_var.get(ch, 0.0)

                # the largest where the data are usable (where the response is noise, the ringing dwarfs it too)
                worst = {ch: float(np.sqrt(np.max(np.where(np.asarray(m.var[ch]) <= MAX_VAR, v, 0.0)))) for ch, v in bias_var.items()}
                parts.append(
                    "the estimator's bias measured on the file's own excitation through "
                    + how
                    + " (largest where usable: "
                    + ", ".join(f"{ch} {100 * w:.2g} %" for ch, w in worst.items())
                    + ")"
                )
    spread = np.concatenate([np.asarray(m.var[ch]) for ch in floor])
    against = np.concatenate([floor[ch] for ch in floor])
    noise_free = bool(np.median(spread / against) < 1e-2)
    if noise_free:
        parts.insert(
            0,
            "NO NOISE: the records repeat to within 1 % of the floor's size at most points (a simulation without "
            "noise?), so the data are judged against the floor alone",
        )
    how = "; ".join(parts)
    var = {ch: (None if v is None else np.asarray(v) + floor[ch]) if ch in floor else v for ch, v in m.var.items()}
    floor_ = Floor(floor, bias_var, steps, how, sims[0] if bias_var is not None and sims else None, noise_free)
    return replace(m, var=var, floor=floor_, noise_source=f"{m.noise_source}; plus the systematic floor: {how}")
