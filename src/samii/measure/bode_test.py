"""The rig's Bode test, run in the simulator and written to a folder: what ``samii measure`` does, as a library call.

:func:`run_bode_test` checks the request against the model (the sample rate divides the physics rate, the run is not
too long, the servo loop is stable at the nominal pose), runs the swept and/or stepped sine (:mod:`samii.measure.campaign`),
checks the result against the linearised simulator and the valve's rails, and writes ``timeseries.csv``, ``frf.csv``,
``bode.png`` and ``run.json`` into an all-or-nothing folder (and a Rerun recording when asked). It returns a
:class:`BodeTest`: the measurements, the checks and the warnings as values, which the command prints and the main job
reads. Refusals are :class:`~samii.errors.InputError` (the request) or :class:`~samii.errors.SimulationUnstable` (the
model), worded with the command's option names.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from importlib import metadata

import numpy as np

from samii.errors import InputError, SimulationUnstable
from samii.frequency_response import SUSTAINED_POINTS, max_deviation
from samii.json_output import dumps
from samii.outputs import LaterOutput, OutputFolder, check_output_file, create_parent, shown_path, write_whole, written_beside
from samii.progress import SILENT, Progress, part
from samii.schema import document, record_of
from samii.schema.measurement import MeasurementRecord
from samii.sim.overrides import as_overrides

__all__ = [
    "BodeTestRequest",
    "BodeTest",
    "MeasureWarning",
    "run_bode_test",
    "OUTPUTS",
    "METHOD_LABEL",
    "MAX_SIMULATED_S",
    "MAX_PHYSICS_STEPS",
    "VALVE_RANGE_V",
    "MIN_AMPLITUDE_V",
    "LINEARITY_WARN_DB",
    "RAIL_FRACTION",
]

#: The data files of each method (besides bode.png and run.json).
OUTPUTS = {
    "swept": ("timeseries.csv", "frf.csv"),
    "stepped": ("timeseries.csv", "frf.csv"),
    "both": ("timeseries.csv", "frf.csv", "timeseries_stepped.csv", "frf_stepped.csv"),
}
METHOD_LABEL = {"swept": "swept sine", "stepped": "stepped sine", "both": "swept and stepped sine"}

#: Longest run accepted [s of simulated time]: an hour (3.6 M physics steps, about 0.5 GB of
#: signals in memory); the default swept sine is 253 s, the default stepped sine about 600 s.
MAX_SIMULATED_S = 3600.0
#: Physics steps a measurement takes at most: 3600 s at 36 microseconds, about 10 minutes at the plugin's ~5
#: microseconds a step. The excitation is computed at the physics rate (8 bytes a step): a timestep_s of 1e-7 made a
#: 253 s run grow to 23 GB before the kernel killed it.
MAX_PHYSICS_STEPS = 1e8
#: Valve command range [V] of the servo amplifier (the plugin clamps v to it).
VALVE_RANGE_V = 10.0
#: Smallest excitation accepted [V]: 3 steps of a 16-bit DAQ over +-10 V (0.3 mV each); below it a
#: rig's measurement is quantisation noise (the simulator's would be round-off).
MIN_AMPLITUDE_V = 1e-3
#: Deviation from the linearised simulator [dB] above which the summary warns that the measurement is
#: not small-signal (at the default 0.1 V it is 0.6 dB; at 1 V, 4.3 dB; at 3 V, 9 dB): for a swept sine the
#: sustained deviation of a band (``max_deviation``'s ``sustained_db``), for a stepped sine any point's.
LINEARITY_WARN_DB = 2.0
#: Fraction of the run the valve command may sit on a rail before the run is reported unstable.
RAIL_FRACTION = 0.01


@dataclass(frozen=True)
class BodeTestRequest:
    """What to measure, as ``samii measure``'s options say it (defaults: the rig's swept sine)."""

    method: str = "swept"  #: "swept", "stepped" or "both"
    freqs_hz: tuple[float, ...] | None = None  #: stepped-sine dwells (None: SteppedSine's 17 points)
    amplitude_v: float | None = None  #: None: the excitations' default, 0.1 V
    averages: int = 3  #: swept-sine repetitions
    tail_s: float | None = None  #: rest after each sweep (None: SweptSine's)
    band_hz: tuple[float, float] = (0.1, 40.0)  #: swept-sine band
    sample_rate_hz: float = 1000.0  #: DAQ rate; must divide the physics rate
    noise: bool = False  #: typical lab sensor noise (samii.measure.daq.SensorNoise)
    seed: int = 0  #: of the sensor-noise generator


@dataclass
class BodeTest:
    """A Bode test's results: what the command prints and the main job summarises."""

    request: BodeTestRequest
    results: dict  #: kind ("swept", "stepped") -> samii.measure.campaign.Measurement
    checks: dict  #: kind -> channel -> deviation from the linearised simulator (max_deviation's)
    peaks: dict  #: kind -> peak load pressure [Pa], valve command [V], joint angle [rad]
    coherence_ok: bool  #: whether the main record has coherence (false for one swept-sine record)
    supply_pressure_pa: float
    #: run.json's content, but timing.total_wall_s: measured once the recording is written too (``later``: once the
    #: folder is committed, without the figure and the recording)
    record: MeasurementRecord
    warnings: list[MeasureWarning] = field(default_factory=list)  #: what the command prints after "warning:"
    #: bode.png and the recording, left for the caller to write (``later``); empty: written, in the folder
    later: tuple[LaterOutput, ...] = ()

    @property
    def written(self) -> list[str]:
        """The files written, as the run names them (run.json's outputs)."""
        return list(self.record.outputs)


def _versions() -> dict[str, str]:
    out = {}
    for name in ("samii", "numpy", "scipy", "mujoco", "matplotlib", "rerun-sdk", "control"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def _excitations(req: BodeTestRequest):
    """The excitations ``req`` asks for, checked; raises InputError naming the option."""
    from samii.measure.daq import antialias_cutoff_hz  # (lazy: this module is imported at samii's start-up, that one is not needed there)
    from samii.measure.excitation import SteppedSine, SweptSine  # (lazy: this module is imported at samii's start-up, that one is not needed there)

    lo, hi = req.band_hz
    freqs = None if req.freqs_hz is None else list(req.freqs_hz)
    if freqs is not None and req.method == "swept":
        raise InputError("--freqs-hz sets the stepped-sine dwells: use it with --method stepped or both")
    if freqs is not None and len(set(freqs)) != len(freqs):
        dup = sorted({f for f in freqs if freqs.count(f) > 1})
        raise InputError(f"--freqs-hz: {', '.join(f'{f:g}' for f in dup)} Hz given more than once; expected distinct frequencies")
    amp = {} if req.amplitude_v is None else {"amplitude_v": req.amplitude_v}
    try:
        sweep = SweptSine(start_hz=lo, stop_hz=hi, repetitions=req.averages, **({} if req.tail_s is None else {"tail_s": req.tail_s}), **amp)
        stepped = SteppedSine(**({} if freqs is None else {"freqs_hz": tuple(freqs)}), **amp)
    except ValueError as exc:
        raise InputError(str(exc)) from None
    plan = [("swept", sweep)] if req.method in ("swept", "both") else []
    if req.method in ("stepped", "both"):
        plan.append(("stepped", stepped))
    top = max(hi if kind == "swept" else max(e.freqs_hz) for kind, e in plan)
    cutoff = antialias_cutoff_hz(req.sample_rate_hz)
    if top > cutoff:
        option = "--band-hz" if req.method != "stepped" and hi > cutoff else "--freqs-hz"
        raise InputError(
            f"{option}: {top:g} Hz lies above the DAQ's anti-alias cutoff {cutoff:g} Hz at --sample-rate-hz "
            f"{req.sample_rate_hz:g} (a quarter of it); lower the frequency or raise the sample rate"
        )
    total = sum(e.duration_s for _, e in plan)
    if total > MAX_SIMULATED_S:
        raise InputError(
            f"the run would simulate {total:.4g} s, more than the {MAX_SIMULATED_S:g} s accepted "
            "(check --tail-s, --averages, --band-hz and --freqs-hz: a dwell lasts at least 4 periods)"
        )
    return sweep, stepped, plan


def _check_loop_stable(model) -> None:
    """Refuse a model whose servo loop is unstable at the nominal pose: it would oscillate on its own, not measure."""
    from samii.sim.linearize import (  # (lazy: this module is imported at samii's start-up, that one is not needed there)
        UNSTABLE_RATE_1_S,
        poles_per_s,
    )

    s = poles_per_s(model)
    bad = s[s.real > UNSTABLE_RATE_1_S]
    if bad.size:
        worst = bad[np.argmax(bad.real)]
        how = (
            f"it would oscillate on its own at {abs(worst.imag) / (2 * np.pi):.3g} Hz"
            if abs(worst.imag) > 1e-6
            else "it would drift away from the pose on its own (a real pole: e.g. a beam buckling under its load)"
        )
        raise SimulationUnstable(
            f"the model under its servo loop is unstable at the nominal pose before any excitation: pole at {worst.real:.3g} "
            f"{worst.imag:+.3g}j 1/s, growing {worst.real:.3g} 1/s; {how}, not measure (check the overridden parameters, "
            "e.g. hydraulic.position_gain, beam.length_m)"
        )


def _check_rails(ts, kind: str) -> None:
    on_rail = np.abs(ts.v) >= VALVE_RANGE_V * (1 - 1e-6)
    if on_rail.mean() > RAIL_FRACTION:
        raise SimulationUnstable(
            f"{kind} run: the valve command sat on its +-{VALVE_RANGE_V:g} V rails for {100 * on_rail.mean():.0f} % of the run; "
            "a saturated loop is not a linear measurement (lower --amplitude-v, check the servo gain); nothing written"
        )


@dataclass(frozen=True)
class MeasureWarning:
    """A finding about the measurement that a user should act on, as data: ``code`` says what, ``run`` which run
    ("swept" or "stepped"), ``values`` the numbers behind it (SI); :attr:`text` words it."""

    code: str  #: "pressure_above_supply", "not_small_signal" or "no_coherence"
    run: str
    values: Mapping[str, object] = field(default_factory=dict)

    @property
    def text(self) -> str:
        v = self.values
        if self.code == "pressure_above_supply":
            p_peak, supply = v["peak_pa"], v["supply_pa"]
            return (
                f"{self.run} run: the load pressure reached {p_peak / 1e6:.2f} MPa, {100 * (p_peak / supply - 1):.0f} % above the "
                f"{supply / 1e6:.3g} MPa supply: the motor pumped oil in faster than the partly closed valve returns it "
                "to the supply (no relief valve is modelled; a rig's would clip the pressure). "
                "The response is far from small-signal: lower --amplitude-v"
            )
        if self.code == "not_small_signal":
            where = (
                f"over a band (the median of {SUSTAINED_POINTS} neighbouring coherent points, 0.5-35 Hz; {v['deviation_deg']:.0f} deg)"
                if self.run == "swept"
                else f"(coherent points, 0.5-35 Hz; {v['deviation_deg']:.0f} deg)"
            )
            return (
                f"{self.run} run: {v['channel']} lies {v['deviation_db']:.1f} dB from the linearised simulator {where}: the response at "
                f"{v['amplitude_v']:g} V is far from small-signal (valve and orifice nonlinearity), so this FRF is not the plant's linear "
                "model; lower --amplitude-v to measure that"
            )
        if self.code == "no_coherence":
            return (
                "one swept-sine record cannot estimate coherence (--averages 1): the coherence panels are empty "
                "and the check against the linearised simulator uses every point"
            )
        raise ValueError(f"unknown measurement warning {self.code!r}")


def _warnings(checks, peaks, coh_ok: bool, supply_pa: float, amp: float) -> list[MeasureWarning]:
    out = []
    for kind, pk in peaks.items():
        p_peak = pk["load_pressure_pa"]
        if p_peak is not None and p_peak > supply_pa:
            out.append(MeasureWarning("pressure_above_supply", kind, {"peak_pa": p_peak, "supply_pa": supply_pa}))
    for kind, check in checks.items():
        # a swept sine's dense grid: the deviation of a band (a point whose coherence is high by chance deviated
        # 6.8 dB at 0.1 V with sensor noise, and lowering the amplitude was advised); a stepped sine's every point
        key, key_deg = ("sustained_db", "sustained_deg") if kind == "swept" else ("max_abs_db", "max_abs_deg")
        ch = max(check, key=lambda c: check[c][key], default=None)
        if ch is not None and check[ch][key] > LINEARITY_WARN_DB:
            values = {
                "channel": ch,
                "deviation_db": check[ch][key],
                "deviation_deg": check[ch][key_deg],
                "amplitude_v": amp,
                "limit_db": LINEARITY_WARN_DB,
            }
            out.append(MeasureWarning("not_small_signal", kind, values))
    if "swept" in checks and not coh_ok:
        out.append(MeasureWarning("no_coherence", "swept"))
    return out


def _model_params(model_file, overrides: dict) -> dict | None:
    """The physical parameters run.json records: the embedded model's or a parameter file's with the overrides; None
    for an MJCF file (its physics is in the file)."""
    from samii.sim.model import (  # (lazy: this module is imported at samii's start-up, that one is not needed there)
        default_params,
        params_with_overrides,
        read_params_file,
    )

    try:
        if model_file is None:
            return asdict(params_with_overrides(default_params(), overrides))
        if str(model_file).lower().endswith(".json"):  # a parameter file (samii calibrate): record what it held
            return asdict(params_with_overrides(read_params_file(model_file), overrides))
    except (OSError, ValueError):
        pass
    return None


def run_bode_test(
    out,
    request: BodeTestRequest = BodeTestRequest(),
    *,
    model=None,
    overrides: Sequence[str] | Mapping[str, float] | None = None,
    rerun=None,
    rerun_fps: float | None = None,
    overwrite: bool = False,
    progress: Progress | None = None,
    argv: Sequence[str] = (),
    relative_to=None,
    later: bool = False,
) -> BodeTest:
    """Run the Bode test ``request`` on ``model`` (an MJCF or parameter file; None: the embedded one) with
    ``overrides`` (``--set`` texts or a mapping, read after the request's own checks) and write it into folder ``out`` (all or nothing), with a Rerun recording at ``rerun`` if given.

    ``progress`` (samii.progress.Progress) counts physics steps over the whole test; ``argv`` is recorded in run.json as the
    command that ran it; ``relative_to`` names the written files relative to that folder (the main job's) instead
    of as given. ``later``: bode.png and the recording are not written here but left in the result's ``later``
    (:class:`samii.outputs.LaterOutput`), for the caller to write after the folder is committed (the main job draws
    them beside the next stages' work); run.json names them all the same."""
    from samii.formats import write_frf_csv, write_text  # (lazy: this module is imported at samii's start-up, that one is not needed there)
    from samii.measure.campaign import linearised_frf, measure  # (lazy: this module is imported at samii's start-up, that one is not needed there)
    from samii.measure.daq import SensorNoise  # (lazy: this module is imported at samii's start-up, that one is not needed there)
    from samii.sim.model import load_model  # (lazy: this module is imported at samii's start-up, that one is not needed there)
    from samii.sim.plugin import hydraulic_params  # (lazy: this module is imported at samii's start-up, that one is not needed there)

    t_start = time.perf_counter()
    sweep, stepped, plan = _excitations(request)
    names = list(OUTPUTS[request.method]) + ["bode.png", "run.json"]
    folder = OutputFolder(out, names, overwrite=overwrite)
    rerun_path = check_output_file(rerun, overwrite=overwrite, option="--rerun", beside=folder) if rerun else None

    overrides = as_overrides(overrides)
    model_obj = load_model(model, overrides=overrides or None)
    dt = float(model_obj.opt.timestep)
    physics_hz = 1.0 / dt
    ratio = physics_hz / request.sample_rate_hz
    if abs(ratio - round(ratio)) > 1e-6 or physics_hz < request.sample_rate_hz:
        raise InputError(f"--sample-rate-hz {request.sample_rate_hz:g} must divide the physics rate {physics_hz:g} Hz")
    steps = sum(e.duration_s for _, e in plan) / dt
    if steps > MAX_PHYSICS_STEPS:
        raise InputError(
            f"the run would take {steps:.3g} physics steps of {dt:.3g} s (the model's timestep_s), more than the "
            f"{MAX_PHYSICS_STEPS:.0e} accepted: hours of computing and {8 * steps / 1e9:.3g} GB for each signal held "
            f"at the physics rate; a timestep_s of at least {dt * steps / MAX_PHYSICS_STEPS:.2g} s (the default is "
            "1e-3 s), or a shorter run"
        )
    _check_loop_stable(model_obj)
    noise = SensorNoise() if request.noise else None
    rng = np.random.default_rng(request.seed)
    frame_steps = None
    if rerun_path:
        from samii.viz.recording import frame_steps_for  # (lazy: this module is imported at samii's start-up, that one is not needed there)

        frame_steps = frame_steps_for(model_obj, rerun_fps)

    total_steps = sum(int(round(e.duration_s / dt)) for _, e in plan)
    progress = progress or SILENT
    progress.expect(total_steps)
    # the first measurement's record is timeseries.csv; the stepped one of --method both is timeseries_stepped.csv
    ts_names = {kind: ("timeseries.csv" if i == 0 else f"timeseries_{kind}.csv") for i, (kind, _) in enumerate(plan)}
    results = {}
    # the recording lives outside --out: moved into place once the folder is complete
    with written_beside(rerun_path) as rrd_tmp, folder:
        for kind, excitation in plan:
            results[kind] = measure(
                model_obj,
                excitation,
                sample_rate_hz=request.sample_rate_hz,
                noise=noise,
                rng=rng,
                frame_steps=frame_steps,
                progress=part(progress, int(round(excitation.duration_s / dt))),
                timeseries_path=folder.path(ts_names[kind]),
            )
            _check_rails(results[kind].timeseries, kind)
        sim_wall = sum(r.run.wall_s for r in results.values())
        simulated_s = sum(e.duration_s for _, e in plan)

        main = results.get("swept") or results["stepped"]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            ref_grid = np.geomspace(min(main.frf.freq_hz[0], 0.1), max(main.frf.freq_hz[-1], 40.0), 400)
            reference = linearised_frf(model_obj, ref_grid)
            coh = main.frf.coherence(main.frf.channels[0])
            coh_ok = coh is not None and bool(np.any(np.isfinite(coh)))
            checks = {
                kind: max_deviation(
                    r.frf,
                    linearised_frf(model_obj, r.frf.freq_hz),
                    band_hz=(0.5, 35.0),
                    min_coherence=0.95 if coh_ok or kind == "stepped" else None,
                )
                for kind, r in results.items()
            }
        write_frf_csv(main.frf, folder.path("frf.csv"))
        if request.method == "both":
            write_frf_csv(results["stepped"].frf, folder.path("frf_stepped.csv"))

        amp = (sweep if "swept" in results else stepped).amplitude_v
        model_name = str(model) if model else "embedded model"
        if overrides:
            model_name += " with " + ", ".join(f"{k}={v:g}" for k, v in overrides.items())
        title = f"samii measure: {METHOD_LABEL[request.method]}, {amp:g} V, {'with' if noise else 'no'} sensor noise\n{model_name}"

        def draw(path) -> None:
            from samii.viz.bode_plot import bode_plot  # (lazy: this module is imported at samii's start-up, that one is not needed there)

            bode_plot(
                results.get("swept").frf if "swept" in results else None,
                stepped=results["stepped"].frf if "stepped" in results else None,
                reference=reference,
                reference_label="linearised simulator",
                title=title,
                path=path,
            )

        if later:
            folder.omit("bode.png")  # (an earlier run's is removed at the commit: the caller writes this run's)
        else:
            draw(folder.path("bode.png"))

        hp = hydraulic_params(model_obj)
        peaks = {
            kind: {
                "load_pressure_pa": float(np.max(np.abs(r.timeseries.p_load))) if r.timeseries.p_load is not None else None,
                "valve_command_v": float(np.max(np.abs(r.timeseries.v))),
                "joint_angle_rad": float(np.max(np.abs(r.timeseries.theta))),
            }
            for kind, r in results.items()
        }
        outputs = [shown_path(folder.final(n), relative_to) for n in names] + ([shown_path(rerun_path, relative_to)] if rerun_path else [])
        summary = {
            "command": "samii measure",
            "argv": list(argv),
            "method": request.method,
            "excitation": {kind: e.describe() for kind, e in plan},
            "daq": {
                "sample_rate_hz": request.sample_rate_hz,
                "antialias": main.timeseries.metadata.get("antialias"),
                "sensor_noise": asdict(noise) if noise else None,
                "seed": request.seed,
            },
            "frf": {k: v for k, v in main.frf.metadata.items() if k.startswith("frf_")},
            "model": {
                "file": str(model) if model else "embedded default",
                "overrides": overrides,
                "timestep_s": dt,
                "params": _model_params(model, overrides),
                "hydraulic": {k: v for k, v in asdict(hp).items() if k != "source"},
            },
            "versions": _versions(),
            "timing": {
                "simulated_s": simulated_s,
                "simulation_wall_s": sim_wall,
                "total_wall_s": time.perf_counter() - t_start,
                "real_time_factor": simulated_s / sim_wall if sim_wall > 0 else None,
            },
            "vs_linearised_simulator_0.5_35_hz": checks[plan[0][0]],
            "peaks": peaks[plan[0][0]],
            "outputs": outputs,
        }
        if request.method == "both":
            summary["vs_linearised_simulator_0.5_35_hz_by_method"] = checks
            summary["peaks_by_method"] = peaks
        said = _warnings(checks, peaks, coh_ok, hp.supply_pressure, amp)
        if said:
            summary["warnings"] = [w.text for w in said]
        record = record_of(MeasurementRecord, summary, "samii.measure.bode_test.run_bode_test")
        write_text(folder.path("run.json"), dumps(document(record), indent=2) + "\n")

        def write_rrd(tmp) -> None:
            from samii.viz.recording import (  # (lazy: this module is imported at samii's start-up, that one is not needed there)
                RunRecord,
                recording_failed,
                write_recording,
            )

            runs = [RunRecord(kind, results[kind].timeseries, results[kind].run.frame_t_s, results[kind].run.frame_qpos,
                                  sweep_hz=exc.frequency_hz(results[kind].timeseries.t),
                                  label=f"samii measure: {kind} sine, {exc.amplitude_v:g} V on the valve command, joint 2 under its position loop")
                        for kind, exc in plan]  # fmt: skip
            create_parent(tmp)
            try:
                write_recording(tmp, model_obj, runs, application_id="samii_measure", thin_frames=rerun_fps is None)
            except (RuntimeError, OSError) as exc:  # rerun's writer reports file-system failures as RuntimeError
                raise recording_failed(exc, rerun_path) from None

        if rerun_path is not None and not later:
            write_rrd(rrd_tmp)
    record = replace(record, timing=replace(record.timing, total_wall_s=time.perf_counter() - t_start))
    left: list[LaterOutput] = []
    if later:
        bode_png = folder.final("bode.png")
        left.append(LaterOutput(bode_png, partial(write_whole, bode_png, draw), forks=True))
        if rerun_path is not None:
            left.append(LaterOutput(rerun_path, partial(write_whole, rerun_path, write_rrd), forks=False))
    return BodeTest(
        request=request,
        results=results,
        checks=checks,
        peaks=peaks,
        coherence_ok=coh_ok,
        supply_pressure_pa=hp.supply_pressure,
        record=record,
        warnings=said,
        later=tuple(left),
    )
