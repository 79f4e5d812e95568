"""Figures of a closed-loop response: step metrics of theta, decay of the base vibration, modes.

All from the time series alone (what a rig gives), SI units:

- theta: rise time (10 % to 90 % of the reference step), overshoot (beyond the
  final value, in % of the step), settle time (last exit from a band of 2 % of
  the step about the final value), each after the step, and the final value in
  % of the step; overshoot and settle only when theta followed the step (its final
  value at least ``FOLLOW_FRACTION`` of it).
- base acceleration: the envelope is the magnitude of the analytic signal
  (:func:`scipy.signal.hilbert`) of ``accel`` minus its value at rest,
  smoothed over 0.2 s. ``settle_s``: time after the event until the envelope
  stays below 5 % of its peak; ``decay_rate_1_s``: minus the slope of a
  least-squares line through the log envelope, from its peak after the event to
  where it first falls below 5 % of that peak (or the end).
- runaway: theta further than ``RUNAWAY_BAND_RAD`` from its reference, or
  the valve command on its rail with one sign, for the whole of the run's last
  ``RUNAWAY_WINDOW_S`` (at most half of the run after its event; :func:`runaway`):
  a loop that has left its operating point for good, whatever the base does.
- modes: a sum of damped exponentials fitted to the base acceleration after
  the event by the matrix pencil method (Hua & Sarkar, IEEE Trans. ASSP 38(5),
  1990), on the signal decimated to 200 Hz; the model order from the singular
  values (above 1e-3 of the largest, at most 16), pairs kept when their amplitude is at least
  2 % of the largest; pairs closer than 3 % in frequency are one mode (the larger kept).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.signal

from samii.threads import one_blas_thread

__all__ = [
    "StepMetrics",
    "BaseMetrics",
    "FittedMode",
    "Instability",
    "step_metrics",
    "base_metrics",
    "envelope",
    "matrix_pencil",
    "response_modes",
    "growth",
    "sustained_oscillation",
    "Runaway",
    "runaway",
    "RUNAWAY_BAND_RAD",
    "RUNAWAY_WINDOW_S",
]

SETTLE_BAND = 0.02  #: theta settle band, fraction of the step
BASE_SETTLE_FRACTION = 0.05  #: base settle threshold, fraction of the envelope's peak
ENVELOPE_SMOOTH_S = 0.2
MODES_RATE_HZ = 200.0
#: theta further than this from its reference through the run's last window has left its operating point:
#: 0.5 rad (29 deg) is ten times the scenarios' 5 deg step, and a loop that holds theta at all (any net
#: negative position feedback on the valve's integrating actuator) brings it back within a few percent of
#: the step. The linearisation every design and prediction stands on is about the nominal pose.
RUNAWAY_BAND_RAD = 0.5
#: The last stretch of a run judged for a runaway (at most half of the run after its event: the time before it
#: is the loop's chance to take the step; a 5 deg step slews in well under 0.1 s even with the valve on its rail).
RUNAWAY_WINDOW_S = 1.0
#: Shorter than this after halving, a run is not judged (a slew may still be under way).
MIN_RUNAWAY_WINDOW_S = 0.25


#: theta's final value must reach this fraction of the step for the response to be said to follow it (the rise
#: time starts there): below it, overshoot and settle about that final value would describe a joint that never moved.
FOLLOW_FRACTION = 0.1


@dataclass(frozen=True)
class StepMetrics:
    rise_s: float | None
    overshoot_pct: float | None
    settle_s: float | None
    #: theta's final value (mean of the last 5 % of the run) in % of the step: 100 with no steady-state error
    final_pct: float | None = None

    @property
    def followed(self) -> bool:
        """theta followed the step: its final value is at least FOLLOW_FRACTION of it, in its direction."""
        return self.final_pct is not None and self.final_pct >= 100.0 * FOLLOW_FRACTION


@dataclass(frozen=True)
class BaseMetrics:
    peak_m_s2: float
    residual_rms_m_s2: float | None
    settle_s: float | None
    decay_rate_1_s: float | None


@dataclass(frozen=True)
class FittedMode:
    freq_hz: float
    zeta: float
    amplitude_m_s2: float

    @property
    def rate_1_s(self) -> float:
        """Real part of the pole, sign flipped: positive for a decaying mode."""
        return self.zeta * 2 * np.pi * self.freq_hz


def step_metrics(t: np.ndarray, theta: np.ndarray, theta_ref: np.ndarray, t_step: float) -> StepMetrics:
    """Rise, overshoot and settle of ``theta`` after a reference step at ``t_step`` (None where undefined)."""
    k0 = int(np.searchsorted(t, t_step))
    if k0 >= t.size - 2:
        return StepMetrics(None, None, None)
    before = float(theta_ref[max(k0 - 1, 0)])
    step = float(theta_ref[-1]) - before
    if step == 0:
        return StepMetrics(None, None, None)
    x = (theta[k0:] - theta[max(k0 - 1, 0)]) / step  # 0 -> 1
    tt = t[k0:] - t[k0]
    n_tail = max(1, int(0.05 * x.size))
    final = float(np.mean(x[-n_tail:]))
    rise = None
    i10 = np.flatnonzero(x >= 0.1)
    i90 = np.flatnonzero(x >= 0.9)
    if i10.size and i90.size:
        rise = float(tt[i90[0]] - tt[i10[0]])
    if final < FOLLOW_FRACTION:  # it did not follow the step: overshoot and settle about where it ended mean nothing
        return StepMetrics(None, None, None, 100.0 * final)
    overshoot = float(max(0.0, (np.max(x) - final) * 100.0))
    out = np.flatnonzero(np.abs(x - final) > SETTLE_BAND)
    settle = 0.0 if out.size == 0 else (float(tt[out[-1] + 1]) if out[-1] + 1 < tt.size else None)
    return StepMetrics(rise, overshoot, settle, 100.0 * final)


def envelope(x: np.ndarray, dt: float, smooth_s: float = ENVELOPE_SMOOTH_S) -> np.ndarray:
    """Magnitude of the analytic signal of ``x``, smoothed by a moving average over ``smooth_s``."""
    if x.size < 4:
        return np.abs(x)
    # the analytic signal of a finite record rings at its ends (the FFT wraps it round): mirror
    # 2 s (or the whole record) onto each end first and crop after
    pad = min(x.size - 1, int(round(2.0 / dt)))
    env = np.abs(scipy.signal.hilbert(np.pad(x, pad, mode="reflect")))[pad : pad + x.size]
    w = max(1, int(round(smooth_s / dt)))
    if w > 1 and env.size > w:
        kernel = np.ones(w) / w
        env = np.convolve(np.pad(env, (w // 2, w - 1 - w // 2), mode="edge"), kernel, mode="valid")
    return env


def base_metrics(
    t: np.ndarray,
    accel: np.ndarray,
    t_disturbance: float,
    *,
    t_decay_s: float | None = None,
    residual_from_s: float | None = None,
    env: np.ndarray | None = None,
) -> BaseMetrics:
    """Peak, residual rms, settle time and decay rate of the base acceleration.

    ``accel`` is relative to the reading at rest (the static equilibrium). Peak
    and settle time count from ``t_disturbance`` (the step, the impulse); the
    decay rate is fitted from the envelope's peak after ``t_decay_s`` (default
    ``t_disturbance``; the switch-on in a Loper test); the residual rms is over
    ``t >= residual_from_s`` (None: not computed). ``env``: :func:`envelope` of ``accel`` from ``t_disturbance`` on,
    when the caller has it (:func:`sustained_oscillation` reads the same).
    """
    a = np.asarray(accel, float)
    dt = float(t[1] - t[0])
    k0 = int(np.searchsorted(t, t_disturbance))
    seg = a[k0:]
    if seg.size < 8:
        return BaseMetrics(float(np.max(np.abs(a))) if a.size else 0.0, None, None, None)
    peak = float(np.max(np.abs(seg)))
    residual = None
    if residual_from_s is not None:
        kr = int(np.searchsorted(t, residual_from_s))
        if kr < t.size:
            residual = float(np.sqrt(np.mean(a[kr:] ** 2)))
    env = envelope(seg, dt) if env is None else env
    limit = BASE_SETTLE_FRACTION * float(np.max(env))
    above = np.flatnonzero(env > limit)
    settle = None if above.size == 0 or above[-1] + 1 >= env.size else float((above[-1] + 1) * dt)
    kd = max(0, int(np.searchsorted(t, t_disturbance if t_decay_s is None else t_decay_s)) - k0)
    rate = None
    if kd < env.size - 8:
        kp = kd + int(np.argmax(env[kd:]))
        below = np.flatnonzero(env[kp:] < BASE_SETTLE_FRACTION * env[kp])
        k_end = kp + (below[0] if below.size else env.size - kp)
        if k_end - kp >= max(8, int(0.2 / dt)) and env[kp] > 0:
            tt = np.arange(kp, k_end) * dt
            rate = float(-np.polyfit(tt, np.log(np.maximum(env[kp:k_end], 1e-300)), 1)[0])
    return BaseMetrics(peak, residual, settle, rate)


def matrix_pencil(y: np.ndarray, dt: float, *, max_order: int = 16, rel_sv: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Poles ``s`` [1/s] and complex amplitudes of ``y[k] ~ sum a_i exp(s_i k dt)`` (matrix pencil method).

    Computed with BLAS on one thread (samii.threads). With two, the SVD's sums split over them: the modes differed in
    their last digits from those of a machine with one core (5 of the main job's 7 closed-loop runs), and in the main
    job, beside the diagnosis's worker process on the other core, the two threads spun against each other (a call
    took 0.3-0.4 s there, 0.1 s on one thread; with nothing beside them two threads took 0.07-0.10 s)."""
    with one_blas_thread():
        return _pencil(np.asarray(y, float), dt, max_order, rel_sv)


def _pencil(y: np.ndarray, dt: float, max_order: int, rel_sv: float) -> tuple[np.ndarray, np.ndarray]:
    N = y.size
    L = N // 3
    if L < 2:
        return np.zeros(0, complex), np.zeros(0, complex)
    Y = np.lib.stride_tricks.sliding_window_view(y, L + 1)  # (N - L) x (L + 1) Hankel
    _, sv, Vh = np.linalg.svd(Y, full_matrices=False)
    M = int(min(max_order, np.sum(sv > rel_sv * sv[0])))
    if M == 0:
        return np.zeros(0, complex), np.zeros(0, complex)
    V = Vh.conj().T[:, :M]
    z = np.linalg.eigvals(np.linalg.pinv(V[:-1]) @ V[1:])
    # drop roots at 0 and any that would overflow over the record (|z|^N beyond 1e150)
    z = z[(np.abs(z) > 1e-12) & (N * np.log(np.maximum(np.abs(z), 1e-300)) < 345.0)]
    if z.size == 0:
        return np.zeros(0, complex), np.zeros(0, complex)
    Z = z[None, :] ** np.arange(N)[:, None]
    amp = np.linalg.lstsq(Z, y.astype(complex), rcond=None)[0]
    return np.log(z) / dt, amp


def response_modes(
    t: np.ndarray, accel: np.ndarray, t_start: float, *, duration_s: float = 6.0, max_freq_hz: float = 45.0, min_rel_amplitude: float = 0.02
) -> list[FittedMode]:
    """Modes (frequency, damping, amplitude) of the base acceleration (relative to rest) from ``t_start`` on, by :func:`matrix_pencil`."""
    dt = float(t[1] - t[0])
    q = max(1, int(round(1.0 / (dt * MODES_RATE_HZ))))
    k0 = int(np.searchsorted(t, t_start))
    k1 = min(t.size, k0 + int(round(duration_s / dt)))
    seg = np.asarray(accel[k0:k1], float)
    if seg.size < 30 * q:
        return []
    y = scipy.signal.decimate(seg, q, ftype="fir", zero_phase=True) if q > 1 else seg
    s, amp = matrix_pencil(y, dt * q)
    keep = (s.imag > 0) & (s.imag / (2 * np.pi) <= max_freq_hz) & (np.abs(s) / (2 * np.pi) >= 0.3)
    s, amp = s[keep], np.abs(amp[keep]) * 2
    if s.size == 0:
        return []
    keep = amp >= min_rel_amplitude * np.max(amp)
    modes = [FittedMode(float(abs(p) / (2 * np.pi)), float(-p.real / abs(p)), float(a)) for p, a in zip(s[keep], amp[keep])]
    merged: list[FittedMode] = []
    for m in sorted(modes, key=lambda m: -m.amplitude_m_s2):
        if all(abs(m.freq_hz - o.freq_hz) > 0.03 * o.freq_hz for o in merged):
            merged.append(m)
    return sorted(merged, key=lambda m: m.freq_hz)


def growth(t: np.ndarray, accel: np.ndarray, t_start: float) -> tuple[float, float] | None:
    """``(growth_rate_1_s, freq_hz)`` of the fastest-growing significant mode after ``t_start``, None if none grows.

    Short records (a run that diverged within a fraction of a second) are
    fitted at the physics rate rather than decimated.
    """
    dt = float(t[1] - t[0])
    k0 = int(np.searchsorted(t, t_start))
    seg = np.asarray(accel[k0:], float)
    if seg.size < 30:
        return None
    if seg.size * dt >= 1.0:
        modes = response_modes(t, accel, t_start, duration_s=seg.size * dt, max_freq_hz=np.inf)
        grow = [m for m in modes if m.zeta < 0]
        if not grow:
            return None
        m = max(grow, key=lambda m: -m.rate_1_s)
        return -m.rate_1_s, m.freq_hz
    s, amp = matrix_pencil(seg[-min(seg.size, 3000) :], dt)
    if s.size == 0:
        return None
    amp = np.abs(amp)
    sig = amp >= 0.02 * np.max(amp)
    s = s[sig & (s.real > 0)]
    if s.size == 0:
        return None
    p = s[np.argmax(s.real)]
    return float(p.real), float(abs(p.imag) / (2 * np.pi))


@dataclass(frozen=True)
class Instability:
    """A base oscillation that does not decay: its growth while it grew, its frequency, what holds it."""

    growth_rate_1_s: float | None  #: slope of the log envelope while it grew (None: it never grew, it only persisted)
    freq_hz: float
    kind: str  #: "growing" (still growing at the end) or "limit cycle" (grew, then held at a level by a nonlinearity)


@dataclass(frozen=True)
class Runaway:
    """A loop that has left its operating point for good (:func:`runaway`)."""

    theta_since_s: float | None  #: theta outside the band from here to the end (None: inside by the end)
    valve_since_s: float | None  #: the valve command on one rail from here to the end (None: off it by the end)
    theta_error_rad: float  #: theta minus its reference at the end
    band_rad: float
    valve_v: float  #: the valve command at the end
    #: theta still moved through the last window by more than a tenth of the band (running away), else it settled
    #: outside the band (a loop that holds theta, but far from where it is told: no operating point either)
    theta_moving: bool = True

    def text(self) -> str:
        parts = []
        if self.theta_since_s is not None:
            how = "ran away from" if self.theta_moving else "settled far from"
            parts.append(
                f"theta {how} its reference (outside the +-{np.degrees(self.band_rad):.3g} deg band from "
                f"t = {self.theta_since_s:.4g} s on, {np.degrees(self.theta_error_rad):.4g} deg off at the end)"
            )
        if self.valve_since_s is not None:
            parts.append(f"the valve command sat on its {self.valve_v:+.3g} V rail from t = {self.valve_since_s:.4g} s to the end")
        return "; ".join(parts)


def runaway(
    t: np.ndarray,
    theta_error_rad: np.ndarray,
    valve_v: np.ndarray,
    *,
    t_event: float,
    rail_v: float,
    band_rad: float = RUNAWAY_BAND_RAD,
    window_s: float = RUNAWAY_WINDOW_S,
) -> Runaway | None:
    """The loop's runaway, if theta stays outside ``band_rad`` of its reference or the valve command on one
    rail (within 0.1 % of ``rail_v``) through the last ``window_s`` of the run (at most half of the run after
    ``t_event``); None otherwise, and None when that half is shorter than ``MIN_RUNAWAY_WINDOW_S``.

    A bounded base oscillation says nothing about the joint: a positive net position feedback drives the valve
    to its rail and the joint turns at the actuator's full speed while the base barely moves
    (``sustained_oscillation`` reads the base alone).
    """
    t = np.asarray(t, float)
    if t.size < 2:
        return None
    dt = float(t[1] - t[0])
    after = t[-1] + dt - t_event  # how long the run went on after its event
    window_s = min(window_s, 0.5 * after)  # the shortest runs the commands allow (3 s, the step at 1 s) are judged too
    if window_s < MIN_RUNAWAY_WINDOW_S:
        return None
    err = np.asarray(theta_error_rad, float)
    v = np.asarray(valve_v, float)
    k0 = int(np.searchsorted(t, t[-1] + dt - window_s))
    out = ~(np.abs(err) <= band_rad)  # NaN counts as out
    on_rail = (np.abs(v) >= rail_v * (1 - 1e-3)) & (np.sign(v) == np.sign(v[-1]))

    def since(flag: np.ndarray) -> float | None:
        if not np.all(flag[k0:]):
            return None
        inside = np.flatnonzero(~flag)
        return float(t[inside[-1] + 1] if inside.size else t[0])

    th, va = since(out), since(on_rail)
    if th is None and va is None:
        return None
    moving = bool(np.ptp(err[k0:]) > 0.1 * band_rad) if np.all(np.isfinite(err[k0:])) else True
    return Runaway(th, va, float(err[-1]), float(band_rad), float(v[-1]), moving)


def _dominant_freq_hz(x: np.ndarray, dt: float) -> float:
    """Frequency of the largest peak of the spectrum of ``x`` (Hann window, zero-padded 16 x, parabolic peak)."""
    x = (x - np.mean(x)) * np.hanning(x.size)
    nfft = 1 << int(np.ceil(np.log2(16 * x.size)))
    spec = np.abs(np.fft.rfft(x, nfft))
    k = int(np.argmax(spec[1:])) + 1
    if 0 < k < spec.size - 1:
        a, b, c = np.log(spec[k - 1 : k + 2] + 1e-300)
        k = k + 0.5 * (a - c) / (a - 2 * b + c) if (a - 2 * b + c) != 0 else k
    return float(k / (nfft * dt))


def sustained_oscillation(
    t: np.ndarray,
    accel: np.ndarray,
    t_event: float,
    *,
    min_decay_1_s: float = 0.05,
    tail_fraction: float = 0.4,
    min_tail_level: float = 0.3,
    env: np.ndarray | None = None,
) -> Instability | None:
    """The base oscillation after ``t_event`` if it does not decay, else None.

    It does not decay when, over the last ``tail_fraction`` of the record, its
    log envelope falls slower than ``min_decay_1_s`` and stays above
    ``min_tail_level`` of its largest value (a 10 s record cannot tell a slower
    decay from none). Its growth rate is the slope of the log envelope of the
    signal band-passed around the tail's frequency (0.7-1.4 times), from the
    envelope's lowest point after the event to where it first reaches 30 % of
    its largest value (still small signal), or 80 % when that is too short to
    fit (a fast growth); None when it did not grow (a disturbance that only
    persisted). The frequency is the spectrum's peak over the growth (a limit
    cycle's frequency can differ), else over the tail. ``env``: :func:`envelope` of ``accel`` from ``t_event`` on,
    when the caller has it.
    """
    dt = float(t[1] - t[0])
    k0 = int(np.searchsorted(t, t_event))
    seg = np.asarray(accel[k0:], float)
    if seg.size < int(2.0 / dt):
        return None
    env = envelope(seg, dt) if env is None else env
    k_tail = int((1 - tail_fraction) * env.size)
    tail = env[k_tail:]
    tt = np.arange(k_tail, env.size) * dt
    slope = float(np.polyfit(tt, np.log(np.maximum(tail, 1e-300)), 1)[0])
    if slope < -min_decay_1_s or np.mean(tail) < min_tail_level * np.max(env):
        return None
    # the oscillation's frequency from the tail, then its growth on the band around it (the other modes'
    # transients removed): from the envelope's lowest point to where it first reaches 30 % of its largest
    freq = _dominant_freq_hz(seg[k_tail:], dt)
    rate = None
    nyq = 0.5 / dt
    if 0.7 * freq > 0.05 and 1.4 * freq < 0.95 * nyq:
        sos = scipy.signal.butter(4, [0.7 * freq / nyq, 1.4 * freq / nyq], btype="bandpass", output="sos")
        benv = envelope(scipy.signal.sosfiltfilt(sos, seg), dt, smooth_s=1.0 / freq)
        for level in (0.3, 0.8):  # small-signal growth if it lasts long enough to fit, else up to the limit cycle
            top = np.flatnonzero(benv >= level * np.max(benv))
            k_b = int(top[0])
            k_a = int(np.argmin(benv[:k_b])) if k_b > 0 else 0
            if k_b - k_a >= max(8, int(0.1 / dt)) and benv[k_a] > 0:
                ta = np.arange(k_a, k_b) * dt
                rate = float(np.polyfit(ta, np.log(benv[k_a:k_b]), 1)[0])
                if rate > min_decay_1_s:
                    # the frequency while it grew (at least a second of signal up to the window's end)
                    freq = _dominant_freq_hz(seg[max(0, k_b - max(k_b - k_a, int(1.0 / dt))) : k_b], dt)
                    break
                rate = None
    kind = "growing" if slope > min_decay_1_s else "limit cycle"
    return Instability(rate, freq, kind)
