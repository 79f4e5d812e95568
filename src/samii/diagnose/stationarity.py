"""Whether a file's records repeat one experiment: a rig that changes during the file.

The diagnosis weighs residuals against the spread between records, which
assumes the records repeat one experiment with fresh noise. A rig that changes
during the file breaks that: an accelerometer whose gain steps at mid-file, a
base mode that drifts with temperature. Nothing in the effect library is such
a change, and the spread it inflates hides it from the residual tests: on a
second, independent rig a 10 % step of the accelerometer's gain came out as
"nothing missing".

Noise is rough from point to point; a change of the rig is smooth over
frequency. Each record's deviation from the records' weighted estimate,
``d_k = H_k / H - 1`` per channel, is averaged over windows of ``WINDOW``
points of the FRF's grid, and each window mean is set against its own
scatter within the window (the point-to-point variance over the points,
pooled over ``POOL_WINDOWS`` neighbouring windows and divided by the independent points,
``n_eff = WINDOW / L`` with L the noise's correlation length): ``2 sum_k |mean d_k|^2 / (var d_k / n_eff)``
over ``2 (n_records - 1)`` is F-distributed with that many and ``2 (POOL_WINDOWS n_eff - 1)`` degrees of
freedom when the records repeat (a scatter from one window's 9 correlated points alone, against
chi-square, let pure noise pass a nominal 1e-5 at 1e-4 to 1e-3). Sign-alternating records are compared within each sign: an even-order distortion
(an asymmetric valve) enters + and - records with opposite signs, smoothly, and is no change of
the rig. Records that do not rest between sweeps differ by the tails they
inherit from the one before (the first inherits none): the same deviations of
the model's noise-free response to the file's own r, recorded the same way
(:attr:`samii.measure.floor.Floor.simulated`), are subtracted first. A window beyond its ``ALPHA`` / (windows x channels) quantile, whose
largest record mean also exceeds ``PRACTICAL_FACTOR`` x the stated relative
floor (a change the floor could make is no change), is a band where the
records differ; merged, the bands are reported as unexplained.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from samii.frequency_response import CHANNEL_NAMES
from samii.measure.floor import PRACTICAL_FACTOR, REL_FLOOR
from samii.measure.frf import CHANNEL_PAIRS
from samii.measure.frf_variance import spectra_at

__all__ = ["RecordChange", "record_changes", "WINDOW"]

#: Points of the FRF's grid per window.
WINDOW = 9
#: Neighbouring windows whose within-window scatter is pooled.
POOL_WINDOWS = 5
#: Only points whose stated relative error variance is under this (10 % standard deviation) are tested: where a
#: record's response is weak its ratio to the estimate is heavy-tailed (a ratio of noisy spectra), and windows of
#: such points near xdd/theta's antiresonance and below 1 Hz passed on 7 of 24 clean EffectRig files.
GOOD_VAR = 0.01
ALPHA = 1e-3


@dataclass(frozen=True)
class RecordChange:
    """A band where a file's records differ beyond their noise, smoothly over frequency."""

    source: str
    channel: str
    lo_hz: float
    hi_hz: float
    chi2: float  # the band's largest window statistic per degree of freedom
    largest_pct: float  # the largest record's mean deviation from the estimate there [%]
    record: int  # which record (0-based) deviates most

    def text(self) -> str:
        name = CHANNEL_NAMES.get(self.channel, self.channel)
        return (
            f"{self.source}: the records are not repeats over {name} {self.lo_hz:.3g}-{self.hi_hz:.3g} Hz: record {self.record + 1} "
            f"differs from their estimate by {self.largest_pct:.2g} %, smoothly over frequency (chi2 {self.chi2:.3g} per degree of "
            "freedom against the scatter within the band): the rig changed during the file (a sensor's gain, a mode that drifts), "
            "which no effect of the library is"
        )


def record_changes(m, *, alpha: float = ALPHA) -> list[RecordChange]:
    """The bands where ``m``'s records differ (module docstring); none for a file that is not a time series of at
    least 3 records."""

    ts, layout = m.timeseries, m.layout
    if ts is None or layout is None or layout.n_records < 3 or ts.r is None:
        return []
    f = m.frf.freq_hz
    spec, r_records = spectra_at(ts, layout, f)
    n_rec = r_records.shape[0]
    sim = getattr(m.floor, "simulated", None)
    sim_spec = spectra_at(sim, layout, f)[0] if sim is not None else None
    # records compared within each sign (the estimate of a group: its mean ratio), each group of at least 2
    norms = np.linalg.norm(r_records, axis=1)
    signs = np.sign(r_records @ r_records[0] / np.maximum(norms * norms[0], 1e-300))
    use = np.ones(n_rec, bool)
    if sim_spec is None and float(getattr(layout, "rest_s", 0.0) or 0.0) <= 0.0:
        use[0] = False  # no rest and no model of the tails: the first record, which inherits none, is left out
    groups = [np.flatnonzero((signs == sg) & use) for sg in (1.0, -1.0)]
    groups = [g for g in groups if g.size >= 2]
    if not groups:
        return []
    dof = 2.0 * sum(g.size - 1 for g in groups)
    order = np.concatenate(groups)  # the record each row of the deviations is
    corr = max(float(m.corr_length), 1.0)
    found: list[tuple[str, int, int, float, float, int]] = []
    tests = []
    for ch in ("act", "total"):
        if ch not in m.frf.channels or m.var.get(ch) is None:
            continue
        num, den = CHANNEL_PAIRS[ch]

        def deviations(sp):
            with np.errstate(all="ignore"):
                hk = sp[num] / sp[den]  # noqa: B023 - called within this iteration
                return np.concatenate([hk[g] / np.mean(hk[g], axis=0)[None, :] - 1.0 for g in groups])

        d = deviations(spec)
        if sim_spec is not None:  # what the records' tails make them differ by, as the model says
            d = d - np.nan_to_num(deviations(sim_spec))
        ok = np.all(np.isfinite(d), axis=0) & (np.asarray(m.var[ch]) <= GOOD_VAR)
        idx = np.flatnonzero(ok)
        wins = [idx[a : a + WINDOW] for a in range(0, idx.size - WINDOW + 1, WINDOW)]
        if not wins:
            continue
        # each point's deviation in units of its stated error (the noise changes by decades over a window near an
        # antiresonance, and one noisy point would carry the window's mean)
        z = d / np.sqrt(np.asarray(m.var[ch]))[None, :]
        raw = np.stack([d[:, sel].mean(axis=1) for sel in wins], axis=1)  # (records, windows)
        means = np.stack([z[:, sel].mean(axis=1) for sel in wins], axis=1)
        scat = np.stack([np.mean(np.abs(z[:, sel] - z[:, sel].mean(axis=1)[:, None]) ** 2, axis=1) * WINDOW / (WINDOW - 1) for sel in wins], axis=1)
        # the scatter pooled over POOL_WINDOWS neighbouring windows (the noise changes slowly with frequency; a change
        # of the rig is smooth and does not raise it): from 9 correlated points alone its tail let noise through
        kern = np.ones(POOL_WINDOWS)
        pooled = np.stack([np.convolve(row, kern, "same") / np.convolve(np.ones(row.size), kern, "same") for row in scat])
        counts = np.convolve(np.ones(len(wins)), kern, "same")
        for j, sel in enumerate(wins):
            n_eff = WINDOW / corr
            stat = float(2.0 * np.sum(np.abs(means[:, j]) ** 2 / np.maximum(pooled[:, j] / n_eff, 1e-300)))
            dof2 = max(2.0 * (counts[j] * WINDOW / corr - 1.0), 2.0)
            tests.append((ch, int(sel[0]), int(sel[-1]), stat, raw[:, j], dof2))
    if not tests:
        return []
    least = PRACTICAL_FACTOR * REL_FLOOR
    for ch, lo, hi, stat, mean, dof2 in tests:
        k = int(np.argmax(np.abs(mean)))
        if stat > dof * stats.f.isf(alpha / len(tests), dof, dof2) and abs(mean[k]) > least:
            found.append((ch, lo, hi, stat / dof, 100.0 * float(abs(mean[k])), int(order[k])))
    out: list[RecordChange] = []
    for ch, lo, hi, chi2, pct, k in found:  # merge neighbouring windows of one channel
        if out and out[-1].channel == ch and lo <= int(np.searchsorted(f, out[-1].hi_hz)) + WINDOW + 1:
            last = out[-1]
            big = pct > last.largest_pct
            out[-1] = RecordChange(
                m.source, ch, last.lo_hz, float(f[hi]), max(chi2, last.chi2), max(pct, last.largest_pct), k if big else last.record
            )
        else:
            out.append(RecordChange(m.source, ch, float(f[lo]), float(f[hi]), chi2, pct, k))
    return out
