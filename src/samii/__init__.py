"""samii: simulate, measure, identify and control SAMII, a hydraulic arm on a flexible beam.

The pipeline (see README.md)::

    sim -> measure -> identify -> design -> closedloop -> diagnose

Each stage is a subpackage; values passed between stages are typed
(``FrequencyResponse``, fit results, controllers). Everything is SI inside.
"""

from samii import frequency_response

__version__ = "0.1.0"
__all__ = ["CHANNELS", "FrequencyResponse", "__version__"]


def __getattr__(name: str):
    # imported on first use: the ``samii`` command starts (and handles Ctrl-C) before numpy is loaded
    if name in ("CHANNELS", "FrequencyResponse"):
        return getattr(frequency_response, name)
    raise AttributeError(f"module 'samii' has no attribute {name!r}")
