"""``--baseline sim``: the calibrated simulator as the model under test, and what the diagnosis
finds carried into it as physics.

1. **Calibrate.** The simulator's :data:`MODE_KNOBS` (the physical parameters that set the three
   base modes, their damping and the hydraulic pole pair) are calibrated to the first file in the
   diagnosis's own chi2 (:func:`calibrate_simulator`), its linearisation times a correction: the
   simulator measured like the file over its linearisation (:func:`correction`: what the nonlinear
   simulator does at the file's amplitude). When a nonlinearity was divided out of the data, to
   the linearised data. No channel gain is calibrated, so an accelerometer's gain error stays
   testable.
2. **Baseline.** That simulator with its knobs free through its first-order sensitivity
   (:class:`LocalSimulator`), refitted with each candidate effect by the same forward selection
   as the notebook's structure.
3. **Carry.** Each effect found becomes a simulator option (:data:`CARRY`): a command delay in the
   hydraulic plugin, the sensors' dynamics in the DAQ (``samii.sim.sensor_dynamics``), a dead
   band or saturation in the valve; an extra base mode a body on a compliant mount at the beam's
   end (:data:`BODY`, :func:`tip_body_options`), a gain asymmetry the valve's negative direction's
   gain, valve dynamics or a real pole-zero pair the
   spool's time constant (:data:`SPOOL`); these in a second round (``samii.diagnose.diagnosis``).
   Kinds with no simulator counterpart yet (an actuator mode, hysteresis) are listed as not
   carried, with the reason. A leaky integrator is not tried against the simulator: its pole
   near 0 is the leakage coefficient, a mode knob.
4. **Recalibrate** the mode knobs together with the linear options carried (started at the values
   found): a parameter the first calibration bent to imitate the missing effect goes back. The
   correction is recomputed at the result, and the calibration repeated, while the cost falls.
5. **Select again** (``samii.diagnose.diagnosis``) with the whole library against the recalibrated
   simulator: what the simulator cannot take, and nothing the first calibration's bending made up.
6. **Re-measure** the nonlinear simulator like each file (the file's sweep when its metadata gives
   it, else a sweep over its band at its amplitude), before and after, and report the
   simulator's error against the data as measured: rms dB, rms deg and chi2 per channel on the
   file's usable points, the same measure as the diagnosis's error. The re-measured response is
   interpolated onto the file's frequencies (log |H| and unwrapped phase, linear in log f).

7. **Carry only what lowers its error** (:func:`simulator_report`): each carried effect is taken out
   again, knobs kept, and the simulator re-measured; one whose carry does not lower the chi2 of the
   channels it acts on, or raises any channel's rms dB, rms deg or chi2 by more than 10 %, is not
   carried, the rest recalibrated without it; a carry that raises the chi2 over every channel, or
   any channel's measure by more than 10 %, is undone.
8. **Say what it cannot represent** (:func:`misfits`): bands where the simulator, before and after
   the carry, misses the data beyond their noise and floor by a practical amount, with their size;
   :meth:`SimulatorReport.verdict_text` names them and whatever the carry made worse.

The simulator's own sensor noise is off in the re-measurement: the error is the model's, against
the data's noise.

Before all of this, the sweep's harmonics in the data are tested in excess of the simulator's own
(:func:`measured_like`: the starting simulator measured like the file): its orifice law makes a 3rd
harmonic beyond 1 % where the command reaches ~0.3 V, which is not something it lacks.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from samii.calibrate.calibrate import MODE_KNOBS, PHYSICAL_LIMITS, default_bounds
from samii.calibrate.simulator import SimulatorFRF, parameter_value
from samii.diagnose.model import Baseline, Dataset
from samii.diagnose.nonlinear import ASYMMETRY_MAX_RATIO, asymmetry_fraction, asymmetry_ratio
from samii.diagnose.residuals import errors_from_residuals, full_residuals, unexplained_bands
from samii.errors import SimulationUnstable
from samii.forkmap import fork_calls, fork_map, sharing
from samii.frequency_response import CHANNEL_NAMES, CHANNELS, FrequencyResponse, interpolate_frf
from samii.measure.campaign import linearised_frf, measure
from samii.measure.daq import SensorNoise
from samii.measure.excitation import SweptSine
from samii.measure.floor import PRACTICAL_FACTOR, REL_FLOOR
from samii.measure.measured import Measured, from_timeseries
from samii.progress import SILENT, Progress
from samii.sim.linearize import UNSTABLE_RATE_1_S, base_modes, poles_per_s
from samii.sim.mjcf import SamiiParams
from samii.sim.model import default_params, load_model, load_spec, make_data, params_with_overrides

__all__ = [
    "CARRY",
    "BODY",
    "SPOOL",
    "LATE",
    "spool_lag_s",
    "NOT_CARRIED",
    "tip_body_options",
    "body_effect_values",
    "LocalSimulator",
    "Misfit",
    "misfits",
    "SimulatorCalibration",
    "SimulatorReport",
    "calibrate_simulator",
    "correction",
    "simulator_baseline",
    "carry",
    "carry_and_recalibrate",
    "sweep_like",
    "measured_like",
    "measurement_like",
    "remeasure",
    "simulator_report",
]

#: effect label -> (simulator parameter, the effect's parameter giving its value)
CARRY: Mapping[str, tuple[str, str]] = {
    "delay/command": ("hydraulic.command_delay", "delay_s"),
    "delay/theta_sensor": ("sensor.theta_delay_s", "delay_s"),
    "delay/accel_sensor": ("sensor.accel_delay_s", "delay_s"),
    "sensor/accel_lowpass": ("sensor.accel_lowpass_hz", "corner_hz"),
    "sensor/accel_lowpass2": ("sensor.accel_antialias_hz", "corner_hz"),
    "sensor/accel_highpass": ("sensor.accel_highpass_hz", "corner_hz"),
    "sensor/accel_gain": ("sensor.accel_gain", "gain"),
    "nonlinear/dead_band": ("hydraulic.valve_dead_band", "dead_band_v"),
    "nonlinear/saturation": ("hydraulic.valve_saturation", "saturation_v"),
    "nonlinear/asymmetry": ("hydraulic.valve_asymmetry", "asymmetry_fraction"),
}
#: An extra base mode becomes a body on a compliant mount at the beam's end: its mass, and its
#: frequency and damping ratio on a rigid mount (``samii.sim.mjcf.BeamParams``). All three are
#: recalibrated; the effect is then reported as the recalibrated simulator's extra mode.
BODY: Mapping[str, tuple[str, str, str]] = {
    "extra_mode/base_mode": ("beam.tip_body_mass_kg", "beam.tip_body_freq_hz", "beam.tip_body_damping_ratio"),
}
#: Valve dynamics become the simulator's spool time constant (its valve is a first-order lag): the
#: found second-order lag at ``f`` with damping ``zeta`` adds its low-frequency group delay
#: ``2 zeta / (2 pi f)`` to the spool's time constant, which is then recalibrated with the knobs.
#: Like a body, it is carried in the second round only (diagnosis: a kind the first selection cannot
#: carry is imitated by one it can, and the reverse). A real pole/zero pair is the exact ratio of two
#: first-order spools, (1 + s tau0)/(1 + s tau): its low-frequency group delay 1/w_p - 1/w_z is added
#: the same way.
SPOOL: Mapping[str, str] = {"actuator/valve": "hydraulic.valve_time_constant", "actuator/pole_zero": "hydraulic.valve_time_constant"}
#: The first selection against the simulator tries only :data:`CARRY`'s kinds, what it carries as an option set
#: directly. Neither valve dynamics (near damping 0.7 a flat magnitude with a nearly linear phase: a 4 ms delay
#: beside an AC coupling was taken as a 59 Hz valve) nor a real pole/zero pair (tried there, it stood beside a
#: 20 Hz accelerometer roll-off and a 4 ms delay as a 5 % and 2 % change of the spool, with a gain error and a
#: theta delay of 0.08 ms) is among them; a spool twice as slow is then imitated by a theta delay, an
#: accelerometer roll-off and a gain error, and found as the pair only in the second round.
#: Kinds carried in the second round, after the first selection's effects (samii.diagnose.diagnosis).
LATE = (*BODY, *SPOOL)
#: The trial mass whose effect on xdd/theta, to first order in the mass, scales a found residue to a mass.
_TRIAL_MASS_KG = 0.05
#: Options of the valve's law: set, not recalibrated (the linearisation takes the ideal valve).
_LAWS = ("hydraulic.valve_dead_band", "hydraulic.valve_saturation", "hydraulic.valve_asymmetry")
#: Why a kind is not carried.
NOT_CARRIED: Mapping[str, str] = {
    "extra_mode/act_mode": "the simulator has no option for a compliance in joint 2's drive yet",
    "nonlinear/hysteresis": "the simulator's valve has no play (hysteresis) option yet",
}


@dataclass(frozen=True, eq=False)
class SimulatorCalibration:
    params: SamiiParams  #: the calibrated simulator
    result: Calibration
    source: str  #: the file it was calibrated to


@dataclass(frozen=True, eq=False)
class SimulatorReport:
    """The simulator's error against the data before and after the effects were carried into it."""

    error_before: Mapping[str, object]  #: channel -> ChannelError of the calibrated simulator, re-measured
    error_after: Mapping[str, object]  #: ... with the effects carried and recalibrated
    changes: Mapping[str, float]  #: parameters changed from the first calibration, with their new values
    carried: tuple[str, ...]  #: effect labels carried
    not_carried: tuple[str, ...]  #: "label: reason"
    before: SimulatorCalibration
    after: SimulatorCalibration
    remeasured_before: tuple[FrequencyResponse, ...]  #: per file, on the re-measurement's own frequencies
    remeasured_after: tuple[FrequencyResponse, ...]
    dropped: tuple[str, ...] = ()  #: first-pass proposals the second pass did not need
    #: where the calibrated simulator, before anything is carried, misses the data beyond their noise and floor
    misfit_before: tuple[Misfit, ...] = ()
    #: ... and with the effects carried: where it cannot represent the data
    misfit_after: tuple[Misfit, ...] = ()
    #: "label: reason" for effects whose carry did not lower the simulator's error on their own channels (not carried)
    not_lowering: tuple[str, ...] = ()
    #: "label: reason" for effects found against the simulator where, with them, it still cannot represent the data,
    #: that cannot be told from images of what it lacks (samii.diagnose.attribution): not reported as effects
    unattributed: tuple[str, ...] = ()

    @property
    def worse(self) -> list[str]:
        """Each channel and measure (rms dB, rms deg, chi2) the carry makes worse, as text: what the verdict must say."""
        return _worse(self.error_before, self.error_after)

    def verdict_text(self) -> str:
        """What the verdict line says of the simulator: whether it can represent the data, and any error the carry raised."""
        parts = []
        if self.misfit_after:
            parts.append(
                "the simulator"
                + (" with them" if self.carried else "")
                + " cannot represent the data at "
                + "; ".join(m.text() for m in _largest(self.misfit_after))
            )
        if self.worse:
            parts.append("carrying them makes its error worse: " + ", ".join(self.worse))
        if self.unattributed:
            labels = list(dict.fromkeys(u.split(":", 1)[0] for u in self.unattributed))
            parts.append("found against it but not told from images of what it lacks (not reported as effects): " + ", ".join(labels))
        return "; ".join(parts)

    def to_dict(self) -> dict:
        return {
            "error_before": {k: v.to_dict() for k, v in self.error_before.items()},
            "error_after": {k: v.to_dict() for k, v in self.error_after.items()},
            "changes": dict(self.changes),
            "carried": list(self.carried),
            "not_carried": list(self.not_carried),
            "not_lowering": list(self.not_lowering),
            "unattributed": list(self.unattributed),
            "worse": self.worse,
            "verdict": self.verdict_text(),
            "misfit_before": [m.to_dict() for m in self.misfit_before],
            "cannot_represent": [m.to_dict() for m in self.misfit_after],
            "first_pass_dropped": list(self.dropped),
            "calibrated_to": self.before.source,
            "calibration": {"before": _calibration_dict(self.before), "after": _calibration_dict(self.after)},
        }


def _calibration_dict(c: SimulatorCalibration) -> dict:
    r = c.result
    return {
        "values": dict(r.values),
        "stderr": dict(r.stderr),
        "converged": bool(r.converged),
        "status": r.status,
        "chi2_per_residual": r.cost / max(r.n_residuals, 1),
        "rms": {ch: {"rms_db": db, "rms_deg": deg} for ch, (db, deg) in r.rms.items()},
        "bounds": {n: list(b) for n, b in (r.bounds or {}).items()},
    }


def correction(params: SamiiParams, m: Measured) -> FrequencyResponse:
    """The simulator measured like ``m`` over its linearisation, per channel, on ``m``'s frequencies:
    what the nonlinear simulator does at the file's amplitude that its small-signal model does not
    (the orifice law, a valve law carried in, the estimator's own bias), to first order
    independent of the knobs a calibration moves."""
    measured = interpolate_frf(remeasure(params, m), m.frf.freq_hz)
    lin = _linearised(params, m.frf.freq_hz)
    ch = {}
    for c in ("act", "base", "total"):
        r = measured[c] / lin.response(c)
        ch[c] = np.where(np.isfinite(r), r, 1.0)  # outside the re-measured span: no correction
    return FrequencyResponse(
        m.frf.freq_hz,
        act=ch["act"],
        base=ch["base"],
        total=ch["total"],
        metadata={"source": "simulator measured / linearised (samii diagnose --baseline sim)"},
    )


@dataclass(frozen=True)
class Calibration:
    """What :func:`calibrate_simulator` found (SI, each parameter in its own unit)."""

    names: tuple[str, ...]
    start: Mapping[str, float]
    values: Mapping[str, float]
    stderr: Mapping[str, float]
    cost: float  #: chi2 of the diagnosis's residuals in the fit's weights (noise and any distortion; 1 per residual at the noise)
    n_residuals: int
    converged: bool
    status: str
    rms: Mapping[str, tuple[float, float]]  #: channel -> (dB, deg) over the usable points
    bounds: Mapping[str, tuple[float, float]] | None = None  #: name -> (lo, hi) the calibration kept it in


def calibrate_simulator(
    m: Measured,
    *,
    start: SamiiParams | None = None,
    extra: Mapping[str, float] | None = None,
    corrected_by: FrequencyResponse | None = None,
    max_nfev: int = 60,
    anchor: Mapping[str, float] | None = None,
) -> SimulatorCalibration:
    """The simulator's mode knobs (and the ``extra`` options, started at their values; a valve law is
    set, not calibrated) calibrated to ``m``, divided by ``corrected_by`` (:func:`correction`) when
    given: the linearised simulator times the correction is then what matches the data.

    The cost is the diagnosis's own chi2: log(data/model) on the file's usable points of theta/v
    and xdd/v (a command delay is in both, and only xdd/v holds it where it is large), each weighted
    by its noise (plus any distortion measured, Measured.model_var). ``samii calibrate``'s engine (``SimulatorFRF`` and its derivatives, the bounds of
    ``default_bounds``, trust-region least squares in the logarithms of the parameters), not its
    cost: that takes every point of the band weighted by coherence, and the noise floor's points
    (xdd/v 40 dB off below 1 Hz) pulled a 20 Hz accelerometer roll-off to 21.3 Hz.

    The bounds are ``default_bounds`` about ``anchor``'s value of each knob (default: the start's):
    a recalibration passes the first calibration's start, so that its range stays about the
    simulator the diagnosis began with. Chained from one calibration's result to the next, the
    factor-10 spans compounded: on data from an independent rig (``samii.diagnose.rig.EffectRig``)
    the first calibration took ``hydraulic.total_volume`` from 9.1e-6 to 3.9e-6 m^3, and the
    recalibration's correction rounds, each bounded a factor 10 about the one before, to 7.7e-8
    (1/120 of the start), where the simulator diverged at its 1 ms step; anchored, it stops at 1/10.
    """

    base = default_params() if start is None else start
    extra = dict(extra or {})
    laws = {k: v for k, v in extra.items() if k in _LAWS}
    linear = {k: v for k, v in extra.items() if k not in _LAWS}
    base = params_with_overrides(base, laws)
    # a knob at 0 (no leakage, say) cannot be calibrated in its logarithm: it stays at 0
    names = tuple(n for n in MODE_KNOBS if parameter_value(base, n) > 0) + tuple(linear)
    x0 = np.array([float(linear[n]) if n in linear else parameter_value(base, n) for n in names])
    bounds = [default_bounds(n, float(anchor[n]) if anchor and n in anchor else v) for n, v in zip(names, x0)]
    top = _MAX_CORNER_OF_RATE / base.timestep_s  # sensor corners the physics rate represents
    bounds = [(lo, min(hi, top) if n.endswith("_hz") else hi, why) for n, (lo, hi, why) in zip(names, bounds)]
    # a body's mount must stay resolved by the physics step (SamiiParams refuses 2 pi f dt > 1); 1 % margin for the
    # derivatives' steps
    mount = 0.99 / (2 * np.pi * base.timestep_s)
    bounds = [(lo, min(hi, mount) if n == BODY["extra_mode/base_mode"][1] else hi, why) for n, (lo, hi, why) in zip(names, bounds)]
    lo = np.log([b[0] for b in bounds])
    hi = np.log([b[1] for b in bounds])
    sim = SimulatorFRF(base, names)
    ds = Dataset.from_measured(m)
    channels = tuple(ds.data)
    w = 2 * np.pi * ds.freq_hz
    corr = {c: (np.ones(ds.freq_hz.size) if corrected_by is None else corrected_by.response(c)) for c in ("act", "base", "total")}

    def parts(z, derivatives):
        x = np.exp(z)
        h = sim.log_responses(x, w, ("act", "base"), derivatives=derivatives)
        res, jac = [], []
        for c in channels:
            k = ds.keep[c]
            if c == "total":
                model = h["act"][0] * h["base"][0]
                d = h["act"][1] + h["base"][1] if derivatives else None
            else:
                model, d = h[c]
            e = np.log(ds.data[c] / (model[k] * corr[c][k]))
            wt = ds.inv_sigma[c]
            res += [e.real * wt, e.imag * wt]
            if derivatives:
                de = -d[k] * x  # d e / d log x
                jac += [de.real * wt[:, None], de.imag * wt[:, None]]
        return np.concatenate(res), (np.vstack(jac) if derivatives else None)

    z0 = np.clip(np.log(x0), lo + 1e-9, hi - 1e-9)
    r0 = parts(z0, False)[0]

    # the data come from a loop that is stable: knobs that make the simulator's closed loop grow are not its
    # calibration, whatever its linearised response (an unstable pole's magnitude is a stable one's; on the second
    # rig's 2 ms delay the knobs went to a pole growing at 3.0 1/s at 8.0 Hz, and the simulator measured like the file
    # was a limit cycle). A step there is made to cost more than the start (the trust region then shrinks).
    def growth(z):  # (on the model the responses were just computed on)
        return closed_loop_growth(sim.model(np.exp(z)))

    guard = growth(z0) <= UNSTABLE_RATE_1_S
    held = []  # the unstable knobs a step was refused at

    def residuals(z):
        r = parts(z, False)[0]
        if guard and growth(z) > UNSTABLE_RATE_1_S:
            held.append(z)
            return 10.0 * np.maximum(np.abs(r0), np.abs(r)) + 1.0
        return r

    sol = least_squares(residuals, z0, jac=lambda z: parts(z, True)[1], bounds=(lo, hi), method="trf", max_nfev=max_nfev, xtol=1e-8, ftol=1e-8)
    r, j = parts(sol.x, True)
    cost = float(r @ r)
    x = np.exp(sol.x)
    dof = max(r.size - x.size, 1)
    cov = np.linalg.pinv(j.T @ j) * (cost / dof) * ds.corr_length
    se = np.sqrt(np.clip(np.diag(cov), 0, None)) * x
    rms, offset = {}, 0
    for c in channels:  # r holds each channel's real then imaginary parts, weighted
        n = int(ds.keep[c].sum())
        re, im = r[offset : offset + n] / ds.inv_sigma[c], r[offset + n : offset + 2 * n] / ds.inv_sigma[c]
        offset += 2 * n
        if n == 0:  # (no usable point: theta under a 12-bit encoder's step) no error to state
            continue
        rms[c] = (float(20 / np.log(10) * np.sqrt(np.mean(re**2))), float(np.degrees(np.sqrt(np.mean(im**2)))))
    on_bound = [n for n, z, a, b in zip(names, sol.x, lo, hi) if min(z - a, b - z) < 1e-3]
    result = Calibration(
        names,
        dict(zip(names, map(float, x0))),
        dict(zip(names, map(float, x))),
        dict(zip(names, map(float, se))),
        cost,
        int(r.size),
        bool(sol.success) and not on_bound and not held,
        str(sol.message)
        + (f"; on a bound: {', '.join(on_bound)}" if on_bound else "")
        + (
            f"; held where its position loop stays stable ({len(held)} step(s) toward knobs where it grows refused: "
            "the data pull the simulator to an unstable loop, which no stable rig measures)"
            if held
            else ""
        ),
        rms,
        {n: (float(b[0]), float(b[1])) for n, b in zip(names, bounds)},
    )
    return SimulatorCalibration(sim.samii_params(x), result, m.source)


def closed_loop_growth(model) -> float:
    """The fastest growth rate [1/s] of the compiled simulator ``model`` about its equilibrium, its position loop
    closed (``samii.sim.linearize.poles_per_s``): positive when it is unstable (a valve law bounds it to a limit cycle)."""
    return float(np.max(poles_per_s(model).real))


def _linearised(params: SamiiParams, freq_hz: np.ndarray) -> FrequencyResponse:
    """The linearised simulator with ``params`` at ``freq_hz``."""

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # scipy logm accuracy notes
        return linearised_frf(load_model(params=params), np.asarray(freq_hz, float))


@dataclass(frozen=True, eq=False)  # holds a cache: compare by identity
class LocalSimulator:
    """The simulator near a calibration as a model structure for the diagnosis: its mode knobs are
    the baseline's parameters, refitted with the effects like the notebook structure's, through
    the first-order expansion ``log H(x) = log H(x0) + J (log x - log x0)`` (J by central
    differences of the linearised simulator, ``SimulatorFRF``). A selection then weighs an effect
    against what the knobs can do, as item 3 asks of a baseline, at the cost of one Jacobian per
    frequency grid instead of a calibration per candidate. The values the diagnosis reports come
    from the real recalibration (:func:`calibrate_simulator`), not from this expansion."""

    at: SamiiParams  #: the calibration expanded about
    names: tuple[str, ...] = MODE_KNOBS
    power: int = 0  # no modal form: samii.diagnose.model.relabel_modes leaves it alone
    n_modes: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "_sim", SimulatorFRF(self.at, self.names))
        object.__setattr__(self, "x0", np.array([parameter_value(self.at, n) for n in self.names]))
        object.__setattr__(self, "_tables", {})
        object.__setattr__(self, "_modes", None)

    @property
    def param_names(self) -> tuple[str, ...]:
        return self.names

    @property
    def positive(self) -> np.ndarray:
        return self._sim.positive

    #: The knobs may move this factor either side of the calibration: where the expansion holds
    #: (a mode knob moved by 2x shifts a mode by ~40 %).
    SPAN = 2.0

    def log_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of log x for the optimiser (all knobs are positive)."""
        return np.log(self.x0 / self.SPAN), np.log(self.x0 * self.SPAN)

    def vector(self, values: Mapping[str, float]) -> np.ndarray:
        return np.array([float(values[n]) for n in self.names])

    def params(self, x) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.names, x)}

    def _table(self, w: np.ndarray) -> dict:
        key = w.tobytes()
        hit = self._tables.get(key)
        if hit is None:
            full = self._sim.log_responses(self.x0, w, ("act", "base"), derivatives=True)
            hit = {c: (h, d * self.x0) for c, (h, d) in full.items()}  # d log H / d log x
            if len(self._tables) > 32:
                self._tables.clear()
            self._tables[key] = hit
        return hit

    def log_responses(self, x, w, channels=("act", "base"), *, derivatives: bool = True) -> dict:
        """channel -> (H, d log H / d x or None), as ``ModelStructure.log_responses``."""
        w = np.asarray(w, float)
        x = np.asarray(x, float)
        table = self._table(w)
        dz = np.log(x) - np.log(self.x0)
        out = {}
        for c in channels:
            parts = ("act", "base") if c == "total" else (c,)
            h = np.ones(w.size, complex)
            d = np.zeros((w.size, x.size), complex)
            for p in parts:
                h0, j = table[p]
                h = h * h0 * np.exp(j @ dz)
                d = d + j / x
            out[c] = (h, d if derivatives else None)
        return out

    def mode_freqs_hz(self) -> tuple[float, ...]:
        """The simulator's base modes [Hz] at the calibration expanded about (joint 2 held): what an extra base mode
        within 5 % of is one of its own modes split in two (samii.diagnose.select._duplicate_mode)."""
        if self._modes is None:
            object.__setattr__(self, "_modes", tuple(float(m.freq_hz) for m in simulator_base_modes(self.at)))
        return self._modes

    def response(self, values: Mapping[str, float], freq_hz: np.ndarray, channel: str) -> np.ndarray:
        return self.log_responses(self.vector(values), 2 * np.pi * np.asarray(freq_hz, float), (channel,), derivatives=False)[channel][0]


def simulator_baseline(cal: SimulatorCalibration, corrections: Sequence[FrequencyResponse]) -> Baseline:
    """The calibrated simulator, its mode knobs free (:class:`LocalSimulator`), times each file's
    correction (:func:`correction`, one per file in order)."""
    st = LocalSimulator(cal.params)
    x0 = st.params(st.x0)
    return Baseline(
        structure=st,
        params=tuple(dict(x0) for _ in corrections),
        correction=tuple(corrections),
        label=f"the simulator calibrated to {cal.source}, its mode knobs refitted with the effects",
        reference=None,
    )


#: Options that add to what the simulator has (a delay found is a delay beyond the simulator's own).
_ADDITIVE = ("hydraulic.command_delay", "sensor.theta_delay_s", "sensor.accel_delay_s")
#: Sensor corners the simulator's physics rate can represent: below this fraction of it.
_MAX_CORNER_OF_RATE = 0.45


def carry(effects: Sequence, params: SamiiParams, *, refuse: Mapping[str, str] | None = None) -> tuple[dict[str, float], list[str], list[str]]:
    """(options to set, labels carried, "label: reason" not carried) for the found effects, on the
    simulator ``params``. A delay adds to the simulator's own; a gain error multiplies its gain.
    ``refuse``: labels not to carry, with the reason (a valve law whose level the harmonics do not
    fix). Expected effects (a delay the sampling explains) are not carried: the simulator samples too."""
    options, carried, not_carried = {}, [], []
    refuse = dict(refuse or {})
    for e in effects:
        if getattr(e, "expected", False):
            continue
        label = f"{e.category}/{e.kind}"
        if label in refuse:
            not_carried.append(f"{label}: {refuse[label]}")
            continue
        if label in BODY:
            body = tip_body_options(e, params)
            if isinstance(body, str):
                not_carried.append(f"{label}: {body}")
            elif any(n in options for n in body):
                not_carried.append(
                    f"{label}: a second extra mode (the simulator takes one body on the tip; kept the first, {options[BODY[label][1]]:.4g} Hz)"
                )
            else:
                options.update(body)
                carried.append(label)
            continue
        if label in SPOOL:  # the spool takes the lag's low-frequency group delay
            name = SPOOL[label]
            value = parameter_value(params, name) + spool_lag_s(e)
            lo, hi, why = PHYSICAL_LIMITS[name]
            if not lo <= value <= hi:
                not_carried.append(
                    f"{label}: as the spool's lag ({1e3 * parameter_value(params, name):.3g} ms "
                    f"{'+' if spool_lag_s(e) >= 0 else '-'} {1e3 * abs(spool_lag_s(e)):.3g} ms) it would be "
                    f"{1e3 * value:.3g} ms, outside {1e3 * lo:g}-{1e3 * hi:g} ms ({why})"
                )
                continue
        elif label not in CARRY:
            not_carried.append(f"{label}: {NOT_CARRIED.get(label, 'no simulator option for it')}")
            continue
        elif CARRY[label][1] not in e.params:
            not_carried.append(
                f"{label}: no level to carry (found from the amplitude dependence alone)"
                if e.kind != "asymmetry"
                else f"{label}: no level to carry (its 2nd harmonic's ratio not measured in enough segments)"
            )
            continue
        else:
            name, key = CARRY[label]
            value = float(e.params[key])
        if name == "sensor.accel_gain":
            value *= params.sensor.accel_gain
        elif name == "hydraulic.valve_asymmetry":
            # found in excess of the simulator's own 2nd harmonic (samii.diagnose.nonlinear.excess_over): the ratios add

            rho = float(asymmetry_ratio(parameter_value(params, name)) + asymmetry_ratio(value))
            value = asymmetry_fraction(rho) if abs(rho) < ASYMMETRY_MAX_RATIO else np.inf
            if not -1.0 <= value < 1.0:
                not_carried.append(
                    f"{label}: with the simulator's own asymmetry, a 2nd-harmonic ratio of {100 * rho:.3g} % "
                    "is beyond the valve option's (a negative direction's gain of 0-2)"
                )
                continue
        elif name in _ADDITIVE:
            value += parameter_value(params, name)
        elif name.endswith("_hz") and value >= _MAX_CORNER_OF_RATE / params.timestep_s:
            not_carried.append(f"{label}: {value:.4g} Hz is beyond what the simulator's physics rate ({1 / params.timestep_s:g} Hz) represents")
            continue
        if name in options:
            not_carried.append(f"{label}: a second {name} (kept the first, {options[name]:g})")
            continue
        options[name] = value
        carried.append(label)
    return options, carried, not_carried


def spool_lag_s(effect) -> float:
    """The low-frequency group delay [s] a valve-dynamics or pole/zero effect adds to theta/v: 2 zeta / w for a
    second-order lag, 1/w_p - 1/w_z for a real pole/zero pair (negative for a lead)."""
    p = effect.params
    if effect.kind == "pole_zero":
        return 1.0 / (2.0 * np.pi * float(p["pole_hz"])) - 1.0 / (2.0 * np.pi * float(p["zero_hz"]))
    return 2.0 * float(p["zeta"]) / (2.0 * np.pi * float(p["freq_hz"]))


def _base_channel(params: SamiiParams, freq_hz: np.ndarray) -> np.ndarray:
    return _linearised(params, freq_hz).response("base")


def _fit_residue(dh: np.ndarray, freq_hz: np.ndarray, f: float, zeta: float) -> float:
    """The real B whose ``B s^4 / (s^2 + 2 zeta w s + w^2)`` (the ``extra_mode/base_mode`` term) is
    nearest ``dh`` in least squares."""
    s, w = 2j * np.pi * freq_hz, 2 * np.pi * f
    basis = s**4 / (s * s + 2 * zeta * w * s + w * w)
    return float(np.sum((np.conj(basis) * dh).real) / np.sum(np.abs(basis) ** 2))


def _near(f: float, zeta: float) -> np.ndarray:
    """Frequencies across a mode at ``f``: its half-power band and more (the residue's fit), at most f/10 to 1.9 f
    (a "mode" of damping 0.41, proposed from data the simulator cannot represent, reached -4.8 Hz)."""
    half = min(max(3 * zeta, 0.05), 0.9)
    return f * np.linspace(1 - half, 1 + half, 61)


def tip_body_options(effect, params: SamiiParams) -> dict[str, float] | str:
    """The simulator options (``BODY``) for an extra base mode found as ``effect``, on ``params``, or
    why it cannot be carried. The body's frequency and damping on its mount start at the mode's; its
    mass is the residue over the residue a trial mass gives (the added term is first order in a
    small mass: it is the base's response times the mount's dynamic mass times the tip's
    compliance). A residue of the other sign is not a body on the tip."""
    label = f"{effect.category}/{effect.kind}"
    mass, freq, zeta = BODY[label]
    if parameter_value(params, mass) > 0:
        return "the simulator already has a body on the tip (it takes one)"
    f, z, b = (float(effect.params[k]) for k in ("freq_hz", "zeta", "residue"))
    if 2 * np.pi * f * params.timestep_s > 1.0:
        return f"{f:.4g} Hz is beyond what the simulator's physics rate ({1 / params.timestep_s:g} Hz) represents"
    trial = {mass: _TRIAL_MASS_KG, freq: f, zeta: max(z, 1e-3)}
    grid = _near(f, z)
    b1 = _fit_residue(_base_channel(params_with_overrides(params, trial), grid) - _base_channel(params, grid), grid, f, z)
    if not (np.isfinite(b1) and b1 != 0 and b / b1 > 0):
        return f"its residue {b:.3g} has the sign of no body on the tip (a {_TRIAL_MASS_KG:g} kg trial body gives {b1:.3g}): another structure's mode"
    return {mass: _TRIAL_MASS_KG * b / b1, freq: f, zeta: max(z, 1e-3)}


def simulator_base_modes(params: SamiiParams):
    """The simulator's base modes with joint 2 held (the poles of xdd/theta) at ``params``, below its Nyquist rate."""

    spec, _ = load_spec(params=params)
    model = load_model(params=params)
    data = make_data(model)
    theta2 = float(data.qpos[model.jnt_qposadr[model.joint("joint2").id]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return base_modes(spec, theta2, max_freq_hz=0.5 / params.timestep_s)


def _tip_body_mode(params: SamiiParams):
    """The base mode (joint 2 held: the pole of xdd/theta) the tip body adds to ``params``: of the
    modes with the body, the one whose removal leaves the modes without it best matched."""
    with_body = simulator_base_modes(params)
    without = np.log([m.freq_hz for m in simulator_base_modes(params_with_overrides(params, {BODY["extra_mode/base_mode"][0]: 0.0}))])

    def mismatch(i):
        rest = np.log([m.freq_hz for j, m in enumerate(with_body) if j != i])
        k = min(rest.size, without.size)
        return float(np.sum(np.abs(rest[:k] - without[:k])))

    return with_body[min(range(len(with_body)), key=mismatch)]


def body_effect_values(after: SamiiParams, stderr: Mapping[str, float]) -> tuple[dict, dict]:
    """(params, stderr) of the ``extra_mode/base_mode`` effect the recalibrated simulator ``after``
    carries as its tip body: the mode it adds (frequency and damping, joint 2 held), and the
    residue of the body's added term in xdd/theta there. The standard errors are the calibrated
    options' scaled to the mode's (first order: the mode moves with the mount's frequency, its
    residue with the mass)."""
    mass, freq, zeta = BODY["extra_mode/base_mode"]
    mode = _tip_body_mode(after)
    grid = _near(mode.freq_hz, mode.zeta)
    dh = _base_channel(after, grid) - _base_channel(params_with_overrides(after, {mass: 0.0}), grid)
    b = _fit_residue(dh, grid, mode.freq_hz, mode.zeta)
    rel = {n: float(stderr.get(n, np.nan)) / parameter_value(after, n) for n in (mass, freq, zeta)}
    values = {"freq_hz": mode.freq_hz, "zeta": mode.zeta, "residue": b}
    return values, {"freq_hz": mode.freq_hz * rel[freq], "zeta": mode.zeta * rel[zeta], "residue": abs(b) * rel[mass]}


def found_value(name: str, before: SamiiParams, value: float, se: float) -> tuple[float, float]:
    """The effect's value from the simulator option's recalibrated ``value`` (and its stderr): what
    :func:`carry` added to or multiplied into the simulator ``before``, undone."""
    if name == "sensor.accel_gain":
        g = before.sensor.accel_gain
        return value / g, se / g
    if name in _ADDITIVE:
        return value - parameter_value(before, name), se
    return value, se


def sweep_like(m: Measured):
    """The swept sine a file was measured with, from its metadata (``samii measure`` writes every
    setting), else one over its band at its amplitude (0.1 V when unknown), two sign-alternating
    repetitions. Repetitions are capped at 2: the simulator's re-measurement is noise-free."""

    meta = dict(m.timeseries.metadata) if m.timeseries is not None else dict(m.frf.metadata)
    try:
        sweep = SweptSine.from_metadata(meta)
        return replace(sweep, repetitions=min(sweep.repetitions, 2))
    except (KeyError, ValueError, TypeError):
        f = m.frf.freq_hz
        return SweptSine(start_hz=float(f.min()), stop_hz=float(f.max()), amplitude_v=float(m.amplitude_v or 0.1), repetitions=2)


def _measure_like(params: SamiiParams, m: Measured, sweep, **kwargs):
    """The nonlinear simulator with ``params`` measured with ``sweep`` at file ``m``'s DAQ rate
    (``samii.measure.campaign.measure``; ``kwargs`` its noise and rng)."""

    physics = 1.0 / params.timestep_s
    # the DAQ needs a rate the physics rate is a whole multiple of: the file's, else the nearest such
    ratio = max(1, round(physics / float(m.sample_rate_hz or physics)))
    return measure(load_model(params=params), sweep, sample_rate_hz=physics / ratio, **kwargs)


def measurement_like(params: SamiiParams, m: Measured, *, frame_steps: int | None = None):
    """The nonlinear simulator with ``params`` measured like file ``m`` (:func:`sweep_like`, no
    noise): the whole ``samii.measure.campaign.Measurement``, with the joint positions every
    ``frame_steps`` physics steps when given (for a recording)."""
    return _measure_like(params, m, sweep_like(m), frame_steps=frame_steps)


#: The simulator's re-measurements kept (params, file) -> FRF: a measurement without noise is a function of its
#: parameters and the file's sweep, and the selection's correction at a calibration re-measures what the report
#: just measured at it (two to four simulated measurements of ~15 in a diagnosis).
_REMEASURED: dict = {}
REMEASURED_KEPT = 16


def _remeasured_key(params: SamiiParams, m: Measured) -> tuple:
    return repr(params), id(m)


def remember_remeasured(params: SamiiParams, m: Measured, frf: FrequencyResponse) -> None:
    """Keep ``frf`` as :func:`remeasure`'s result for ``params`` and ``m`` (computed elsewhere: in a worker)."""
    while len(_REMEASURED) >= REMEASURED_KEPT:
        _REMEASURED.pop(next(iter(_REMEASURED)))
    _REMEASURED[_remeasured_key(params, m)] = (m, frf)  # (m held: its id stays its own while kept)


def remeasure(params: SamiiParams, m: Measured) -> FrequencyResponse:
    """The nonlinear simulator with ``params`` measured like file ``m`` (on its own frequencies); a measurement
    made already for the same parameters and file is returned again (:data:`_REMEASURED`)."""
    kept = _REMEASURED.get(_remeasured_key(params, m))
    if kept is not None and kept[0] is m:
        return kept[1]
    frf = measurement_like(params, m).frf
    remember_remeasured(params, m, frf)
    return frf


#: The simulator's own harmonics are measured with the DAQ's noise scaled by this (the harmonic test needs a
#: record-to-record spread; a tenth of the data's keeps the reference's share of the excess test's variance ~1 %)
#: over this many sweeps.
OWN_HARMONICS_NOISE = 0.1
OWN_HARMONICS_REPETITIONS = 3


def measured_like(params: SamiiParams, m: Measured) -> Measured | None:
    """The nonlinear simulator with ``params`` measured like file ``m`` (:func:`sweep_like`, 3 sweeps,
    a tenth of the DAQ's noise, seeded): the reference for the simulator's own harmonics of the
    sweep (``samii.diagnose.nonlinear.excess_over``). None when ``m`` has no time series."""

    if m.timeseries is None:
        return None
    meas = _measure_like(
        params,
        m,
        replace(sweep_like(m), repetitions=OWN_HARMONICS_REPETITIONS),
        noise=SensorNoise().scaled(OWN_HARMONICS_NOISE),
        rng=np.random.default_rng(0),
    )
    return from_timeseries(meas.timeseries, source=f"the simulator measured like {m.source}")


def _residuals(ds: Dataset, h: FrequencyResponse) -> dict[str, np.ndarray]:
    """log(data/simulator) on ``ds``'s usable points (NaN where the re-measurement does not reach: its sweep's
    estimate starts a little inside the file's band, 0.1007 Hz against 0.1 Hz)."""
    on = interpolate_frf(h, ds.freq_hz)
    out = {}
    for ch in ds.data:
        model = on[ch][ds.keep[ch]]
        e = np.full(model.size, complex(np.nan, np.nan))
        ok = np.isfinite(model) & (model != 0)
        e[ok] = np.log(ds.data[ch][ok] / model[ok])
        out[ch] = e
    return out


#: A carry makes a channel's measure worse when it rises by more than this fraction (the re-measurement is
#: noise-free and deterministic: smaller changes are interpolation's).
WORSE_TOLERANCE = 0.01
#: A carry that raises any channel's rms dB, rms deg or chi2 by more than this fraction is undone whole (a trade of
#: one channel's error for another's is no carry of what the simulator lacks; on the second rig's eq 9.4 plants,
#: which the simulator cannot represent, 4 effects carried lowered chi2 262 -> 136 on theta/v but took xdd/theta's
#: phase error from 22 to 42 deg, with a 42 kg body on the tip); smaller rises are said in the verdict.
UNDO_TOLERANCE = 0.10
#: Channels of the residuals an effect on a model channel changes: theta/v's is in xdd/v too, xdd/theta's too;
#: one on both (a theta sensor's delay) cancels in xdd/v.
RESIDUAL_CHANNELS: Mapping[str, tuple[str, ...]] = {"act": ("act", "total"), "base": ("base", "total"), "both": ("act", "base")}
#: A carry lowers its channels' error when their chi2 (summed over points) falls by at least this fraction.
LOWERS = 0.01


@dataclass(frozen=True)
class Misfit:
    """A band where the simulator measured like the data misses them beyond their noise and floor
    (``samii.diagnose.residuals.unexplained_bands``' test) by a practical amount: the rms of
    |log(data/simulator)| over the band above ``PRACTICAL_FACTOR`` x the relative floor (1.5 %)."""

    source: str
    channel: str
    lo_hz: float
    hi_hz: float
    rms_db: float
    rms_deg: float
    chi2: float  #: per residual, against the data's noise and floor
    n_points: int

    def to_dict(self) -> dict:
        return asdict(self)

    def text(self) -> str:
        return (
            f"{CHANNEL_NAMES[self.channel]} {self.lo_hz:.3g}-{self.hi_hz:.3g} Hz (by {self.rms_db:.2g} dB, {self.rms_deg:.2g} deg "
            f"rms; chi2 {self.chi2:.3g})"
        )


def _worse(before: Mapping[str, object], after: Mapping[str, object], tolerance: float | None = None) -> list[str]:
    """Each channel and measure (rms dB, rms deg, chi2) higher in ``after`` than in ``before`` by more than
    ``tolerance`` (default :data:`WORSE_TOLERANCE`), as text ("theta/v rms deg 20.2 -> 24 deg")."""
    tolerance = WORSE_TOLERANCE if tolerance is None else tolerance

    out = []
    for ch, b in before.items():
        a = after.get(ch)
        if a is None:
            continue
        for name, x, y, unit in (("rms dB", b.rms_db, a.rms_db, " dB"), ("rms deg", b.rms_deg, a.rms_deg, " deg"), ("chi2", b.chi2, a.chi2, "")):
            if x is not None and y is not None and y > x * (1 + tolerance):
                out.append(f"{CHANNEL_NAMES[ch]} {name} {x:.3g} -> {y:.3g}{unit}")
    return out


def _largest(misfits: Sequence[Misfit], n: int = 3) -> list[Misfit]:
    """The ``n`` misfits with the most chi2 (per residual times points), in frequency order per channel."""
    top = sorted(misfits, key=lambda m: -m.chi2 * m.n_points)[:n]
    return sorted(top, key=lambda m: (m.channel, m.lo_hz))


def misfits(datasets: Sequence[Dataset], residuals: Sequence[Mapping[str, np.ndarray]]) -> tuple[Misfit, ...]:
    """Where residuals log(data/simulator) (one mapping per dataset, on its usable points) exceed the data's
    noise and floor, significantly (the diagnosis's band test) and practically (:class:`Misfit`)."""

    out = []
    for b in unexplained_bands(datasets, residuals):
        ds, res = next((ds, r) for ds, r in zip(datasets, residuals) if ds.source == b.source)
        e, _ = full_residuals(ds, res, noise_only=False)[b.channel]
        sel = (ds.freq_hz >= b.lo_hz) & (ds.freq_hz <= b.hi_hz) & np.isfinite(e)
        if not sel.any() or np.sqrt(np.mean(np.abs(e[sel]) ** 2)) < PRACTICAL_FACTOR * REL_FLOOR:
            continue
        out.append(
            Misfit(
                b.source,
                b.channel,
                b.lo_hz,
                b.hi_hz,
                float(20 / np.log(10) * np.sqrt(np.mean(e[sel].real ** 2))),
                float(np.degrees(np.sqrt(np.mean(e[sel].imag ** 2)))),
                b.chi2,
                b.n_points,
            )
        )
    return tuple(out)


def _chi2_sum(err: Mapping[str, object], channels: Sequence[str]) -> float:
    """chi2 summed over the points of ``channels`` (ChannelError's per-residual chi2 times its points); rms in dB and
    degrees when the noise is not known (their squares' sum, in the same proportion)."""
    total = 0.0
    for ch in channels:
        e = err.get(ch)
        if e is None:
            continue
        total += e.n_points * (e.chi2 if e.chi2 is not None else (e.rms_db * np.log(10) / 20) ** 2 + np.radians(e.rms_deg) ** 2)
    return total


#: Times the correction is recomputed at the recalibrated simulator (each: one simulated measurement
#: and one calibration, ~10 s on 2 cores).
CORRECTION_STEPS = 2


def carry_and_recalibrate(
    measured_raw: Sequence[Measured],
    measured_fit: Sequence[Measured],
    before: SimulatorCalibration,
    effects: Sequence,
    *,
    progress: Progress | None = None,
    refuse: Mapping[str, str] | None = None,
    correction_steps: int = CORRECTION_STEPS,
):
    """(recalibrated simulator, options set, labels carried, "label: reason" not carried): ``effects``
    carried into the simulator calibrated as ``before`` (:func:`carry`) and the knobs recalibrated
    with the linear options (:func:`simulator_report`'s steps 3 and 4), the correction recomputed at
    most ``correction_steps`` times; ``before`` itself when nothing is carried."""
    stage = (progress or SILENT).stage
    options, carried, not_carried = carry(effects, before.params, refuse=refuse)
    if not options:
        return before, options, carried, not_carried
    stage("recalibrating the simulator with the effects")
    # the correction of the simulator with the options carried holds a carried valve law's
    # describing function; the data as measured then, unless a nonlinearity stays uncarried
    uncarried_law = any(e.category == "nonlinear" and f"{e.category}/{e.kind}" not in carried for e in effects)
    data = measured_fit[0] if uncarried_law else measured_raw[0]
    # the correction depends a little on the knobs near the modes: recomputed at the recalibrated
    # simulator and recalibrated, until the cost stops falling (a 20 Hz roll-off: 21.35 Hz with
    # the correction of the first calibration's knobs, 20.24 Hz after one such step, 20.19 after two)
    params, after = params_with_overrides(before.params, options), None
    for _ in range(1 + correction_steps):
        try:
            corr = correction(params, data)
        except SimulationUnstable as exc:
            # the simulator with them (or with its knobs recalibrated to them) diverges when measured like the file:
            # nothing is carried (a carry the simulator cannot run is not what it lacks), and the reason is said
            why = f"the simulator with {'it' if len(carried) == 1 else 'them'} carried diverges when measured like {data.source} ({exc})"
            return before, {}, [], list(not_carried) + [f"{label}: {why}" for label in carried]
        trial = calibrate_simulator(
            data, start=params, extra={n: parameter_value(params, n) for n in options}, corrected_by=corr, anchor=before.result.start
        )
        done = after is not None and trial.result.cost > (1 - 0.01) * after.result.cost
        if after is None or trial.result.cost < after.result.cost:
            after = trial
        if done:
            break
        params = after.params
    return after, options, carried, not_carried


def simulator_report(
    measured_raw: Sequence[Measured],
    measured_fit: Sequence[Measured],
    before: SimulatorCalibration,
    effects: Sequence,
    *,
    progress: Progress | None = None,
    refuse: Mapping[str, str] | None = None,
) -> SimulatorReport:
    """Carry ``effects`` into the simulator calibrated as ``before``, recalibrate, re-measure both
    like each file, and compare with the files as measured (``measured_raw``). The recalibration
    uses the first file as measured when every valve law found is carried (the simulator's
    correction then holds the law), else ``measured_fit[0]`` (the law divided out).

    Before anything is carried, where the calibrated simulator misses the data is measured band by
    band (:func:`misfits`); after, where it still does (it cannot represent the data there).
    Only what lowers the simulator's error is carried: each carried effect is taken out again (its
    options back at the calibration's values, the recalibrated knobs kept) and the simulator
    re-measured; an effect whose carry does not lower the chi2 of the channels it acts on
    (:data:`RESIDUAL_CHANNELS` of its own channel) by :data:`LOWERS`, or raises any channel's rms dB,
    rms deg or chi2 by more than :data:`UNDO_TOLERANCE`, is not carried, and the rest are
    recalibrated without it. A carry that still raises the chi2 summed over the channels, or any channel's
    rms dB, rms deg or chi2 by more than :data:`UNDO_TOLERANCE`, is undone."""

    stage = (progress or SILENT).stage
    refuse = dict(refuse or {})
    datasets = [Dataset.from_measured(m) for m in measured_raw]

    def measured_error(params):
        h = tuple(fork_map(lambda m: remeasure(params, m), measured_raw))  # the files' simulations at once
        for m, x in zip(measured_raw, h):  # (kept here too when a worker measured them)
            remember_remeasured(params, m, x)
        res = [_residuals(ds, x) for ds, x in zip(datasets, h)]
        return h, res, errors_from_residuals(datasets, res)

    def carry_now(progress=progress):
        return carry_and_recalibrate(measured_raw, measured_fit, before, effects, progress=progress, refuse=refuse)

    def carried_and_measured():
        """carry_and_recalibrate with ``refuse`` as it stands, and the result re-measured (the same as before when nothing is carried)."""
        out = carry_now()
        return out, (measured_before if out[0] is before else measured_error(out[0].params))

    stage("re-measuring the simulator and carrying the effects")
    # the simulator as calibrated is re-measured while the effects are carried and recalibrated (samii.forkmap; the
    # worker that carries reports no stages; nothing carried, it returns ``before`` itself)
    with sharing(before):
        measured_before, first = fork_calls([lambda: measured_error(before.params), lambda: carry_now(progress=None)])
    h_before, res_before, err_before = measured_before
    for m, x in zip(measured_raw, h_before):  # (measured in a worker: kept here for the selection's correction)
        remember_remeasured(before.params, m, x)
    after, options, carried, not_carried = first
    h_after, res_after, err_after = measured_before if after is before else measured_error(after.params)
    not_lowering = []
    if carried:
        stage("testing each carried effect against the simulator's error")
        tested = [e for e in effects if f"{e.category}/{e.kind}" in carried and f"{e.category}/{e.kind}" not in refuse]

        def error_without(e):
            names = carry([e], before.params)[0]
            return measured_error(params_with_overrides(after.params, {n: parameter_value(before.params, n) for n in names}))[2]

        for e, err_without in zip(tested, fork_map(error_without, tested)):  # each taken out, re-measured at once
            label = f"{e.category}/{e.kind}"
            if label in refuse:  # (an effect of the same label refused just before)
                continue
            chans = RESIDUAL_CHANNELS.get(e.channel, CHANNELS)
            with_it, without = _chi2_sum(err_after, chans), _chi2_sum(err_without, chans)
            raised = _worse(err_without, err_after, UNDO_TOLERANCE)  # (a tenth: rises of a few % at the noise are no harm)
            lowers = with_it < (1 - LOWERS) * without
            if not lowers or raised:
                refuse[label] = (
                    f"carried, it does not lower the simulator's error on {' and '.join(CHANNEL_NAMES[c] for c in chans)} "
                    f"(chi2 {without:.4g} without it, {with_it:.4g} with it, the knobs recalibrated with it)"
                    if not lowers
                    else f"carried, it raises the simulator's {', '.join(raised)} (without it -> with it; the knobs recalibrated with it)"
                )
                not_lowering.append(f"{label}: {refuse[label]}")
        if not_lowering:
            (after, options, carried, not_carried), (h_after, res_after, err_after) = carried_and_measured()
        b, a = _chi2_sum(err_before, CHANNELS), _chi2_sum(err_after, CHANNELS)
        traded = _worse(err_before, err_after, UNDO_TOLERANCE)
        if carried and (not a < b or traded):
            why = (
                f"chi2 over every channel {b:.4g} -> {a:.4g}"
                if not a < b
                else f"{', '.join(traded)}, beyond {100 * UNDO_TOLERANCE:g} % (chi2 over every channel {b:.4g} -> {a:.4g})"
            )
            not_lowering += [
                f"{label}: carried with {', '.join(x for x in carried if x != label) or 'nothing else'}, the "
                f"effects raise the simulator's error ({why}): none carried"
                for label in carried
            ]
            not_carried = list(not_carried) + not_lowering[-len(carried) :]
            after, options, carried = before, {}, []
            h_after, res_after, err_after = measured_before
    changes = {}
    for name in sorted(set(after.result.values) | set(options)):
        old = parameter_value(before.params, name)
        new = parameter_value(after.params, name)
        if new != old:
            changes[name] = new
    return SimulatorReport(
        err_before,
        err_after,
        changes,
        tuple(carried),
        tuple(not_carried),
        before,
        after,
        h_before,
        h_after,
        misfit_before=misfits(datasets, res_before),
        misfit_after=misfits(datasets, res_after),
        not_lowering=tuple(not_lowering),
    )
