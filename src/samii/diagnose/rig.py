"""An independent linear rig with effects the diagnosis is not told about, for testing it.

The notebook's actuator and base (eq 9.1/9.2, SI as :class:`samii.measure.linear_rig.LinearRig`)
under the position loop ``v = r - Kp theta``, with optional physics a rig may
have and a model may lack:

* ``command_delay_s``: the valve acts on v(t - T) (inside the loop);
* ``valve_hz, valve_zeta``: second-order valve dynamics (inside the loop);
* ``leak_per_s``: the actuator's integrator a real pole at ``a`` [1/s], theta/v x s/(s - a)
  (flow lost with the load pressure against a holding torque that changes with theta; ``a`` > 0
  for a destabilising load, as gravity on samii's simulator's arm: ``samii.diagnose.effects``);
* ``act_mode``: (f_p, z_p, f_z, z_z), a structural pole/zero pair in theta/v (inside the loop);
* ``base_mode``: (f, z, B), a base mode the modal sum lacks;
* ``accel_lowpass_hz`` (+ ``accel_lowpass_order``): the accelerometer's Butterworth roll-off (recording only);
* ``accel_highpass_hz``: AC coupling of the accelerometer (recording only);
* ``accel_delay_s``, ``theta_delay_s``: channels read late (recording only);
* ``valve_nonlinearity``, a nonlinearity on the command inside the loop:
  ``("dead_band", d)`` (no flow while ``|v| < d`` V, spool overlap;
  ``sign(v) max(|v| - d, 0)``), ``("saturation", L)`` (the flow stops growing
  beyond ``|v| = L`` V, spool travel or flow limit; ``clip(v, -L, L)``),
  ``("asymmetry", a)`` (the negative direction's gain ``1 - a``: unequal
  piston areas, a worn edge) or ``("hysteresis", h)`` (a play of half-width
  ``h`` V: the output follows the command only once it has moved ``h`` past
  it, the spool's friction or the torque motor's magnetic hysteresis).

The response to a rest-to-rest excitation is computed exactly in the frequency
domain (FFT of the whole run, zero-padded 2x so nothing wraps around), the
filters from ``scipy.signal``'s analogue designs, delays as exact phase; then
white sensor noise is added. Sampling is the DAQ's: every channel is the
continuous signal at the sample times (no hold in the loop: the rig's valve
sees an analogue command).

With a valve nonlinearity the loop cannot be solved in the frequency domain:
it is stepped in time at ``OVERSAMPLE`` x the sample rate (r interpolated
by a cubic spline), theta/v discretised exactly for a held input (zero-order
hold, which delays the valve's input by half a step: 0.125 ms at 1 kHz x 4,
an eighth of a sample) and diagonalised, the command delay a whole number of
steps; what lies outside the loop (the base, the sensors) is applied in the
frequency domain as above.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.fft
from scipy import signal
from scipy.interpolate import CubicSpline

from samii.identify.structures import ModelStructure
from samii.measure.linear_rig import DEG
from samii.notebook import EQ9_4, actuator_tf
from samii.timeseries import TimeSeries

__all__ = ["EffectRig", "OVERSAMPLE", "valve_law"]

#: Steps of the time-domain loop per DAQ sample (valve nonlinearity only).
OVERSAMPLE = 4


VALVE_LAWS = ("dead_band", "saturation", "asymmetry", "hysteresis")


def valve_law(kind: str, value: float):
    """The valve nonlinearity ``u = N(v)`` (module docstring) as a function of a float, called once per step in order
    (the hysteresis keeps its state between calls)."""
    if kind not in VALVE_LAWS:
        raise ValueError(f"valve nonlinearity must be one of {', '.join(map(repr, VALVE_LAWS))}, got {kind!r}")
    if not (np.isfinite(value) and value > 0) or (kind == "asymmetry" and value >= 1.0):
        what = "a fraction in (0, 1)" if kind == "asymmetry" else "a positive number of volts"
        raise ValueError(f"valve nonlinearity {kind!r}: its level must be {what}, got {value!r}")
    if kind == "dead_band":
        return lambda v: v - value if v > value else (v + value if v < -value else 0.0)
    if kind == "saturation":
        return lambda v: value if v > value else (-value if v < -value else v)
    if kind == "asymmetry":
        low = 1.0 - value
        return lambda v: v if v >= 0.0 else low * v
    state = [0.0]

    def play(v: float) -> float:
        y = state[0]
        if v > y + value:
            y = v - value
        elif v < y - value:
            y = v + value
        state[0] = y
        return y

    return play


@dataclass(frozen=True)
class EffectRig:
    params: dict | None = None  # notebook parameters (default eq 9.4)
    position_gain_v_per_rad: float = 1.0 / DEG
    command_delay_s: float = 0.0
    valve_hz: float | None = None
    valve_zeta: float = 0.7
    leak_per_s: float = 0.0
    act_mode: tuple | None = None
    base_mode: tuple | None = None
    accel_lowpass_hz: float | None = None
    accel_lowpass_order: int = 1
    accel_highpass_hz: float | None = None
    accel_delay_s: float = 0.0
    theta_delay_s: float = 0.0
    valve_nonlinearity: tuple | None = None
    noise: dict = field(default_factory=lambda: {"v": 1e-3, "theta": 5e-4, "accel": 1e-2})

    def _p(self) -> dict:
        return dict(self.params or EQ9_4)

    def responses(self, f_hz: np.ndarray) -> dict[str, np.ndarray]:
        """Open-loop G (theta/v), B (xdd/theta) and the recording factors at ``f_hz``."""

        p = self._p()
        st = ModelStructure.notebook_3mode()
        f = np.asarray(f_hz, float)
        s = 2j * np.pi * f
        with np.errstate(all="ignore"):
            G = np.where(f > 0, st.response(p, np.where(f > 0, f, 1.0), "act") * DEG, 0.0)
            B = st.response(p, np.where(f > 0, f, 1.0), "base") / DEG
        B = np.where(f > 0, B, 0.0)
        with np.errstate(all="ignore"):
            leak = np.where(f > 0, s / (s - self.leak_per_s), 0.0)
        G = G * np.exp(-s * self.command_delay_s) * self._loop_factor(s) * leak
        if self.base_mode:
            fm, zm, bm = self.base_mode
            wm = 2 * np.pi * fm
            B = B + bm * s**4 / (s * s + 2 * zm * wm * s + wm * wm)
        ma, mt = self._sensor_factors(f)
        return {"G": G, "B": B, "accel": ma, "theta": mt}

    def _loop_polys(self) -> tuple[np.ndarray, np.ndarray]:
        """Numerator and denominator (in s) of the valve and act-mode factors of theta/v."""
        num, den = np.ones(1), np.ones(1)
        if self.valve_hz:
            wv = 2 * np.pi * self.valve_hz
            num, den = num * wv * wv, np.polymul(den, [1.0, 2 * self.valve_zeta * wv, wv * wv])
        if self.act_mode:
            fp, zp, fz, zz = self.act_mode
            wp, wz = 2 * np.pi * fp, 2 * np.pi * fz
            num = np.polymul(num, (wp / wz) ** 2 * np.array([1.0, 2 * zz * wz, wz * wz]))
            den = np.polymul(den, [1.0, 2 * zp * wp, wp * wp])
        return num, den

    def _leaky(self, num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """theta/v's polynomials with its integrator 1/s replaced by 1/(s - a) (``leak_per_s``)."""
        num, den = np.asarray(num, float), np.asarray(den, float)
        if not self.leak_per_s:
            return num, den
        if den[-1] != 0.0:
            raise ValueError("EffectRig: theta/v has no integrator to leak")
        return num, np.polymul(den[:-1], [1.0, -self.leak_per_s])

    def _loop_factor(self, s: np.ndarray) -> np.ndarray:
        num, den = self._loop_polys()
        return np.polyval(num, s) / np.polyval(den, s)

    def _sensor_factors(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = 2j * np.pi * f
        ma = np.exp(-s * self.accel_delay_s)
        if self.accel_lowpass_hz:
            b, a = signal.butter(self.accel_lowpass_order, 2 * np.pi * self.accel_lowpass_hz, analog=True)
            ma = ma * signal.freqs(b, a, 2 * np.pi * f)[1]
        if self.accel_highpass_hz:
            b, a = signal.butter(1, 2 * np.pi * self.accel_highpass_hz, btype="highpass", analog=True)
            ma = ma * signal.freqs(b, a, 2 * np.pi * f)[1]
        return ma, np.exp(-s * self.theta_delay_s)

    def closed_loop_poles(self, pade_order: int = 8) -> np.ndarray:
        """Poles [1/s] of the position loop ``theta/r = G/(1 + Kp G)`` with the linear plant (the valve
        nonlinearity left out), the command delay as a Pade approximant of ``pade_order`` (exact to far above
        the loop's crossover for the delays here: a phase error below 1e-6 rad at 8 ms and 40 Hz)."""
        import control  # (lazy: imports control, only when called)

        g = ModelStructure.notebook_3mode().to_tf(self._p(), "act") * DEG
        g = control.tf(*self._leaky(g.num[0][0], g.den[0][0]))
        num, den = self._loop_polys()
        g = g * control.tf(num, den)
        if self.command_delay_s > 0:
            g = g * control.tf(*control.pade(self.command_delay_s, pade_order))
        return np.asarray(control.poles(control.feedback(self.position_gain_v_per_rad * g, 1)))

    def check_stable(self) -> None:
        """Raise ``ValueError`` if the position loop is unstable: no rig can be measured so, and the
        frequency-domain response of an unstable loop is not its time response (it wraps around in time)."""
        worst = self.closed_loop_poles()
        worst = worst[np.argmax(worst.real)]
        if worst.real >= 0:
            raise ValueError(
                f"EffectRig: the position loop (Kp = {self.position_gain_v_per_rad:.4g} V/rad) is unstable with these "
                f"parameters: a closed-loop pole at {worst.real:.3g} {worst.imag:+.3g}j 1/s"
            )

    @classmethod
    def drawn(cls, rng: np.random.Generator, *, spread: float = 0.15, max_draws: int = 100, **effects) -> EffectRig:
        """A rig with each of eq 9.4's parameters drawn uniformly within ``spread`` of its value, and ``effects``;
        drawn again while the position loop is unstable (:meth:`check_stable`). About 7 % of draws at 15 % are with
        no effect (eq 9.4's loop has a gain margin of only 3.04 at the actuator's 8.9 Hz resonance), 11 % with a
        4 ms command delay, 15 % with 8 ms. Raises ``ValueError`` after ``max_draws`` unstable ones."""

        last = None
        for _ in range(max_draws):
            rig = cls(params={k: v * (1.0 + spread * rng.uniform(-1.0, 1.0)) for k, v in EQ9_4.items()}, **effects)
            try:
                rig.check_stable()
                return rig
            except ValueError as exc:
                last = exc
        raise ValueError(f"no stable rig in {max_draws} draws with {effects}: {last}")

    def simulate(self, r: np.ndarray, *, sample_rate_hz: float, rng: np.random.Generator | None = None, metadata: dict | None = None) -> TimeSeries:
        """Closed-loop response to the rest-to-rest excitation ``r`` [V], with sensor noise when ``rng`` is given.
        Refuses a rig whose position loop is unstable (:meth:`check_stable`)."""
        self.check_stable()
        r = np.asarray(r, float)
        n = r.size
        nfft = scipy.fft.next_fast_len(2 * n, real=True)
        f = np.fft.rfftfreq(nfft, 1.0 / sample_rate_hz)
        resp = self.responses(f)
        G, B = resp["G"], resp["B"]
        if self.valve_nonlinearity is None:
            R = scipy.fft.rfft(r, nfft)
            V = R / (1.0 + self.position_gain_v_per_rad * G)
            TH = G * V
        else:
            v, theta = self._loop_in_time(r, sample_rate_hz)
            V, TH = scipy.fft.rfft(v, nfft), scipy.fft.rfft(theta, nfft)
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

    def _loop_in_time(self, r: np.ndarray, sample_rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """v and theta at the sample times, the loop stepped with the valve nonlinearity (module docstring)."""

        law = valve_law(*self.valve_nonlinearity)
        tf = actuator_tf(self._p())
        lnum, lden = self._loop_polys()
        anum, aden = self._leaky(tf.num[0][0], tf.den[0][0])
        num = DEG * np.polymul(anum, lnum)
        den = np.polymul(aden, lden)
        dt = 1.0 / (OVERSAMPLE * sample_rate_hz)
        # partial fractions, each first-order mode held exactly over a step (the integrator's pole stays at 0, or at
        # leak_per_s: a companion-form realisation and eig moved it to -0.004 rad/s, a 0.4 deg phase lead at 0.1 Hz)
        res, poles, direct = signal.residue(num, den)
        if np.asarray(direct).size and np.any(np.abs(direct) > 0):
            raise ValueError("EffectRig: theta/v must be strictly proper")
        gaps = np.abs(poles[:, None] - poles[None, :]) + np.eye(poles.size) * 1e300
        if np.min(gaps) < 1e-6 * max(1.0, float(np.max(np.abs(poles)))):
            raise ValueError("EffectRig: the loop's poles are (nearly) repeated; move the valve or act-mode frequency off the actuator's poles")
        lam = [complex(np.exp(p * dt)) for p in poles]
        bm = [complex(dt if p == 0 else (np.exp(p * dt) - 1.0) / p) for p in poles]
        cm = [complex(c) for c in res]
        n = r.size
        # r between its samples: a cubic spline (through the samples; error ~(w dt)^4/384, 1e-5 at 40 Hz). A polyphase
        # filter's passband ripple (resample_poly's, ~1e-3) scales r between samples, and at low frequency, where
        # v = S r is small, that was a 0.4 deg phase error in theta/v at 0.1 Hz

        ri = CubicSpline(np.arange(n), r)(np.arange(n * OVERSAMPLE) / OVERSAMPLE).tolist()
        kp = self.position_gain_v_per_rad
        lag = int(round(self.command_delay_s / dt))
        held = [0.0] * lag  # the valve's input, ``lag`` steps late
        x = [0j] * len(lam)
        idx = range(len(lam))
        v_out, th_out = np.empty(n), np.empty(n)
        for k, rk in enumerate(ri):
            th = sum((cm[i] * x[i]).real for i in idx)
            v = rk - kp * th
            if k % OVERSAMPLE == 0:
                j = k // OVERSAMPLE
                v_out[j], th_out[j] = v, th
            held.append(v)
            u = law(held.pop(0))
            x = [lam[i] * x[i] + bm[i] * u for i in idx]
        return v_out, th_out
