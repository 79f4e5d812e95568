"""A fit's concerns and caveats as data: a code, the figures it rests on, the parameters it names, what to try.

A *concern* says the fit's parameters should not be used (the solver put one where no reading of the data would, the
data are noise, the starts missed the cost's lowest minimum); a *caveat* says what to know before using them (a mode
the data do not determine, residuals far above the noise in bands). Both are :class:`Finding` values with a ``code``
(one of :data:`CODES`), the ``values`` it rests on, the parameters it ``names`` and the ``remedies`` that apply (codes
of :data:`REMEDIES`). The sentence is rendered from those fields (:meth:`Finding.words`): the figures are worded here,
the remedies in the spelling of the caller's options (:data:`COMMAND_LINE`, the commands' flags, by default: fit.json
is the command's file; :data:`PYTHON` names :func:`samii.identify.fit.fit`'s keywords).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from samii.json_output import finite_or_none

__all__ = ["CODES", "COMMAND_LINE", "KINDS", "PYTHON", "REMEDIES", "Finding"]

#: What each code finds. ``kind`` (below) sorts them further: a "misplaced" parameter makes a concern, an
#: "unmeasured" one a caveat.
CODES = {
    "outside_band": "a mode's frequency lies outside the fitted band: only its tail is seen",
    "overdamped": "a mode's damping is above 1/sqrt(2): it has no resonant peak",
    "in_noise": "a mode sits where the fitted channels are noise",
    "damping_on_bound": "a damping ratio is on its bound",
    "out_of_order": "two modes are out of the structure's order",
    "unresolved_pair": "two modes are closer than their half-power bandwidths: one resonance fitted by two",
    "noise_only": "no point of the fitted channels has coherence enough to be tested: the data are noise",
    "not_lowest": "a frequency's own profile reaches a cost far below the fit's: the starts missed the lowest minimum",
    "misfit_bands": "the residuals are far above the data's noise in bands: the structure misses an effect there",
}

#: How a finding bears on the parameters (``Finding.kind``).
KINDS = ("misplaced", "unmeasured", "noise", "start", "structure")

#: What to try, by code; the words name the options in the caller's spelling (``{band}``, ``{modes}``, ``{weighting}``).
REMEDIES = {
    "widen_band": "widen {band} to include it",
    "band_where_holds": "fit {band} where the structure holds",
    "band_where_coherent": "fit {band} where the coherence is high",
    "narrower_band": "try a narrower {band}",
    "fewer_modes": "fewer {modes}",
    "try_fewer_modes": "try fewer {modes}",
    "weigh_by_coherence": "fit with {weighting} (the noise floor counts as much as the resonances in the notebook's cost)",
    "more_excitation": "measure with more excitation",
    "more_excitation_there": "measure with more excitation there",
    "other_starts": "fit from other starts, or with coherence, where the data have it",
    "look_at_bands": "look at the bands for the missing effect",
}

#: The options as the command line spells them (``samii fit``).
COMMAND_LINE = MappingProxyType({"band": "--band-hz", "modes": "--modes", "weighting": "--weighting coherence"})
#: The options as :func:`samii.identify.fit.fit` spells them.
PYTHON = MappingProxyType({"band": "band_hz", "modes": "n_modes in the structure", "weighting": "weighting='coherence'"})


@dataclass(frozen=True)
class Finding:
    """One concern or caveat of a fit.

    ``code``: one of :data:`CODES`. ``kind``: "misplaced" (the solver put a parameter where no reading of the data
    would: a concern), "unmeasured" (the data do not determine it, wherever it is put: a caveat), "noise" (no
    parameter is determined), "start" (the starts missed the lowest minimum) or "structure" (the structure misses an
    effect in bands). ``values``: the figures it rests on (frequencies in Hz). ``names``: the parameters it concerns.
    ``remedies``: codes of :data:`REMEDIES`, in the order they are said.
    """

    code: str
    kind: str
    values: Mapping[str, object] = field(default_factory=dict)
    names: tuple[str, ...] = ()
    remedies: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.code not in CODES:
            raise ValueError(f"unknown code {self.code!r}; known: {', '.join(CODES)}")
        unknown = [r for r in self.remedies if r not in REMEDIES]
        if unknown:
            raise ValueError(f"unknown remedies {unknown}; known: {', '.join(REMEDIES)}")
        if self.kind not in KINDS:
            raise ValueError(f"unknown kind {self.kind!r}; known: {', '.join(KINDS)}")
        object.__setattr__(self, "values", MappingProxyType(dict(self.values)))

    @property
    def finding(self) -> str:
        """What was found, in words (no remedy)."""
        return _FINDINGS[self.code](self.values)

    def words(self, options: Mapping[str, str] = COMMAND_LINE) -> str:
        """The finding and what to try, the options in ``options``' spelling."""
        said = ""
        for r in self.remedies:
            said += (", or " if r in _ALTERNATIVES else ", ") * bool(said) + REMEDIES[r].format(**options)
        return f"{self.finding}: {_ADVICE[self.code](self.values).format(remedies=said)}"

    @property
    def text(self) -> str:
        """:meth:`words` in the command line's spelling (what ``samii fit`` prints and fit.json holds)."""
        return self.words()

    def to_dict(self) -> dict:
        """JSON-ready: the code, kind, values (tuples as lists, numpy numbers as Python's), names, remedies and the text."""
        return {
            "code": self.code,
            "kind": self.kind,
            "values": finite_or_none(dict(self.values)),
            "names": list(self.names),
            "remedies": list(self.remedies),
            "text": self.text,
        }


def _noise_how(v: Mapping) -> str:
    c = v["coherence"]
    if v["read_from"] == "coherence":
        return f"coherence {c:.2f} in {v['channel']} around it, corrected for the bias of {v['averages'] or 'its'} averages"
    return f"{v['channel']} has no coherence; its scatter about the fit there is {np.sqrt(1 / c - 1):.2g} of the response, a coherence of {c:.2f}"


def _bands(v: Mapping) -> str:
    return "; ".join(f"{ch} {lo:.3g}-{hi:.3g} Hz" for ch, lo, hi in v["bands"])


def _misfit(v: Mapping) -> str:
    ratio = ", ".join(f"{c} {r:.3g}" for c, r in v["noise_ratio"].items() if r is not None)
    return f"the residuals are far above the data's noise in {len(v['bands'])} band(s) ({_bands(v)})" + (
        f"; RMS residual / random error: {ratio}" if ratio else ""
    )


_FINDINGS = {
    "outside_band": lambda v: f"mode {v['mode']} = {v['freq_hz']:.3g} Hz lies outside the fitted band {v['band_hz'][0]:.3g}-{v['band_hz'][1]:.3g} Hz",
    "overdamped": lambda v: (
        f"mode {v['mode']} = {v['freq_hz']:.3g} Hz has damping {v['damping']} = {v['zeta']:.3g}, above 1/sqrt(2): it has no "
        "resonant peak, so it is a shape the fit chose, not a mode the data show"
    ),
    "in_noise": lambda v: f"mode {v['mode']} = {v['freq_hz']:.3g} Hz sits where the data are noise ({_noise_how(v)}), not at a measured resonance",
    "damping_on_bound": lambda v: f"damping {v['damping']} = {v['zeta']:.4g} is on its bound {tuple(v['bounds'])}",
    "out_of_order": lambda v: f"mode {v['upper']} = {v['upper_hz']:.3g} Hz lies below mode {v['lower']} = {v['lower_hz']:.3g} Hz",
    "unresolved_pair": lambda v: (
        f"modes {v['lower']} = {v['lower_hz']:.3g} Hz and {v['upper']} = {v['upper_hz']:.3g} Hz are closer than their half-power bandwidths"
    ),
    "noise_only": lambda v: f"no point has coherence >= {v['min_coherence']:g} in the fitted channels (the highest is {v['highest']:.3g})",
    "not_lowest": lambda v: (
        f"{v['param']} is not at the minimum of the fit's cost: held at {v['held_hz']:.4g} Hz (the fit's {v['fit_hz']:.4g} Hz) "
        f"the others re-solved reach a cost {v['below']:.3g} squared standard errors lower, so the fit's value lies outside "
        "its own 99.9 % interval"
    ),
    "misfit_bands": _misfit,
}

#: Remedies said as alternatives to those before them (", or ...").
_ALTERNATIVES = frozenset({"fewer_modes", "look_at_bands"})

#: Each code's advice around its remedies (``{remedies}``).
_ADVICE = {
    "outside_band": lambda v: "{remedies}",
    "overdamped": lambda v: "{remedies}",
    "in_noise": lambda v: "the data do not determine it; {remedies}",
    "damping_on_bound": lambda v: "the mode is not in the data as modelled; {remedies}",
    "out_of_order": lambda v: (
        "the structure numbers its modes upward"
        + (" (mode 2 is the actuator zero wz)" if v["tied"] else "")
        + ", so a mode has left the place the data give it; {remedies}"
    ),
    "unresolved_pair": lambda v: "one resonance fitted by two modes; {remedies}",
    "noise_only": lambda v: "the data are noise, and no parameter is determined by them; {remedies}",
    "not_lowest": lambda v: "the starts did not reach the cost's lowest minimum ({remedies})",
    "misfit_bands": lambda v: (
        "the model structure misses an effect there, and the parameters are this structure's best compromise, not the system's; {remedies}"
    ),
}
