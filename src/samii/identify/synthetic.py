"""Synthetic frequency responses with the random error of an averaged swept sine.

Used by the known-answer tests and the studies, because the notebook's measured
data are not available. The noise model is stated here once:

* Coherence of each channel follows from a noise floor ``dynamic_range_db``
  below the channel's largest magnitude on the grid: a point with magnitude
  |H| sees ``g = 1 / (1 + (r max|H| / |H|)^2)``, r = 10^(-dynamic_range_db/20),
  clipped below at ``min_coherence``. So coherence is high near resonances and
  falls at antiresonances and where a channel is small (theta/v above 20 Hz,
  the s^4 base channel below 1 Hz), as on a rig. The clip stands for an
  analyzer that autoranges and an operator who raises the excitation where the
  response is weak; without it the base channel below 0.5 Hz would be pure
  noise and the notebook's unweighted 0.1-40 Hz fits could not have worked.
* The estimate's random error (Bendat & Piersol, *Random Data*, 4th ed.,
  table 9.6) has a normalised gain error ``eps = sqrt(1-g) / sqrt(2 n g)`` for
  ``n`` averages and the same standard deviation in radians for the phase.
* Noise is applied multiplicatively in the log domain:
  ``H_noisy = H exp(eps (a + j b))`` with a, b independent standard normals,
  so the dB error is Gaussian with std ``8.69 eps`` dB and the phase error
  Gaussian with std ``57.3 eps`` deg.

Defaults: ``n_averages=3`` (notebook chapter 9: "The swept sine data is based on
3 averages"); ``dynamic_range_db=60`` and ``min_coherence=0.5`` are assumptions
(no figure for them survives): coherence 0.999 at 30 dB below a channel's peak
(0.03 dB, 0.2 deg), 0.5 at 60 dB below (3.5 dB, 24 deg).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from samii.frequency_response import Channel, FrequencyResponse

__all__ = ["SweptSineNoise", "coherence_model", "random_error", "synthesize"]


@dataclass(frozen=True)
class SweptSineNoise:
    """Random error of an averaged swept-sine FRF estimate (see module docstring)."""

    n_averages: int = 3
    dynamic_range_db: float = 60.0
    min_coherence: float = 0.5

    def __post_init__(self) -> None:
        if int(self.n_averages) != self.n_averages or self.n_averages < 1:
            raise ValueError(f"n_averages must be a positive integer, got {self.n_averages}")
        if not self.dynamic_range_db > 0:
            raise ValueError(f"dynamic_range_db must be > 0, got {self.dynamic_range_db}")
        if not 0 < self.min_coherence < 1:
            raise ValueError(f"min_coherence must lie in (0, 1), got {self.min_coherence}")


def coherence_model(h: np.ndarray, noise: SweptSineNoise) -> np.ndarray:
    """Coherence of a channel with response ``h`` under an output noise floor."""
    mag = np.abs(np.asarray(h, complex))
    r = 10.0 ** (-noise.dynamic_range_db / 20.0)
    g = 1.0 / (1.0 + (r * np.max(mag) / mag) ** 2)
    return np.maximum(g, noise.min_coherence)


def random_error(coherence: np.ndarray, n_averages: int) -> np.ndarray:
    """Normalised random error of |H| (and std of the phase in rad), Bendat & Piersol table 9.6."""
    g = np.asarray(coherence, float)
    return np.sqrt((1.0 - g) / (2.0 * n_averages * g))


def synthesize(
    freq_hz: np.ndarray,
    responses: Mapping[Channel, np.ndarray],
    *,
    noise: SweptSineNoise | None,
    rng: np.random.Generator | None = None,
    metadata: Mapping[str, str] | None = None,
) -> FrequencyResponse:
    """A FrequencyResponse from exact complex responses, optionally with swept-sine noise.

    Parameters
    ----------
    freq_hz : array
        Frequency grid [Hz].
    responses : mapping channel -> complex array
        Exact responses on the grid (e.g. from ``ModelStructure.response``).
    noise : SweptSineNoise or None
        None gives noise-free data with coherence 1.
    rng : numpy Generator
        Required when ``noise`` is given.
    """
    kw: dict = {}
    meta = dict(metadata or {})
    meta.setdefault("source", "synthetic (samii.identify.synthetic)")
    if noise is not None:
        if rng is None:
            raise ValueError("synthesize with noise needs a seeded numpy Generator (rng=)")
        meta["noise"] = (
            f"swept sine, {noise.n_averages} averages, noise floor {noise.dynamic_range_db} dB below each channel's peak, coherence >= {noise.min_coherence}"
        )
        meta.setdefault("frf_records", f"{noise.n_averages} (synthetic: the noise model's averages)")  # read by the lack-of-fit test
    for ch, h in responses.items():
        h = np.asarray(h, complex)
        if noise is None:
            kw[ch], kw[f"{ch}_coh"] = h, np.ones(h.shape)
            continue
        g = coherence_model(h, noise)
        eps = random_error(g, noise.n_averages)
        kw[ch] = h * np.exp(eps * (rng.standard_normal(h.shape) + 1j * rng.standard_normal(h.shape)))
        kw[f"{ch}_coh"] = g
    return FrequencyResponse(np.asarray(freq_hz, float), metadata=meta, **kw)
