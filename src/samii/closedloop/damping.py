"""A controller that damps the base: tuned acceleration feedback, designed on a fit of measured Bode data.

The step the notebook's author planned after chapter 11 ("a new controller ...
considering the third mode"), made robust rather than exact. The method:

1. **Model** (from data, never from the simulator's linearisation): the
   notebook's 3-mode structure (eq 9.1/9.2) fitted to a swept-sine FRF over
   0.5-30 Hz (:func:`samii.identify.fit.fit`). With the servo amplifier's known
   gain Kp closed around the fitted theta/v, the plant seen by a command added
   to the valve is ``P = (xdd/theta) G / (1 + Kp G)``, ``G`` = theta/v.
2. **Controller**: acceleration feedback through a second-order low-pass tuned
   to base mode 1 (Goh & Caughey, "On the stability problem caused by finite
   actuator dynamics in the collocated control of large space structures",
   Int. J. Control 41(3), 1985; "acceleration feedback", AF), with one more
   first-order roll-off at the fitted mode 3::

       v_added = -k F(s) xdd,   F(s) = w_f^2 / (s^2 + 2 zeta_f w_f s + w_f^2) * w_3 / (s + w_3),
       w_f = w_1, zeta_f = 1/sqrt(2)

   At w_1 the filter lags about 90 deg, so the command is in phase with the
   base *velocity*: damping of mode 1. Above it the filter rolls off at 40 dB
   per decade, and at 60 dB beyond the last fitted mode, where the notebook's
   structure no longer describes the data (the actuator's 32 Hz pair: without
   that roll-off the measured loop's sensitivity reaches 1.13 near 31 Hz, so the
   loop takes damping from that pair; with it 1.05). It adds to the servo
   amplifier's position loop (the reference is untouched).
3. **Gain**: the loop is discretised as the card runs it (``F`` and the plant
   by ZOH at the sample time, the computation delay as ``z^-d``); the sign is
   the one that moves mode 1 left; ``k`` is the stability limit on the fitted
   model divided by the gain margin (default 6 dB), lowered further while any
   closed-loop mode of the fitted model is more than 2 % less damped than in
   open loop (2 %: below what a damping fitted to a response resolves).
4. **Check on the data**: with an FRF, the sensitivity ``|1/(1 + L)|`` of the
   loop built from the *measured* theta/v and xdd/v (not the fit) is reported
   above the fit band, where the model is not trusted (``max_sensitivity_above_band``).
5. **The sensors** (issue 35, item 4), when the rig's are known (:class:`SensorChain`: the
   model's ``sensor.*`` options, a diagnosis's, and the controller card's anti-alias filter):
   the data were measured through them, so their response is divided out of theta/v and xdd/v
   before the fit (the fit is of the plant, as the structure assumes), and the controller reads
   the base through them, so their continuous laws (delays as 3rd-order Padé) are in the loop whose
   stability limit sets the gain. A design blind to a 10 Hz roll-off takes the roll-off's lag for
   the plant's and its gain for one with a margin it does not have on the rig.

:func:`compare_methods` (used by ``experiments/closed_loop``) sets this against
three-mode pole placement with an observer on the same fit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from samii import notebook as nb
from samii.closedloop.controllers import SavedController
from samii.controller import LinearController
from samii.errors import InputError, input_error_of
from samii.identify.fit import check_not_noise, fit
from samii.progress import SILENT, Progress, part

if TYPE_CHECKING:
    from samii.sim.sensor_dynamics import SensorDynamics

__all__ = [
    "DampingDesign",
    "design_damping",
    "servo_gain_margin",
    "servo_loop_growing",
    "servo_loop_contradiction",
    "damping_plant",
    "measured_fit",
    "measured_sensitivity",
    "with_data_check",
    "damping_from_frf",
    "damping_from_simulation",
    "FIT_BAND_HZ",
    "SensorChain",
    "without_sensors",
    "sensors_from_diagnosis",
]

#: Fit band [Hz]: the base modes (1.7, 9.9, 25 Hz) and the servo pair (8 Hz); above 30 Hz the
#: notebook's structure misses the actuator's 32 Hz pair (model card), below 0.5 Hz the
#: acceleration is too weak to measure.
FIT_BAND_HZ = (0.5, 30.0)
GAIN_MARGIN_DB = 6.0
FILTER_ZETA = 1.0 / math.sqrt(2.0)
#: A fitted mode may lose this fraction of its open-loop damping (below a response fit's resolution).
DAMPING_TOLERANCE = 0.02


@dataclass(frozen=True)
class DampingDesign:
    params: Mapping[str, float]  #: the fitted notebook parameters (SI: theta in rad, xdd in m/s²)
    position_gain_v_per_rad: float
    sample_time_s: float
    delay_samples: int  #: computation delay the design allows for
    filter_hz: float
    filter_zeta: float
    rolloff_hz: float | None  #: the first-order roll-off (the fitted mode 3), None without a mode 3
    gain_v_per_m_s2: float  #: k (sign included): v_added = -k F(s) xdd
    gain_limit_v_per_m_s2: float  #: the stability limit on the fitted model
    gain_margin_db: float  #: achieved
    open_loop_poles_s: np.ndarray  #: the fitted plant's poles (servo loop closed)
    closed_loop_poles_s: np.ndarray  #: with the controller, on the fitted model
    controller: SavedController
    fit_summary: Mapping[str, object] = field(default_factory=dict)
    #: largest |1/(1 + L)| of the loop built from the measured FRF above the fit band (None: not checked)
    max_sensitivity_above_band: float | None = None
    sensitivity_band_hz: tuple[float, float] | None = None
    #: the sensor chain the design took into account (None: ideal sensors, no anti-alias filter)
    chain: SensorChain | None = None

    @property
    def sensor_chain(self) -> dict[str, float]:
        """The chain's options not ideal, by name (:meth:`SensorChain.describe`; empty: none)."""
        return self.chain.describe() if self.chain is not None else {}

    def to_dict(self) -> dict:
        """The design as ``samii design damping --json`` prints it (SI units; the controller itself is its own file)."""
        return {
            "method": "tuned acceleration feedback, added to the servo amplifier's command",
            "fit": {k: (float(v) if isinstance(v, (int, float)) else v) for k, v in self.fit_summary.items()},
            "fit_params": {k: float(v) for k, v in self.params.items()},
            "sample_time_s": self.sample_time_s,
            "delay_samples": self.delay_samples,
            "filter_hz": self.filter_hz,
            "filter_zeta": self.filter_zeta,
            "rolloff_hz": self.rolloff_hz,
            "gain_v_per_m_s2": self.gain_v_per_m_s2,
            "gain_limit_v_per_m_s2": self.gain_limit_v_per_m_s2,
            "gain_margin_db": self.gain_margin_db,
            "modes_on_fitted_model": self.mode_table(),
            "max_sensitivity_above_fit_band": self.max_sensitivity_above_band,
            "sensitivity_band_hz": None if self.sensitivity_band_hz is None else list(self.sensitivity_band_hz),
            "sensor_chain": self.sensor_chain,
        }

    def mode_table(self) -> list[dict[str, float]]:
        """Open- and closed-loop frequency and damping of each complex pole pair of the fitted model."""
        out = []
        ol = self.open_loop_poles_s[self.open_loop_poles_s.imag > 1e-6]
        cl = self.closed_loop_poles_s[self.closed_loop_poles_s.imag > 1e-6]
        for p in sorted(ol, key=abs):
            q = cl[np.argmin(np.abs(cl - p))]
            out.append({"freq_hz": abs(p) / (2 * np.pi), "zeta_open": -p.real / abs(p),
                        "freq_hz_closed": abs(q) / (2 * np.pi), "zeta_closed": -q.real / abs(q)})  # fmt: skip
        return out


def damping_plant(params: Mapping[str, float], position_gain_v_per_rad: float):
    """``xdd / v_added`` with the servo loop closed: ``(xdd/theta) G / (1 + Kp G)`` (python-control, continuous)."""
    import control  # (lazy: imports control, only when called)

    G = nb.actuator_tf(params)
    H = nb.base_tf(params, numerator="s4", w2_factors=False)
    return control.minreal(H * G / (1 + position_gain_v_per_rad * G), verbose=False)


#: A servo gain margin under this on the fit is refused by ``samii design damping --frf``: the data's theta/v and the
#: stated gain make a loop at least twice as hot as an unstable one (theta in mrad: 0.0135; in degrees 0.029), beyond
#: what a fit's error could (drawn rigs spread 30 % around eq 9.4, all measurable, keep 1.003 and more).
SERVO_MARGIN_REFUSED = 0.5


def servo_gain_margin(params: Mapping[str, float], position_gain_v_per_rad: float) -> tuple[float, float | None]:
    """Gain margin of the servo amplifier's position loop ``Kp G`` on the fitted theta/v ``G``, and the frequency [Hz]
    where its phase crosses -180 deg (``(inf, None)`` where it never does).

    The data were measured with that loop closed and the rig ran, so a hydraulic position servo crossing over below
    its actuator's resonance has a margin above 1 there (the notebook's eq 9.4: 3.04 at 8.9 Hz; the embedded model's
    measured fit 1.67 at 8.2 Hz). A margin under 1 says that the data's theta/v and the stated gain do not belong
    together: theta in mrad (1000x) or degrees (57x), or another amplifier gain. A relative-degree-2 fit can be
    stable conditionally at such gains, a rig with its valve lag and sampling is not: on theta in mrad the damping
    design came out 74x too hot, called 6 dB from its limit, and the loop ran away."""
    import control  # (lazy: imports control, only when called)

    gm, _, w_gm, _ = control.margin(position_gain_v_per_rad * nb.actuator_tf(params))
    if not np.isfinite(gm) or not np.isfinite(w_gm) or w_gm <= 0:
        return math.inf, None
    return float(gm), float(w_gm) / (2 * np.pi)


def servo_loop_growing(params: Mapping[str, float], position_gain_v_per_rad: float) -> complex | None:
    """The fastest-growing pole [1/s] of the servo loop ``Kp G / (1 + Kp G)`` on the fitted theta/v ``G``, or None
    when it has none in the right half-plane. The gain margin alone does not say it: on the default measurement's
    FRF with theta x10 the loop crosses -180 deg twice and ``control.margin`` gave 1.35 at 9.6 Hz where the loop has a
    pole growing at 9.5 Hz (a damping design then came out 121 dB below a limit of 0.0001, k = 9e-11, doing nothing,
    and said so as a design); with theta x2 the margin was 0.83, above the refusal's 0.5."""
    import control  # (lazy: imports control, only when called)

    G = nb.actuator_tf(params)
    poles = np.asarray(control.poles(control.feedback(position_gain_v_per_rad * G, 1)), complex)
    growing = poles[poles.real > 1e-9 * np.maximum(np.abs(poles), 1.0)]
    return complex(growing[np.argmax(growing.real)]) if growing.size else None


def servo_loop_contradiction(params: Mapping[str, float], position_gain_v_per_rad: float) -> str | None:
    """What makes the servo loop on the fitted theta/v unstable, though the data were measured in it and the rig ran
    (a gain margin under SERVO_MARGIN_REFUSED, or a pole growing: :func:`servo_gain_margin`,
    :func:`servo_loop_growing`), as words after "theta/v (the model fitted to it) ", or None."""
    kp = position_gain_v_per_rad
    gm, f_gm = servo_gain_margin(params, kp)
    if gm < SERVO_MARGIN_REFUSED:
        return (
            f"times the position gain {kp:.4g} V/rad is {1.0 / gm:.3g} at {f_gm:.3g} Hz, where its phase crosses -180 deg "
            "(above 1 there a loop is unstable)"
        )
    if (growing := servo_loop_growing(params, kp)) is not None:
        return (
            f"in a loop closed by the position gain {kp:.4g} V/rad has a pole growing at {growing.real:.3g} 1/s "
            f"({abs(growing.imag) / (2 * np.pi):.3g} Hz)"
        )
    return None


@dataclass(frozen=True)
class SensorChain:
    """What lies between the rig and the controller's samples: the sensors' dynamics (``samii.sim.sensor_dynamics``:
    their ``sensor.*`` options) and the controller card's anti-alias filter (``samii.closedloop.card``), as continuous
    laws: first-order roll-off and AC coupling, second-order Butterworth, the card's 8th-order Butterworth, a gain,
    delays."""

    sensors: SensorDynamics  #: the sensors' options (samii.sim.sensor_dynamics)
    antialias_hz: float | None = None

    @property
    def ideal(self) -> bool:
        return bool(self.sensors.ideal) and self.antialias_hz is None

    def describe(self) -> dict:
        """The options not ideal, by name (``antialias_hz`` the card's filter)."""
        return {**self.sensors.changed(), **({"antialias_hz": self.antialias_hz} if self.antialias_hz is not None else {})}

    def text(self) -> str:
        """The options not ideal, in words with units."""
        card = f"the card's anti-alias filter at {self.antialias_hz:g} Hz" if self.antialias_hz is not None else ""
        return ", ".join(x for x in (self.sensors.text(), card) if x)

    def _accel_factors(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """accel's filters without its delay, as factors of first and second order: (numerator, denominator) polynomials
        in s (highest power first; an 8th-order Butterworth as one polynomial is too ill-conditioned to discretise)."""
        from scipy import signal  # (lazy: scipy.signal takes ~0.7 s to import)

        s = self.sensors
        out = [(np.array([float(s.accel_gain)]), np.array([1.0]))]
        if s.accel_lowpass_hz > 0:
            w = 2 * np.pi * s.accel_lowpass_hz
            out.append((np.array([w]), np.array([1.0, w])))
        if s.accel_antialias_hz > 0:
            out.append(signal.butter(2, 2 * np.pi * s.accel_antialias_hz, analog=True))
        if s.accel_highpass_hz > 0:
            out.append((np.array([1.0, 0.0]), np.array([1.0, 2 * np.pi * s.accel_highpass_hz])))
        return out + self._card_factors()

    def _card_factors(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The card's anti-alias filter (an even-order Butterworth) as second-order factors of unit DC gain."""
        if self.antialias_hz is None:
            return []
        from samii.measure.daq import ANTIALIAS_ORDER  # (lazy: imports scipy.signal, only when called)

        w = 2 * np.pi * self.antialias_hz
        angles = np.pi * (2 * np.arange(ANTIALIAS_ORDER // 2) + 1) / (2 * ANTIALIAS_ORDER)  # each pair's angle off the imaginary axis
        return [(np.array([w * w]), np.array([1.0, 2 * np.sin(a) * w, w * w])) for a in angles]

    def response(self, freq_hz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(theta's, accel's) complex response at ``freq_hz``: exact delays. theta's is the angle sensor's delay and the
        card's filter (what the controller would read of theta); :meth:`measured_response` is what a measurement saw."""
        jw = 2j * np.pi * np.asarray(freq_hz, float)
        accel = np.exp(-jw * self.sensors.accel_delay_s) * _product(self._accel_factors(), jw)
        theta = np.exp(-jw * self.sensors.theta_delay_s) * _product(self._card_factors(), jw)
        return theta, accel

    def card_response(self, freq_hz: np.ndarray) -> np.ndarray:
        """The card's anti-alias filter alone at ``freq_hz`` (1 without one)."""
        return _product(self._card_factors(), 2j * np.pi * np.asarray(freq_hz, float))

    def measured_response(self, freq_hz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(theta's, accel's) response a measurement's data carry: the sensors' alone (a measurement has its own DAQ,
        whose anti-alias filter its FRF estimate divides out), exact delays."""
        return SensorChain(self.sensors).response(freq_hz)

    def accel_ss(self):
        """accel's chain as a continuous python-control state-space system, its factors in series (its delay a 3rd-order
        Padé)."""
        import control  # (lazy: imports control, only when called)

        factors = self._accel_factors()
        if self.sensors.accel_delay_s > 0:
            factors.append(control.pade(self.sensors.accel_delay_s, 3))
        out = control.ss(control.tf(*factors[0]))
        for b, a in factors[1:]:
            out = control.ss(control.tf(b, a)) * out
        return out


def _product(factors: list[tuple[np.ndarray, np.ndarray]], s: np.ndarray) -> np.ndarray:
    """The product of the rational factors ``(numerator, denominator)`` at ``s``."""
    out = np.ones_like(s)
    for b, a in factors:
        out = out * np.polyval(b, s) / np.polyval(a, s)
    return out


def _known(chain: SensorChain | None) -> SensorChain | None:
    """``chain`` when it has anything to say, else None (ideal sensors and no anti-alias filter: the design as it was
    before sensor chains)."""
    return None if chain is None or chain.ideal else chain


#: The sensor options a diagnosis names, by its effects' labels (samii.diagnose.simulator.CARRY's sensor entries).
SENSOR_EFFECTS = (
    "delay/theta_sensor",
    "delay/accel_sensor",
    "sensor/accel_lowpass",
    "sensor/accel_lowpass2",
    "sensor/accel_highpass",
    "sensor/accel_gain",
)


def sensors_from_diagnosis(path) -> dict[str, float]:
    """The sensor options (``sensor.*`` by name, SI) a diagnosis found: ``diagnosis.json`` of ``samii diagnose``. Against
    the simulator, the values it carried into it (recalibrated); else each sensor effect's own reading. An InputError
    names the file when it is not a diagnosis; an empty mapping when it found nothing of the sensors."""
    from samii.diagnose.simulator import CARRY  # (lazy: imports mujoco, only when called)
    from samii.schema import read_file  # (lazy: read only when a diagnosis is given)
    from samii.schema.diagnosis import DiagnosisRecord  # (lazy: read only when a diagnosis is given)

    record = read_file(path, "diagnosis file", DiagnosisRecord, missing=f"--sensors-from {path}: no such file")
    names = {CARRY[label][0] for label in SENSOR_EFFECTS}
    if record.simulator:  # what was carried into the simulator and recalibrated there (an effect not carried: not taken)
        return {k: float(v) for k, v in dict(record.simulator.get("changes") or {}).items() if k in names and v is not None}
    out: dict[str, float] = {}
    for e in record.found:
        label = f"{e.category}/{e.kind}"
        if label in SENSOR_EFFECTS and e.params.get(CARRY[label][1]) is not None:
            out[CARRY[label][0]] = float(e.params[CARRY[label][1]])
    return out


def without_sensors(frf, chain: SensorChain):
    """``frf`` (measured through the sensors of ``chain``) with their response divided out: the plant's theta/v and
    xdd/v (and xdd/theta), as the notebook's structure describes them; ``frf`` itself without a chain."""
    if _known(chain) is None:
        return frf
    g_theta, g_accel = chain.measured_response(frf.freq_hz)
    act = None if frf.act is None else frf.act / g_theta
    total = None if frf.total is None else frf.total / g_accel
    base = None if frf.base is None else frf.base * g_theta / g_accel
    return replace(frf, act=act, base=base, total=total)


def _discrete_loop(params, kp, T, delay, chain: SensorChain | None = None):
    """(plant ZOH with the delay, filter factory): python-control discrete state-space objects; the plant seen through
    ``chain``'s accelerometer when given."""
    import control  # (lazy: imports control, only when called)

    plant = control.ss(damping_plant(params, kp))
    if _known(chain) is not None:
        plant = chain.accel_ss() * plant
    Pd = control.c2d(plant, T, "zoh")
    for _ in range(delay):
        Pd = Pd * control.ss(control.tf([1.0], [1.0, 0.0], T))
    return Pd


def _filter(wf: float, zf: float, T: float, w_rolloff: float | None = None):
    """F(s) of the module docstring, discretised by ZOH."""
    import control  # (lazy: imports control, only when called)

    F = control.tf([wf**2], [1.0, 2 * zf * wf, wf**2])
    if w_rolloff is not None:
        F = F * control.tf([w_rolloff], [1.0, w_rolloff])
    return control.ss(control.c2d(F, T, "zoh"))


def _closed_poles(Pd, Fd, k: float) -> np.ndarray:
    import control  # (lazy: imports control, only when called)

    T = Pd.dt
    z = control.poles(control.feedback(Pd, Fd * k, sign=-1))
    z = z[np.abs(z) > 1e-12]
    return np.log(z.astype(complex)) / T


def _plant_partners(ol: np.ndarray, Pd, Fd, cl: np.ndarray) -> np.ndarray:
    """The closed-loop poles ``cl`` paired with the plant's poles ``ol``: every closed-loop pole is assigned to one of
    the loop's open-loop poles (those of ``Pd`` and ``Fd``, where the closed loop's start at gain 0) by the least total
    distance (scipy's linear_sum_assignment), and those of the plant's are kept."""
    from scipy.optimize import linear_sum_assignment  # (lazy: imports scipy.optimize, only when called)

    T = Pd.dt
    z = np.concatenate([np.asarray(Pd.poles(), complex), np.asarray(Fd.poles(), complex)])
    start = np.log(z[np.abs(z) > 1e-12]) / T
    rows, cols = linear_sum_assignment(np.abs(start[:, None] - cl[None, :]))
    partner = dict(zip(rows, cols))
    mine = [int(np.argmin(np.abs(start - p))) for p in ol]
    return np.array([cl[partner[i]] for i in mine if i in partner])


def _stable(Pd, Fd, k: float) -> bool:
    return bool(np.all(_closed_poles(Pd, Fd, k).real < 0))


def _no_mode_worse(ol: np.ndarray, cl: np.ndarray, tol: float = DAMPING_TOLERANCE) -> bool:
    """Every complex open-loop pole's nearest closed-loop pole keeps at least ``1 - tol`` of its damping."""
    cl = cl[cl.imag > 1e-6]
    for p in ol[ol.imag > 1e-6]:
        q = cl[np.argmin(np.abs(cl - p))]
        if -q.real / abs(q) < (1.0 - tol) * (-p.real / abs(p)):
            return False
    return True


def design_damping(
    params: Mapping[str, float],
    *,
    position_gain_v_per_rad: float,
    sample_time_s: float = 1e-3,
    delay_samples: int = 1,
    gain_margin_db: float = GAIN_MARGIN_DB,
    filter_zeta: float = FILTER_ZETA,
    fit_summary: Mapping[str, object] | None = None,
    chain: SensorChain | None = None,
) -> DampingDesign:
    """Tuned acceleration feedback on the fitted model ``params`` (module docstring), the base read through ``chain``
    (None: ideal sensors)."""
    T = float(sample_time_s)
    chain = _known(chain)
    Pd = _discrete_loop(params, position_gain_v_per_rad, T, int(delay_samples), chain)
    wf = float(params["w1"])
    w_roll = float(params["w3"]) if "w3" in params and np.isfinite(params["w3"]) else None
    Fd = _filter(wf, filter_zeta, T, w_roll)
    # the plant's modes: with a sensor chain, the loop's poles without it (the sensors' own, a roll-off's or a delay's
    # Pade pair, are no modes to keep damped); the computation delay's are at z = 0 and dropped
    blind = chain is None
    plant_poles = np.asarray((Pd if blind else _discrete_loop(params, position_gain_v_per_rad, T, int(delay_samples))).poles(), complex)
    ol = np.log(plant_poles[np.abs(plant_poles) > 1e-12]) / T
    # sign: the one that moves mode 1 to the left at a small gain
    p1 = ol[ol.imag > 0][np.argmin(np.abs(np.abs(ol[ol.imag > 0]) - wf))]
    probe = 1e-4
    moved = {}
    for sign in (1.0, -1.0):
        cl = _closed_poles(Pd, Fd, sign * probe)
        q = cl[np.argmin(np.abs(cl - p1))]
        moved[sign] = q.real - p1.real
    sign = min(moved, key=moved.get)
    # stability limit: grow the gain by decades, then bisect (log scale)
    lo, hi = probe, None
    k = probe
    while k < 1e6:
        k *= 10
        if _stable(Pd, Fd, sign * k):
            lo = k
        else:
            hi = k
            break
    if hi is None:
        raise RuntimeError("the fitted model stays stable for any acceleration-feedback gain up to 1e6 V/(m/s²): check the fit")
    for _ in range(50):
        mid = math.sqrt(lo * hi)
        if _stable(Pd, Fd, sign * mid):
            lo = mid
        else:
            hi = mid
    k_lim = lo
    k = k_lim * 10 ** (-gain_margin_db / 20)

    def modes_at(gain: float) -> np.ndarray:
        """The closed loop's poles at ``gain`` that belong to the plant's: each closed-loop pole paired with one
        open-loop pole, the controller's and a sensor chain's set apart (a plant mode nearest a filter's pole must not
        be judged by that pole; on the designs without a chain the pairing is the nearest pole's, as it was)."""
        return _plant_partners(ol, Pd, Fd, _closed_poles(Pd, Fd, gain))

    cl = modes_at(sign * k)
    while not _no_mode_worse(ol, cl) and k > 1e-6 * k_lim:
        k *= 10 ** (-1 / 20)  # 1 dB at a time
        cl = modes_at(sign * k)
    gain = sign * k
    A, B, C, D = (np.atleast_2d(np.asarray(x, float)) for x in (Fd.A, Fd.B, Fd.C, Fd.D))
    c = LinearController(
        A, B, -gain * C, -gain * D, sample_time_s=T, inputs=("accel",),
        name=f"tuned acceleration feedback: k = {gain:.4g} V/(m/s²), 2nd-order low-pass at {wf / (2 * np.pi):.4g} Hz, zeta {filter_zeta:.3g}"
        + (f", roll-off at {w_roll / (2 * np.pi):.4g} Hz" if w_roll else ""),
        method="filter discretised by zero-order hold; gain from the fitted model's stability limit",
        model_units="SI: accel in m/s², v in volts (added to the servo amplifier's command)",
    )  # fmt: skip
    prov = {
        "designed_on": "a fit of the notebook's 3-mode structure to measured Bode data",
        "method": "tuned acceleration feedback (samii.closedloop.damping)",
        "fit_params": {k2: float(v) for k2, v in params.items()},
        "position_gain_v_per_rad": position_gain_v_per_rad,
        "delay_samples_designed_for": int(delay_samples),
        "gain_limit_v_per_m_s2": sign * k_lim,
        "gain_margin_db": 20 * math.log10(k_lim / k),
        **({"fit": dict(fit_summary)} if fit_summary else {}),
        **({"sensor_chain": chain.describe()} if chain is not None else {}),
    }
    return DampingDesign(
        params=dict(params), position_gain_v_per_rad=position_gain_v_per_rad, sample_time_s=T, delay_samples=int(delay_samples),
        filter_hz=wf / (2 * np.pi), filter_zeta=filter_zeta, rolloff_hz=None if w_roll is None else w_roll / (2 * np.pi), gain_v_per_m_s2=gain, gain_limit_v_per_m_s2=sign * k_lim,
        gain_margin_db=20 * math.log10(k_lim / k), open_loop_poles_s=ol, closed_loop_poles_s=cl,
        controller=SavedController(c, False, prov), fit_summary=dict(fit_summary or {}),
        chain=chain,
    )  # fmt: skip


def measured_sensitivity(
    design: DampingDesign, frf, *, above_hz: float, chain: SensorChain | None = None
) -> tuple[float | None, tuple[float, float] | None]:
    """Largest ``|1/(1 - C P)|`` over the measured points above ``above_hz``, with ``P = (xdd/v) / (1 + Kp theta/v)``
    from the data (not the fit) and ``C`` the controller with its design delay; ``(None, None)`` without such points.
    With ``chain``, the data were measured through its sensors: the servo loop's theta/v is the data's with the angle
    sensor's response divided out (the amplifier reads the joint), xdd/v the data's (the controller reads the
    accelerometer) times the card's anti-alias filter."""
    f = np.asarray(frf.freq_hz, float)
    act = frf.act
    total = frf.total if frf.total is not None else (act * frf.base if act is not None and frf.base is not None else None)
    sel = f > above_hz
    if act is None or total is None or not np.any(sel):
        return None, None
    c = design.controller.controller
    z = np.exp(2j * np.pi * f[sel] * c.sample_time_s)
    Cz = np.asarray(c.statespace()(z)).ravel() * z ** (-design.delay_samples)  # python-control evaluates C(z)
    act, total = act[sel], total[sel]
    if _known(chain) is not None:
        g_theta, _ = chain.measured_response(f[sel])
        act, total = act / g_theta, total * chain.card_response(f[sel])
    P = total / (1 + design.position_gain_v_per_rad * act)
    S = 1.0 / (1.0 - Cz * P)
    return float(np.max(np.abs(S))), (float(f[sel].min()), float(f[sel].max()))


def with_data_check(design: DampingDesign, frf, chain: SensorChain | None = None) -> DampingDesign:
    """``design`` with :func:`measured_sensitivity` above its fit band filled in (``frf`` measured through ``chain``)."""

    hi = float(design.fit_summary.get("band_hz", FIT_BAND_HZ)[1]) if design.fit_summary else FIT_BAND_HZ[1]
    smax, band = measured_sensitivity(design, frf, above_hz=hi, chain=chain)
    return replace(design, max_sensitivity_above_band=smax, sensitivity_band_hz=band)


def measured_fit(frf, *, band_hz: tuple[float, float] = FIT_BAND_HZ):
    """The notebook's 3-mode s^4 structure fitted to ``frf`` (coherence-weighted when it has coherence)."""

    lo, hi = band_hz
    f = np.asarray(frf.freq_hz)
    band = (max(lo, float(f.min())), min(hi, float(f.max())))
    if not band[0] < band[1]:
        n = int(np.count_nonzero((f >= lo) & (f <= hi)))
        raise ValueError(
            f"{n} frequency point(s) in the design's fit band {lo:g}-{hi:g} Hz (the data span "
            f"{f.min():.4g}-{f.max():.4g} Hz); a fit of the 3-mode model needs a band of many"
        )
    check_not_noise(frf, band_hz=band)  # a design on noise: refused (a fit of it is not sound, said below in any case)
    return fit(frf, weighting="auto", band_hz=band, profile=False)  # the design reads the parameters, not their intervals


def damping_from_frf(
    data,
    *,
    source: str,
    position_gain_v_per_rad: float,
    sample_time_s: float = 1e-3,
    delay_samples: int = 1,
    gain_margin_db: float = GAIN_MARGIN_DB,
    chain: SensorChain | None = None,
) -> DampingDesign:
    """The damping controller designed on a fit of measured Bode data ``data`` (read from the file ``source``, which
    the refusals name): refused (:class:`~samii.errors.InputError`) when the data lack a channel, cannot be fitted, the
    fit is not sound, or the fit says the servo loop the data were measured in was unstable. ``chain``: the sensors
    the data were measured through and the controller will read through (step 5 of the module docstring)."""

    missing = ([] if "act" in data.channels else ["act"]) + ([] if {"base", "total"} & set(data.channels) else ["base or total"])
    if missing:
        raise InputError(f"{source}: the damping design needs the act channel and base or total; missing {', '.join(missing)}")
    kp = position_gain_v_per_rad
    try:
        fr = measured_fit(without_sensors(data, chain))
    except (ValueError, KeyError) as exc:  # the data cannot be fitted (too few points in the band, noise): the file's
        raise input_error_of(source, exc) from None
    if not fr.sound:  # a controller on parameters the fit says not to use: refused, in samii fit's words
        why = "; ".join(c.text for c in fr.concerns) or f"it did not converge ({fr.message})"
        raise InputError(
            f"{source}: the notebook's 3-mode model fitted to it over {fr.band_hz[0]:.3g}-{fr.band_hz[1]:.3g} Hz is "
            "not a sound fit, and a controller designed on its parameters would not be trusted; samii fit "
            f"{source} --band-hz {fr.band_hz[0]:.3g} {fr.band_hz[1]:.3g} says why: {why}"
        )
    if (said := servo_loop_contradiction(fr.params, kp)) is not None:
        raise InputError(
            f"{source}: theta/v (the 3-mode model fitted to it) {said}: "
            "the servo loop the data were measured in would be unstable, yet the rig ran (a hydraulic position servo keeps a gain margin there: the embedded model's measured fit "
            "has 1.67). Is theta in rad (in mrad theta/v is 1000x too large, in degrees 57x), and is "
            "--position-gain the servo amplifier's gain in V/rad?"
        )
    summary = {"data": source, "band_hz": list(fr.band_hz), "rms_mag_db": dict(fr.rms_mag_db),
               "rms_phase_deg": dict(fr.rms_phase_deg), "converged": bool(fr.converged)}  # fmt: skip
    d = design_damping(fr.params, position_gain_v_per_rad=kp, sample_time_s=sample_time_s, delay_samples=delay_samples,
                       gain_margin_db=gain_margin_db, fit_summary=summary, chain=chain)  # fmt: skip
    return with_data_check(d, data, chain)


def damping_from_simulation(
    model,
    *,
    seed: int = 0,
    sample_time_s: float = 1e-3,
    delay_samples: int = 1,
    gain_margin_db: float = GAIN_MARGIN_DB,
    progress: Progress | None = None,
    antialias_hz: float | None = None,
) -> DampingDesign:
    """Measure ``model`` (swept sine, sensor noise on), fit, design: the damping controller of the current model, which
    knows its own sensors (``sensor.*``: divided out of the data before the fit and in the loop it is designed on) and,
    with ``antialias_hz``, the card's anti-alias filter. ``progress`` (samii.progress.Progress) is told the three
    stages, the measurement's physics steps within the first."""
    from samii.measure.campaign import measure_swept  # (lazy: imports mujoco, scipy, only when called)
    from samii.measure.daq import SensorNoise  # (lazy: imports mujoco, scipy, only when called)
    from samii.sim.plugin import hydraulic_params  # (lazy: imports mujoco, only when called)
    from samii.sim.sensor_dynamics import SensorDynamics  # (lazy: imports mujoco, only when called)

    chain = SensorChain(SensorDynamics.from_model(model), antialias_hz)
    progress = progress or SILENT
    progress.expect(3)
    progress.stage("measuring (swept sine 0.1-40 Hz, 3 records, sensor noise)")
    meas = measure_swept(model, noise=SensorNoise(), rng=np.random.default_rng(seed), progress=part(progress, 1))
    progress.stage("fitting the notebook's 3-mode model")
    fr = measured_fit(without_sensors(meas.frf, chain))
    progress.advance()
    summary = {"band_hz": list(fr.band_hz), "rms_mag_db": dict(fr.rms_mag_db), "rms_phase_deg": dict(fr.rms_phase_deg),
               "converged": bool(fr.converged), "measurement": f"samii measure (swept sine, noise, seed {seed})"}  # fmt: skip
    progress.stage("designing the acceleration feedback")
    d = design_damping(fr.params, position_gain_v_per_rad=hydraulic_params(model).position_gain, sample_time_s=sample_time_s,
                       delay_samples=delay_samples, gain_margin_db=gain_margin_db, fit_summary=summary, chain=chain)  # fmt: skip
    progress.advance()
    return with_data_check(d, meas.frf, chain)
