"""The frequency-response value that flows between measure, identify and diagnose.

Channels follow DATA_FORMATS.md:

=========  ================  =================
channel    transfer function unit of magnitude
=========  ================  =================
``act``    theta / v         rad/V
``base``   xdd / theta       (m/s²)/rad
``total``  xdd / v           (m/s²)/V
=========  ================  =================

Values are complex; magnitude and phase (degrees, unwrapped) are derived.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Literal, get_args

import numpy as np

__all__ = ["Channel", "CHANNELS", "CHANNEL_NAMES", "FrequencyResponse", "max_deviation", "interpolate_frf"]

Channel = Literal["act", "base", "total"]
CHANNELS: tuple[Channel, ...] = get_args(Channel)
#: How the channels are named in text: theta/v, xdd/theta, xdd/v.
CHANNEL_NAMES = {"act": "theta/v", "base": "xdd/theta", "total": "xdd/v"}


def _as_array(name: str, value, dtype) -> np.ndarray:
    arr = np.asarray(value, dtype=dtype)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = int(np.flatnonzero(~np.isfinite(arr))[0])
        raise ValueError(f"{name} has a NaN or infinite value at index {bad}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class FrequencyResponse:
    """Complex frequency response of SAMII's channels on one frequency grid.

    Parameters
    ----------
    freq_hz : array
        Strictly increasing, positive frequencies [Hz].
    act, base, total : array of complex, optional
        theta/v [rad/V], xdd/theta [(m/s²)/rad], xdd/v [(m/s²)/V].
    act_coh, base_coh, total_coh : array, optional
        Coherence of each channel, 0...1.
    metadata : mapping of str to str
        Free-form provenance (``# key: value`` lines of the CSV format).
    """

    freq_hz: np.ndarray
    act: np.ndarray | None = None
    base: np.ndarray | None = None
    total: np.ndarray | None = None
    act_coh: np.ndarray | None = None
    base_coh: np.ndarray | None = None
    total_coh: np.ndarray | None = None
    metadata: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        f = _as_array("freq_hz", self.freq_hz, float)
        if f.size == 0:
            raise ValueError("freq_hz is empty")
        if f[0] <= 0:
            raise ValueError(f"freq_hz must be positive, got {f[0]} at index 0")
        steps = np.diff(f)
        if np.any(steps <= 0):
            bad = int(np.flatnonzero(steps <= 0)[0]) + 1
            raise ValueError(f"freq_hz must be strictly increasing, got {f[bad - 1]} then {f[bad]} at index {bad}")
        object.__setattr__(self, "freq_hz", f)
        present = False
        for ch in CHANNELS:
            h = getattr(self, ch)
            if h is not None:
                present = True
                h = _as_array(ch, h, complex)
                if h.shape != f.shape:
                    raise ValueError(f"{ch} has {h.size} points, freq_hz has {f.size}")
                object.__setattr__(self, ch, h)
            c = getattr(self, f"{ch}_coh")
            if c is not None:
                if h is None:
                    raise ValueError(f"{ch}_coh given without channel {ch}")
                c = _as_array(f"{ch}_coh", c, float)
                if c.shape != f.shape:
                    raise ValueError(f"{ch}_coh has {c.size} points, freq_hz has {f.size}")
                if np.any((c < -1e-9) | (c > 1 + 1e-9)):
                    bad = int(np.flatnonzero((c < -1e-9) | (c > 1 + 1e-9))[0])
                    raise ValueError(f"{ch}_coh must lie in 0...1, got {c[bad]} at index {bad}")
                object.__setattr__(self, f"{ch}_coh", c)
        if not present:
            raise ValueError("a frequency response needs at least one of the channels act, base, total")
        object.__setattr__(self, "metadata", MappingProxyType(dict(self.metadata)))

    @property
    def w(self) -> np.ndarray:
        """Angular frequencies [rad/s]."""
        return 2.0 * np.pi * self.freq_hz

    @property
    def channels(self) -> tuple[Channel, ...]:
        """The channels present, in the order act, base, total."""
        return tuple(ch for ch in CHANNELS if getattr(self, ch) is not None)

    def response(self, channel: Channel) -> np.ndarray:
        """Complex response of ``channel``; KeyError if absent."""
        h = getattr(self, channel)
        if h is None:
            raise KeyError(f"channel {channel!r} is not in this frequency response (has {self.channels})")
        return h

    def coherence(self, channel: Channel) -> np.ndarray | None:
        """Coherence of ``channel``, or None if not measured."""
        self.response(channel)
        return getattr(self, f"{channel}_coh")

    def magnitude_db(self, channel: Channel) -> np.ndarray:
        return 20.0 * np.log10(np.abs(self.response(channel)))

    def phase_deg(self, channel: Channel) -> np.ndarray:
        """Unwrapped phase in degrees."""
        return np.degrees(np.unwrap(np.angle(self.response(channel))))

    def band(self, lo_hz: float, hi_hz: float) -> FrequencyResponse:
        """The points with lo_hz <= f <= hi_hz."""
        keep = (self.freq_hz >= lo_hz) & (self.freq_hz <= hi_hz)
        if not np.any(keep):
            raise ValueError(f"no frequency point in the band {lo_hz}-{hi_hz} Hz (data span {self.freq_hz[0]:.3g}-{self.freq_hz[-1]:.3g} Hz)")
        kw = {}
        for ch in CHANNELS:
            for name in (ch, f"{ch}_coh"):
                v = getattr(self, name)
                kw[name] = None if v is None else v[keep]
        return FrequencyResponse(self.freq_hz[keep], metadata=self.metadata, **kw)


def max_deviation(
    measured: FrequencyResponse,
    reference: FrequencyResponse,
    *,
    band_hz: tuple[float, float],
    min_coherence: float | None = None,
) -> dict[Channel, dict[str, float]]:
    """Largest |dB| and |deg| difference of ``measured`` from ``reference`` (same grid) per channel.

    Over ``band_hz``; with ``min_coherence`` only where the measured coherence
    exceeds it. Returns ``{channel: {"max_abs_db", "max_abs_deg", "sustained_db",
    "sustained_deg", "points"}}``; a channel with no point left is omitted.
    ``sustained_*``: the largest median over SUSTAINED_POINTS neighbouring points
    (the largest deviation most of a band shows: a systematic one, as a
    nonlinearity's, not one noisy point; with fewer points, the largest).
    """
    if measured.freq_hz.shape != reference.freq_hz.shape or not np.allclose(measured.freq_hz, reference.freq_hz, rtol=1e-12):
        raise ValueError("max_deviation needs both responses on the same frequency grid")
    f = measured.freq_hz
    out: dict[Channel, dict[str, float]] = {}
    for ch in measured.channels:
        keep = (f >= band_hz[0]) & (f <= band_hz[1])
        coh = measured.coherence(ch)
        if min_coherence is not None and coh is not None:
            keep &= coh > min_coherence
        if not np.any(keep) or ch not in reference.channels:
            continue
        ratio = measured.response(ch)[keep] / reference.response(ch)[keep]
        db, deg = np.abs(20 * np.log10(np.abs(ratio))), np.abs(np.angle(ratio, deg=True))
        out[ch] = {
            "max_abs_db": float(np.max(db)),
            "max_abs_deg": float(np.max(deg)),
            "sustained_db": _sustained(db),
            "sustained_deg": _sustained(deg),
            "points": int(keep.sum()),
        }
    return out


#: Neighbouring points whose median :func:`max_deviation` calls sustained (on a swept sine's 100-per-decade grid, a
#: band of 12 % in frequency: a point whose coherence is high by chance, 1 in a few hundred from 3 averages, is one).
SUSTAINED_POINTS = 5


def _sustained(x: np.ndarray) -> float:
    if x.size < SUSTAINED_POINTS:
        return float(np.max(x))
    windows = np.lib.stride_tricks.sliding_window_view(x, SUSTAINED_POINTS)
    return float(np.max(np.median(windows, axis=1)))


def interpolate_frf(src: FrequencyResponse, freq_hz: np.ndarray) -> dict[str, np.ndarray]:
    """``src``'s channels at ``freq_hz`` (channel -> complex array): log |H| and unwrapped phase,
    linear in log f; NaN outside ``src``'s span (no extrapolation, so a caller sees where it has
    no value; a FrequencyResponse cannot hold NaN)."""
    f = np.asarray(freq_hz, float)
    lf, lq = np.log(src.freq_hz), np.log(f)
    out = {}
    for ch in src.channels:
        h = src.response(ch)
        mag = np.interp(lq, lf, np.log(np.abs(h)), left=np.nan, right=np.nan)
        ph = np.interp(lq, lf, np.unwrap(np.angle(h)), left=np.nan, right=np.nan)
        out[ch] = np.exp(mag + 1j * ph)
    return out
