"""Phase of a measured frequency response for drawing: unwrapped through the well-measured points."""

from __future__ import annotations

import numpy as np

__all__ = ["ANCHOR_COHERENCE", "anchored_phase_deg"]

#: Points with at least this coherence carry the phase unwrapping (random phase
#: error below 2.6 deg for 3 averages, Bendat & Piersol table 9.6).
ANCHOR_COHERENCE = 0.9


def anchored_phase_deg(h: np.ndarray, coherence: np.ndarray | None = None, *, min_coherence: float = ANCHOR_COHERENCE) -> np.ndarray:
    """Phase of ``h`` [deg], unwrapped through the well-measured points only.

    ``np.unwrap`` from the first point lets every noisy low-coherence point that
    jumps by more than 180 deg add a turn to all the points after it (a data
    phase drawn 1000 deg off). Here the points with coherence >= ``min_coherence``
    are unwrapped among themselves, starting from the principal value of the
    first of them; every other point takes the turn that puts it nearest the
    phase interpolated between its well-measured neighbours. Without coherence
    (or with fewer than 2 good points) all points count as good.
    """
    ang = np.angle(np.asarray(h, complex))
    good = np.ones(ang.size, bool) if coherence is None else np.asarray(coherence) >= min_coherence
    if good.sum() < 2:
        good = np.ones(ang.size, bool)
    idx = np.flatnonzero(good)
    ph_good = np.unwrap(ang[idx])
    ref = np.interp(np.arange(ang.size), idx, ph_good)
    ph = ang + 2 * np.pi * np.round((ref - ang) / (2 * np.pi))
    ph[idx] = ph_good
    return np.degrees(ph)
