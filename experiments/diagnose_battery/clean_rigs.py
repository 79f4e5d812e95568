"""False alarms on fresh clean rigs: the diagnosis of rigs with no effect, each drawn within 15 % of eq 9.4.

``python experiments/diagnose_battery/clean_rigs.py`` diagnoses 101 clean rigs (``EffectRig.drawn`` with
seeds 1000-1039 and 300-320 at 0.1 V, 2000-2019 at 0.05 V, 3000-3019 at 0.3 V: the README's set), each
with the battery's sweep and noise, and prints every effect found (none is the goal) and the spread of
the clean fits' chi2 per degree of freedom. About 3 minutes on 2 cores.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from run import FS, SPREAD, _sweep  # noqa: E402

from samii.diagnose.diagnosis import diagnose  # noqa: E402
from samii.diagnose.rig import EffectRig  # noqa: E402
from samii.measure.measured import from_timeseries  # noqa: E402

SEEDS = [(s, 0.1) for s in (*range(1000, 1040), *range(300, 321))] + [(s, 0.05) for s in range(2000, 2020)] + [(s, 0.3) for s in range(3000, 3020)]


def main() -> None:
    alarms, chi2 = [], []
    for seed, amp in SEEDS:
        rng = np.random.default_rng(seed)
        rig = EffectRig.drawn(rng, spread=SPREAD)
        m = from_timeseries(rig.simulate(_sweep(amp), sample_rate_hz=FS, rng=rng), source=f"clean seed {seed} @ {amp:g} V")
        d = diagnose([m])
        found = [e for e in d.effects if not e.expected]
        chi2.append(d.after.chi2 / d.after.dof)
        if found:
            alarms.append((seed, amp, [(e.category, e.kind, e.params) for e in found]))
            print(f"seed {seed} at {amp:g} V: FALSE ALARM {alarms[-1][2]}", flush=True)
    print(
        f"{len(alarms)} false alarms on {len(SEEDS)} clean rigs; chi2/dof of the clean fits {min(chi2):.3g}-{max(chi2):.3g} "
        f"(median {np.median(chi2):.3g})"
    )


if __name__ == "__main__":
    main()
