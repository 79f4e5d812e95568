"""samii: simulate, measure, identify and control SAMII, a hydraulic arm on a flexible beam.

The pipeline (see README.md)::

    sim -> measure -> identify -> design -> closedloop -> diagnose

Each stage is a subpackage; values passed between stages are typed
(``FrequencyResponse``, fit results, controllers). Everything is SI inside.
"""

__version__ = "0.1.0"
__all__ = ["CHANNELS", "FrequencyResponse", "__version__"]


def __getattr__(name: str):
    if name in ("CHANNELS", "FrequencyResponse"):
        from samii import frequency_response  # (lazy: the samii command installs its Ctrl-C handling before numpy loads)

        return getattr(frequency_response, name)
    raise AttributeError(f"module 'samii' has no attribute {name!r}")
