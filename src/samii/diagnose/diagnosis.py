"""A diagnosis: what the model lacks, found in the residual against the data's own noise.

:func:`diagnose` takes one or more measured files of one rig
(:mod:`samii.measure.measured`), fits the baseline
(:mod:`samii.diagnose.baseline`), selects effects from the library by F-test
(:mod:`samii.diagnose.select`) and returns a :class:`Diagnosis`: the effects
with their evidence, the error before and after per channel, and the bands
where a significant residual remains that nothing in the library explains.

Error per channel (``act`` theta/v, ``base`` xdd/theta, ``total`` xdd/v),
pooled over the files: the residual ``e = ln(H_data/H_model)`` as rms dB
(20 log10 e^Re e) and rms deg (Im e), and ``chi2``: the mean of the squared
residual over its predicted random error, per real residual (1 when the
model is right and the noise estimate too; 3-record spreads put it at about
1.2, see tests/test_diagnose_core.py).

A delay of at most one sample is the sampling itself (a zero-order hold
delays the command by half a sample, a DAQ that computes the next command
from this sample's reading by up to one, a multiplexed ADC reads its
channels up to a sample apart): it is reported, flagged ``expected``, and
does not make the verdict "effects". The sample is the fastest file's (the
strictest); a file that does not state its rate gets no such allowance.
Where every file states its rate the command's hold, with the images it
folds back, is tried on the model found and kept by BIC
(samii.diagnose.sampling.with_hold_found); with it, a delay found is the
rig's beyond it.

Unexplained bands: after the selection, the squared normalised residual of
each channel averaged over ``BAND_POINTS`` neighbouring points is compared
with its chi-square quantile at ``ALPHA`` / (windows), with ``2 BAND_POINTS / L``
degrees of freedom (``L`` the noise's correlation length) and the noise
scale from the median (never below the predicted; when the file's noise is
unknown, the median alone): windows beyond it, merged, are the bands.

When a file's noise is unknown (no coherence, one record) its points are
weighed alike and the reported ``chi2`` is None: there is no noise to be
a multiple of.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from samii.diagnose.attribution import product_only
from samii.diagnose.attribution import unattributed as unattributed_why
from samii.diagnose.baseline import SavedFit, check_level, notebook_baseline, read_fit_json, saved_fit_baseline
from samii.diagnose.effects import library
from samii.diagnose.evidence import Joined, Refusal, Rival, evidence_text, joined_text, values_text
from samii.diagnose.model import Baseline, Dataset, Fit, fit_model, relabel_modes, start_vectors
from samii.diagnose.nonlinear import MAX_DF_CHI2, MIN_AMPLITUDE_RATIO, NonlinearEvidence, distortion_var, find_nonlinear, harmonic_errors, linearised
from samii.diagnose.residuals import (
    Band,
    ChannelError,
    channel_errors,
    even_misfit,
    full_residuals,
    model_response,
    unexplained_bands,
)
from samii.diagnose.sampling import feedthrough_note, feedthrough_of, hold_note, with_hold_found, with_sampling
from samii.diagnose.select import ALPHA, AMBIGUOUS_CHI2, Step, _noise_var, _vectors, forward_select, sample_s, within_sampling
from samii.diagnose.stationarity import record_changes
from samii.forkmap import fork_calls
from samii.frequency_response import CHANNEL_NAMES
from samii.measure.floor import with_floor
from samii.measure.frf_variance import MAX_VAR
from samii.measure.measured import Measured, check_actuator_sign, with_roughness_noise
from samii.progress import SILENT, Progress
from samii.schema import record_of
from samii.schema.diagnosis import DiagnosisRecord

__all__ = ["ChannelError", "FoundEffect", "Band", "Diagnosis", "diagnose", "RULE"]

RULE = (
    f"an effect joins when its F-test against the model without it passes at alpha = {ALPHA:g} "
    "(Bonferroni over the kinds tried in each round, and over the places an extra mode's frequency was searched; F in "
    "the richer model's chi2 per degree of freedom, never below the stated noise's, and divided by the noise's "
    "correlation length), "
    "then earlier effects it makes unnecessary are dropped; ties beyond p = 1e-300 go to the smallest BIC"
)


@dataclass(frozen=True)
class FoundEffect:
    category: str
    kind: str
    channel: str
    params: dict
    stderr: dict
    evidence: str
    expected: bool = False
    #: The test that admitted it (samii.diagnose.evidence.Joined: chi2 before and after, F, dof, p), where it has one.
    joined: Joined | None = None
    #: Readings that fit almost as well in its place, or that move its values (samii.diagnose.evidence.Rival).
    rivals: tuple[Rival, ...] = ()
    #: The sampling interval [s] when it is within one sample (``expected``: the sampling itself, not a miss).
    sample_s: float | None = None
    #: Found beside a nonlinearity: it may be that nonlinearity's image (said in ``evidence``).
    beside_nonlinearity: bool = False
    #: A nonlinear effect's evidence as figures (samii.diagnose.nonlinear.NonlinearEvidence: its harmonics, the
    #: amplitude test across files).
    nonlinear: NonlinearEvidence | None = None

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True, eq=False)
class Diagnosis:
    measured: tuple[Measured, ...]
    datasets: tuple[Dataset, ...]
    baseline: Baseline
    before: Fit
    after: Fit
    steps: tuple[Step, ...]
    tried: tuple[dict, ...]
    effects: tuple[FoundEffect, ...]
    error_before: dict
    error_after: dict
    unexplained: tuple[Band, ...]
    rule: str = RULE
    notes: tuple[str, ...] = field(default=())
    harmonics: tuple = field(default=())  # HarmonicAnalysis per time-series file
    amplitude_tests: tuple = field(default=())  # AmplitudeTest per pair of files
    #: The files as measured, when a nonlinearity was divided out of ``measured`` (``before`` is fitted to these).
    raw_measured: tuple | None = None
    #: ``--baseline sim``: the effects carried into the simulator, its error before and after (samii.diagnose.simulator).
    simulator: object | None = None
    #: The nonlinear findings (samii.diagnose.nonlinear.NonlinearFinding), with the analyses they rest on.
    nonlinear: tuple = field(default=())
    #: What the final model places where only xdd/v is usable (samii.diagnose.attribution.ProductOnly): its channel
    #: is not measured.
    product_only: tuple = field(default=())

    @property
    def harmonic_error(self) -> tuple | None:
        """The sweep's harmonics' error before (a linear model makes none) and after (the nonlinear laws found), when a
        law with a level was found (samii.diagnose.nonlinear.harmonic_errors): what a nonlinear effect explains."""
        return harmonic_errors(self.nonlinear)

    @property
    def refused(self) -> list[dict]:
        """Every candidate that passed the F-test but was refused, with its reason (below the excited band, cancels
        within its uncertainty, smaller than the measurement's floor, indistinguishable from the sampling...): its
        words, its class, and the code and figures they are rendered from (samii.diagnose.evidence.Refusal)."""
        return [
            {
                "round": t["round"],
                "effect": t["effect"],
                "params": dict(t["params"]),
                "reason": t["refused"],
                "class": Refusal(**t["refusal"]).cls,
                **Refusal(**t["refusal"]).to_dict(),
                "log10_p": t["log10_p_test"],
            }
            for t in self.tried
            if t.get("refused")
        ]

    @property
    def verdict(self) -> str:
        return "effects" if any(not e.expected for e in self.effects) else "none"

    def residuals(self, which: str = "after") -> list[dict[str, tuple[np.ndarray, np.ndarray]]]:
        """Per file: channel -> (e on the full grid, NaN where unusable; its variance). ``before``: the baseline on the
        data as measured; ``after``: the augmented model on the data with any nonlinearity divided out."""
        if which == "after":
            return [full_residuals(ds, res) for ds, res in zip(self.datasets, self.after.residuals)]
        datasets = self.datasets if self.raw_measured is None else [Dataset.from_measured(m) for m in self.raw_measured]
        return [full_residuals(ds, res) for ds, res in zip(datasets, self.before.residuals)]

    def model(self, i: int, freq_hz: np.ndarray, which: str = "after") -> dict[str, np.ndarray]:
        """act, base and total of the baseline (``before``) or the augmented model (``after``) of file ``i``."""
        return model_response(self.after if which == "after" else self.before, i, freq_hz)

    def record(self) -> DiagnosisRecord:
        """diagnosis.json as typed values (samii.schema.diagnosis), checked against its schema."""
        return record_of(DiagnosisRecord, self.to_dict(), "samii.diagnose.diagnosis.Diagnosis.to_dict")

    def to_dict(self) -> dict:
        he = self.harmonic_error
        return {
            "verdict": self.verdict,
            "effects": [e.to_dict() for e in self.effects],
            "error_before": {k: v.to_dict() for k, v in self.error_before.items()},
            "error_after": {k: v.to_dict() for k, v in self.error_after.items()},
            "simulator": None if self.simulator is None else self.simulator.to_dict(),
            "harmonic_error": None if he is None else {"before": he[0].to_dict(), "after": he[1].to_dict()},
            "unexplained": [b.to_dict() for b in self.unexplained],
            "refused": self.refused,
            "floor": [
                {
                    "source": m.source,
                    "how": None if m.floor is None else m.floor.how,
                    "quantisation_steps": None if m.floor is None else dict(m.floor.quant_steps),
                }
                for m in self.measured
            ],
            "baseline": self.baseline.label,
            "sampling": {
                "hold_s": list(self.after.baseline.hold_s) or None,
                "hold_seen": self.after.baseline.hold_seen,
                **dict(zip(("feedthrough_lag_samples", "stderr"), feedthrough_of(self.after) or (None, None))),
                "how": "hold_s: per file, the command's zero-order hold (half a sample) in the model, on the command of every fit "
                "(null: not modelled; hold_seen: it fits better with it by the F-test, else as well with fewer effects); "
                "xdd/v's direct feedthrough (a held command's steps) reaches the data feedthrough_lag_samples after the "
                "rest of its response (null: not modelled, or no feedthrough the data see; samii.diagnose.sampling)",
            },
            "rule": self.rule,
            "files": [
                {
                    "source": m.source,
                    "noise": m.noise_source,
                    "amplitude_v": m.amplitude_v,
                    "sample_rate_hz": m.sample_rate_hz,
                    "records": None
                    if m.layout is None
                    else {"record_s": m.layout.record_s, "start_s": m.layout.start_s, "n_records": m.layout.n_records, "how": m.layout.how},
                    "corr_length": m.corr_length,
                    "noise_free": bool(m.floor is not None and m.floor.noise_free),
                    "usable_points": {ch: int(k.sum()) for ch, k in ds.keep.items()},
                }
                for m, ds in zip(self.measured, self.datasets)
            ],
            "baseline_params": [dict(p) for p in self.after.baseline_params] if self.baseline.free else None,
            "baseline_stderr": [dict(p) for p in self.after.baseline_stderr] if self.baseline.free else None,
            "chi2_per_dof": {"before": self.before.chi2 / self.before.dof, "after": self.after.chi2 / self.after.dof},
            "steps": [
                {
                    "effect": s.label,
                    "F": s.f_stat,
                    "dof": list(s.dof),
                    "log10_p": s.log10_p,
                    "chi2_before": s.chi2_before,
                    "chi2_after": s.chi2_after,
                    **({"places_searched": s.places} if s.places > 1.0 else {}),
                }
                for s in self.steps
            ],
            "nonlinear_tests": {
                "harmonics": [
                    {
                        "source": h.source,
                        "segments_tested": int(sum(np.isfinite(h.log10_p[k]).sum() for k in h.log10_p)),
                        "significant": h.n_significant,
                        "threshold_log10_p": h.threshold_log10_p,
                        "max_ratio": {str(k): _max_tested(h, k) for k in h.ratio},
                    }
                    for h in self.harmonics
                ],
                "amplitude": [
                    {
                        "sources": list(t.sources),
                        "amplitudes_v": list(t.amplitudes_v),
                        "chi2": t.chi2,
                        "dof": t.dof,
                        "log10_p": t.log10_p,
                        "gain_change_db": t.gain_change_db,
                        "n_points": t.n_points,
                        "channel": t.channel,
                    }
                    for t in self.amplitude_tests
                ],
            },
            "product_only": [asdict(p) for p in self.product_only],
            "notes": list(self.notes),
        }


def check_residual_dof(datasets: Sequence[Dataset], before: Fit, sources: Sequence[str]) -> None:
    """Refuse data the baseline fits exactly: no more residuals (magnitude and phase of each usable point) than its
    free parameters, so no lack of fit could show and no effect be tested (a 10 Hz file whose band holds three points)."""
    if before.n_residuals > before.n_params:
        return
    points = "; ".join(
        f"{src}: " + ", ".join(f"{CHANNEL_NAMES.get(ch, ch)} {int(k.sum())}" for ch, k in ds.keep.items()) for src, ds in zip(sources, datasets)
    )
    raise ValueError(
        f"{', '.join(sources)}: too few usable points to test anything ({points}: {before.n_residuals} residuals, "
        f"magnitude and phase, for the baseline's {before.n_params} free parameters, which fit them exactly); a "
        "diagnosis needs more: a wider band, more coherent points, a faster sample rate"
    )


def _max_tested(h, k: int) -> float | None:
    tested = np.isfinite(h.log10_p[k])
    return float(np.max(np.abs(h.ratio[k][tested]))) if tested.any() else None


def _on_points_of(raw: Measured, divided: Measured) -> Measured:
    """``raw`` without the points ``divided`` (the same file, divided by a describing function) leaves out
    (variance above MAX_VAR: where a law passes less than half the command), so that the error before and after
    are on the same points; ``raw`` itself when none is left out."""
    var = dict(raw.var)
    changed = False
    for ch in ("act", "total"):
        v, d = raw.var.get(ch), divided.var.get(ch)
        if v is None or d is None or d.shape != v.shape:
            continue
        out = d > MAX_VAR
        if np.any(out & (v <= MAX_VAR)):
            var[ch] = np.where(out, d, v)
            changed = True
    return replace(raw, var=var) if changed else raw


def _file_chi2(ds: Dataset, res: Mapping[str, np.ndarray]) -> float:
    """The fit's weighted chi2 on one file (its weights: noise and any model variance)."""
    return float(sum(np.sum(np.abs(r * ds.inv_sigma[ch]) ** 2) for ch, r in res.items()))


def _least_distorted(datasets: Sequence[Dataset], harmonics: Sequence) -> int:
    """The file whose sweep harmonics are smallest (none significant counts 0; a file without a harmonic test last):
    a saturation distorts the largest amplitude most, a dead band or a play the smallest."""

    def distortion(ds: Dataset) -> float:
        h = next((h for h in harmonics if h.source == ds.source), None)
        if h is None:
            return np.inf
        sig = [np.abs(h.ratio[k][h.significant(k)]) for k in h.ratio]
        return float(max((x.max() for x in sig if x.size), default=0.0))

    return int(min(range(len(datasets)), key=lambda i: (distortion(datasets[i]), -(datasets[i].amplitude_v or 0.0))))


def _drop_amplitude_images(datasets: Sequence[Dataset], baseline: Baseline, fit: Fit, harmonics: Sequence = ()) -> tuple[Fit, list[str]]:
    """With a nonlinearity found and files at amplitudes at least MIN_AMPLITUDE_RATIO apart: a linear effect holds
    at every amplitude, so one whose removal lets the least distorted file (:func:`_least_distorted`) fit better by
    more than AMBIGUOUS_CHI2 of the fit's variances (its weights: noise and distortion) is the nonlinearity's image
    in the others (held-out battery rig, a 0.4 V saturation at 0.1 and 0.3 V: a "base mode" at 8.57 Hz, damping
    0.13, fitted to the 0.3 V file near the hydraulic resonance, made the 0.1 V file's xdd/v chi2 there 3x its
    noise). Dropped one at a time, the largest gain first, refitted, until none is. The threshold is one effect's,
    with no correction for the effects tried. Returns the fit and the dropped effects' descriptions."""

    amps = [ds.amplitude_v for ds in datasets]
    if len(datasets) < 2 or any(not a for a in amps) or max(amps) < MIN_AMPLITUDE_RATIO * min(amps):
        return fit, []
    lo = _least_distorted(datasets, harmonics)
    corr = max(ds.corr_length for ds in datasets)
    dropped = []
    while fit.effects:
        s2 = _noise_var(fit, corr)
        worst = None
        for i, e in enumerate(fit.effects):
            rest = [x for j, x in enumerate(fit.effects) if j != i]
            without = fit_model(list(datasets), baseline, _vectors(rest), start_baseline=start_vectors(fit))
            gain = _file_chi2(datasets[lo], fit.residuals[lo]) - _file_chi2(datasets[lo], without.residuals[lo])
            if gain > AMBIGUOUS_CHI2 * s2 and (worst is None or gain > worst[0]):
                worst = (gain, e, without)
        if worst is None:
            break
        gain, e, fit = worst
        dropped.append(
            f"{e.kind.label} ({values_text(e.kind.label, dict(e.values))}): without it the {amps[lo]:.3g} V file, the "
            f"least distorted, fits better by {gain / s2:.3g} of the fit's variances"
        )
        fit = relabel_modes(list(datasets), fit)
    return fit, dropped


def _log_distance(a: dict, b: dict) -> float:
    """How far apart two value sets of one kind lie (sum of |log ratio|; a zero or missing value counts 0; values
    of opposite sign, a leak's pole at +0.2 and -0.2 1/s or a residue's, are infinitely far apart)."""

    def one(x, v):
        if not x or not v:
            return 0.0
        return abs(np.log(x / v)) if (x > 0) == (v > 0) else np.inf

    return sum(one(a.get(n), v) for n, v in b.items())


#: A swap record describes a found effect when its kept values lie within this log distance of the effect's.
MATCH_DISTANCE = 0.05


def _record_for(records: Sequence[dict], label: str, values: dict) -> dict | None:
    """The swap record whose kept effect is ``label`` with values nearest ``values`` (within MATCH_DISTANCE):
    an extra mode may be found more than once, so the label alone does not say which."""
    near = [(_log_distance(t["kept_params"], values), i) for i, t in enumerate(records) if t.get("kept") == label]
    near = [(d, i) for d, i in near if d < MATCH_DISTANCE]
    return records[min(near)[1]] if near else None


def _moved(v_alt: dict, v_now: dict) -> bool:
    """Any of an effect's values differs by more than 5 % between two fits."""
    return any(abs(v_alt[n] / v_now[n] - 1.0) > 0.05 for n in v_now if v_now[n])


def _rival(how: str, record: dict, without_hold: bool) -> Rival:
    """A swap or richer round's record as a :class:`Rival` of its kept effect, with the other effects whose values
    it moves by more than 5 % (the found values of those depend on which of the two is taken)."""
    moved = tuple((lab, dict(v_alt)) for (lab, v_alt), (_, v_now) in zip(record["rival_rest"], record["kept_rest"]) if _moved(v_alt, v_now))
    return Rival(
        how,
        record["rival"],
        record["delta_in_noise"],
        record["extra_params"] if how == "richer" else None,
        dict(record["rival_params"]),
        moved,
        without_hold=without_hold,
    )


def _effects(
    after: Fit, steps: Sequence[Step], tried: Sequence[dict], measured: Sequence[Measured], pre: Mapping[str, dict] | None = None
) -> list[FoundEffect]:
    """The found effects with their evidence. ``pre``: where the command's hold joined the model after the selection
    (samii.diagnose.sampling.with_hold_found), each effect's values in the model the selection found (label -> values,
    the labels found once): the rivals were fitted against it, and are looked up by them."""
    pre = pre or {}
    sample = sample_s(measured)
    added = [s for s in steps if not s.label.startswith("removed ")]
    swaps = [t for t in tried if t.get("round") == "swap"]
    final_swaps = [t for t in swaps if not t.get("interim")]  # an earlier round's rival described an earlier model
    out = []
    used: set[int] = set()

    for e in after.effects:
        k = e.kind
        mine = [i for i, s in enumerate(added) if s.label == k.label and i not in used]
        # the step whose effect is nearest these values; the later on ties
        j = min(mine, key=lambda i: (_log_distance(e.values, added[i].values or {}), -i)) if mine else None
        if j is not None:
            used.add(j)
            s = added[j]
            joined = Joined.of_step("f_test", s)
        else:
            swap = next((t for t in reversed(swaps) if t.get("swapped") and t["effect"] == k.label), None)  # the latest
            if swap is None:
                joined = Joined("refit")
            else:
                richer = bool(swap.get("richer"))
                joined = Joined(
                    "swap",
                    swap["chi2_current"],
                    swap["chi2"],
                    f_stat=swap["F"] if richer else None,
                    log10_p=swap["log10_p"] if richer else None,
                    replaced=swap["alternative_to"],
                    extra_params=swap["extra_params"] if richer else 0,
                )
        rivals = []
        near_equal = [t for t in final_swaps if t["delta_in_noise"] < AMBIGUOUS_CHI2 and "kept" in t]
        lookup = pre.get(k.label, e.values)
        without_hold = k.label in pre
        rival = _record_for(near_equal, k.label, lookup)
        if rival is not None:
            rivals.append(_rival("in_its_place", rival, without_hold))
        richer = _record_for([t for t in tried if t.get("round") == "richer"], k.label, lookup)
        if richer is not None:
            rivals.append(_rival("richer", richer, without_hold))
        for t in near_equal:  # another effect's near-equal rival that moves this one's values
            if t is rival:
                continue
            v_alt = next(
                (
                    v_alt
                    for (lab, v_now), (_, v_alt) in zip(t["kept_rest"], t["rival_rest"])
                    if lab == k.label and _log_distance(v_now, e.values) < MATCH_DISTANCE and _moved(v_alt, v_now)
                ),
                None,
            )
            if v_alt is not None:
                rivals.append(Rival("moves_it", t["rival"], values=dict(v_alt), in_place_of=t["kept"]))
        sampled = sample if within_sampling(e, sample) else None
        text = evidence_text(k.label, k.describe(e.values), joined, rivals, sampled)
        out.append(
            FoundEffect(
                k.category,
                k.kind,
                k.channel,
                dict(e.values),
                dict(e.stderr),
                text,
                sampled is not None,
                joined=joined,
                rivals=tuple(rivals),
                sample_s=sampled,
            )
        )
    return out


#: An extra mode's frequencies may lie this factor beyond the measured band (a peak at its edge), no further:
#: outside the band a "mode" is a shape the data cannot tell from noise.
BAND_MARGIN = 1.25


def _within_band(kind, datasets: Sequence[Dataset]):
    """``kind`` with its mode frequencies bounded to the measured band (module constant BAND_MARGIN)."""
    if kind.category != "extra_mode":
        return kind
    lo = min(float(ds.freq_hz[0]) for ds in datasets) / BAND_MARGIN
    hi = max(float(ds.freq_hz[-1]) for ds in datasets) * BAND_MARGIN
    params = tuple(replace(p, lo=max(p.lo, lo), hi=min(p.hi, hi)) if p.unit == "Hz" else p for p in kind.params)
    return replace(kind, params=params)


def _noise_from_roughness(m: Measured, saved) -> Measured:
    """``m`` itself if its noise is known, else with the noise estimated from its residual against the baseline
    fitted with uniform weights (:func:`samii.measure.measured.with_roughness_noise`)."""

    ds = Dataset.from_measured(m)
    if ds.known_noise:
        return m
    bl = notebook_baseline([m]) if saved is None else saved_fit_baseline(saved, [ds])
    fit = fit_model([ds], bl, [])
    model = model_response(fit, 0, m.frf.freq_hz)
    return with_roughness_noise(m, {ch: model[ch] for ch in m.frf.channels})


def _with_floor(m: Measured) -> Measured:
    """``m`` with its systematic floor (:mod:`samii.measure.floor`): the estimator's bias measured through the
    notebook's structure fitted to the file alone (a description of its dynamics, whatever the baseline), the
    quantisation of its columns and the stated relative floor."""

    if m.timeseries is None or m.layout is None or any(m.var.get(ch) is None for ch in m.frf.channels):
        return with_floor(m)
    try:  # (the sampled feedthrough left out: the estimator's bias is a difference of the model, second order in it)
        fit = fit_model([Dataset.from_measured(m)], notebook_baseline([m]), [])
    except ValueError:
        return with_floor(m)
    return with_floor(m, lambda f: model_response(fit, 0, f))


def _kinds(datasets: Sequence[Dataset], *, fixed_baseline: bool, simulator: bool = False) -> list:
    """The library's kinds the datasets' channels can test against the baseline (``simulator``: the calibrated
    simulator's), each bounded to their band."""
    have = set().union(*(ds.data for ds in datasets))
    channels = ("act", "base") if {"act", "base"} <= have or {"act", "total"} <= have else tuple(c for c in ("act", "base") if c in have)
    return [_within_band(k, datasets) for k in library(fixed_baseline=fixed_baseline, channels=channels, pure_integrator=not simulator)]


def _beside_nonlinearity(effects: Sequence[FoundEffect], where: str) -> list[FoundEffect]:
    """``effects`` found beside a nonlinearity, each but the expected marked so and its evidence saying it may be that
    nonlinearity's image (``where``: in what)."""
    said = f"; found beside a nonlinearity: it may be that nonlinearity's image{where}"
    return [e if e.expected else replace(e, evidence=e.evidence + said, beside_nonlinearity=True) for e in effects]


def _select_against(cal, files, keep, *, alpha, progress, baseline=None):
    """(datasets, fit, steps, candidates): the forward selection on ``files`` against the simulator
    calibrated as ``cal`` (its correction recomputed at it; or ``baseline``, that simulator with the
    correction it was calibrated with), over the library's kinds ``keep`` accepts."""
    from samii.diagnose.simulator import correction, simulator_baseline  # (lazy: imports mujoco, only when called)

    datasets = tuple(Dataset.from_measured(m) for m in files)
    bl = baseline if baseline is not None else simulator_baseline(cal, [correction(cal.params, m) for m in files])
    kinds = [k for k in _kinds(datasets, fixed_baseline=True, simulator=True) if keep(k.label)]
    _, after, steps, tried = forward_select(list(datasets), bl, kinds, alpha=alpha, progress=progress)
    return datasets, after, list(steps), list(tried)


#: Rounds of carrying under ``--baseline sim``: the first carries what the first selection found (the
#: kinds in ``CARRY``); a second runs when the selection after it finds an extra base mode or valve
#: dynamics, carried as a body on the tip (``BODY``) or as the spool's time constant (``SPOOL``) with
#: what the first selection finds again beside it.
CARRY_ROUNDS = 2


def _no_level(finding) -> str | None:
    """Why a valve law found is not carried into the simulator, or None: it is carried only at a level the
    harmonics fix, where its describing function fits them; an asymmetry's describing function is a gain, and its
    level is its 2nd harmonic's ratio where one constant fits it."""
    if finding.kind == "asymmetry":
        if finding.harmonics and finding.params.get("ratio_chi2", np.inf) <= MAX_DF_CHI2:
            return None
        return "its 2nd harmonic's ratio is far from one constant: the two directions differ by more than a gain"
    if finding.harmonics and finding.law_fits:
        return None
    return "its describing function does not fit the harmonics, so no level to carry"


def _simulator_pass(raw, measured, calibrated, effects, nonlinear, steps, *, alpha, progress, first_baseline=None, first_fit=None):
    """``--baseline sim`` after the first selection (which tried only what the simulator can take):
    carry the effects into the simulator, recalibrate, and select again with the whole library
    against the simulator with them. The first calibration, made without the effects, bent the knobs
    to imitate them, so the first pass may report images of that bending beside the real effect:
    only what the second pass still needs is kept, and the carried effects are reported with the
    values the recalibration gives them. With nothing carried the second selection still runs, for
    what the simulator cannot take in the first round (valve dynamics, an extra mode) or at all (a play).

    Valve dynamics are not in the first selection either: with them, a 4 ms command delay beside an AC
    coupling was taken as valve dynamics (carried as a slower spool) and the delay as the accelerometer's.
    The reverse holds too: on the simulator's data with its spool twice as slow (8.97 ms), the first
    selection takes a theta delay, an accelerometer roll-off and a gain error for it. The selection after
    that carry finds a real pole/zero pair, the exact ratio of two first-order spools, and it goes the
    bodies' way with valve dynamics: carried alone as the spool's time constant
    (:data:`samii.diagnose.simulator.SPOOL`), then the first selection again, which then needs none of
    the three (8.90 ms carried). A pair in the first selection instead stood beside a 20 Hz roll-off and
    a 4 ms delay as small changes of the spool.

    An extra base mode is not in the first selection: against knobs bent by a missing delay modes
    appear as its images (a 4 ms delay brought three; a 3 ms accelerometer delay two near mode 3,
    and with them a swap turned the delay into a 77 Hz roll-off). When the selection after the
    carry still finds one, a second round runs: the mode alone is carried into the first
    calibration as a body on the tip (:data:`samii.diagnose.simulator.BODY`) and recalibrated, the
    first selection is made again against that simulator (what it found before may have been the
    missing mode's image: a 15 Hz body came out as a 0.3 % accelerometer gain error), and what it
    finds is carried with the body, from the first calibration, before the last selection.

    What is found where the simulator with it still cannot represent the data is attributed only when it takes out
    most of the misfit it acts in (:mod:`samii.diagnose.attribution`): the first selection's findings (``first_fit``:
    its datasets and fit) before they are carried, a mode before the second round carries it, and everything found
    at the end; the rest is listed as refused (round "attribution") and not carried.

    Returns (effects, (files, datasets, final fit), SimulatorReport, later steps, later candidates)."""
    progress = progress or SILENT
    from samii.calibrate.simulator import parameter_value  # (lazy: imports mujoco, only when called)
    from samii.diagnose.simulator import (  # (lazy: imports mujoco, only when called)
        BODY,
        CARRY,
        LATE,
        SPOOL,
        body_effect_values,
        carry,
        carry_and_recalibrate,
        found_value,
        misfits,
        simulator_report,
        spool_lag_s,
    )

    refuse = {f"nonlinear/{f.kind}": reason for f in nonlinear if (reason := _no_level(f)) is not None}

    def attribute(ds, fit, found):
        """(effect, why) for each linear effect of ``found`` ((effect, the values its change is judged by) pairs, in
        ``fit`` or in its baseline; on datasets ``ds``) that cannot be told from an image of what the simulator lacks."""
        left = misfits(ds, fit.residuals)
        if not left:
            return []
        out = []
        for e, values in found:
            if not e.expected and e.category != "nonlinear":
                if (why := unattributed_why(fit, ds, left, f"{e.category}/{e.kind}", values)) is not None:
                    out.append((e, why))
        return out

    # what the first selection found where the simulator with it still misses the data is attributed first, or not
    # carried (a carry of an image bends the knobs the rest is fitted against); a second round's first selection
    # replaces these
    first_gone = attribute(*first_fit, [(e, e.params) for e in effects]) if first_fit is not None else []
    to_carry = list(effects)
    steps_by_label = {s.label: s for s in steps}
    more_steps, more_tried = [], []
    body_not_carried: list[str] = []
    for round_ in range(CARRY_ROUNDS):
        not_attributed = {f"{e.category}/{e.kind}": f"not attributed: {why}" for e, why in first_gone}
        report = simulator_report(raw, measured, calibrated, to_carry, progress=progress, refuse={**refuse, **not_attributed})
        uncarried_law = any(f"nonlinear/{f.kind}" not in report.carried for f in nonlinear)
        # with every law in the simulator, its correction holds their describing functions: the data as measured
        files = measured if uncarried_law else raw
        progress.stage("selecting again against the simulator with the effects")
        # nothing carried: against the simulator of the first selection, with the correction its knobs were calibrated
        # with. Recomputed at those knobs, on data the simulator cannot represent (the second rig's eq 9.4 plants, knobs
        # bent far), the correction no longer matched them and the second selection ended 6x above the error before
        # (chi2 468 -> 2790 on theta/v, a 2 ms command delay missed, two base "modes" at 2.0 and 7.2 Hz)
        same = report.after is calibrated and files is measured
        datasets, after, steps2, tried2 = _select_against(
            report.after,
            files,
            lambda label: label not in report.carried,  # noqa: B023 - called within this iteration
            alpha=alpha,
            progress=progress,
            baseline=first_baseline if same else None,
        )
        more_steps += steps2
        more_tried += tried2
        second = _effects(after, steps2, tried2, files)
        bodies = [e for e in second if not e.expected and f"{e.category}/{e.kind}" in LATE]
        # (one the simulator with it would still miss the data around cannot be told from an image: not carried)
        images = [e for e, _ in attribute(datasets, after, [(e, e.params) for e in bodies])]
        bodies = [e for e in bodies if not any(e is x for x in images)]
        if not bodies or nonlinear or round_ == CARRY_ROUNDS - 1:
            break  # beside a nonlinearity a mode found may be its image: not carried
        # the mode alone in the first calibration, recalibrated; the first selection again against it. That simulator
        # only hosts the selection (the carry after it recalibrates with the correction recomputed): one calibration at
        # the correction of its start, not recomputed (on a 6-minute file with a 4 ms delay and a 15 Hz body the
        # second calibration took 8.6 of the round's 25 s, for a cost 0.5 % lower against data it lacks the delay of)
        body = bodies[0]
        with_body, _, body_carried, body_not = carry_and_recalibrate(raw, measured, calibrated, [body], progress=progress, correction_steps=0)
        if not body_carried:
            body_not_carried = list(body_not)  # (why: its residue's sign, or the simulator with it diverges)
            break  # (a residue no body on the tip makes): reported as found, not carried
        progress.stage("selecting again against the simulator with the extra mode")
        ds_b, after_b, steps_b, tried_b = _select_against(with_body, measured, lambda label: label in CARRY, alpha=alpha, progress=progress)
        more_steps += steps_b
        steps_by_label.update({s.label: s for s in steps_b})
        steps_by_label.update({s.label: s for s in steps2 if s.label in LATE})
        more_tried += tried_b
        found_b = _effects(after_b, steps_b, tried_b, measured)
        first_gone = attribute(ds_b, after_b, [(e, e.params) for e in found_b])  # (against the simulator with the mode)
        to_carry = found_b + [body]
    out = []
    judged_by: list[dict] = []  # per effect of ``out``, the values its change is judged by (a carried one's as found)
    for e in to_carry:
        label = f"{e.category}/{e.kind}"
        if label not in report.carried or e.category == "nonlinear":
            continue
        judged_by.append(dict(e.params))  # (each effect carried is appended to ``out`` once, below)
        r = report.after.result
        step = steps_by_label.get(label)
        joined = None if step is None else Joined.of_step("simulator", step)
        why = f"{joined_text(joined)}; " if joined else ""
        if label in BODY:
            values, se = body_effect_values(report.after.params, r.stderr)
            mass, freq, zeta = (parameter_value(report.after.params, n) for n in BODY[label])
            out.append(
                FoundEffect(
                    e.category,
                    e.kind,
                    e.channel,
                    values,
                    se,
                    f"{why}carried into the simulator as a body on the beam's end ({mass:.3g} kg on a mount of "
                    f"{freq:.4g} Hz, damping ratio {zeta:.3g}: {', '.join(BODY[label])}) and recalibrated with its "
                    "mode knobs; the mode it adds, joint 2 held",
                    joined=joined,
                )
            )
            continue
        if label in SPOOL:
            name = SPOOL[label]
            tau, tau0, se = r.values[name], parameter_value(report.before.params, name), r.stderr[name]
            out.append(
                FoundEffect(
                    e.category,
                    e.kind,
                    e.channel,
                    {"spool_time_constant_s": tau, "added_lag_s": tau - tau0},
                    {"spool_time_constant_s": se, "added_lag_s": se},
                    f"{why}the valve is {'slower' if tau > tau0 else 'faster'} than the simulator's: carried into the simulator as {name} (its "
                    f"first-order spool, {1e3 * tau0:.3g} -> {1e3 * tau:.3g} ms, corner {1 / (2 * np.pi * tau):.3g} Hz), "
                    f"found after the first carry as {'a real pole/zero pair' if e.kind == 'pole_zero' else 'valve dynamics'} "
                    f"({values_text(label, e.params)}"
                    + (f"; the simulator's spool corner is {1 / (2 * np.pi * tau0):.3g} Hz" if e.kind == "pole_zero" else "")
                    + "); "
                    f"the spool started at {1e3 * (tau0 + spool_lag_s(e)):.3g} ms, its low-frequency group delay "
                    f"({1e3 * spool_lag_s(e):+.3g} ms) added, and was recalibrated with the mode knobs"
                    + (" (a resonant valve's peak it cannot take)" if e.kind == "valve" else ""),
                    joined=joined,
                )
            )
            continue
        name, key = CARRY[label]
        value, se = found_value(name, report.before.params, r.values[name], r.stderr[name])
        out.append(
            FoundEffect(
                e.category,
                e.kind,
                e.channel,
                {key: value},
                {key: se},
                f"{why}carried into the simulator as {name} and recalibrated with its mode knobs",
                joined=joined,
            )
        )
    if nonlinear:
        second = _beside_nonlinearity(second, "")
    judged_by += [dict(e.params) for e in second]
    out += second
    # where the simulator with everything found still cannot represent the data, what was found there must explain
    # most of the misfit it acts in, or it is not told from an image of the structure the simulator lacks
    final_gone = attribute(datasets, after, list(zip(out, judged_by)))
    gone = [e for e, _ in final_gone]
    out = [e for e in out if not any(e is x for x in gone)]

    def refused(e, why):
        label = f"{e.category}/{e.kind}"
        step = steps_by_label.get(label) or next((s for s in more_steps if s.label == label), None)
        return {
            "round": "attribution",
            "effect": label,
            "params": dict(e.params),
            "refused": why.text,
            "refusal": why.to_dict(),
            "log10_p_test": None if step is None else step.log10_p,
        }

    more_tried = [refused(e, why) for e, why in first_gone] + more_tried + [refused(e, why) for e, why in final_gone]
    unattributed = [f"{e.category}/{e.kind}: {why}" for e, why in first_gone + final_gone]
    rest = [x for x in after.effects if not any(x.kind.label == f"{e.category}/{e.kind}" and dict(x.values) == e.params for e in gone)]
    if len(rest) < len(after.effects):
        # the final model without them: the error after and the bands left are of what is reported

        after = fit_model(list(datasets), after.baseline, _vectors(rest), start_baseline=start_vectors(after))
    out += [e for e in effects if e.category == "nonlinear"]
    # what stays uncarried is what the final list holds; the first pass's other proposals were images
    # of the simulator calibrated without the carried effects
    _, carriable, not_carried = carry([e for e in second if any(e is k for k in out)], report.before.params)
    why_not = (
        "found beside a nonlinearity (it may be the nonlinearity's image)"
        if nonlinear
        else f"found by the last selection, after {round_ + 1} round{'s' if round_ else ''} of carrying"
    )
    not_carried += [f"{label}: {why_not}" for label in carriable]
    not_carried += carry([e for e in effects if e.category == "nonlinear"], report.before.params, refuse=refuse)[2]
    not_carried += [n for n in report.not_lowering + tuple(body_not_carried) if n not in not_carried]
    dropped = [
        f"{e.category}/{e.kind}"
        for e in effects
        if not e.expected
        and e.category != "nonlinear"
        and f"{e.category}/{e.kind}" not in report.carried
        and f"{e.category}/{e.kind}" not in not_attributed
        and not any(f"{o.category}/{o.kind}" == f"{e.category}/{e.kind}" for o in out)
    ]
    report = replace(report, not_carried=tuple(not_carried), dropped=tuple(dropped), unattributed=tuple(unattributed))
    return out, (tuple(files), datasets, after), report, more_steps, more_tried


def diagnose(
    measured: Sequence[Measured], *, baseline="notebook", alpha: float = ALPHA, progress: Progress | None = None, simulator_params=None
) -> Diagnosis:
    """Diagnose the files of one rig against ``baseline``: "notebook", "sim" (the calibrated simulator,
    started from ``simulator_params``, default the embedded model's; the effects found are carried into
    it, :mod:`samii.diagnose.simulator`), a saved fit (:class:`SavedFit`) or its path.

    ``progress`` (samii.progress.Progress) is told each stage and advanced by every candidate tried (a unit each; the
    count is not known ahead, so it never says a total).
    """

    progress = progress or SILENT
    sim = baseline == "sim"
    saved = None if baseline in ("notebook", "sim") else baseline if isinstance(baseline, SavedFit) else read_fit_json(baseline)
    given = tuple(measured)
    if not given:
        raise ValueError("no data to diagnose")
    for m in given:
        check_actuator_sign(m)
    measured = tuple(_noise_from_roughness(m, saved) for m in given)
    notes = [w for m in given for w in m.warnings]
    notes += [f"{m.source}: no coherence and no records; the noise of each point is {m.noise_source}" for m, g in zip(measured, given) if m is not g]

    jobs = [lambda m=m: _with_floor(m) for m in measured]
    if sim:  # the simulator's own harmonics (its orifice law) are not what it lacks: the data's are tested in excess of them
        from samii.diagnose.simulator import measured_like  # (lazy: imports mujoco, only when called)
        from samii.sim.model import default_params  # (lazy: imports mujoco, only when called)

        progress.stage("measuring the systematic floor and the simulator's own harmonics")
        own = default_params() if simulator_params is None else simulator_params
        # (only where the harmonic test can run: records found, theta/v measured; the floor changes none of these)
        jobs += [
            lambda m=m: measured_like(own, m) if m.layout is not None and m.layout.n_records >= 2 and "act" in m.frf.channels else None
            for m in measured
        ]
    else:
        progress.stage("measuring the systematic floor")
    done = fork_calls(jobs)  # each file's floor (and the simulator like it) at once
    measured, references = tuple(done[: len(measured)]), (done[len(measured) :] if sim else None)

    changes = [c for m in measured for c in record_changes(m, alpha=alpha)]
    floored = measured
    jobs = [lambda: find_nonlinear(floored, alpha=alpha, references=references, reference_label="the simulator's own harmonics")]
    if not sim and saved is None:
        # the notebook baseline's start on these data, meanwhile on the other core: used when the nonlinearity leaves
        # them as they are (no law to divide out, no distortion to add to the noise), else computed again below
        jobs.append(lambda: notebook_baseline(floored))
    (nonlinear, nl_notes, harmonics, amp_tests), *early = fork_calls(jobs)
    for f in nonlinear:  # where the data show distortion, their best linear approximation is uncertain by it
        for h in f.harmonics:
            measured = tuple(distortion_var(m, h) if m.source == h.source else m for m in measured)
    raw = measured
    divided_notes, at = [], len(notes)  # notes on the data divided by a law, in their place among the notes
    for f in nonlinear:  # a law on the command that explains the harmonics: the linear model is fitted to the data without it
        if f.harmonics and f.law_fits:
            for h in f.harmonics:
                measured = tuple(linearised(m, f, h) if m.source == h.source else m for m in measured)
                divided_notes.append(
                    f"{h.source}: the linear fit, its error after and the figures use theta/v and xdd/v divided "
                    f"by the {f.kind.replace('_', ' ')}'s describing function (the error before is the baseline's on "
                    "the data as measured)"
                )
    datasets = tuple(Dataset.from_measured(m) for m in measured)
    calibrated = None
    if sim:
        from samii.diagnose.simulator import CARRY, calibrate_simulator, correction, simulator_baseline  # (lazy: imports mujoco, only when called)
        from samii.sim.model import default_params  # (lazy: imports mujoco, only when called)

        progress.stage("calibrating the simulator")

        start = default_params() if simulator_params is None else simulator_params
        corrections = [correction(start, m) for m in measured]
        calibrated = calibrate_simulator(measured[0], start=start, corrected_by=corrections[0])
        # the correction stays the start's here: recomputed at knobs a missing effect has bent (a 20 Hz
        # roll-off moved joint 1's damping 2.3x) it misled the selection; after the carry it is iterated
        notes.append(
            f"the simulator's {', '.join(calibrated.result.names)} were calibrated to {measured[0].source} "
            f"({'converged' if calibrated.result.converged else 'NOT converged: ' + calibrated.result.status}); the effects are fitted with those knobs refitted "
            "through the simulator's first-order sensitivity to them"
        )

    held = False  # the command's hold: tried on the model found (samii.diagnose.sampling.with_hold_found)

    def baseline_for(ms, dss):
        if sim:
            return simulator_baseline(calibrated, corrections)
        if saved is not None:
            return saved_fit_baseline(saved, dss)
        same = bool(early) and len(ms) == len(floored) and all(a is b for a, b in zip(ms, floored))
        # how the DAQ samples (its command's hold, xdd's feedthrough): the measurement's
        return with_sampling(dss, early[0] if same else notebook_baseline(ms), hold=held)

    bl = baseline_for(measured, datasets)
    if saved is not None:
        check_level(saved, datasets, bl)
        notes += list(saved.concerns)
    # the simulator's knobs cannot make an accelerometer's gain error: testable against it
    kinds = _kinds(datasets, fixed_baseline=sim or not bl.free, simulator=sim)
    if sim:
        # first what the simulator can take as physics: against knobs a missing effect has bent, a
        # kind it cannot take imitates one it can (a 4 ms delay beside an AC coupling was taken as
        # 59 Hz valve dynamics, chi2 1299 against the delay's 1369); the second selection, after the
        # carry, has the whole library for what remains
        kinds = [k for k in kinds if k.label in CARRY]
    before, after, steps, tried = forward_select(list(datasets), bl, kinds, alpha=alpha, progress=progress)
    try:
        check_residual_dof(datasets, before, [m.source for m in measured])
    except ValueError as exc:  # the cause may be the data's aliasing (a file sampled at 10/s of a 40 Hz sweep): said too
        said = [w for m in given for w in m.aliasing]
        raise ValueError(str(exc) + (f"; besides, {said[0]}" if said else "")) from None
    if before.n_residuals - before.n_params < before.n_params:
        notes.append(
            f"the baseline's {before.n_params} free parameters were fitted to {before.n_residuals} residuals (magnitude and "
            "phase of the usable points): with fewer degrees of freedom left than parameters, only a large misfit "
            "could show; a verdict of none says little here (a wider band, more points)"
        )
    pre: dict[str, dict] = {}
    if (with_hold := with_hold_found(datasets, after, steps, alpha=alpha, n_kinds=len(kinds))) is not None:
        # the command's hold on the model found: the model with it, and the baseline alone with it for the error before

        labels = [e.kind.label for e in after.effects]
        pre = {e.kind.label: dict(e.values) for e in after.effects if labels.count(e.kind.label) == 1}
        held = True
        after = relabel_modes(list(datasets), with_hold)
        before = fit_model(list(datasets), after.baseline, [], start_baseline=start_vectors(before))
    if (hold_text := hold_note(after.baseline, [m.source for m in measured])) is not None:
        notes.append(hold_text)
    if feedthrough_of(after) is not None:
        notes.append(feedthrough_note(*feedthrough_of(after)))
    error_before = channel_errors(datasets, before)
    if raw is not measured:  # the baseline on the data as measured, for the error before
        if not sim:  # on the points the divided data keep (where the law passes at least half the command)
            raw = tuple(_on_points_of(r, m) for r, m in zip(raw, measured))
        raw_datasets = tuple(Dataset.from_measured(m) for m in raw)
        before = fit_model(list(raw_datasets), baseline_for(raw, raw_datasets), [])
        error_before = channel_errors(raw_datasets, before)
    if nonlinear and not sim:
        after, images = _drop_amplitude_images(datasets, bl, after, harmonics)
        if images:
            notes.append(
                "dropped as the nonlinearity's image (a linear effect holds at every amplitude, and these make the "
                "least distorted file fit worse): " + "; ".join(images)
            )
    effects = _effects(after, steps, tried, measured, pre)
    if nonlinear:
        effects = _beside_nonlinearity(effects, " in the best linear approximation")
        notes.append(
            "the data are nonlinear: the linear model is fitted to their best linear approximation at the amplitude "
            "measured, and linear effects found with it may be the nonlinearity's image (compare a file at another amplitude)"
        )
    effects += [FoundEffect("nonlinear", f.kind, "act", dict(f.params), dict(f.stderr), f.evidence, nonlinear=f.data) for f in nonlinear]
    report = None
    final = (datasets, after)
    if sim:
        effects, (files, sim_datasets, sim_after), report, more_steps, more_tried = _simulator_pass(
            raw, measured, calibrated, effects, nonlinear, steps, alpha=alpha, progress=progress, first_baseline=bl, first_fit=(datasets, after)
        )
        final = (sim_datasets, sim_after)
        steps, tried = list(steps) + more_steps, list(tried) + more_tried
        if files is raw and raw is not measured:
            # every valve law is in the simulator: the final model and its figures are on the data as measured
            measured, raw = raw, raw
            divided_notes = [
                "the valve law is carried into the simulator: the final fit, its error after and the figures are on "
                "the data as measured (the law inside the simulator's correction)"
            ]
        notes += [f"not carried into the simulator: {n}" for n in report.not_carried]
        if report.dropped:
            notes.append(
                f"against the simulator calibrated without the carried effects the first selection also proposed "
                f"{', '.join(report.dropped)}; with them carried and the simulator recalibrated these were no longer needed "
                "(images of the first calibration's compromise)"
            )
    datasets, after = final

    placed_by_total = tuple(product_only(datasets, after))
    notes += [p.text() for p in placed_by_total]
    notes += [c.text() for c in changes]
    unexplained = unexplained_bands(datasets, after.residuals, alpha=alpha)
    unexplained += [
        Band(c.source, c.channel, c.lo_hz, c.hi_hz, c.chi2, int(np.sum((m.frf.freq_hz >= c.lo_hz) & (m.frf.freq_hz <= c.hi_hz))), "records differ")
        for c in changes
        for m in measured
        if m.source == c.source
    ]
    errors_after = channel_errors(datasets, after)
    if any(not e.expected for e in effects) and not unexplained and (left := even_misfit(errors_after)):
        # (without an effect the verdict says it; with them it read as if they explained the data: a stepped sine of 17
        # dwells, chi2 per residual 33 after its one effect, and no band of misfit on so few points)
        notes.append(
            "after the effects found the residual stays above the noise (chi2 per residual "
            + ", ".join(f"{CHANNEL_NAMES.get(c, c)} {v:.3g}" for c, v in left.items())
            + ") evenly, with no band standing out: more is missing than these, or the noise these data are judged "
            "against is too small for them; not explained"
        )
    return Diagnosis(
        measured,
        datasets,
        bl,
        before,
        after,
        tuple(steps),
        tuple(tried),
        tuple(effects),
        error_before,
        errors_after,
        tuple(unexplained),
        notes=tuple(notes[:at] + divided_notes + notes[at:] + nl_notes),
        harmonics=tuple(harmonics),
        amplitude_tests=tuple(amp_tests),
        raw_measured=None if raw is measured else raw,
        simulator=report,
        nonlinear=tuple(nonlinear),
        product_only=placed_by_total,
    )
