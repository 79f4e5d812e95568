"""How the data acquisition samples xdd/v's direct feedthrough: a property of the measurement, fitted with the baseline.

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

from dataclasses import replace
from typing import Sequence

import numpy as np

from samii.diagnose.effects import LIBRARY
from samii.diagnose.model import Baseline, Dataset, Fit, fit_model
from samii.diagnose.select import ALPHA, _f_test
from samii.forkmap import fork_calls, sharing

__all__ = ["with_feedthrough", "feedthrough_of", "feedthrough_note"]


def with_feedthrough(ds_list: Sequence[Dataset], baseline: Baseline, *, alpha: float = ALPHA) -> Baseline:
    """``baseline`` marked to model the sampled feedthrough on ``ds_list`` (its lag started where that test put it)
    where it can be (a structure refitted, files that state their sample rate) and the data show it beyond a delay
    (the baseline and a command delay, with the lag free against without it, F-test at ``alpha``); else ``baseline``
    itself."""
    if not baseline.free or baseline.correction or not all(ds.sample_rate_hz for ds in ds_list):
        return baseline
    if not any(ch in ds.data for ds in ds_list for ch in ("base", "total")):
        return baseline
    delay = next(k for k in LIBRARY if k.label == "delay/command")
    hold = [(delay, np.array([0.5 / max(ds.sample_rate_hz for ds in ds_list)]))]
    with sharing(baseline, delay, *ds_list):  # (the fits come back holding these very objects)
        without, with_lag = fork_calls([lambda: fit_model(list(ds_list), baseline, hold),
                                        lambda: fit_model(list(ds_list), baseline, hold, lag_start=0.0)])
    _, _, log10_p = _f_test(without, with_lag, max(ds.corr_length for ds in ds_list))
    if not log10_p < np.log10(alpha):
        return baseline
    return replace(baseline, feedthrough_lag=with_lag.feedthrough_lag[0], sample_rates_hz=tuple(float(ds.sample_rate_hz) for ds in ds_list))


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
    return (f"xdd/v passes the command straight through at high frequency (eq 9.1/9.2: theta/v of relative degree 2), and its steps "
            f"reach the data {lag:+.2f} +- {se:.2f} samples after the rest of the response ({how}): modelled as the measurement's "
            "sampling, not an effect of the rig (samii.diagnose.sampling)")
