"""samii.identify: fit the notebook's transfer-function models to frequency-response data.

Structures (eq 9.1 actuator, N-mode base with s^4 or s^2 numerator) are
``ModelStructure``; the notebook's weighted dB/phase cost is ``FitProblem``;
``fit`` runs bounded least squares from several starts and returns a
``FitResult`` with standard errors, RMS errors and identifiability warnings.
"""

from samii.identify.cost import FitProblem, notebook_cost
from samii.identify.fit import FitResult, fit, fit_problem
from samii.identify.structures import ModelStructure
from samii.identify.synthetic import SweptSineNoise, synthesize

__all__ = ["FitProblem", "FitResult", "ModelStructure", "SweptSineNoise", "fit", "fit_problem", "notebook_cost", "synthesize"]
