"""An independent linear rig with effects the diagnosis is not told about, for testing it.

The notebook's actuator and base (eq 9.1/9.2, SI as :class:`samii.measure.linear_rig.LinearRig`)
under the position loop ``v = r - Kp theta``, with optional physics a rig may
have and a model may lack:

* ``command_delay_s``: the valve acts on v(t - T) (inside the loop);
* ``valve_hz, valve_zeta``: second-order valve dynamics (inside the loop);
* ``act_mode``: (f_p, z_p, f_z, z_z), a structural pole/zero pair in theta/v (inside the loop);
* ``base_mode``: (f, z, B), a base mode the modal sum lacks;
* ``accel_lowpass_hz`` (+ ``accel_lowpass_order``): the accelerometer's Butterworth roll-off (recording only);
* ``accel_highpass_hz``: AC coupling of the accelerometer (recording only);
* ``accel_delay_s``, ``theta_delay_s``: channels read late (recording only).

The response to a rest-to-rest excitation is computed exactly in the frequency
domain (FFT of the whole run, zero-padded 2x so nothing wraps around), the
filters from ``scipy.signal``'s analogue designs, delays as exact phase; then
white sensor noise is added. Sampling is the DAQ's: every channel is the
continuous signal at the sample times (no hold in the loop: the rig's valve
sees an analogue command).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.fft
from scipy import signal

from samii.measure.linear_rig import DEG
from samii.measure.timeseries import TimeSeries

__all__ = ["EffectRig"]


@dataclass(frozen=True)
class EffectRig:
    params: dict | None = None  # notebook parameters (default eq 9.4)
    position_gain_v_per_rad: float = 1.0 / DEG
    command_delay_s: float = 0.0
    valve_hz: float | None = None
    valve_zeta: float = 0.7
    act_mode: tuple | None = None
    base_mode: tuple | None = None
    accel_lowpass_hz: float | None = None
    accel_lowpass_order: int = 1
    accel_highpass_hz: float | None = None
    accel_delay_s: float = 0.0
    theta_delay_s: float = 0.0
    noise: dict = field(default_factory=lambda: {"v": 1e-3, "theta": 5e-4, "accel": 1e-2})

    def _p(self) -> dict:
        from samii.notebook import EQ9_4

        return dict(self.params or EQ9_4)

    def responses(self, f_hz: np.ndarray) -> dict[str, np.ndarray]:
        """Open-loop G (theta/v), B (xdd/theta) and the recording factors at ``f_hz``."""
        from samii.identify.structures import ModelStructure

        p = self._p()
        st = ModelStructure.notebook_3mode()
        f = np.asarray(f_hz, float)
        s = 2j * np.pi * f
        with np.errstate(all="ignore"):
            G = np.where(f > 0, st.response(p, np.where(f > 0, f, 1.0), "act") * DEG, 0.0)
            B = st.response(p, np.where(f > 0, f, 1.0), "base") / DEG
        B = np.where(f > 0, B, 0.0)
        G = G * np.exp(-s * self.command_delay_s)
        if self.valve_hz:
            wv = 2 * np.pi * self.valve_hz
            G = G * wv * wv / (s * s + 2 * self.valve_zeta * wv * s + wv * wv)
        if self.act_mode:
            fp, zp, fz, zz = self.act_mode
            wp, wz = 2 * np.pi * fp, 2 * np.pi * fz
            G = G * (wp / wz) ** 2 * (s * s + 2 * zz * wz * s + wz * wz) / (s * s + 2 * zp * wp * s + wp * wp)
        if self.base_mode:
            fm, zm, bm = self.base_mode
            wm = 2 * np.pi * fm
            B = B + bm * s**4 / (s * s + 2 * zm * wm * s + wm * wm)
        ma = np.exp(-s * self.accel_delay_s)
        if self.accel_lowpass_hz:
            b, a = signal.butter(self.accel_lowpass_order, 2 * np.pi * self.accel_lowpass_hz, analog=True)
            ma = ma * signal.freqs(b, a, 2 * np.pi * f)[1]
        if self.accel_highpass_hz:
            b, a = signal.butter(1, 2 * np.pi * self.accel_highpass_hz, btype="highpass", analog=True)
            ma = ma * signal.freqs(b, a, 2 * np.pi * f)[1]
        mt = np.exp(-s * self.theta_delay_s)
        return {"G": G, "B": B, "accel": ma, "theta": mt}

    def simulate(self, r: np.ndarray, *, sample_rate_hz: float, rng: np.random.Generator | None = None, metadata: dict | None = None) -> TimeSeries:
        """Closed-loop response to the rest-to-rest excitation ``r`` [V], with sensor noise when ``rng`` is given."""
        r = np.asarray(r, float)
        n = r.size
        nfft = scipy.fft.next_fast_len(2 * n, real=True)
        f = np.fft.rfftfreq(nfft, 1.0 / sample_rate_hz)
        resp = self.responses(f)
        G, B = resp["G"], resp["B"]
        R = scipy.fft.rfft(r, nfft)
        V = R / (1.0 + self.position_gain_v_per_rad * G)
        TH = G * V
        A = B * TH
        out = {
            "v": scipy.fft.irfft(V, nfft)[:n],
            "theta": scipy.fft.irfft(TH * resp["theta"], nfft)[:n],
            "accel": scipy.fft.irfft(A * resp["accel"], nfft)[:n],
        }
        if rng is not None:
            for k, sd in self.noise.items():
                out[k] = out[k] + sd * rng.standard_normal(n)
        t = np.arange(n) / sample_rate_hz
        return TimeSeries(t=t, r=r, metadata=dict(metadata or {"source": "samii.diagnose.rig.EffectRig"}), **out)
