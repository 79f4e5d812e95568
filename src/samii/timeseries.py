"""The sampled signals of one measurement run, as DATA_FORMATS.md defines them.

Required signals: ``t`` [s] (uniform), ``v`` [V] (everything the joint-2
servo-valve received), ``theta`` [rad] (joint 2 relative to the nominal pose),
``accel`` [m/s²] (base acceleration at the beam tip, gravity removed).
Optional: ``r`` [V] (the excitation added to the valve command),
``theta_ref`` [rad], ``p_load`` [Pa], ``spool`` (-1...1). Any other column is
kept in ``extra`` and ignored by samii.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

__all__ = [
    "REQUIRED_COLUMNS",
    "OPTIONAL_COLUMNS",
    "SIGNAL_COLUMNS",
    "TIME_UNIFORMITY_RTOL",
    "TimeSeries",
    "first_nonuniform_step",
    "typical_step",
]

REQUIRED_COLUMNS: tuple[str, ...] = ("t", "v", "theta", "accel")
OPTIONAL_COLUMNS: tuple[str, ...] = ("r", "theta_ref", "p_load", "spool")
#: Every standard signal column, in file order (all but ``t``).
SIGNAL_COLUMNS: tuple[str, ...] = REQUIRED_COLUMNS[1:] + OPTIONAL_COLUMNS
#: DATA_FORMATS.md: "t uniformly sampled (relative spacing within 1e-6)".
TIME_UNIFORMITY_RTOL = 1e-6


def typical_step(t: np.ndarray) -> float:
    """The median step of ``t``: the sampling interval a few dropped or repeated samples do not move."""
    return float(np.median(np.diff(t))) if t.size >= 2 else float("nan")


def first_nonuniform_step(t: np.ndarray, rtol: float = TIME_UNIFORMITY_RTOL) -> int | None:
    """Index ``i`` of the first step ``t[i] - t[i-1]`` that is not uniform, or None.

    A step is uniform if it differs from the typical (median) step by at most
    ``rtol`` times that step, and the typical step is positive. The median, not
    the mean ``(t[-1]-t[0])/(n-1)``, is the reference so that one dropped sample
    is found where it is: with the mean, the gap shifts the mean and the very
    first step is reported. Returns 1 if the typical step is not positive.
    """
    if t.size < 2:
        return None
    steps = np.diff(t)
    ref = typical_step(t)
    bad = ~(np.abs(steps - ref) <= rtol * ref) if ref > 0 else np.ones(steps.size, bool)
    if not np.any(bad):
        return None
    return int(np.flatnonzero(bad)[0]) + 1


def _signal(name: str, value, n: int | None) -> np.ndarray:
    arr = np.array(value, dtype=float)  # a copy: the value owns its data
    if arr.ndim != 1:
        raise ValueError(f"signal {name!r} must be one-dimensional, got shape {arr.shape}")
    if n is not None and arr.size != n:
        raise ValueError(f"signal {name!r} has {arr.size} samples, t has {n}")
    if not np.all(np.isfinite(arr)):
        bad = int(np.flatnonzero(~np.isfinite(arr))[0])
        raise ValueError(f"signal {name!r} has a NaN or infinite value ({float(arr[bad]):g}) at sample {bad}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class TimeSeries:
    """Uniformly sampled signals of one run (SI units).

    Parameters
    ----------
    t : array
        Sample times [s], uniform within a relative spacing of 1e-6, at least 2 samples.
    v : array
        Valve command [V]: controller output plus excitation.
    theta : array
        Joint-2 angle relative to the nominal pose [rad].
    accel : array
        Base acceleration at the beam tip along the bending direction, gravity removed [m/s²].
    r, theta_ref, p_load, spool : array, optional
        Excitation [V], angle reference [rad], load pressure [Pa], spool position (-1...1).
    extra : mapping of str to array
        Other columns, kept and ignored.
    metadata : mapping of str to str
        Provenance (the ``# key: value`` lines of the CSV format).
    """

    t: np.ndarray
    v: np.ndarray
    theta: np.ndarray
    accel: np.ndarray
    r: np.ndarray | None = None
    theta_ref: np.ndarray | None = None
    p_load: np.ndarray | None = None
    spool: np.ndarray | None = None
    extra: Mapping[str, np.ndarray] = field(default_factory=dict)
    metadata: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = _signal("t", self.t, None)
        if t.size < 2:
            raise ValueError(f"a time series needs at least 2 samples, got {t.size}")
        i = first_nonuniform_step(t)
        if i is not None:
            raise ValueError(
                f"t must be uniformly sampled and increasing (relative spacing within {TIME_UNIFORMITY_RTOL:g}); "
                f"step {i} is {float(t[i] - t[i - 1]):.9g} s, the typical (median) step is {typical_step(t):.9g} s"
            )
        object.__setattr__(self, "t", t)
        for name in REQUIRED_COLUMNS[1:]:
            object.__setattr__(self, name, _signal(name, getattr(self, name), t.size))
        for name in OPTIONAL_COLUMNS:
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _signal(name, getattr(self, name), t.size))
        if self.spool is not None and np.any(np.abs(self.spool) > 1.0 + 1e-9):
            bad = int(np.flatnonzero(np.abs(self.spool) > 1.0 + 1e-9)[0])
            raise ValueError(f"signal 'spool' must lie in -1...1, got {float(self.spool[bad]):g} at sample {bad}")
        extra = {}
        for name, value in self.extra.items():
            if name in REQUIRED_COLUMNS or name in OPTIONAL_COLUMNS:
                raise ValueError(f"extra column {name!r} is a standard column; pass it as the field {name}")
            extra[str(name)] = _signal(name, value, t.size)
        object.__setattr__(self, "extra", MappingProxyType(extra))
        object.__setattr__(self, "metadata", MappingProxyType({str(k): str(v) for k, v in self.metadata.items()}))

    @property
    def dt_s(self) -> float:
        """Mean sample interval [s]."""
        return float((self.t[-1] - self.t[0]) / (self.t.size - 1))

    @property
    def sample_rate_hz(self) -> float:
        return 1.0 / self.dt_s

    def __len__(self) -> int:
        return int(self.t.size)

    def columns(self) -> dict[str, np.ndarray]:
        """All present signals by column name: required, optional, then extra."""
        cols = {name: getattr(self, name) for name in REQUIRED_COLUMNS}
        cols.update({name: getattr(self, name) for name in OPTIONAL_COLUMNS if getattr(self, name) is not None})
        cols.update(self.extra)
        return cols
