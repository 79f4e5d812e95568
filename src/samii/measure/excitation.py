"""Excitation signals of the rig's Bode tests: a repeated swept sine and a stepped (fixed) sine.

Both are added to the joint-2 valve command while the position loop holds the
arm at the nominal pose (the integrator in theta/v drifts open loop, notebook
ch. 9 / DESIGN.md). Both are pure functions of time, so a simulator or a signal
generator can evaluate them at any rate.

Swept sine
----------
A sweep law that gives every octave *at least* ``cycles_per_octave`` cycles and
*at least* ``seconds_per_octave`` seconds, the rule a dynamic signal analyzer
applies per frequency point ("integrate N cycles or T seconds, whichever is
longer"). Written as the sweep rate::

    df/dt = min(f^2 / C, f / L),   C = cycles_per_octave / ln 2,  L = seconds_per_octave / ln 2

Below the corner ``f_c = C / L = cycles_per_octave / seconds_per_octave`` the
sweep is hyperbolic (the period grows linearly; a constant number of cycles per
octave), above it exponential (a constant time per octave). A pure exponential
sweep long enough to give 0.1 Hz three cycles would spend 20 s on every one of
the 8.6 octaves from 0.1 to 40 Hz (~3 min per sweep); the hybrid spends that
time only where cycles are scarce.

Defaults, and why
-----------------
Band 0.1-40 Hz and 3 repetitions as on the rig (notebook ch. 9). 3 cycles and 4 s
per octave give a 63 s sweep.

Amplitude 0.1 V. The constraint is the load pressure at the closed-loop
hydraulic resonance (8.4 Hz, eq 10.1): to move the link there the actuator
needs J w^2 theta / Dm, and with the simulator's 7 MPa supply and 1.7 cm^3/rad
displacement a 2 V sweep (the joint moving 2 deg at low frequency) drives the
load pressure to 95 % of supply, where the orifice law is far from linear
(the FRF near the resonance then moves by 7 dB). At 0.1 V the peak load
pressure is about 1.2 MPa (17 % of supply), the valve command stays below
0.2 V (2 % of its +-10 V range), the joint moves 0.1 deg at low frequency
(theta ~ r / Kp below the loop bandwidth, Kp = 1 V/deg) and the measured FRF
stays within 0.5 dB and 2 deg of the small-signal one over 0.5-35 Hz
(experiments/amplitude_nonlinearity). Raise it for a better signal-to-noise
ratio with sensor noise, at the price of that nonlinearity.

Rest of 20 s after each sweep: the slowest mode of the default simulator,
base mode 1 under the position loop (-0.326 +- 10.86j, ``samii modes``; eq
10.2: -0.3245 +- 10.88j), has a time constant 1/0.326 = 3.1 s; 20 s is 6.5 of
them (what still rings is 0.15 % of it). On the embedded model the FRF is the
same with 15, 20 or 45 s (0.001 dB on xdd/theta at 0.02 V). A model with less
damping needs more (``tail_s``; with the viscous clamp of an earlier model,
zeta1 = 0.008, it took 45 s). With these defaults the campaign is 3 x 84 s =
4.2 min simulated, under 2 s of wall time at 130-150x real time.

The response must come to rest between sweeps: the frequency-response
estimator (:mod:`samii.measure.frf`) takes each repetition as one record from
rest to rest. The rest before a sweep gives the operating point that the
estimator subtracts.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

__all__ = ["SweptSine", "SteppedSine", "DEFAULT_STEPPED_FREQS_HZ"]

#: Default stepped-sine frequencies [Hz]: about 6 per octave over 0.5-35 Hz (the
#: acceptance band of issue 3), plus the base resonances of the embedded model
#: (mode 1 at 1.74 Hz, the theta/v pole pair near 9.9 Hz, mode 3 at 24.9 Hz),
#: which a Bode test must not step over. Settling there is slowest: mode 1's time
#: constant 1/(zeta w) = 3.6 s, so ``settle_s`` = 20 s leaves 0.4 % of the transient.
DEFAULT_STEPPED_FREQS_HZ: tuple[float, ...] = (0.5, 1.0, 1.5, 1.75, 2.5, 4.0, 6.0, 8.0, 9.0, 9.9, 11.0, 14.0, 18.0, 22.0, 25.0, 28.0, 35.0)


def _raised_cosine(x: np.ndarray) -> np.ndarray:
    """0 at x <= 0, 1 at x >= 1, smooth (zero slope at both ends) in between."""
    x = np.clip(x, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * x)


@dataclass(frozen=True)
class SweptSine:
    """A swept sine repeated ``repetitions`` times, each record from rest to rest.

    One record (repetition) is: ``lead_s`` of rest; the active part; ``tail_s``
    of rest. The active part, described upwards, is a fade at ``start_hz`` over
    ``fade_low_cycles``, the sweep ``start_hz`` -> ``stop_hz`` at full amplitude,
    and a fade at ``stop_hz`` over ``fade_high_cycles``; with
    ``direction="down"`` it runs in reverse (fade-in at ``stop_hz``, sweep down,
    fade-out at ``start_hz``). Every frequency of the band is swept at full
    amplitude; the command and its slope start and end at zero.

    Sweeping *down* is the default because the record must end at rest: the
    lightly damped base mode 1 (1.73 Hz) is then crossed about 45 s before the
    end of the sweep, and what still moves when the excitation stops is the
    quasi-static low-frequency response, which follows it to rest within the
    position loop's time constants (slowest 1/4.2 s, eq 10.1). Sweeping up on
    the notebook's model left base mode 1 ringing at 1e-3 of its peak when the
    next record started, which swamped the weak low-frequency acceleration.

    Parameters
    ----------
    start_hz, stop_hz : float
        Band of the sweep [Hz], start_hz < stop_hz whatever the direction.
    amplitude_v : float
        Peak excitation added to the valve command [V] (see the module docstring).
    cycles_per_octave : float
        Minimum number of cycles per octave (governs the low end).
    seconds_per_octave : float
        Minimum time per octave [s] (governs the high end).
    fade_low_cycles, fade_high_cycles : float
        Raised-cosine envelope at the ``start_hz`` and ``stop_hz`` ends, in
        cycles of those frequencies.
    lead_s, tail_s : float
        Rest before and after each sweep [s]. The lead gives the operating
        point. The tail lets the response decay before the next record, so it
        must last a few time constants of the slowest mode (see the module
        docstring); any transient of the excitation rings that mode up. On the
        notebook's model a 3 s tail left ringing that biased the base FRF by
        0.06 dB at 0.5-1 Hz, a 10 s tail by 0.002 dB.
    repetitions : int
        Number of sweeps to average (3 on the rig, notebook ch. 9).
    direction : {"down", "up"}
        Sweep direction.
    alternate_sign : bool
        Repetition k is multiplied by (-1)^k. A linear response flips sign with
        the excitation, an even-order distortion (the vertical reaction of link
        2's centre of mass, l cos(theta) ~ l (1 - theta^2/2); the asymmetry of the
        valve's square-root law about the holding pressure) does not, so the
        estimator (:func:`samii.measure.frf.estimate_frf`) can weight the records
        to cancel it, and its coherence then shows it. With identical repetitions
        it is fully repeatable, coherence stays 1 and it biases the weak
        low-frequency xdd/theta by 10 dB or more at 0.1 V.
    """

    start_hz: float = 0.1
    stop_hz: float = 40.0
    amplitude_v: float = 0.1
    cycles_per_octave: float = 3.0
    seconds_per_octave: float = 4.0
    fade_low_cycles: float = 0.25
    fade_high_cycles: float = 10.0
    lead_s: float = 1.0
    tail_s: float = 20.0
    repetitions: int = 3
    direction: Literal["down", "up"] = "down"
    alternate_sign: bool = True

    def __post_init__(self) -> None:
        for name in ("start_hz", "stop_hz", "amplitude_v", "cycles_per_octave", "seconds_per_octave"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"SweptSine.{name} must be positive and finite, got {value!r}")
        for name in ("fade_low_cycles", "fade_high_cycles", "lead_s", "tail_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"SweptSine.{name} must be non-negative and finite, got {value!r}")
        if self.stop_hz <= self.start_hz:
            raise ValueError(f"SweptSine.stop_hz ({self.stop_hz}) must exceed start_hz ({self.start_hz})")
        if int(self.repetitions) != self.repetitions or self.repetitions < 1:
            raise ValueError(f"SweptSine.repetitions must be a positive integer, got {self.repetitions!r}")
        if self.direction not in ("down", "up"):
            raise ValueError(f"SweptSine.direction must be 'down' or 'up', got {self.direction!r}")

    # -- the sweep law, described upwards ----------------------------------------

    @property
    def _c(self) -> float:
        return self.cycles_per_octave / np.log(2.0)

    @property
    def _l(self) -> float:
        return self.seconds_per_octave / np.log(2.0)

    @property
    def corner_hz(self) -> float:
        """Frequency where the law turns from constant cycles to constant time per octave [Hz]."""
        return self.cycles_per_octave / self.seconds_per_octave

    @property
    def _knee_hz(self) -> float:
        return float(np.clip(self.corner_hz, self.start_hz, self.stop_hz))

    @property
    def _knee_s(self) -> float:
        return self._c * (1.0 / self.start_hz - 1.0 / self._knee_hz)

    @property
    def sweep_s(self) -> float:
        """Duration of the sweep proper between start_hz and stop_hz [s]."""
        return self._knee_s + self._l * np.log(self.stop_hz / self._knee_hz)

    @property
    def fade_low_s(self) -> float:
        return self.fade_low_cycles / self.start_hz

    @property
    def fade_high_s(self) -> float:
        return self.fade_high_cycles / self.stop_hz

    @property
    def active_s(self) -> float:
        """Duration of the excitation within one record [s]."""
        return self.fade_low_s + self.sweep_s + self.fade_high_s

    @property
    def record_s(self) -> float:
        """Length of one repetition, rest to rest [s]."""
        return self.lead_s + self.active_s + self.tail_s

    @property
    def duration_s(self) -> float:
        """The whole campaign [s]."""
        return self.repetitions * self.record_s

    @property
    def record_signs(self) -> tuple[int, ...]:
        """Sign of the excitation in each repetition: (+1, -1, +1, ...) with ``alternate_sign``."""
        return tuple(-1 if (self.alternate_sign and k % 2) else 1 for k in range(self.repetitions))

    def _up_frequency_hz(self, u: np.ndarray) -> np.ndarray:
        """Frequency at time u into the upward active part."""
        tau = np.clip(u - self.fade_low_s, 0.0, self.sweep_s)
        hyper = 1.0 / (1.0 / self.start_hz - np.minimum(tau, self._knee_s) / self._c)
        return np.where(tau <= self._knee_s, hyper, self._knee_hz * np.exp((tau - self._knee_s) / self._l))

    def _up_cycles(self, u: np.ndarray) -> np.ndarray:
        """Cycles completed at time u into the upward active part (integral of the frequency)."""
        tau = np.clip(u - self.fade_low_s, 0.0, self.sweep_s)
        th = np.minimum(tau, self._knee_s)
        hyper = -self._c * np.log1p(-self.start_hz * th / self._c)
        f_log = self._knee_hz * np.exp(np.maximum(tau - self._knee_s, 0.0) / self._l)
        swept = hyper + self._l * (f_log - self._knee_hz)
        before = self.start_hz * np.minimum(u, self.fade_low_s)
        after = self.stop_hz * np.maximum(u - self.fade_low_s - self.sweep_s, 0.0)
        return before + swept + after

    def _up_envelope(self, u: np.ndarray) -> np.ndarray:
        env = np.ones_like(u)
        if self.fade_low_s > 0:
            env = env * _raised_cosine(u / self.fade_low_s)
        if self.fade_high_s > 0:
            env = env * _raised_cosine((self.active_s - u) / self.fade_high_s)
        return env

    def _active_time(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """Time into the active part of the current record, and whether it is active."""
        t = np.asarray(t_s, float)
        inside = (t >= 0) & (t < self.duration_s)
        u = np.where(inside, t % self.record_s, -1.0) - self.lead_s
        return u, inside & (u >= 0) & (u <= self.active_s)

    def frequency_hz(self, t_s) -> np.ndarray:
        """Instantaneous excitation frequency at campaign times ``t_s`` [Hz] (NaN at rest)."""
        u, active = self._active_time(t_s)
        if self.direction == "down":
            u = self.active_s - u
        return np.where(active, self._up_frequency_hz(u), np.nan)

    def signal(self, t_s) -> np.ndarray:
        """Excitation r(t) [V] at campaign times ``t_s`` (t = 0 is the start of the first record)."""
        u, active = self._active_time(t_s)
        if self.direction == "up":
            cycles, env = self._up_cycles(u), self._up_envelope(u)
        else:  # the upward active part played backwards, phase counted from its start
            total = float(self._up_cycles(np.asarray(self.active_s)))
            cycles = total - self._up_cycles(self.active_s - u)
            env = self._up_envelope(self.active_s - u)
        sign = 1.0
        if self.alternate_sign:
            k = np.floor(np.asarray(t_s, float) / self.record_s)
            sign = np.where(k % 2 == 1, -1.0, 1.0)
        return np.where(active, sign * self.amplitude_v * env * np.sin(2.0 * np.pi * cycles), 0.0)

    def describe(self) -> dict[str, float | int | str]:
        """Every setting and the derived durations, for metadata and run.json."""
        signs = ", alternating sign" if self.alternate_sign and self.repetitions > 1 else ""
        return {
            "excitation": f"swept sine {self.start_hz:g}-{self.stop_hz:g} Hz {self.direction}, {self.repetitions} repetitions{signs}",
            "sweep_law": "df/dt = min(f^2/C, f/L): >= cycles_per_octave cycles and >= seconds_per_octave s per octave",
            "start_hz": self.start_hz,
            "stop_hz": self.stop_hz,
            "direction": self.direction,
            "amplitude_v": self.amplitude_v,
            "cycles_per_octave": self.cycles_per_octave,
            "seconds_per_octave": self.seconds_per_octave,
            "corner_hz": self.corner_hz,
            "fade_low_cycles": self.fade_low_cycles,
            "fade_high_cycles": self.fade_high_cycles,
            "lead_s": self.lead_s,
            "tail_s": self.tail_s,
            "sweep_s": self.sweep_s,
            "record_s": self.record_s,
            "repetitions": self.repetitions,
            "alternate_sign": self.alternate_sign,
            "duration_s": self.duration_s,
        }

    @classmethod
    def from_metadata(cls, meta) -> SweptSine:
        """The sweep a record's metadata (:meth:`describe`'s settings, as ``samii measure`` writes
        them in a time series' header) states. Raises KeyError for a missing setting and
        ValueError for one that is not a number (or not a valid sweep)."""
        floats = ("start_hz", "stop_hz", "amplitude_v", "cycles_per_octave", "seconds_per_octave", "fade_low_cycles", "fade_high_cycles",
                  "lead_s", "tail_s")  # fmt: skip
        kw: dict = {k: float(meta[k]) for k in floats}
        kw["repetitions"] = int(float(meta["repetitions"]))
        kw["direction"] = str(meta["direction"]).strip()
        kw["alternate_sign"] = str(meta["alternate_sign"]).strip().lower() in ("true", "1", "yes")
        return cls(**kw)


@dataclass(frozen=True)
class SteppedSine:
    """Stepped (fixed) sine: one dwell per frequency, contiguous in time.

    Each dwell: ``ramp_s`` raised-cosine ramp-up, steady excitation until
    ``settle_s`` after the dwell began, then a measurement window of a whole
    number of periods (at least ``measure_cycles`` and at least ``measure_s``),
    then a ``ramp_s`` ramp-down to zero. The run starts with ``lead_s`` of rest.

    Parameters
    ----------
    freqs_hz : sequence of float
        Dwell frequencies [Hz], positive, any order (kept as given).
    amplitude_v : float
        Peak excitation [V]; 0.1 V as the swept sine (see the module docstring).
    settle_s : float
        Time from the start of a dwell to the start of its measurement [s].
        Default 6.5 time constants of the slowest mode of the default simulator
        (base mode 1 under the position loop, 1/0.326 = 3.1 s).
    ramp_s : float
        Ramp-up and ramp-down time [s]; 4 s (7 periods of base mode 1) rings that
        mode up less than 1 s does (after 15 s of settling, 4 deg left at 1.5 Hz
        instead of 10 deg).
    measure_cycles : int
        Minimum number of whole periods in the measurement window.
    measure_s : float
        Minimum length of the measurement window [s].
    lead_s : float
        Rest at the start of the run [s].
    """

    freqs_hz: tuple[float, ...] = DEFAULT_STEPPED_FREQS_HZ
    amplitude_v: float = 0.1
    settle_s: float = 20.0
    ramp_s: float = 4.0
    measure_cycles: int = 4
    measure_s: float = 2.0
    lead_s: float = 1.0
    _starts: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        freqs = tuple(float(f) for f in np.atleast_1d(np.asarray(self.freqs_hz, float)))
        if not freqs:
            raise ValueError("SteppedSine.freqs_hz is empty")
        if not all(np.isfinite(f) and f > 0 for f in freqs):
            raise ValueError(f"SteppedSine.freqs_hz must be positive and finite, got {freqs}")
        object.__setattr__(self, "freqs_hz", freqs)
        for name in ("amplitude_v", "settle_s", "measure_s"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"SteppedSine.{name} must be positive, got {getattr(self, name)!r}")
        if not (0 <= self.ramp_s <= self.settle_s):
            raise ValueError(f"SteppedSine.ramp_s must lie in 0...settle_s, got {self.ramp_s!r}")
        if self.lead_s < 0:
            raise ValueError(f"SteppedSine.lead_s must be non-negative, got {self.lead_s!r}")
        if int(self.measure_cycles) != self.measure_cycles or self.measure_cycles < 1:
            raise ValueError(f"SteppedSine.measure_cycles must be a positive integer, got {self.measure_cycles!r}")
        starts = self.lead_s + np.concatenate([[0.0], np.cumsum(self.dwell_s)[:-1]])
        object.__setattr__(self, "_starts", starts)

    @property
    def n_cycles(self) -> np.ndarray:
        """Whole periods in each measurement window."""
        f = np.asarray(self.freqs_hz)
        return np.maximum(self.measure_cycles, np.ceil(self.measure_s * f - 1e-9)).astype(int)

    @property
    def window_s(self) -> np.ndarray:
        """Length of each measurement window [s]: n_cycles / f."""
        return self.n_cycles / np.asarray(self.freqs_hz)

    @property
    def dwell_s(self) -> np.ndarray:
        """Length of each dwell [s]."""
        return self.settle_s + self.window_s + self.ramp_s

    @property
    def windows_s(self) -> np.ndarray:
        """Measurement windows as (start, stop) campaign times [s], shape (n, 2)."""
        start = self._starts + self.settle_s
        return np.column_stack([start, start + self.window_s])

    @property
    def duration_s(self) -> float:
        return float(self.lead_s + np.sum(self.dwell_s))

    def frequency_hz(self, t_s) -> np.ndarray:
        """Frequency of the dwell at campaign times ``t_s`` [Hz] (NaN before the first)."""
        t = np.asarray(t_s, float)
        out = np.full(t.shape, np.nan)
        for f, start, dwell in zip(self.freqs_hz, self._starts, self.dwell_s):
            out[(t >= start) & (t < start + dwell)] = f
        return out

    def signal(self, t_s) -> np.ndarray:
        """Excitation r(t) [V] at campaign times ``t_s``."""
        t = np.asarray(t_s, float)
        out = np.zeros_like(t)
        for f, start, dwell in zip(self.freqs_hz, self._starts, self.dwell_s):
            tau = t - start
            inside = (tau >= 0) & (tau < dwell)
            if not np.any(inside):
                continue
            tau = tau[inside]
            env = np.ones_like(tau)
            if self.ramp_s > 0:
                env = _raised_cosine(tau / self.ramp_s) * _raised_cosine((dwell - tau) / self.ramp_s)
            out[inside] = self.amplitude_v * env * np.sin(2.0 * np.pi * f * tau)
        return out

    @classmethod
    def from_metadata(cls, meta) -> SteppedSine:
        """The stepped sine a record's metadata (:meth:`describe`'s settings, as ``samii measure`` writes them in a time
        series' header) states. Raises KeyError for a missing setting and ValueError for one that is not a number (or
        not a valid schedule)."""
        try:
            freqs = json.loads(str(meta["freqs_hz"]))
        except json.JSONDecodeError:
            raise ValueError(f"freqs_hz: expected a list of frequencies [Hz] such as [0.5, 1.0], got {meta['freqs_hz']!r}") from None
        if not isinstance(freqs, list) or not all(isinstance(f, (int, float)) and not isinstance(f, bool) for f in freqs):
            raise ValueError(f"freqs_hz: expected a list of frequencies [Hz] such as [0.5, 1.0], got {meta['freqs_hz']!r}")
        kw: dict = {k: float(meta[k]) for k in ("amplitude_v", "settle_s", "ramp_s", "measure_s", "lead_s")}
        cycles = float(meta["measure_cycles"])
        if cycles != int(cycles):
            raise ValueError(f"measure_cycles: expected a whole number of periods, got {meta['measure_cycles']!r}")
        return cls(freqs_hz=tuple(float(f) for f in freqs), measure_cycles=int(cycles), **kw)

    def describe(self) -> dict[str, float | int | str | list]:
        """Every setting and the derived schedule, for metadata and run.json."""
        return {
            "excitation": f"stepped sine, {len(self.freqs_hz)} frequencies",
            "freqs_hz": list(self.freqs_hz),
            "amplitude_v": self.amplitude_v,
            "settle_s": self.settle_s,
            "ramp_s": self.ramp_s,
            "measure_cycles": self.measure_cycles,
            "measure_s": self.measure_s,
            "lead_s": self.lead_s,
            "n_cycles": self.n_cycles.tolist(),
            "duration_s": self.duration_s,
        }
