"""``summary.json``, the main job's summary, as typed values: :class:`RunSummary` (:meth:`RunSummary.to_json` writes
it, :meth:`RunSummary.from_json` reads it back, refusing a field of the wrong kind by its name and a newer
``schema_version``, :mod:`samii.schema`). Written by :mod:`samii.pipeline`; read by the report
(:mod:`samii.report.page`) and the summary's lines (:mod:`samii.run_summary`). SI units but where a field says."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields

from samii.errors import InputError
from samii.schema import SCHEMA_VERSION, schema_version
from samii.schema.closed_loop import BaseFigures, ThetaFigures
from samii.schema.diagnosis import ChannelErrorRecord, EffectRecord
from samii.schema.typed import EMPTY, as_json, read_as

__all__ = [
    "MARKER",
    "RunSummary",
    "ModesSummary",
    "BaseMode",
    "MeasurementSummary",
    "FitSummary",
    "DampingSummary",
    "ClosedLoopSummary",
    "DiagnosisSummary",
    "FIT_FIELDS",
    "DAMPING_FIELDS",
    "CLOSED_LOOP_FIELDS",
]

#: summary.json says it is a main job's: a folder holding one may be replaced by the next main job.
MARKER = "samii run"


class _Part:
    """A part of the summary: its fields are summary.json's keys, in order."""

    def to_json(self) -> dict:
        return as_json(self)


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
    concerns: tuple[str, ...] = field(metadata=EMPTY)
    caveats: tuple[str, ...] = field(metadata=EMPTY)
    undetermined: tuple[str, ...] = field(metadata=EMPTY)
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
    theta: ThetaFigures | None  #: the step response's figures (samii.closedloop.metrics)
    base: BaseFigures | None  #: the base vibration's figures


@dataclass(frozen=True)
class DiagnosisSummary(_Part):
    verdict: str
    effects: tuple[EffectRecord, ...] = field(metadata=EMPTY)  #: the effects found that a fit does not expect (diagnosis.json's)
    error_before: Mapping[str, ChannelErrorRecord]  #: channel -> the baseline's error (diagnosis.json's)
    error_after: Mapping[str, ChannelErrorRecord]


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

    @classmethod
    def from_json(cls, doc, where="summary.json") -> RunSummary:
        """The summary in ``doc`` (read from ``where``); InputError naming the field for one missing or of the wrong
        kind (each part read into its fields' types)."""
        doc = read_as(Mapping, doc, where)
        version = schema_version(doc, where)
        if doc.get("written_by") != MARKER:
            raise InputError(f"{where}: field 'written_by' is {doc.get('written_by')!r}, expected {MARKER!r}")

        def get(key: str, tp, within: str | None = None):
            d, at = doc, key
            if within is not None:
                if within not in doc:
                    raise InputError(f"{where}: field '{within}' is missing")
                d, at = read_as(Mapping, doc[within], where), f"{within}.{key}"
            if key not in d:
                raise InputError(f"{where}: field '{at}' is missing")
            return read_as(tp, d[key], where, at=at)

        fit, diagnosis = get("fit", FitSummary), get("diagnosis", DiagnosisSummary)
        # (kept as written, the part the lines read checked: the misfit bands)
        if fit.lack_of_fit is not None and fit.lack_of_fit.get("bands") is not None:
            read_as(tuple[_Band, ...], fit.lack_of_fit["bands"], where, at="fit.lack_of_fit.bands")
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
            wall_s=read_as(float | None, doc.get("wall_s"), where, at="wall_s"),
            recordings_mb=read_as(Mapping[str, float], doc.get("recordings_mb") or {}, where, at="recordings_mb"),
            report_error=read_as(str | None, doc.get("report_error"), where, at="report_error"),
            schema_version=version,
        )
