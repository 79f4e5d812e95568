"""Dynamics of the rig's sensors between the physics and the DAQ: what a real accelerometer and
angle sensor add to the signals before they are sampled.

The simulator's sensors are ideal by default. A rig's are not, and ``samii diagnose`` finds
such differences in measured data (``samii.diagnose.effects``, category ``sensor`` and the
sensor delays); these options put the same physics into the simulator, one per kind:

====================  =======  ==========================================================
``accel_gain``        1        scale error k of the accelerometer (a wrong sensitivity)
``accel_lowpass_hz``  Hz       first-order roll-off 1/(1 + s/w_c) (a charge amplifier's)
``accel_antialias_hz`` Hz      second-order Butterworth low-pass (an anti-alias filter)
``accel_highpass_hz`` Hz       first-order AC coupling s/(s + w_h)
``accel_delay_s``     s        the accelerometer's signal arrives this late
``theta_delay_s``     s        the angle signal arrives this late (the servo loop is not
                               affected: it reads the joint directly)
====================  =======  ==========================================================

0 (1 for the gain) means "none"; with every option at its default the signals are exactly those
of the ideal sensors (the filters are not applied at all), so today's model is unchanged.

They live in the model: :func:`samii.sim.mjcf.samii_xml` writes them, when set, as the custom
numeric ``samii_sensor_dynamics`` (the six numbers in the order of :data:`FIELDS`), so a
measurement and the linearised simulator of one model agree without being told.

Discrete time, at the physics rate the DAQ receives: each filter is the bilinear transform of its
continuous law, prewarped at its corner (``scipy.signal.butter``); a delay is a whole number of
samples plus a third-order Lagrange fractional-delay FIR (exact at DC; at a 25th of the sample
rate, 40 Hz at 1 kHz, its gain is within 2e-4 of 1 and its delay within 2e-4 samples of the
asked one; at a tenth of the rate within 0.5 %). :meth:`SensorDynamics.response`
returns the response of exactly these filters, so the linearised simulator matches a simulated
measurement; against the continuous laws the corners differ by the bilinear warping (0.5 % at
40 Hz with a 1 kHz physics rate).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import mujoco
import numpy as np

__all__ = ["FIELDS", "NUMERIC", "SensorDynamics", "SensorFilter"]

#: Custom numeric that carries the options in an MJCF model.
NUMERIC = "samii_sensor_dynamics"
#: Option names in the numeric's order, with their unit.
FIELDS: tuple[tuple[str, str], ...] = (
    ("accel_gain", "1"),
    ("accel_lowpass_hz", "Hz"),
    ("accel_antialias_hz", "Hz"),
    ("accel_highpass_hz", "Hz"),
    ("accel_delay_s", "s"),
    ("theta_delay_s", "s"),
)
#: Longest sensor delay [s].
MAX_DELAY_S = 1.0


@dataclass(frozen=True)
class SensorDynamics:
    """The sensors' own dynamics (module docstring). SI units; 0 (gain 1) = none."""

    accel_gain: float = 1.0
    accel_lowpass_hz: float = 0.0
    accel_antialias_hz: float = 0.0
    accel_highpass_hz: float = 0.0
    accel_delay_s: float = 0.0
    theta_delay_s: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"sensor parameter {f.name} must be a finite number, got {v!r}")
        if not self.accel_gain > 0:
            raise ValueError(f"sensor parameter accel_gain must be > 0 (1 = the true sensitivity), got {self.accel_gain!r}")
        for name in ("accel_lowpass_hz", "accel_antialias_hz", "accel_highpass_hz"):
            if getattr(self, name) < 0:
                raise ValueError(f"sensor parameter {name} must be >= 0 Hz (0 = none), got {getattr(self, name)!r}")
        for name in ("accel_delay_s", "theta_delay_s"):
            if not 0 <= getattr(self, name) <= MAX_DELAY_S:
                raise ValueError(f"sensor parameter {name} must be in [0, {MAX_DELAY_S:g}] s (0 = none), got {getattr(self, name)!r}")

    @property
    def ideal(self) -> bool:
        """True when every option is at its default (the sensors are ideal)."""
        return self == SensorDynamics()

    def changed(self) -> dict[str, float]:
        """The options not at their default (ideal) value, by name."""
        ideal = SensorDynamics()
        return {name: float(getattr(self, name)) for name, _ in FIELDS if getattr(self, name) != getattr(ideal, name)}

    def text(self) -> str:
        """The options not at their default, in words with units ("accel_lowpass_hz 30 Hz, theta_delay_s 0.002 s")."""
        units = dict(FIELDS)
        return ", ".join(f"{name} {value:g}" + ("" if units[name] == "1" else f" {units[name]}") for name, value in self.changed().items())

    def values(self) -> tuple[float, ...]:
        return tuple(float(getattr(self, name)) for name, _ in FIELDS)

    @classmethod
    def from_model(cls, model: mujoco.MjModel) -> SensorDynamics:
        """The options a model carries (ideal sensors when it has no ``samii_sensor_dynamics``)."""
        i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_NUMERIC, NUMERIC)
        if i < 0:
            return cls()
        a, size = int(model.numeric_adr[i]), int(model.numeric_size[i])
        data = np.asarray(model.numeric_data[a : a + size], float)
        if data.size != len(FIELDS):
            raise ValueError(f"custom numeric {NUMERIC!r} must hold {len(FIELDS)} numbers ({', '.join(n for n, _ in FIELDS)}), got {data.size}")
        return cls(**{name: float(v) for (name, _), v in zip(FIELDS, data)})

    def check_rate(self, rate_hz: float) -> None:
        """Raise ValueError when a corner is at or above the Nyquist frequency of ``rate_hz``."""
        for name in ("accel_lowpass_hz", "accel_antialias_hz", "accel_highpass_hz"):
            fc = getattr(self, name)
            if fc >= 0.5 * rate_hz:
                raise ValueError(f"sensor parameter {name} = {fc:g} Hz must be below half the physics rate ({0.5 * rate_hz:g} Hz) to be simulated")

    # -- discrete filters at the physics rate ---------------------------------------------
    def _accel_sos(self, rate_hz: float) -> np.ndarray | None:
        from scipy import signal  # (lazy: scipy.signal takes ~0.7 s and every command imports this module)

        sections = []
        if self.accel_lowpass_hz > 0:
            sections.append(signal.butter(1, self.accel_lowpass_hz, "low", fs=rate_hz, output="sos"))
        if self.accel_antialias_hz > 0:
            sections.append(signal.butter(2, self.accel_antialias_hz, "low", fs=rate_hz, output="sos"))
        if self.accel_highpass_hz > 0:
            sections.append(signal.butter(1, self.accel_highpass_hz, "high", fs=rate_hz, output="sos"))
        if not sections:
            return None
        sos = np.vstack(sections)
        sos[0, :3] *= self.accel_gain
        return sos

    def filters(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """``(theta taps, accel taps, accel sections)``: the filters at ``rate_hz`` as one FIR on theta and, on
        accel, an FIR followed by second-order sections (scipy's ``sos`` layout, None when there are none; the gain
        is in the first section, else in the accel taps). The same filters :class:`SensorFilter` applies to a
        measurement and :meth:`response` describes; the controller card runs them before it samples
        (:mod:`samii.closedloop.card`)."""
        self.check_rate(rate_hz)
        theta = _delay_fir(self.theta_delay_s * rate_hz)
        accel = _delay_fir(self.accel_delay_s * rate_hz)
        sos = self._accel_sos(rate_hz)
        return theta, accel if sos is not None else accel * self.accel_gain, sos

    def response(self, freq_hz: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """(theta factor, accel factor): the complex response of the sensors' filters at the
        physics rate ``rate_hz``, by which an ideal sensor's response is multiplied."""
        self.check_rate(rate_hz)
        f = np.asarray(freq_hz, float)
        w = 2 * np.pi * f / rate_hz
        theta = _fir_response(_delay_fir(self.theta_delay_s * rate_hz), w)
        accel = _fir_response(_delay_fir(self.accel_delay_s * rate_hz), w)
        sos = self._accel_sos(rate_hz)
        if sos is not None:
            from scipy import signal  # (lazy: imports scipy, only when called)

            accel = accel * signal.sosfreqz(sos, worN=w)[1]
        else:
            accel = accel * self.accel_gain
        return theta, accel


def _delay_fir(samples: float) -> np.ndarray:
    """FIR taps of a delay of ``samples`` (>= 0): whole samples, and the fraction by third-order
    Lagrange interpolation, centred on it (below one sample on the first two of its four taps)."""
    if samples <= 0:
        return np.ones(1)
    nearest = round(samples)
    if abs(samples - nearest) < 1e-9 * (1 + samples):
        taps = np.zeros(int(nearest) + 1)
        taps[-1] = 1.0
        return taps
    # taps at start .. start + 3, the delay between the middle two (below one sample: the first two)
    start = max(int(math.floor(samples)) - 1, 0)
    d = samples - start
    h = np.ones(4)
    for k in range(4):
        for j in range(4):
            if j != k:
                h[k] *= (d - j) / (k - j)
    taps = np.zeros(start + 4)
    taps[start:] = h
    return taps


def _fir_response(taps: np.ndarray, w: np.ndarray) -> np.ndarray:
    k = np.arange(taps.size)
    return np.exp(-1j * np.outer(w, k)) @ taps


class SensorFilter:
    """The sensors' dynamics applied chunk by chunk to physics-rate ``theta`` and ``accel``
    columns (the other columns pass unchanged). Each filter starts in steady state at its first
    sample (the operating point), so an AC coupling reads 0 at rest from the start."""

    def __init__(self, dynamics: SensorDynamics, rate_hz: float) -> None:
        dynamics.check_rate(rate_hz)
        self.dynamics = dynamics
        self._theta = _delay_fir(dynamics.theta_delay_s * rate_hz)
        self._accel_fir = _delay_fir(dynamics.accel_delay_s * rate_hz)
        self._sos = dynamics._accel_sos(rate_hz)
        self._state: dict[str, np.ndarray] = {}

    def _fir(self, key: str, taps: np.ndarray, x: np.ndarray) -> np.ndarray:
        if taps.size == 1:
            return x * taps[0]
        from scipy import signal  # (lazy: imports scipy, only when called)

        zi = self._state.get(key)
        if zi is None:
            zi = signal.lfilter_zi(taps, [1.0]) * x[0]
        y, self._state[key] = signal.lfilter(taps, [1.0], x, zi=zi)
        return y

    def process(self, columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        out = dict(columns)
        if len(next(iter(columns.values()), ())) == 0:
            return out
        if "theta" in out:
            out["theta"] = self._fir("theta", self._theta, np.asarray(out["theta"], float))
        if "accel" in out:
            x = self._fir("accel", self._accel_fir, np.asarray(out["accel"], float))
            if self._sos is None:
                x = x * self.dynamics.accel_gain
            else:
                from scipy import signal  # (lazy: imports scipy, only when called)

                zi = self._state.get("sos")
                if zi is None:
                    zi = signal.sosfilt_zi(self._sos) * x[0]
                x, self._state["sos"] = signal.sosfilt(self._sos, x, zi=zi)
            out["accel"] = x
        return out
