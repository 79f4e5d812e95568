"""``diagnosis.json`` (``samii diagnose --out``, the main job's ``diagnose/``): what a model lacks, found in measured
data. Written by :func:`samii.diagnose.files.diagnose_files` from :meth:`samii.diagnose.diagnosis.Diagnosis.to_dict`.
The findings and the errors are typed (what a report reads); the records of how the diagnosis went (each file's
layout, the selection's steps, the nonlinear tests, the simulator's second round) are kept as written, objects whose
keys are those of the analyses (samii.diagnose).

A parameter's value or standard error is null where the data do not determine it."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from samii.schema.typed import key

__all__ = ["EffectRecord", "ChannelErrorRecord", "BandRecord", "RefusalRecord", "HarmonicErrorRecord", "HarmonicErrors", "DiagnosisRecord"]


@dataclass(frozen=True)
class EffectRecord:
    """An effect found (samii.diagnose.diagnosis.FoundEffect): the sentence ``evidence`` is rendered from the figures
    beside it."""

    category: str
    kind: str
    channel: str  #: "act", "base", "total" or "all"
    params: Mapping[str, float | None]
    stderr: Mapping[str, float | None]
    evidence: str
    # (the defaults: fields a diagnosis.json of samii 0.1.0 may lack, as samii.diagnose.diagnosis.FoundEffect's)
    expected: bool = False  #: the sampling itself, not a miss of the model
    joined: Mapping | None = None  #: the test that admitted it (samii.diagnose.evidence.Joined)
    rivals: tuple[Mapping, ...] = ()  #: readings that fit almost as well (samii.diagnose.evidence.Rival)
    sample_s: float | None = None
    beside_nonlinearity: bool = False
    nonlinear: Mapping | None = None  #: a nonlinear effect's evidence (samii.diagnose.nonlinear.NonlinearEvidence)


@dataclass(frozen=True)
class ChannelErrorRecord:
    """A channel's residual over the usable points of every file (samii.diagnose.residuals.ChannelError)."""

    rms_db: float | None
    rms_deg: float | None
    chi2: float | None  #: per real residual, 1 at the noise; None: no noise estimate
    n_points: int


@dataclass(frozen=True)
class BandRecord:
    """A band where a significant residual remains (samii.diagnose.residuals.Band)."""

    source: str
    channel: str
    lo_hz: float
    hi_hz: float
    chi2: float | None
    n_points: int
    why: str  #: "residual", or why the records differ there


@dataclass(frozen=True)
class RefusalRecord:
    """A candidate that passed the F-test and was refused (samii.diagnose.evidence.Refusal)."""

    round: int | str  #: the selection's round, or "final" (the final check of each effect, samii.diagnose.select)
    effect: str
    params: Mapping[str, float | None]
    reason: str  #: in words
    cls: str = field(metadata=key("class"))  #: the reason's class, in words
    # (the defaults: fields a diagnosis.json of samii 0.1.0 may lack)
    code: str | None = None  #: samii.diagnose.evidence.REFUSALS's; None: a file written before refusals had codes
    values: Mapping = field(default_factory=dict)  #: the figures the reason is rendered from
    log10_p: float | None = None


@dataclass(frozen=True)
class HarmonicErrorRecord:
    rms_ratio: float | None
    chi2: float | None
    n_segments: int


@dataclass(frozen=True)
class HarmonicErrors:
    """The sweep's harmonics' error before (a linear model) and after the nonlinear laws found."""

    before: HarmonicErrorRecord
    after: HarmonicErrorRecord


@dataclass(frozen=True)
class DiagnosisRecord:
    """``diagnosis.json``."""

    verdict: str  #: "effects" (one a fit does not expect was found) or "none"
    effects: tuple[EffectRecord, ...]
    error_before: Mapping[str, ChannelErrorRecord]  #: channel -> the baseline's error
    error_after: Mapping[str, ChannelErrorRecord]  #: channel -> the error with the effects
    simulator: Mapping | None  #: --baseline sim: the effects carried into the simulator (samii.diagnose.simulator)
    harmonic_error: HarmonicErrors | None
    unexplained: tuple[BandRecord, ...]
    refused: tuple[RefusalRecord, ...]
    floor: tuple[Mapping, ...]  #: each file's systematic floor (samii.measure.floor)
    baseline: str
    sampling: Mapping
    rule: str  #: the selection's rule, in words
    files: tuple[Mapping, ...]  #: each file as read
    baseline_params: tuple[Mapping, ...] | None  #: a free baseline's parameters per file
    baseline_stderr: tuple[Mapping, ...] | None
    chi2_per_dof: Mapping[str, float | None]
    steps: tuple[Mapping, ...]  #: the selection's steps
    nonlinear_tests: Mapping
    product_only: tuple[Mapping, ...]
    notes: tuple[str, ...]

    @property
    def found(self) -> tuple[EffectRecord, ...]:
        """The effects a fit does not expect (the sampling's own are expected)."""
        return tuple(e for e in self.effects if not e.expected)
