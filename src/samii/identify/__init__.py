"""samii.identify: fit the notebook's transfer-function models to frequency-response data.

Structures (eq 9.1 actuator, N-mode base with s^4 or s^2 numerator) are
``ModelStructure``; the notebook's weighted dB/phase cost is ``FitProblem``;
``fit`` runs bounded least squares from several starts and returns a
``FitResult`` with standard errors, RMS errors, identifiability warnings and a
lack-of-fit report (``samii.identify.lack_of_fit``: bands where the residuals
exceed the random error the data's coherence predicts, i.e. where the model
misses an effect). Parameters the fitted channels do not depend on (the base's
with theta/v alone) are reported as not fitted.

The 95 % intervals were checked by seeded trials (tests/test_identify_fit.py,
fits started 30 % off the truth, 3-average swept-sine noise): coverage 0.965 for
eq 9.4 (520 intervals) and 0.953 for eq 1.4 over 1-12 Hz (400); nominal 0.95.
"""

from samii.identify.cost import FitProblem, notebook_cost
from samii.identify.fit import FitResult, fit, fit_problem
from samii.identify.lack_of_fit import LackOfFit, MisfitBand, lack_of_fit
from samii.identify.structures import ModelStructure
from samii.identify.synthetic import SweptSineNoise, synthesize

__all__ = [
    "FitProblem",
    "FitResult",
    "LackOfFit",
    "MisfitBand",
    "ModelStructure",
    "SweptSineNoise",
    "fit",
    "fit_problem",
    "lack_of_fit",
    "notebook_cost",
    "synthesize",
]
