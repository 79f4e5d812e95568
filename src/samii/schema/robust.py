"""``robust.json`` (``samii robust --out``): a Monte Carlo study of a controller over drawn plants. Written by
:func:`samii.robust.runner.run_study` (:class:`samii.robust.runner.Study`); read back by :func:`read_robust_json`.
Rates in 1/s, times in s, probabilities as fractions; a figure a sample does not have is null (the damping of a run
that could not be judged)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from samii.schema import read_file
from samii.schema.typed import OPTIONAL

__all__ = ["SampleRow", "WorstRow", "Varied", "Influence", "RobustSummaryRecord", "RobustRecord", "read_robust_json"]


@dataclass(frozen=True)
class SampleRow:
    """One plant's run (samii.robust.task.SampleResult)."""

    index: int  #: 0: the nominal plant's; the drawn ones from 1
    stable: bool
    zeta: float | None  #: the least-damped closed-loop mode's damping ratio in 0.1-40 Hz (negative: growing)
    mode_hz: float | None
    growth_rate_1_s: float | None
    base_settle_s: float | None
    theta_settle_s: float | None
    theta_overshoot_pct: float | None
    note: str  #: why it is unstable or could not be judged, in words
    valid: bool  #: false: no plant could be built from the draw (not counted)
    linear_stable: bool
    params: Mapping[str, float] | None = field(default=None, metadata=OPTIONAL)  #: the sample's drawn values


@dataclass(frozen=True)
class WorstRow(SampleRow):
    params_rel_pct: Mapping[str, float | None] | None = None  #: each drawn value's difference from nominal [%]


@dataclass(frozen=True)
class Varied:
    name: str  #: the parameter (samii params)
    nominal: float
    source: str  #: where its spread comes from, in words


@dataclass(frozen=True)
class Influence:
    """A varied parameter's rank correlation with the closed-loop damping."""

    name: str
    spearman: float | None
    p_value: float | None


@dataclass(frozen=True)
class RobustSummaryRecord:
    n_samples: int  #: the valid plants
    n_invalid: int
    n_unstable: int
    p_unstable: float | None
    p_unstable_ci95: tuple[float | None, float | None]  #: exact binomial (Clopper-Pearson)
    zeta_percentiles: Mapping[str, float] | None  #: percentile -> damping ratio
    n_zeta: int
    base_settle_s_percentiles: Mapping[str, float] | None
    worst: tuple[WorstRow, ...]  #: unstable first, by growth rate, then by damping
    influence: tuple[Influence, ...]  #: strongest first


@dataclass(frozen=True)
class RobustRecord:
    """``robust.json``."""

    controller: str
    scenario: str
    seed: int
    n_samples: int  #: drawn
    engine: str  #: what ran it, in words
    wall_s: float
    warnings: tuple[str, ...]
    varied: tuple[Varied, ...]
    nominal_plant: SampleRow
    summary: RobustSummaryRecord
    samples: tuple[SampleRow, ...]


def read_robust_json(path) -> RobustRecord:
    """``robust.json`` at ``path`` as a :class:`RobustRecord`; InputError naming the file and field of one missing,
    damaged or written by a newer samii."""
    return read_file(path, "robust.json", RobustRecord, again="run the study again")
