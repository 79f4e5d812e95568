"""Which samples of a swept run a recording keeps: as many as the eye needs, not the DAQ's every one.

A swept sine spends most of its time at low frequency (a log sweep from 40 to 0.1 Hz is below 2 Hz for
half of it), where 1,000 samples a second draw a 1 Hz sine with 1,000 points per period. In steady state
the rig moves at the excitation's frequency, and after the sweep has passed a resonance the structure
rings there for a few time constants. So the record is cut into buckets, each one ``per_period``-th of a
period of the highest frequency the excitation drove in the last ``ring_s`` seconds and at most
``1 / min_rate`` long: where the sweep is fast a bucket is one sample and every sample stays; where it is
slow a signal keeps each bucket's smallest and largest sample (:func:`envelope`: the curve's peaks and the
noise band's width are the record's, at any zoom coarser than a bucket), and the 3D animation each
bucket's first frame (:func:`kept`). The record itself (``timeseries.csv``) keeps every sample.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import maximum_filter1d

__all__ = ["buckets", "kept", "envelope", "BUCKETS_PER_PERIOD", "MIN_BUCKET_RATE_HZ", "FRAMES_PER_PERIOD_SWEPT", "MIN_THINNED_FPS", "RING_S"]

#: Signal buckets per period of the frequency driven, and the fewest per second; each bucket keeps its
#: smallest and its largest sample (:func:`envelope`), so a curve gets up to twice as many points.
BUCKETS_PER_PERIOD = 12
MIN_BUCKET_RATE_HZ = 25.0
#: 3D frames kept per period of the frequency driven, and the fewest per second (smooth playback).
FRAMES_PER_PERIOD_SWEPT = 8
MIN_THINNED_FPS = 25.0
#: How long the structure rings after the excitation has passed a frequency [s]: a few time constants
#: 1/(zeta w) of base mode 1 (the embedded model's: zeta 0.025 at 1.74 Hz, 3.7 s).
RING_S = 5.0


def buckets(t_s: np.ndarray, drive_hz: np.ndarray, *, per_period: float, min_rate: float, ring_s: float = RING_S) -> np.ndarray:
    """The bucket of each sample at the uniformly spaced times ``t_s`` (0, 1, 2, ...; consecutive samples
    share one): a bucket spans one ``per_period``-th of a period of the highest frequency the excitation
    drove (``drive_hz``, NaN at rest) in the last ``ring_s`` seconds, and at most ``1 / min_rate`` seconds."""
    t = np.asarray(t_s, float)
    n = t.size
    if n < 2:
        return np.arange(n)
    dt = float(np.median(np.diff(t)))
    f = np.nan_to_num(np.asarray(drive_hz, float), nan=0.0)
    width = min(2 * int(np.ceil(ring_s / dt / 2)) + 1, 2 * n + 1)  # odd: the trailing window [t - ring_s, t]
    recent = maximum_filter1d(f, size=width, origin=(width - 1) // 2, mode="nearest")
    rate = np.maximum(per_period * recent, min_rate)
    phase = np.concatenate([[0.0], np.cumsum(np.diff(t) * rate[1:])])
    edge = np.concatenate([[True], np.floor(phase[1:]) > np.floor(phase[:-1])])
    return np.cumsum(edge) - 1


def kept(t_s: np.ndarray, drive_hz: np.ndarray, *, per_period: float, min_rate: float, ring_s: float = RING_S) -> np.ndarray:
    """Boolean mask: the first sample of each of :func:`buckets`' buckets, and the last sample (3D frames)."""
    b = buckets(t_s, drive_hz, per_period=per_period, min_rate=min_rate, ring_s=ring_s)
    keep = np.concatenate([[True], np.diff(b) > 0]) if b.size else np.zeros(0, bool)
    if keep.size:
        keep[-1] = True
    return keep


def envelope(values: np.ndarray, bucket: np.ndarray) -> np.ndarray:
    """Boolean mask: in each bucket its smallest and its largest sample (one if they are the same), and the
    first and last samples; a signal drawn from them has the record's envelope (its peaks, its noise band's
    width) at any zoom coarser than a bucket. Of a run of non-finite samples (a sweep's frequency at
    rest) its first and last are kept: a gap stays a gap."""
    v = np.asarray(values, float)
    n = v.size
    keep = np.zeros(n, bool)
    if n == 0:
        return keep
    bad = ~np.isfinite(v)
    starts = np.flatnonzero(np.concatenate([[True], np.diff(bucket) > 0]))
    for fn, fill in ((np.minimum, np.inf), (np.maximum, -np.inf)):
        w = np.where(bad, fill, v)
        extreme = fn.reduceat(w, starts)
        hit = np.flatnonzero(w == np.repeat(extreme, np.diff(np.append(starts, n))))
        _, first = np.unique(bucket[hit], return_index=True)
        keep[hit[first]] = True
    keep[0] = keep[-1] = True
    edges = bad & ~(np.concatenate([[False], bad[:-1]]) & np.concatenate([bad[1:], [False]]))
    return keep | edges
