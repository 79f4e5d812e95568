"""samii.measure: the rig's Bode measurement, done on recorded signals.

Modules: ``timeseries`` (the sampled-signals value), ``io`` (the file formats of
DATA_FORMATS.md). Import from the modules; this package imports nothing heavy.
"""
