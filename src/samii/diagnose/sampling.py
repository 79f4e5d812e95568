"""How the data acquisition samples: the command's hold and xdd/v's direct feedthrough, properties of the measurement.

**The hold.** A DAQ that writes its command sample by sample holds each value for a sample (a zero-order hold): the
rig sees the command half a sample late, on both channels (theta/v and xdd/v; xdd/theta not at all), whatever the rig,
and the data fold back the images of the rest of the spectrum (the pulse transfer function: model.hold_factor,
model.sampled_images; 1-2 % of xdd/v at 30-40 Hz at 500 Hz behind a 30 Hz accelerometer roll-off, which the
selection read as a broad base "mode" at 36.7 Hz). A delay is one number per channel to the data: a command delay c
and sensor delays t (theta) and a (xdd) show only as c + t on theta/v and c + a on xdd/v, so the hold's half sample,
left for the selection to find, came out on a sensor (a 3 ms accelerometer delay read as 3.5 ms beside a "0.5 ms
theta delay", an exact tie) or steered the rest (at 500 Hz a 30 Hz accelerometer roll-off read at 40 Hz beside a
1.4 ms accelerometer delay; the second rig's battery, stop 33).

Whether the command is held is the DAQ's, and the data tell it only once the effects are found: before, their misfit
counts as noise, and a command delay as long as the hold fits alike with it or without it. Assumed for every file
that states its rate (stop 34's first try), it bent the selection on an analogue command (the EffectRig's): an
actuator pole/zero pair beside a base mode, a 3 ms accelerometer delay read 2.5 ms. So the selection runs without
it, and :func:`with_hold_found` then tries it on the model found: every delay shortened so that each channel's total
stays, the effects it makes unnecessary dropped, kept by BIC. A held command's rig keeps it (the sampling's delay
with one effect fewer, its images fitted); an analogue command's, where it fits no better, does not. Where it is
kept for fewer effects alone (Baseline.hold_seen False), the data cannot tell it from an analogue command half a
sample longer, and the report says so.

**The feedthrough.**

The notebook's xdd/v tends to a constant at high frequency (theta/v has relative degree 2, xdd/theta grows as
s^2), so the steps of a held command pass straight into xdd. When those steps are read depends on the DAQ, not on
the rig's dynamics: a DAQ that reads its channels before it writes the new command sees each step one sample late
(half a sample later than the hold's half-sample delay of the rest), one that writes first sees it at once (half a
sample early), an analogue command has no steps (:func:`samii.diagnose.model.feedthrough_term` has the physics).
Left out of the model, that is a misfit of decibels near xdd/v's antiresonance at 500 Hz and a few tenths of a
decibel at 1 kHz, which the selection took for a 48 Hz actuator lag on a clean rig, a 75 Hz anti-alias filter for a
3 ms accelerometer delay, and delays one sample long (the second test rig's battery, stop 30).

The lag is one number for the files (one DAQ), within half a sample either way. It is modelled when the data
need it beyond a delay: the baseline with a command delay, fitted with the lag free and without it, F-test at the
selection's level (ALPHA). An analogue command (the EffectRig) has no lag to find; tested against the baseline
alone, a lag "passed" there by taking up the xdd/v part of a 0.6 ms command delay, which then went unreported.
Once modelled it is fitted in every fit whose baseline is refitted (held with it): it is the
measurement's, not an effect of the rig, so it is never a finding. (Estimated once and then held, it was wrong
where the baseline was: a 15 Hz base mode missing, -0.5 where the rig's is +0.5, and the selection then missed the
hold's delay.) Where xdd/v has no feedthrough (a valve or a filter ahead of it) the data cannot see it. A saved fit
or the simulator as the baseline (responses held fixed) do not model it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from scipy import stats

from samii.diagnose.effects import LIBRARY
from samii.diagnose.model import Baseline, Dataset, Fit, fit_model, noise_level, start_vectors
from samii.diagnose.select import ALPHA, _backward, _bic, _f_test, _vectors
from samii.forkmap import fork_calls, sharing

__all__ = ["with_sampling", "with_hold_found", "with_feedthrough", "feedthrough_of", "feedthrough_note", "hold_note"]

_DELAY = next(k for k in LIBRARY if k.label == "delay/command")


def _sampled(ds_list: Sequence[Dataset], baseline: Baseline) -> bool:
    """The sampling can be modelled: a structure refitted (a saved fit's or the simulator's responses are held as they
    are, their own sampling in them) and files that all state their sample rate."""
    return baseline.free and not baseline.correction and all(ds.sample_rate_hz for ds in ds_list)


def _holds(ds_list: Sequence[Dataset]) -> tuple[float, ...]:
    """Per file, its command's hold [s]: half a sample."""
    return tuple(0.5 / float(ds.sample_rate_hz) for ds in ds_list)


def _command_delay(ds_list, baseline: Baseline, start_s: float, **kwargs) -> Fit:
    """``baseline`` with a free command delay started at ``start_s``."""
    return fit_model(list(ds_list), baseline, [(_DELAY, np.array([start_s]))], **kwargs)


def with_feedthrough(ds_list: Sequence[Dataset], baseline: Baseline, *, alpha: float = ALPHA) -> Baseline:
    """``baseline`` marked to model the sampled feedthrough on ``ds_list`` (its lag started where that test put it)
    where it can be (a structure refitted, files that state their sample rate) and the data show it beyond a delay
    (the baseline and a command delay, with the lag free against without it, F-test at ``alpha``); else ``baseline``
    itself."""
    if not _sampled(ds_list, baseline):
        return baseline
    if not any(ch in ds.data for ds in ds_list for ch in ("base", "total")):
        return baseline
    start = (0.1 if baseline.hold_s else 0.5) / max(ds.sample_rate_hz for ds in ds_list)  # (beyond the hold, or the hold)
    with sharing(baseline, _DELAY, *ds_list):  # (the fits come back holding these very objects)
        without, with_lag = fork_calls(
            [lambda: _command_delay(ds_list, baseline, start), lambda: _command_delay(ds_list, baseline, start, lag_start=0.0)]
        )
    _, _, log10_p = _f_test(without, with_lag, max(ds.corr_length for ds in ds_list))
    if not log10_p < np.log10(alpha):
        return baseline
    return replace(baseline, feedthrough_lag=with_lag.feedthrough_lag[0], sample_rates_hz=tuple(float(ds.sample_rate_hz) for ds in ds_list))


def with_sampling(ds_list: Sequence[Dataset], baseline: Baseline, *, alpha: float = ALPHA, hold: bool = False) -> Baseline:
    """``baseline`` with the measurement's sampling: xdd/v's sampled feedthrough where the data show it
    (:func:`with_feedthrough`), and the command's hold where ``hold`` (:func:`with_hold_found` found it on the model;
    the selection runs without it), half a sample of each file's rate."""
    if hold and _sampled(ds_list, baseline):
        baseline = replace(baseline, hold_s=_holds(ds_list))
    return with_feedthrough(ds_list, baseline, alpha=alpha)


def with_hold_found(ds_list: Sequence[Dataset], fit: Fit, steps: list, *, alpha: float = ALPHA, n_kinds: int = 1) -> Fit | None:
    """``fit`` (found without the hold) with the command's hold in its baseline, where the data, with the effects
    found, prefer it so; else None.

    The hold cannot be judged before the effects are found: against a baseline that lacks them their misfit counts as
    noise, and a command delay as long as the hold fits alike with it or without it. Assumed there, it bent the
    selection on an analogue command (samii.diagnose.rig.EffectRig's, which has neither the hold's half sample nor its
    images): an actuator pole/zero pair at 110/23 Hz beside a 15 Hz base mode, a 3 ms accelerometer delay read
    2.5 ms with theta/v 0.5 ms off. So the selection runs without it, and the model found is then refitted with it:
    every delay shortened so that each channel's total stays (the command's by the hold, or, where the command has
    less, the sensors' by the rest), the effects it then makes unnecessary dropped (select._backward, at the
    selection's level over ``n_kinds``, their removal recorded in ``steps``), and it is kept where its BIC is the
    smaller (select._bic, on the two fits' smaller noise scale). A held command's sampling delay found on a sensor
    (a 3 ms accelerometer delay read 3.5 ms beside a "0.5 ms theta delay") becomes the hold and the sensor's own; the
    images the hold folds back go into the model (a 30 Hz roll-off at 500 Hz read at 40 Hz beside an accelerometer
    delay); an analogue command's model, where the hold fits no better, stays as it was."""
    bl = fit.baseline
    if bl.hold_s or not _sampled(ds_list, bl):
        return None
    held = replace(bl, hold_s=_holds(ds_list))
    hold = max(held.hold_s)
    delays = {e.kind.label: e.values["delay_s"] for e in fit.effects if e.kind.category == "delay"}
    deficit = max(hold - delays.get(_DELAY.label, 0.0), 0.0)
    vectors = []
    for kind, x in _vectors(fit.effects):
        if kind.category == "delay":
            x = x - (hold if kind.label == _DELAY.label else deficit)
            if x[0] <= 0.1 * hold:  # (all but a twentieth of a sample of it) the hold's
                continue
        vectors.append((kind, x))
    corr = max(ds.corr_length for ds in ds_list)
    refit = fit_model(list(ds_list), held, vectors, start_baseline=start_vectors(fit))
    removed: list = []
    if len(refit.effects) > 1:
        refit = _backward(list(ds_list), held, refit, corr, float(np.log10(alpha / max(n_kinds, 1))), removed)
    s2 = min(fit.chi2 / fit.dof, refit.chi2 / refit.dof)
    if not _bic(refit, s2, corr) < _bic(fit, s2, corr):
        return None
    gain = (fit.chi2 - refit.chi2) / noise_level(refit.chi2, refit.dof) / corr
    seen = bool(gain > 0.0 and stats.f.logsf(gain, 1, max(refit.dof, 1)) / np.log(10) < np.log10(alpha))
    steps.extend(removed)
    return replace(refit, baseline=replace(held, hold_seen=seen)) if seen else refit


def hold_note(baseline: Baseline, sources: Sequence[str]) -> str | None:
    """The diagnosis's note on the command's hold, where the baseline models it."""
    if not baseline.hold_s:
        return None
    each = ", ".join(f"{1e3 * h:.3g} ms" for h in baseline.hold_s)
    how = (
        "the data show it: the model with it fits better by the F-test"
        if baseline.hold_seen
        else "it fits the data as well as the model without it, with fewer effects: the sampling's own delay, which the "
        "data cannot tell from an analogue command's half a sample longer"
    )
    return (
        f"the command is held for a sample (a zero-order hold) and reaches the rig half a sample late ({each} for "
        f"{', '.join(sources)}), with the images the sampling folds back ({how}): modelled as the measurement's sampling, "
        "in every fit, not an effect of the rig; a delay found is the rig's beyond it (samii.diagnose.sampling)"
    )


def feedthrough_of(fit: Fit) -> tuple[float, float] | None:
    """(lag [samples], its standard error) of ``fit`` where the data determine it; None where it was not modelled or
    the data cannot see it (no feedthrough in xdd/v)."""
    if fit.feedthrough_lag is None:
        return None
    lag, se = fit.feedthrough_lag
    return (lag, se) if np.isfinite(se) and se > 0.0 else None


def feedthrough_note(lag: float, se: float) -> str:
    """The diagnosis's note on the lag it fitted."""
    if lag > 0.25:
        how = "a DAQ that reads its channels before it writes the new command"
    elif lag < -0.25:
        how = "a DAQ that writes the command before it reads its channels"
    else:
        how = "an analogue command, or one read mid-step"
    # the lag lies within +-0.5 samples (model.FEEDTHROUGH_LAG_MAX): an error beyond that range says the data do not place
    # it (on a file with a drifting sensor: "+0.50 +- 8117.28 samples")
    when = (
        f"reach the data {lag:+.2f} +- {se:.2f} samples after the rest of the response ({how})"
        if se <= 1.0
        else f"reach the data at a lag the data do not place (fitted {lag:+.2f} samples, standard error {se:.3g}: more than the "
        "one sample the lag can span)"
    )
    return (
        f"xdd/v passes the command straight through at high frequency (eq 9.1/9.2: theta/v of relative degree 2), and its steps "
        f"{when}: modelled as the measurement's sampling, not an effect of the rig (samii.diagnose.sampling)"
    )
