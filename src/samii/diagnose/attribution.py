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

from dataclasses import replace
from typing import Mapping, Sequence

import numpy as np

from samii.diagnose.effects import LIBRARY, Effect
from samii.diagnose.model import Dataset, Fit

#: The residual's power left by an effect within the misfit bands it acts in, as a fraction of the power without
#: it, above which it is not told from an image: its rms must at least halve (1/2 squared).
EXPLAINS = 0.25

_KINDS = {k.label: k for k in LIBRARY}


def _change(fit: Fit, i: int, freq_hz: np.ndarray, label: str, values: Mapping[str, float]) -> dict[str, np.ndarray]:
    """ln(model with the effect / model without it) per channel of file ``i`` at ``freq_hz``: taken out of ``fit``
    when one of its effects has ``label`` and ``values``, else added to it (an effect the baseline already holds:
    carried into the simulator; to first order the same change)."""
    from samii.diagnose.diagnosis import model_response

    mine = [j for j, e in enumerate(fit.effects) if e.kind.label == label and all(
        np.isclose(e.values.get(n, np.nan), v, rtol=1e-9) for n, v in values.items())]
    if mine:
        without = replace(fit, effects=tuple(e for j, e in enumerate(fit.effects) if j != mine[0]))
        with_it = fit
    else:
        kind = _KINDS[label]
        effect = Effect(kind, {p.name: float(values[p.name]) for p in kind.params}, {})
        without, with_it = fit, replace(fit, effects=fit.effects + (effect,))
    a, b = model_response(with_it, i, freq_hz), model_response(without, i, freq_hz)
    return {ch: np.log(a[ch] / b[ch]) for ch in a}


def unattributed(fit: Fit, datasets: Sequence[Dataset], bands: Sequence, label: str, values: Mapping[str, float]) -> str | None:
    """Why the effect ``label`` with ``values`` cannot be told from an image of what ``fit`` (the final model, the
    effect in it or in its baseline) lacks, or None (module docstring). ``bands``: where ``fit`` still misses the
    data (``samii.diagnose.simulator.Misfit``: source, channel, lo_hz, hi_hz, rms_db, rms_deg)."""
    from samii.diagnose.diagnosis import CHANNEL_NAMES, _full_residuals
    from samii.diagnose.floor import PRACTICAL_FACTOR, REL_FLOOR

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
        res = _full_residuals(ds, fit.residuals[i])
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
    return (f"not told from an image of what the model lacks: with it the model still misses the data where it acts "
            f"({len(where)} band(s), the largest {CHANNEL_NAMES[worst.channel]} {worst.lo_hz:.3g}-{worst.hi_hz:.3g} Hz by "
            f"{worst.rms_db:.2g} dB, {worst.rms_deg:.2g} deg rms), and there it takes out {100 * (1 - with_power / without_power):.0f} % "
            f"of the residual's power, less than the {100 * (1 - EXPLAINS):.0f} % an effect of the rig takes out of its own change")
