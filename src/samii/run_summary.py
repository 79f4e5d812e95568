"""The main job's summary: what ``summary.json`` holds beside the stages' own files, and the lines a person reads.

:class:`RunSummary` is the file as typed values (:meth:`RunSummary.to_json` writes it, :meth:`RunSummary.from_json`
reads it back, refusing a field of the wrong kind by its name and a newer ``schema_version``, :mod:`samii.schema`).
Shared by the pipeline (:mod:`samii.pipeline`, which writes it) and the report (:mod:`samii.report.page`, which
reads it).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import MISSING, asdict, dataclass, field, fields, is_dataclass
from types import UnionType
from typing import Union, get_args, get_origin, get_type_hints

import numpy as np

from samii.errors import InputError
from samii.identify.report import verdict_text
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
    """A JSON document read into the types of a dataclass's fields (``float``, ``int``, ``bool``, ``str``, ``X | None``,
    ``tuple[X, ...]``, ``tuple[X, Y]``, ``Mapping[str, X]``, a bare ``Mapping``, another dataclass); a value of the wrong
    kind is an InputError naming the file and the field. Numbers are kept as read (a whole number stays one).

    A field absent is refused, but for one with a default or one that admits null (read as null: a field added since a
    folder was written, as the closed-loop runs' ``instability``), and a list of strings or of objects (the fit's
    concerns, the diagnosis's effects), absent or null, which reads as none (as the first readers took them)."""

    def __init__(self, where):
        self.where = where

    def fail(self, path: str, value, expected: str):
        shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:40] + "..."
        raise InputError(f"{self.where}: field '{path}' holds {shown}; expected {expected}")

    def missing(self, path: str):
        raise InputError(f"{self.where}: field '{path}' is missing")

    def part(self, cls, d, path: str = ""):
        """An instance of dataclass ``cls`` from the object ``d`` at ``path``."""
        d = self.read(Mapping, d, path or "(the document)")
        hints = get_type_hints(cls)
        values = {}
        for f in fields(cls):
            where = f"{path}.{f.name}" if path else f.name
            if f.name in d:
                values[f.name] = self.read(hints[f.name], d[f.name], where)
            elif hints[f.name] in _NONE_IS_EMPTY:
                values[f.name] = ()
            elif _admits_none(hints[f.name]) and f.default is MISSING and f.default_factory is MISSING:
                values[f.name] = None
            elif f.default is MISSING and f.default_factory is MISSING:
                self.missing(where)
        return cls(**values)

    def read(self, tp, v, path: str, *, or_null: bool = False):
        """``v`` read as type ``tp`` at ``path`` (``or_null``: said to admit null, in a message)."""
        null = " or null" if or_null else ""
        if _admits_none(tp):
            return None if v is None else self.read(_without_none(tp), v, path, or_null=True)
        if tp in _NONE_IS_EMPTY and v is None:
            return ()
        origin, args = get_origin(tp) or tp, get_args(tp)
        if tp in _PLAIN:
            if not _is(v, tp):
                self.fail(path, v, _PLAIN[tp][0] + null)
        elif is_dataclass(tp):
            return self.part(tp, v, path)
        elif origin is tuple:
            each = args[0] if len(args) == 2 and args[1] is Ellipsis else None
            kinds = [each] * len(v) if each and isinstance(v, list) else list(args)
            if each:
                said = "a list of " + ("some numbers" if each is float else _PLAIN[each][1] if each in _PLAIN else "objects")
            elif len(set(args)) == 1 and args[0] in _PLAIN:
                said = f"a list of {len(args)} {_PLAIN[args[0]][1]}"
            else:
                said = f"a list of {len(args)} values"
            if not isinstance(v, list) or len(v) != len(kinds):
                self.fail(path, v, said + null)
            if not all(_is(x, k) for x, k in zip(v, kinds) if k in _PLAIN):  # (a list of plain values shown whole)
                self.fail(path, v, said + null)
            return tuple(self.read(k, x, f"{path}[{i}]") for i, (x, k) in enumerate(zip(v, kinds)))
        elif origin is Mapping:
            if not isinstance(v, Mapping):
                self.fail(path, v, "an object" + null)
            if args:
                return {k: self.read(args[1], x, f"{path}.{k}") for k, x in v.items()}
        else:  # (a type this reader was not taught: a programming error, not the file's)
            raise TypeError(f"_Reader cannot read {tp!r}")
        return v


#: Lists that read as none when absent or null.
_NONE_IS_EMPTY = (tuple[str, ...], tuple[Mapping, ...])

#: The plain kinds a field can have: (one said, several said).
_PLAIN = {
    float: ("a number", "numbers"),
    int: ("a whole number", "whole numbers"),
    bool: ("true or false", "true or false values"),
    str: ("a string", "strings"),
}


def _admits_none(tp) -> bool:
    return get_origin(tp) in (Union, UnionType) and type(None) in get_args(tp)


def _without_none(tp):
    inner = [a for a in get_args(tp) if a is not type(None)]
    if len(inner) != 1:  # (a programming error: the reader says which kind it expects, one)
        raise TypeError(f"_Reader reads X | None, not {tp!r}")
    return inner[0]


def _is(x, kind) -> bool:
    if kind is float:
        return not isinstance(x, bool) and isinstance(x, (int, float))
    if kind is int:
        return not isinstance(x, bool) and isinstance(x, int)
    return isinstance(x, kind)


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
    sensor_noise: Mapping[str, float | None] | None  #: rms of each sensor's noise (samii.measure.daq.SensorNoise)


@dataclass(frozen=True)
class _Effect:
    """What the summary's lines read of a found effect (diagnosis.json's, kept as written): checked when read."""

    category: str
    kind: str


@dataclass(frozen=True)
class _Band:
    """What the summary's lines read of a band of fit/fit.json's lack_of_fit (samii.identify.lack_of_fit.MisfitBand):
    checked when read, the band kept as written."""

    channel: str
    f_lo_hz: float
    f_hi_hz: float


@dataclass(frozen=True)
class FitSummary(_Part):
    """The notebook's 3-mode model fitted to the measurement, beside eq 9.4 (SI: rad/s, theta in rad)."""

    params: Mapping[str, float | None]  #: None: not fitted (the data lack its channel)
    stderr: Mapping[str, float | None]  #: None: not determined by the data (an infinite standard error)
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
    theta: Mapping[str, float | None] | None  #: the step response's figures (samii.closedloop.metrics)
    base: Mapping[str, float | None] | None  #: the base vibration's figures


@dataclass(frozen=True)
class DiagnosisSummary(_Part):
    verdict: str
    effects: tuple[Mapping, ...]  #: the effects found that a fit does not expect (diagnosis.json's, as written)
    error_before: Mapping[str, Mapping[str, float | None]]  #: channel -> rms_db, rms_deg, chi2 ... (samii.diagnose.residuals.ChannelError)
    error_after: Mapping[str, Mapping[str, float | None]]


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
        return summary_lines(self, out)

    @classmethod
    def from_json(cls, doc, where="summary.json") -> RunSummary:
        """The summary in ``doc`` (read from ``where``); InputError naming the field for one missing or of the wrong
        kind (each part read into its fields' types)."""
        r = _Reader(where)
        doc = r.read(Mapping, doc, "(the document)")
        version = schema_version(doc, where)
        if doc.get("written_by") != MARKER:
            raise InputError(f"{where}: field 'written_by' is {doc.get('written_by')!r}, expected {MARKER!r}")

        def get(key: str, tp, within: str | None = None):
            d, where = doc, key
            if within is not None:
                if within not in doc:
                    r.missing(within)
                d, where = r.read(Mapping, doc[within], within), f"{within}.{key}"
            if key not in d:
                r.missing(where)
            return r.read(tp, d[key], where)

        fit, diagnosis = get("fit", FitSummary), get("diagnosis", DiagnosisSummary)
        # (kept as written, the parts the lines read checked: the misfit bands, each effect's category and kind)
        if fit.lack_of_fit is not None and fit.lack_of_fit.get("bands") is not None:
            r.read(tuple[_Band, ...], fit.lack_of_fit["bands"], "fit.lack_of_fit.bands")
        r.read(tuple[_Effect, ...], list(diagnosis.effects), "diagnosis.effects")
        return cls(
            seed=get("seed", int),
            model_file=get("file", str, "model"),
            overrides=get("overrides", tuple[str, ...], "model"),
            modes=get("modes", ModesSummary),
            measurement=get("measurement", MeasurementSummary),
            fit=fit,
            damping_design=get("damping_design", DampingSummary),
            closed_loop=get("closed_loop", Mapping[str, ClosedLoopSummary]),
            diagnosis=diagnosis,
            wall_s=r.read(float | None, doc.get("wall_s"), "wall_s"),
            recordings_mb=r.read(Mapping[str, float], doc.get("recordings_mb") or {}, "recordings_mb"),
            report_error=r.read(str | None, doc.get("report_error"), "report_error"),
            schema_version=version,
        )


def _f(x, spec: str) -> str:
    """``x`` formatted, "n/a" for None (a figure a run does not have: the settling time of a joint that did not follow
    its step)."""
    return "n/a" if x is None else format(x, spec)


def summary_lines(s: RunSummary, out) -> list[str]:
    """The summary a person reads: at most 20 lines."""

    m = s.modes
    lines = [
        "SAMII main job: "
        + ("embedded model" if s.model_file == "embedded default" else s.model_file)
        + (f" with {', '.join(s.overrides)}" if s.overrides else "")
    ]
    lines.append(
        "base modes (joint 2 held): "
        + ", ".join(f"{b.freq_hz:.2f} Hz (zeta {b.zeta:.3f})" for b in m.base_modes)
        + (f"; servo-loop pair {m.servo_pair_1_s[0]:.1f} ± {m.servo_pair_1_s[1]:.1f}j 1/s" if m.servo_pair_1_s else "")
    )
    me = s.measurement
    lines.append(
        f"measured: {me.excitation}, {me.amplitude_v:g} V on the valve command, {me.simulated_s:.0f} s at "
        f"{me.sample_rate_hz:g} samples/s, sensor noise (seed {s.seed})"
    )
    f, eq = s.fit.params, s.fit.eq9_4

    def hz(d: Mapping, name: str) -> str:  # a frequency [rad/s] in Hz; n/a for a parameter not fitted
        w = d.get(name)
        return _f(None if w is None else w / (2 * np.pi), ".2f")

    def zeta(d: Mapping, name: str) -> str:
        return _f(d.get(name), ".3f")

    def ratio(d: Mapping, a: str, b: str) -> str:
        x, y = d.get(a), d.get(b)
        return _f(None if x is None or not y else x / y, ".3f")

    lines.append(f"fit of the notebook's 3-mode model beside eq 9.4: {verdict_text(s.fit.to_json())} (fit/fit.json):")
    lines.append(
        f"  modes {hz(f, 'w1')} / {hz(f, 'wz')} / {hz(f, 'w3')} Hz (eq 9.4: {hz(eq, 'w1')} / {hz(eq, 'wz')} / {hz(eq, 'w3')}); "
        f"zeta {zeta(f, 'z1')} / {zeta(f, 'zz')} / {zeta(f, 'z3')} ({zeta(eq, 'z1')} / {zeta(eq, 'zz')} / {zeta(eq, 'z3')})"
    )
    lines.append(
        f"  actuator pair {hz(f, 'wp')} Hz zeta {zeta(f, 'zp')} (eq 9.4: {hz(eq, 'wp')} Hz, {zeta(eq, 'zp')}); "
        f"B2/B1 {ratio(f, 'B2', 'B1')} ({ratio(eq, 'B2', 'B1')}), B3/B1 {ratio(f, 'B3', 'B1')} ({ratio(eq, 'B3', 'B1')})"
    )
    cl = s.closed_loop
    lines.append("closed loop in the nonlinear simulator (step 5 deg; Loper: switched on at 2 s):")
    for name, _, label in CONTROLLERS:
        st, lo = cl[f"{name}_step"], cl[f"{name}_loper"]
        if not st.stable or not lo.stable:
            bad = st if not st.stable else lo
            if bad.instability:
                grow, hz_ = bad.instability, ""
            else:
                grow = f"growing at {bad.growth_rate_1_s:.3g} 1/s" if bad.growth_rate_1_s else "diverging"
                hz_ = f" at {bad.unstable_mode_hz:.3g} Hz" if bad.unstable_mode_hz else ""
            what = f"UNSTABLE ({grow}{hz_}; the run is in closedloop/{name}_{'step' if bad is st else 'loper'}/)"
        else:
            th, ba, lb = st.theta or {}, st.base or {}, lo.base or {}
            what = (
                f"stable; step: theta settles {_f(th.get('settle_s'), '.2f')} s, base {_f(ba.get('settle_s'), '.2f')} s; "
                f"Loper: base decays at {_f(lb.get('decay_rate_1_s'), '.2f')} 1/s"
            )
        lines.append(f"  {label:<24} {what}")
    dl, ds, alone = cl["damping_loper"], cl["damping_step"], cl["servo_loop_alone_step"]
    over = [(r.theta or {}).get("overshoot_pct") for r in (ds, alone)]  # what damping the base costs the joint
    (t_alone, t_damped), (rate, free) = ([(r.base or {}).get("settle_s") for r in (alone, ds)],
                                         [(dl.base or {}).get(k) for k in ("decay_rate_1_s", "free_decay_rate_1_s")])  # fmt: skip
    if dl.stable and ds.stable and None not in (t_alone, rate) and t_damped and free:  # (ratios of figures each run has)
        lines.append(
            f"damping controller: the base settles {t_alone / t_damped:.1f}x sooner after the step "
            f"({t_damped:.2f} s against {t_alone:.2f} s under the servo loop alone); in the Loper test "
            f"its vibration decays {rate / free:.1f}x faster than free"
            + ("" if None in over else f"; theta overshoots the step by {over[0]:.0f} % ({over[1]:.0f} % alone)")
        )
    dg = s.diagnosis
    eff = ", ".join(f"{e['category']}/{e['kind']}" for e in dg.effects) or "nothing"
    lines.append(f"diagnosis of the fit against the measured record: {dg.verdict}; found {eff}")

    def num(d: Mapping, key: str) -> float:  # (a figure may be null: chi2 with no noise estimate)
        v = d.get(key)
        return float("nan") if v is None else float(v)

    for ch, name, note in (("act", "theta/v", " (chi2 1: the noise)"), ("total", "xdd/v", "")):
        b, a = dg.error_before.get(ch, {}), dg.error_after.get(ch, {})
        if b and a:
            lines.append(
                f"  {name} error {num(b, 'rms_db'):.2g} dB / {num(b, 'rms_deg'):.2g} deg, chi2 {num(b, 'chi2'):.3g} -> "
                f"{num(a, 'rms_db'):.2g} dB / {num(a, 'rms_deg'):.2g} deg, chi2 {num(a, 'chi2'):.3g} with them{note}"
            )
    report = "report.html (open it in a browser), " if not s.report_error else "(NOT report.html: see the warning above) "
    rrd = " and ".join(f"{n} ({s.recordings_mb[n]:.0f} MB)" if s.recordings_mb.get(n) is not None else n for n in RECORDINGS)
    lines.append(
        f"wrote {out}/ in {_f(s.wall_s, '.0f')} s: {report}summary.json, measure/, fit/, controllers/, "
        f"closedloop/, diagnose/; {rrd} (open with `rerun FILE`)"
    )
    return lines[:20]
