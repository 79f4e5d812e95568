"""Whether an effect found against a model that still misses the data can be told from an image of what it lacks.

The F-test and the floor (samii.diagnose.select) judge an effect against the model without it. When the model
with every effect still misses the data beyond their noise and floor (``samii.diagnose.simulator.misfits``: the
calibrated simulator on a rig whose structure it does not share), a library shape fitted there takes up part of
a misfit of another shape: a significant, practically large change that is no property of the rig. Against the
simulator, the second rig's eq 9.4 plants (a 2 ms command delay) gave base "modes" at 1.7 and 7.6 Hz and a
pole/zero pair at 4.1/5.2 Hz beside a residual of 4-6 dB and 40-70 deg left in the same bands.

The test: within the bands the final model still misses, where the effect changes the response by more than the
practical floor, the effect must explain most of what is there. The residual's power over those points with the
effect must be at most ``EXPLAINS`` of its power without it (its rms at least halved). A real effect takes its
own change out and leaves that band's other misfit; an image leaves most of the misfit it was fitted to. Where
the final model leaves no such band, nothing is asked beyond the selection's tests.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from samii.diagnose.effects import LIBRARY, TWO_PI, Effect
from samii.diagnose.evidence import Refusal
from samii.diagnose.model import Dataset, Fit
from samii.diagnose.residuals import full_residuals, model_response, runs
from samii.frequency_response import CHANNEL_NAMES
from samii.measure.floor import PRACTICAL_FACTOR, REL_FLOOR

#: The residual's power left by an effect within the misfit bands it acts in, as a fraction of the power without
#: it, above which it is not told from an image: its rms must at least halve (1/2 squared).
EXPLAINS = 0.25

_KINDS = {k.label: k for k in LIBRARY}


def _change(fit: Fit, i: int, freq_hz: np.ndarray, label: str, values: Mapping[str, float]) -> dict[str, np.ndarray]:
    """ln(model with the effect / model without it) per channel of file ``i`` at ``freq_hz``: taken out of ``fit``
    when one of its effects has ``label`` and ``values``, else added to it (an effect the baseline already holds:
    carried into the simulator; to first order the same change)."""
    mine = [
        j
        for j, e in enumerate(fit.effects)
        if e.kind.label == label and all(np.isclose(e.values.get(n, np.nan), v, rtol=1e-9) for n, v in values.items())
    ]
    if mine:
        without = replace(fit, effects=tuple(e for j, e in enumerate(fit.effects) if j != mine[0]))
        with_it = fit
    else:
        kind = _KINDS[label]
        effect = Effect(kind, {p.name: float(values[p.name]) for p in kind.params}, {})
        without, with_it = fit, replace(fit, effects=fit.effects + (effect,))
    a, b = model_response(with_it, i, freq_hz), model_response(without, i, freq_hz)
    return {ch: np.log(a[ch] / b[ch]) for ch in a}


def unattributed(fit: Fit, datasets: Sequence[Dataset], bands: Sequence, label: str, values: Mapping[str, float]) -> Refusal | None:
    """Why the effect ``label`` with ``values`` cannot be told from an image of what ``fit`` (the final model, the
    effect in it or in its baseline) lacks, or None (module docstring). ``bands``: where ``fit`` still misses the
    data (``samii.diagnose.simulator.Misfit``: source, channel, lo_hz, hi_hz, rms_db, rms_deg)."""

    if label not in _KINDS or not bands:
        return None
    if any(p.name not in values for p in _KINDS[label].params):
        return None
    with_power = without_power = 0.0
    where = []
    for i, ds in enumerate(datasets):
        mine = [b for b in bands if b.source == ds.source]
        if not mine:
            continue
        change = _change(fit, i, ds.freq_hz, label, values)
        res = full_residuals(ds, fit.residuals[i])
        for b in mine:
            if b.channel not in change or b.channel not in res:
                continue
            r1 = res[b.channel][0]
            sel = (ds.freq_hz >= b.lo_hz) & (ds.freq_hz <= b.hi_hz) & np.isfinite(r1)
            c = change[b.channel][sel]
            if not sel.any() or np.sqrt(np.mean(np.abs(c) ** 2)) <= PRACTICAL_FACTOR * REL_FLOOR:
                continue  # it does not act there: that misfit is not its business
            with_power += float(np.sum(np.abs(r1[sel]) ** 2))
            without_power += float(np.sum(np.abs(r1[sel] + c) ** 2))
            where.append(b)
    if not where or with_power <= EXPLAINS * without_power:
        return None
    worst = max(where, key=lambda b: b.chi2 * b.n_points)
    said = {"n_bands": len(where), "channel": worst.channel, "channel_name": CHANNEL_NAMES[worst.channel]}
    said |= {"band_hz": (worst.lo_hz, worst.hi_hz), "rms_db": worst.rms_db, "rms_deg": worst.rms_deg}
    return Refusal("image", {**said, "takes_out_pct": 100 * (1 - with_power / without_power), "needed_pct": 100 * (1 - EXPLAINS)})


#: Points a band where only xdd/v is usable must hold to be named: fewer are the odd point where theta/v's variance
#: crosses its limit, not a band.
PRODUCT_ONLY_POINTS = 3
#: A resonance or corner is placed by xdd/v alone only this factor inside the band's edge where theta/v is usable:
#: nearer, theta/v's own points see its flank (theta/v's zero wz at 10.0 Hz, damped 0.05, moves theta/v at 8.9 Hz
#: fivefold), further in a valve's lag or a mode moves theta/v's last usable points by a few percent, which the
#: baseline's own gains and dampings absorb.
PRODUCT_ONLY_MARGIN = 1.25
#: An effect's parameters that place it in frequency (Hz), in the order they are named, with what each is beside another.
_FREQ_PARAMS = {"freq_hz": "pole", "corner_hz": "corner", "pole_hz": "pole", "zero_freq_hz": "zero", "zero_hz": "zero"}


def _product_only_runs(ds: Dataset) -> list[tuple[float, float, bool, bool]]:
    """The bands of ``ds`` where xdd/v is usable and neither theta/v nor xdd/theta is, runs of at least
    PRODUCT_ONLY_POINTS consecutive points: (lo Hz, hi Hz, whether theta/v is usable below lo, and above hi)."""

    if "total" not in ds.keep:
        return []
    others = np.zeros(ds.freq_hz.size, bool)
    for ch in ("act", "base"):
        if ch in ds.keep:
            others |= np.asarray(ds.keep[ch], bool)
    only = np.asarray(ds.keep["total"], bool) & ~others
    return [
        (float(ds.freq_hz[a]), float(ds.freq_hz[b - 1]), bool(others[:a].any()), bool(others[b:].any()))
        for a, b in runs(only)
        if b - a >= PRODUCT_ONLY_POINTS
    ]


@dataclass(frozen=True)
class Placed:
    """A resonance or corner a model places in frequency: ``what`` (an effect's kind, or "base mode K" / "wp" of the
    baseline), its frequencies [Hz] (an actuator mode: pole and zero), and the channel whose factor holds it."""

    what: str
    freqs_hz: tuple[float, ...]
    channel: str  # "act" or "base"
    baseline: bool = False
    #: What each frequency is where there are several ("pole", "zero"), in ``freqs_hz``'s order
    roles: tuple[str, ...] = ()

    def text(self) -> str:
        side = CHANNEL_NAMES.get(self.channel, self.channel)
        if self.baseline:
            name = "theta/v resonance wp" if self.what == "wp" else self.what
            return f"the baseline's {name} ({self.freqs_hz[0]:.3g} Hz; {side})"
        if len(self.freqs_hz) == 1:
            return f"{self.what} ({self.freqs_hz[0]:.3g} Hz; {side})"
        return f"{self.what} ({', '.join(f'{r} {f:.3g} Hz' for r, f in zip(self.roles, self.freqs_hz))}; {side})"


@dataclass(frozen=True)
class ProductOnly:
    """What a model places in a band of one file where only xdd/v is usable (:func:`product_only`)."""

    source: str
    lo_hz: float
    hi_hz: float
    placed: tuple[Placed, ...]

    def text(self) -> str:
        return (
            f"{self.source}: from {self.lo_hz:.3g} to {self.hi_hz:.3g} Hz only xdd/v is usable (theta/v is noise there: "
            f"theta barely moves; xdd/theta, the quotient, with it); what the model places there "
            f"({'; '.join(p.text() for p in self.placed)}) is seen through xdd/v = theta/v x xdd/theta alone, so whether "
            "the actuator (theta/v) or the base (xdd/theta) has it is not measured: another reading of the same data (an "
            "actuator's lag or mode in place of a base mode, or the reverse) can fit about as well; to tell, measure "
            "theta/v in that band (a larger excitation there, a finer angle sensor)"
        )


def _placed(fit: Fit, i: int) -> list[Placed]:
    """What ``fit`` places in frequency for file ``i``: each effect with a frequency and the baseline's own resonances
    (the notebook's structure: theta/v's pole pair wp, the base's modes; a structure without named modes: none)."""
    out = []
    for e in fit.effects:
        names = [n for n in _FREQ_PARAMS if n in e.values]
        if names:
            out.append(Placed(e.kind.kind, tuple(float(e.values[n]) for n in names), e.kind.channel, roles=tuple(_FREQ_PARAMS[n] for n in names)))
    st = fit.baseline.structure
    if st is None or not fit.baseline_params or not hasattr(st, "mode_names") or i >= len(fit.baseline_params):
        return out
    p = fit.baseline_params[i]
    if "wp" in p:
        out.append(Placed("wp", (p["wp"] / TWO_PI,), "act", baseline=True))
    for k in range(1, st.n_modes + 1):
        wn, _ = st.mode_names(k)
        if wn in p:
            out.append(Placed(f"base mode {k}", (p[wn] / TWO_PI,), "base", baseline=True))
    return out


def product_only(datasets: Sequence[Dataset], fit: Fit) -> list[ProductOnly]:
    """What ``fit`` places where only xdd/v is usable, per file and band. There theta/v (and with it xdd/theta, the
    quotient) is noise: theta barely moves above the servo loop's crossover. xdd/v = theta/v x xdd/theta sees a
    resonance or a lag there, but not which factor has it; the model's structure alone decides whether it is the
    actuator's (a valve's lag, a mode theta/v sees) or the base's (a base mode), and small changes of the data (their
    units, an offset, a hum) tip that decision. Battery C's rig.csv (the default simulator: base mode 3 at 23.3 Hz,
    the oil column's resonance at 31.7 Hz, theta/v usable to 9 Hz) was read as an actuator mode at 23.6 Hz beside the
    baseline's mode 3 at 32.4 Hz (chi2 746), with theta in degrees as the baseline's mode 3 at 23.6 Hz and a valve at
    32.3 Hz (782), and with xdd in g as the same mode 3 and a base mode at 32.4 Hz (759), on about 635 degrees of freedom."""
    out = []
    for i, ds in enumerate(datasets):
        placed = sorted(_placed(fit, i), key=lambda p: min(p.freqs_hz))
        for lo, hi, below, above in _product_only_runs(ds):
            lo_in = lo * PRODUCT_ONLY_MARGIN if below else lo
            hi_in = hi / PRODUCT_ONLY_MARGIN if above else hi
            inside = tuple(p for p in placed if any(lo_in <= f <= hi_in for f in p.freqs_hz))
            if inside:
                out.append(ProductOnly(ds.source, lo, hi, inside))
    return out
