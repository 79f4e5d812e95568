"""samii: simulate, measure, identify and control SAMII, a hydraulic arm on a flexible beam.

The pipeline (see README.md)::

    sim -> measure -> identify -> design -> closedloop -> diagnose

Each stage is a subpackage; values passed between stages are typed
(``FrequencyResponse``, fit results, controllers). Everything is SI inside.
"""

from samii.frequency_response import CHANNELS, FrequencyResponse

__version__ = "0.1.0"
__all__ = ["CHANNELS", "FrequencyResponse", "__version__"]
