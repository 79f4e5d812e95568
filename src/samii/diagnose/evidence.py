"""A found effect's evidence as data: how it joined the model, its rivals, and the sentence rendered from them.

:class:`Joined` holds the test that admitted an effect (the F-test against the model before it: chi2 before and
after, its parameters, F on its degrees of freedom, log10 p, the places a broad mode was searched over; a swap for an
effect that had joined by F-test; the joint refit; the F-test against the calibrated simulator), :class:`Rival` a
reading of the data that fits almost as well in its place (chi2 within samii.diagnose.select.AMBIGUOUS_CHI2 noise
variances; a richer one whose extra parameters the F-test does not justify; another effect's rival that moves this
one's values). :func:`evidence_text` renders a found effect's sentence from them, so a reader (or a test) takes the
figures from the fields, never from the words. A nonlinear effect's evidence lives beside its laws, in
:mod:`samii.diagnose.nonlinear` (``NonlinearEvidence``: its harmonics and the amplitude test across files).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from samii.diagnose.effects import LIBRARY

__all__ = ["JOINED_HOW", "REFUSALS", "RIVAL_HOW", "Joined", "Refusal", "Rival", "evidence_text", "values_text"]

#: How a found effect joined the model (``Joined.how``).
JOINED_HOW = {
    "f_test": "it lowered chi2 enough for its parameters by the F-test against the model before it",
    "swap": "it replaced an effect that had joined by F-test, with no more parameters or with more the F-test justifies",
    "refit": "kept by the joint refit of everything found",
    "simulator": "its F-test against the simulator calibrated without it (diagnose --baseline sim)",
}

#: How a rival fits almost as well (``Rival.how``).
RIVAL_HOW = {
    "in_its_place": "in the effect's place, chi2 within AMBIGUOUS_CHI2 noise variances",
    "richer": "in its place with more parameters, which the F-test does not justify: the simpler is kept",
    "moves_it": "in place of another effect, which moves this one's values by more than 5 %",
}


@dataclass(frozen=True)
class Joined:
    """The test that admitted a found effect (``how``: a key of :data:`JOINED_HOW`).

    ``chi2_before``/``chi2_after``: the model's chi2 before and after it joined; ``dof``: the F-test's degrees of
    freedom (its parameters, the residual's); ``f_stat`` and ``log10_p`` (-300 or below: p underflows, said
    "p < 1e-300"; -inf where F's tail underflows entirely, null in JSON); ``places``: the independent places a broad mode's frequency was searched over (``log10_p``
    includes them). A swap: ``replaced`` names the effect it replaced, ``extra_params`` its parameters beyond that
    effect's (0: none; F and p given only when more).
    """

    how: str
    chi2_before: float | None = None
    chi2_after: float | None = None
    dof: tuple[int, int] | None = None
    f_stat: float | None = None
    log10_p: float | None = None
    places: float = 1.0
    replaced: str | None = None
    extra_params: int | None = None

    def __post_init__(self) -> None:
        if self.how not in JOINED_HOW:
            raise ValueError(f"Joined.how must be one of {', '.join(JOINED_HOW)}, got {self.how!r}")

    @classmethod
    def of_step(cls, how: str, step) -> Joined:
        """The F-test of a selection's step (samii.diagnose.select.Step) as ``how`` it joined."""
        return cls(how, step.chi2_before, step.chi2_after, tuple(step.dof), step.f_stat, step.log10_p, step.places)


@dataclass(frozen=True)
class Rival:
    """A reading of the data that fits almost as well (``how``: a key of :data:`RIVAL_HOW`).

    ``effect``: the rival's label. ``delta_in_noise``: how much lower the kept effect's chi2 is than the rival's, in
    noise variances (negative: the richer rival's is lower). ``extra_params``: a richer rival's parameters beyond the
    kept effect's. ``values``: the rival's own values, or (``moves_it``) this effect's values with the rival in place
    of ``in_place_of``. ``moved``: other effects' values with the rival in place, those that move by more than 5 %.
    ``without_hold``: the rival was fitted against the model without the command's hold (the values looked up there).
    """

    how: str
    effect: str
    delta_in_noise: float | None = None
    extra_params: int | None = None
    values: Mapping[str, float] = field(default_factory=dict)
    moved: tuple[tuple[str, Mapping[str, float]], ...] = ()
    in_place_of: str | None = None
    without_hold: bool = False

    def __post_init__(self) -> None:
        if self.how not in RIVAL_HOW:
            raise ValueError(f"Rival.how must be one of {', '.join(RIVAL_HOW)}, got {self.how!r}")


def values_text(label: str, values: Mapping[str, float]) -> str:
    """``values`` of the effect ``label`` in units a reader knows (a delay in ms)."""

    units = {p.name: p.unit for k in LIBRARY if k.label == label for p in k.params}
    return ", ".join(
        f"{n} {1e3 * v:.3g} ms" if n == "delay_s" else f"{n} {v:.4g}{' ' + units[n] if units.get(n, '1') != '1' else ''}" for n, v in values.items()
    )


def p_text(log10_p: float, digits: int = 1) -> str:
    """A p-value in words from its log10 (``digits`` after the point): p < 1e-300 where it underflows."""
    return "p < 1e-300" if log10_p <= -300 else f"p = 10^{log10_p:.{digits}f}"


def joined_text(j: Joined) -> str:
    """How ``j``'s effect joined, in words."""
    if j.how == "f_test":
        p = p_text(j.log10_p)
        if j.places > 1.0 and j.log10_p > -300:
            p += f" (the best of the {j.places:.0f} places a mode this broad has in the band)"
        return (
            f"adding it lowers chi2 from {j.chi2_before:.4g} to {j.chi2_after:.4g} for {j.dof[0]} parameter(s): "
            f"F = {j.f_stat:.3g} on ({j.dof[0]}, {j.dof[1]}) dof, {p}"
        )
    if j.how == "swap":
        more = f"{j.extra_params} more parameter(s)" if j.extra_params else "no more parameters"
        text = f"it replaced {j.replaced}, which had joined by F-test, with {more}: chi2 {j.chi2_before:.4g} -> {j.chi2_after:.4g}"
        return text + (f", F = {j.f_stat:.3g}, {p_text(j.log10_p)}" if j.extra_params else "")
    if j.how == "simulator":
        return f"F = {j.f_stat:.3g}, {p_text(j.log10_p)} against the simulator calibrated without it"
    return "kept by the joint refit"


def _rival_values(r: Rival) -> str:
    parts = [f"; its {values_text(r.effect, r.values)}"] if r.values else []
    if r.moved:
        parts.append("; with it " + ", ".join(f"{lab} {values_text(lab, v)}" for lab, v in r.moved))
    return "".join(parts)


def rival_text(label: str, r: Rival) -> str:
    """``r``, a rival of the effect ``label``, in words (beginning "; ")."""
    hold = " in the model without the command's hold" if r.without_hold else ""
    if r.how == "in_its_place":
        return (
            f"; but {r.effect} in its place fits almost as well (chi2 differs by {r.delta_in_noise:.2g} noise variances"
            f"{_rival_values(r)}{hold}): these data hardly tell the two apart"
        )
    if r.how == "richer":
        d = r.delta_in_noise
        how = f"lower by {d:.2g} noise variances" if d > 0 else f"higher by {-d:.2g} noise variances"
        return (
            f"; but {r.effect} in its place fits almost as well (with {r.extra_params} more parameter(s) its chi2 "
            f"is {how}, which its extra parameters do not justify by the F-test{_rival_values(r)}{hold}): these data "
            "hardly tell the two apart, and the simpler is kept"
        )
    return f"; with {r.effect} in place of {r.in_place_of} (which fits almost as well) it is {values_text(label, r.values)}"


def sampling_text(sample_s: float) -> str:
    """Why an effect within one sample is expected (beginning "; ")."""
    return (
        f"; at most one sample ({1e3 * sample_s:.3g} ms at {1.0 / sample_s:.4g} Hz), the sampling itself "
        "(zero-order hold, a command computed from the last reading): expected, not a miss"
    )


def evidence_text(label: str, description: str, joined: Joined, rivals: Sequence[Rival] = (), sample_s: float | None = None) -> str:
    """A found effect's evidence sentence, rendered from its fields: what it is (``description``, the kind's own
    words for its values), how it joined, its rivals, and (``sample_s``) that it is the sampling itself."""
    text = f"{description}; {joined_text(joined)}" + "".join(rival_text(label, r) for r in rivals)
    return text + (sampling_text(sample_s) if sample_s is not None else "")


def _band(v: Mapping) -> str:
    return f"the excited band {v['band_hz'][0]:.3g}-{v['band_hz'][1]:.3g} Hz"


#: Why a candidate that passed the F-test is refused, by code: its class (the phrase the report and diagnosis.json's
#: ``refused[].class`` give) and its words, rendered from the refusal's values.
REFUSALS = {
    "split_mode": ("a mode split in two", lambda v: "a mode split in two: within 5 % of a mode the model has"),
    "unresolved_mode": (
        "a mode the data cannot resolve",
        lambda v: "a mode the data cannot resolve: narrower than the frequency spacing, or its pole and zero closer than it",
    ),
    "theta_unusable": (
        "cannot be placed",
        lambda v: (
            "cannot be placed: no point of theta/v or xdd/theta is usable (theta under its noise or its encoder's step), "
            "and in xdd/v alone an actuator, a base and a sensor effect multiply the same response"
        ),
    ),
    "pair_below_band": (
        "below the excited band",
        lambda v: (
            f"below the excited band: neither its zero ({v['zero_hz']:.3g} Hz) nor its pole ({v['pole_hz']:.3g} Hz) lies "
            f"within a factor {v['margin']:g} of {_band(v)}"
        ),
    ),
    "pair_above_band": (
        "above the excited band",
        lambda v: (
            f"above the excited band: neither its zero ({v['zero_hz']:.3g} Hz) nor its pole ({v['pole_hz']:.3g} Hz) lies "
            f"within a factor {v['margin']:g} of {_band(v)} (there it is a group delay or lead)"
        ),
    ),
    "corners_undetermined": (
        "not determined by the data",
        lambda v: (
            f"not determined by the data: its corners ({v['zero_hz']:.3g} and {v['pole_hz']:.3g} Hz) have a standard error of "
            f"{v['ln_se']:.2g} in ln (more than a factor e either way)"
        ),
    ),
    "damping_on_bound": (
        "not a resonance",
        lambda v: (
            f"not a resonance: its damping sits on the library's bound ({v['bound']:g}), the data want a broader shape than a mode (a tilt or a bump)"
        ),
    ),
    "mode_on_range_end": (
        "not placed by the data",
        lambda v: (
            f"not placed by the data: its {v['param']} ({v['value']:.4g} Hz) sits on an end of the range searched "
            f"({v['range'][0]:.3g}-{v['range'][1]:.3g} Hz, the measured band widened by a factor): the data want it further out"
        ),
    ),
    "frequency_undetermined": (
        "not determined by the data",
        lambda v: (
            f"not determined by the data: its frequency ({v['freq_hz']:.3g} Hz) has a standard error of {v['ln_se']:.2g} "
            "in ln (more than a factor e either way)"
        ),
    ),
    "cancels": (
        "cancels within its uncertainty",
        lambda v: (
            f"cancels within its uncertainty: its pole and zero pairs ({v['freq_hz']:.3g} and {v['zero_freq_hz']:.3g} Hz) differ "
            "by less than twice their standard error"
        ),
    ),
    "longer_than_record": (
        "longer than a record",
        lambda v: f"its time constant ({v['time_constant_s']:.3g} s) is longer than a record ({v['record_s']:.3g} s): the data cannot see it settle",
    ),
    "corner_within_sampling": (
        "indistinguishable from the sampling",
        lambda v: (
            f"indistinguishable from the sampling: its corner ({v['corner_hz']:.3g} Hz) lies beyond a factor {v['margin']:g} of "
            f"{_band(v)}, where it is a group delay of {1e3 * v['lag_s']:.3g} ms, at most one sample ({1e3 * v['sample_s']:.3g} ms)"
        ),
    ),
    "corner_above_band": (
        "above the excited band",
        lambda v: (
            f"above the excited band: its corner ({v['corner_hz']:.3g} Hz) lies beyond a factor {v['margin']:g} of {_band(v)}, "
            f"where it is a group delay of {1e3 * v['lag_s']:.3g} ms (a delay, not a corner the data can place)"
        ),
    ),
    "on_range_end": (
        "not placed by the data",
        lambda v: (
            f"not placed by the data: its {v['param']} ({v['value']:.6g} {v['unit']}) sits on an end of the range the library "
            f"searches ({v['range'][0]:g} to {v['range'][1]:g}): the data want it further out, where it is no {v['kind']} they show"
        ),
    ),
    "no_usable_point": ("smaller than the measurement's floor", lambda v: "smaller than the measurement's floor: it changes no usable point"),
    "below_floor": (
        "smaller than the measurement's floor",
        lambda v: (
            f"smaller than the measurement's floor: it changes the response by more than {v['factor']:g} x the systematic floor "
            f"at {v['points']} point(s), fewer than {v['needed']} (at most {100 * v['largest_change']:.2g} % at {v['freq_hz']:.3g} Hz "
            f"on {v['channel']}, {v['largest_ratio']:.2g} x that limit)"
        ),
    ),
    "image": (
        "not told from an image",
        lambda v: (
            f"not told from an image of what the model lacks: with it the model still misses the data where it acts "
            f"({v['n_bands']} band(s), the largest {v['channel_name']} {v['band_hz'][0]:.3g}-{v['band_hz'][1]:.3g} Hz by "
            f"{v['rms_db']:.2g} dB, {v['rms_deg']:.2g} deg rms), and there it takes out {v['takes_out_pct']:.0f} % "
            f"of the residual's power, less than the {v['needed_pct']:.0f} % an effect of the rig takes out of its own change"
        ),
    ),
}


@dataclass(frozen=True)
class Refusal:
    """Why a candidate that passed the F-test is not an effect these data show: ``code`` (a key of :data:`REFUSALS`)
    and the figures it rests on (``values``, frequencies in Hz, times in s); ``cls`` its class, ``text`` its words."""

    code: str
    values: Mapping[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.code not in REFUSALS:
            raise ValueError(f"Refusal.code must be one of {', '.join(REFUSALS)}, got {self.code!r}")

    @property
    def cls(self) -> str:
        return REFUSALS[self.code][0]

    @property
    def text(self) -> str:
        return REFUSALS[self.code][1](self.values)

    def __str__(self) -> str:
        return self.text

    def to_dict(self) -> dict:
        """``{"code", "values"}``: what a tried record keeps (``Refusal(**d)`` reads it back)."""
        return {"code": self.code, "values": dict(self.values)}
