"""The main job's summary: what ``summary.json`` holds beside the stages' own files, and the lines a person reads.

:class:`RunSummary` is the file as typed values (:meth:`RunSummary.to_json` writes it, :meth:`RunSummary.from_json`
reads it back, refusing a field of the wrong kind by its name and a newer ``schema_version``, :mod:`samii.schema`).
Shared by the pipeline (:mod:`samii.pipeline`, which writes it) and the report (:mod:`samii.report.page`, which
reads it).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields

from samii.errors import InputError
from samii.schema import SCHEMA_VERSION, schema_version

__all__ = [
    "CONTROLLERS",
    "SCENARIOS",
    "MARKER",
    "RECORDINGS",
    "summary_lines",
    "RunSummary",
    "ModesSummary",
    "BaseMode",
    "MeasurementSummary",
    "FitSummary",
    "DampingSummary",
    "ClosedLoopSummary",
    "DiagnosisSummary",
]

#: (name in the output, samii closedloop --controller, label in the summary) run closed loop; "damping" is designed by the main job.
CONTROLLERS = (
    ("notebook_cancel", "notebook-cancel", "pole cancelling (ch 10)"),
    ("notebook_place", "notebook-place", "pole placement (ch 8)"),
    ("damping", None, "damping controller"),
)
SCENARIOS = ("step", "loper")
#: The Rerun recordings a main job writes beside its stages' folders, and what each shows.
RECORDINGS = {"measure.rrd": "the swept-sine measurement", "closedloop.rrd": "the damping controller's Loper test beside the servo loop alone"}
#: summary.json says it is a main job's: a folder holding one may be replaced by the next main job.
MARKER = "samii run"


class _Reader:
    """Fields of one JSON document, each taken with the kind it must have; a wrong one is an InputError naming the
    file and the field."""

    def __init__(self, where):
        self.where = where

    def fail(self, path: str, value, expected: str):
        shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:40] + "..."
        raise InputError(f"{self.where}: field '{path}' holds {shown}; expected {expected}")

    def obj(self, d, path: str, *, optional: bool = False) -> Mapping | None:
        if d is None and optional:
            return None
        if not isinstance(d, Mapping):
            self.fail(path, d, "an object")
        return d

    def get(self, d: Mapping, key: str, path: str):
        if key not in d:
            raise InputError(f"{self.where}: field '{path}{key}' is missing")
        return d[key]

    def num(self, d: Mapping, key: str, path: str = "", *, optional: bool = False) -> float | None:
        v = d.get(key) if optional else self.get(d, key, path)
        if v is None and optional:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(path + key, v, "a number" + (" or null" if optional else ""))
        return float(v)

    def text(self, d: Mapping, key: str, path: str = "", *, optional: bool = False) -> str | None:
        v = d.get(key) if optional else self.get(d, key, path)
        if v is None and optional:
            return None
        if not isinstance(v, str):
            self.fail(path + key, v, "a string" + (" or null" if optional else ""))
        return v

    def flag(self, d: Mapping, key: str, path: str = "") -> bool:
        v = self.get(d, key, path)
        if not isinstance(v, bool):
            self.fail(path + key, v, "true or false")
        return v

    def texts(self, d: Mapping, key: str, path: str = "") -> tuple[str, ...]:
        v = d.get(key) or []
        if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
            self.fail(path + key, v, "a list of strings")
        return tuple(v)

    def nums(self, d: Mapping, key: str, path: str = "", *, length: int | None = None, optional: bool = False) -> tuple[float, ...] | None:
        v = d.get(key) if optional else self.get(d, key, path)
        if v is None and optional:
            return None
        said = f"a list of {length or 'some'} numbers" + (" or null" if optional else "")
        if not isinstance(v, list) or (length is not None and len(v) != length):
            self.fail(path + key, v, said)
        if any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in v):
            self.fail(path + key, v, said)
        return tuple(float(x) for x in v)

    def numbers(self, d: Mapping, key: str, path: str = "") -> dict[str, float | None]:
        v = self.obj(self.get(d, key, path), path + key)
        for k, x in v.items():
            if x is not None and (isinstance(x, bool) or not isinstance(x, (int, float))):
                self.fail(f"{path}{key}.{k}", x, "a number or null")
        return {k: None if x is None else float(x) for k, x in v.items()}


def _plain(value):
    """``value`` as JSON values: tuples as lists, mappings as dicts (a part's fields as summary.json holds them)."""
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


class _Part:
    """A part of the summary: its fields are summary.json's keys, in order."""

    def to_json(self) -> dict:
        return _plain(asdict(self))


@dataclass(frozen=True)
class BaseMode:
    freq_hz: float
    zeta: float


@dataclass(frozen=True)
class ModesSummary(_Part):
    """The model's base modes (joint 2 held) and servo-loop pair at the nominal pose, from its linearisation."""

    pose_deg: tuple[float, ...]
    base_modes: tuple[BaseMode, ...]
    servo_pair_1_s: tuple[float, float] | None  #: (real part, |imaginary part|) [1/s]; None: no pair at 30-80 rad/s


@dataclass(frozen=True)
class MeasurementSummary(_Part):
    excitation: str
    amplitude_v: float
    sample_rate_hz: float
    simulated_s: float
    sensor_noise: Mapping[str, float] | None  #: rms of each sensor's noise (samii.measure.daq.SensorNoise)


@dataclass(frozen=True)
class FitSummary(_Part):
    """The notebook's 3-mode model fitted to the measurement, beside eq 9.4 (SI: rad/s, theta in rad)."""

    params: Mapping[str, float | None]
    stderr: Mapping[str, float | None]
    eq9_4: Mapping[str, float | None]
    sound: bool
    verdict: str
    concerns: tuple[str, ...]
    caveats: tuple[str, ...]
    undetermined: tuple[str, ...]
    lack_of_fit: Mapping | None  #: fit/fit.json's lack_of_fit (samii.identify.lack_of_fit)
    rms_mag_db: Mapping[str, float | None]
    rms_phase_deg: Mapping[str, float | None]


@dataclass(frozen=True)
class DampingSummary(_Part):
    """The damping design's figures (samii.closedloop.damping.DampingDesign.to_dict's)."""

    gain_v_per_m_s2: float | None
    gain_limit_v_per_m_s2: float | None
    gain_margin_db: float | None
    filter_hz: float | None
    rolloff_hz: float | None  #: None: a design without a mode-3 roll-off


@dataclass(frozen=True)
class ClosedLoopSummary(_Part):
    """A closed-loop run's figures (samii.closedloop.scenario's as_json)."""

    stable: bool
    unstable_mode_hz: float | None
    growth_rate_1_s: float | None
    instability: str | None  #: in words, for an unstable run
    theta: Mapping | None  #: the step response's figures (samii.closedloop.metrics)
    base: Mapping | None  #: the base vibration's figures


@dataclass(frozen=True)
class DiagnosisSummary(_Part):
    verdict: str
    effects: tuple[Mapping, ...]  #: the effects found that a fit does not expect (diagnosis.json's, as written)
    error_before: Mapping  #: channel -> rms_db, rms_deg, chi2 ... (samii.diagnose.residuals.ChannelError)
    error_after: Mapping


def _names(part, skip: tuple[str, ...] = ()) -> tuple[str, ...]:
    return tuple(f.name for f in fields(part) if f.name not in skip)


#: The fit's fields the summary repeats from fit/fit.json, after params, stderr and eq9_4.
FIT_FIELDS = _names(FitSummary, skip=("params", "stderr", "eq9_4"))
#: The damping design's fields the summary repeats.
DAMPING_FIELDS = _names(DampingSummary)
#: A closed-loop run's fields the summary repeats.
CLOSED_LOOP_FIELDS = _names(ClosedLoopSummary)


@dataclass(frozen=True)
class RunSummary:
    """summary.json: the main job's figures, one value per line of its printed summary."""

    seed: int
    model_file: str  #: "embedded default" or the model's path
    overrides: tuple[str, ...]  #: as given, NAME=VALUE
    modes: ModesSummary
    measurement: MeasurementSummary
    fit: FitSummary
    damping_design: DampingSummary
    closed_loop: Mapping[str, ClosedLoopSummary]  #: "<controller>_<scenario>" (CONTROLLERS, SCENARIOS, servo_loop_alone_step)
    diagnosis: DiagnosisSummary
    wall_s: float | None = None
    recordings_mb: Mapping[str, float] = field(default_factory=dict)
    report_error: str | None = None  #: why report.html was not written
    #: The version the file was read as (samii.schema); to_json writes this samii's layout, version SCHEMA_VERSION.
    schema_version: int = SCHEMA_VERSION

    def to_json(self) -> dict:
        doc = {
            "schema_version": SCHEMA_VERSION,
            "written_by": MARKER,
            "seed": self.seed,
            "model": {"file": self.model_file, "overrides": list(self.overrides)},
            "modes": self.modes.to_json(),
            "measurement": self.measurement.to_json(),
            "fit": self.fit.to_json(),
            "damping_design": self.damping_design.to_json(),
            "closed_loop": {k: v.to_json() for k, v in self.closed_loop.items()},
            "diagnosis": self.diagnosis.to_json(),
            "wall_s": self.wall_s,
            "recordings_mb": dict(self.recordings_mb),
        }
        if self.report_error is not None:
            doc["report_error"] = self.report_error
        return doc

    def lines(self, out) -> list[str]:
        """The summary a person reads (:func:`summary_lines`), naming the folder ``out``."""
        return summary_lines(self.to_json(), out)

    @classmethod
    def from_json(cls, doc, where="summary.json") -> RunSummary:
        """The summary in ``doc`` (read from ``where``); InputError naming the field for one of the wrong kind."""
        r = _Reader(where)
        doc = r.obj(doc, "(the document)")
        version = schema_version(doc, where)
        if doc.get("written_by") != MARKER:
            raise InputError(f"{where}: field 'written_by' is {doc.get('written_by')!r}, expected {MARKER!r}")
        model = r.obj(r.get(doc, "model", ""), "model")
        modes = r.obj(r.get(doc, "modes", ""), "modes")
        base_modes = r.get(modes, "base_modes", "modes.")
        if not isinstance(base_modes, list):
            r.fail("modes.base_modes", base_modes, "a list")
        meas = r.obj(r.get(doc, "measurement", ""), "measurement")
        fit = r.obj(r.get(doc, "fit", ""), "fit")
        design = r.obj(r.get(doc, "damping_design", ""), "damping_design")
        loops = r.obj(r.get(doc, "closed_loop", ""), "closed_loop")
        diag = r.obj(r.get(doc, "diagnosis", ""), "diagnosis")
        effects = diag.get("effects") or []
        if not isinstance(effects, list) or not all(isinstance(e, Mapping) for e in effects):
            r.fail("diagnosis.effects", effects, "a list of objects")
        rec = r.obj(doc.get("recordings_mb") or {}, "recordings_mb")
        seed = doc.get("seed")
        if isinstance(seed, bool) or not isinstance(seed, int):
            r.fail("seed", seed, "a whole number")

        def loop(name: str, d) -> ClosedLoopSummary:
            p = f"closed_loop.{name}."
            d = r.obj(d, p[:-1])
            return ClosedLoopSummary(
                stable=r.flag(d, "stable", p),
                unstable_mode_hz=r.num(d, "unstable_mode_hz", p, optional=True),
                growth_rate_1_s=r.num(d, "growth_rate_1_s", p, optional=True),
                instability=r.text(d, "instability", p, optional=True),
                theta=r.obj(d.get("theta"), p + "theta", optional=True),
                base=r.obj(d.get("base"), p + "base", optional=True),
            )

        return cls(
            seed=seed,
            model_file=r.text(model, "file", "model."),
            overrides=r.texts(model, "overrides", "model."),
            modes=ModesSummary(
                pose_deg=r.nums(modes, "pose_deg", "modes."),
                base_modes=tuple(
                    BaseMode(
                        r.num(r.obj(b, f"modes.base_modes[{i}]"), "freq_hz", f"modes.base_modes[{i}]."), r.num(b, "zeta", f"modes.base_modes[{i}].")
                    )
                    for i, b in enumerate(base_modes)
                ),
                servo_pair_1_s=r.nums(modes, "servo_pair_1_s", "modes.", length=2, optional=True),
            ),
            measurement=MeasurementSummary(
                excitation=r.text(meas, "excitation", "measurement."),
                amplitude_v=r.num(meas, "amplitude_v", "measurement."),
                sample_rate_hz=r.num(meas, "sample_rate_hz", "measurement."),
                simulated_s=r.num(meas, "simulated_s", "measurement."),
                sensor_noise=r.obj(meas.get("sensor_noise"), "measurement.sensor_noise", optional=True),
            ),
            fit=FitSummary(
                params=r.numbers(fit, "params", "fit."),
                stderr=r.numbers(fit, "stderr", "fit."),
                eq9_4=r.numbers(fit, "eq9_4", "fit."),
                sound=r.flag(fit, "sound", "fit."),
                verdict=r.text(fit, "verdict", "fit."),
                concerns=r.texts(fit, "concerns", "fit."),
                caveats=r.texts(fit, "caveats", "fit."),
                undetermined=r.texts(fit, "undetermined", "fit."),
                lack_of_fit=r.obj(fit.get("lack_of_fit"), "fit.lack_of_fit", optional=True),
                rms_mag_db=r.numbers(fit, "rms_mag_db", "fit."),
                rms_phase_deg=r.numbers(fit, "rms_phase_deg", "fit."),
            ),
            damping_design=DampingSummary(**{k: r.num(design, k, "damping_design.", optional=True) for k in DAMPING_FIELDS}),
            closed_loop={name: loop(name, d) for name, d in loops.items()},
            diagnosis=DiagnosisSummary(
                verdict=r.text(diag, "verdict", "diagnosis."),
                effects=tuple(effects),
                error_before=r.obj(r.get(diag, "error_before", "diagnosis."), "diagnosis.error_before"),
                error_after=r.obj(r.get(diag, "error_after", "diagnosis."), "diagnosis.error_after"),
            ),
            wall_s=r.num(doc, "wall_s", "", optional=True),
            recordings_mb={k: r.num(rec, k, "recordings_mb.") for k in rec},
            report_error=r.text(doc, "report_error", "", optional=True),
            schema_version=version,
        )


def summary_lines(s: dict, out) -> list[str]:
    """The summary a person reads: at most 20 lines."""
    import numpy as np

    m = s["modes"]
    lines = [
        "SAMII main job: "
        + ("embedded model" if s["model"]["file"] == "embedded default" else s["model"]["file"])
        + (f" with {', '.join(s['model']['overrides'])}" if s["model"]["overrides"] else "")
    ]
    lines.append(
        "base modes (joint 2 held): "
        + ", ".join(f"{b['freq_hz']:.2f} Hz (zeta {b['zeta']:.3f})" for b in m["base_modes"])
        + (f"; servo-loop pair {m['servo_pair_1_s'][0]:.1f} ± {m['servo_pair_1_s'][1]:.1f}j 1/s" if m["servo_pair_1_s"] else "")
    )
    me = s["measurement"]
    lines.append(
        f"measured: {me['excitation']}, {me['amplitude_v']:g} V on the valve command, {me['simulated_s']:.0f} s at "
        f"{me['sample_rate_hz']:g} samples/s, sensor noise (seed {s['seed']})"
    )
    f = s["fit"]["params"]
    eq = s["fit"]["eq9_4"]

    def hz(w):
        return w / (2 * np.pi)

    from samii.identify.report import verdict_text

    lines.append(f"fit of the notebook's 3-mode model beside eq 9.4: {verdict_text(s['fit'])} (fit/fit.json):")
    lines.append(
        f"  modes {hz(f['w1']):.2f} / {hz(f['wz']):.2f} / {hz(f['w3']):.2f} Hz (eq 9.4: {hz(eq['w1']):.2f} / {hz(eq['wz']):.2f} / "
        f"{hz(eq['w3']):.2f}); zeta {f['z1']:.3f} / {f['zz']:.3f} / {f['z3']:.3f} ({eq['z1']:.3f} / {eq['zz']:.3f} / {eq['z3']:.3f})"
    )
    lines.append(
        f"  actuator pair {hz(f['wp']):.2f} Hz zeta {f['zp']:.3f} (eq 9.4: {hz(eq['wp']):.2f} Hz, {eq['zp']:.3f}); "
        f"B2/B1 {f['B2'] / f['B1']:.3f} ({eq['B2'] / eq['B1']:.3f}), B3/B1 {f['B3'] / f['B1']:.3f} ({eq['B3'] / eq['B1']:.3f})"
    )
    cl = s["closed_loop"]
    lines.append("closed loop in the nonlinear simulator (step 5 deg; Loper: switched on at 2 s):")
    for name, _, label in CONTROLLERS:
        st, lo = cl[f"{name}_step"], cl[f"{name}_loper"]
        if not st["stable"] or not lo["stable"]:
            bad = st if not st["stable"] else lo
            if bad.get("instability"):
                grow, hz_ = bad["instability"], ""
            else:
                grow = f"growing at {bad['growth_rate_1_s']:.3g} 1/s" if bad.get("growth_rate_1_s") else "diverging"
                hz_ = f" at {bad['unstable_mode_hz']:.3g} Hz" if bad.get("unstable_mode_hz") else ""
            what = f"UNSTABLE ({grow}{hz_}; the run is in closedloop/{name}_{'step' if bad is st else 'loper'}/)"
        else:
            what = (
                f"stable; step: theta settles {st['theta']['settle_s']:.2f} s, base {st['base']['settle_s']:.2f} s; "
                f"Loper: base decays at {lo['base']['decay_rate_1_s']:.2f} 1/s"
            )
        lines.append(f"  {label:<24} {what}")
    dl, ds, alone = cl["damping_loper"], cl["damping_step"], cl["servo_loop_alone_step"]
    over = [(r.get("theta") or {}).get("overshoot_pct") for r in (ds, alone)]  # what damping the base costs the joint
    if dl["stable"] and ds["stable"] and dl["base"].get("free_decay_rate_1_s"):
        lines.append(
            f"damping controller: the base settles {alone['base']['settle_s'] / ds['base']['settle_s']:.1f}x sooner after the step "
            f"({ds['base']['settle_s']:.2f} s against {alone['base']['settle_s']:.2f} s under the servo loop alone); in the Loper test "
            f"its vibration decays {dl['base']['decay_rate_1_s'] / dl['base']['free_decay_rate_1_s']:.1f}x faster than free"
            + ("" if None in over else f"; theta overshoots the step by {over[0]:.0f} % ({over[1]:.0f} % alone)")
        )
    dg = s["diagnosis"]
    eff = ", ".join(f"{e['category']}/{e['kind']}" for e in dg["effects"]) or "nothing"
    lines.append(f"diagnosis of the fit against the measured record: {dg['verdict']}; found {eff}")

    def num(d: dict, key: str) -> float:  # (a figure may be null: chi2 with no noise estimate)
        v = d.get(key)
        return float("nan") if v is None else float(v)

    for ch, name, note in (("act", "theta/v", " (chi2 1: the noise)"), ("total", "xdd/v", "")):
        b, a = dg["error_before"].get(ch, {}), dg["error_after"].get(ch, {})
        if b and a:
            lines.append(
                f"  {name} error {num(b, 'rms_db'):.2g} dB / {num(b, 'rms_deg'):.2g} deg, chi2 {num(b, 'chi2'):.3g} -> "
                f"{num(a, 'rms_db'):.2g} dB / {num(a, 'rms_deg'):.2g} deg, chi2 {num(a, 'chi2'):.3g} with them{note}"
            )
    report = "report.html (open it in a browser), " if not s.get("report_error") else "(NOT report.html: see the warning above) "
    rrd = " and ".join(f"{n} ({s['recordings_mb'][n]:.0f} MB)" if (s.get("recordings_mb") or {}).get(n) is not None else n for n in RECORDINGS)
    lines.append(
        f"wrote {out}/ in {s['wall_s']:.0f} s: {report}summary.json, measure/, fit/, controllers/, "
        f"closedloop/, diagnose/; {rrd} (open with `rerun FILE`)"
    )
    return lines[:20]
