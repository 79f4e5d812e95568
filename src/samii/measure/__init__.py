"""samii.measure: the rig's Bode measurement, done on recorded signals.

Modules (import from them; this package imports nothing heavy):

- ``timeseries``: the sampled-signals value :class:`TimeSeries`.
- ``io``: the file formats of DATA_FORMATS.md (time-series CSV, FRF CSV, rig-era .mat).
- ``excitation``: swept sine (:class:`SweptSine`) and stepped sine (:class:`SteppedSine`).
- ``daq``: anti-alias filtering, sampling at the DAQ rate, seeded sensor noise.
- ``frf``: closed-loop FRF with the excitation as instrument, with coherence.
- ``stepped``: steady-state sine correlation at the stepped-sine frequencies.
- ``linear_rig``: the notebook's transfer functions under the position loop, a
  linear stand-in used to prove the chain against an exact FRF.
"""
