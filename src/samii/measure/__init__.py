"""samii.measure: the rig's Bode measurement, done on recorded signals.

Modules (import from them; this package imports nothing heavy):

- ``excitation``: swept sine (:class:`SweptSine`) and stepped sine (:class:`SteppedSine`).
- ``daq``: anti-alias filtering, sampling at the DAQ rate, seeded sensor noise.
- ``frf``: closed-loop FRF with the excitation as instrument, with coherence.
- ``frf_variance``: a time series' FRF with the random error of every point, from its records' spread.
- ``stepped``: steady-state sine correlation at the stepped-sine frequencies.
- ``measured``: measured data (a time series, an FRF file, a rig-era .mat) as an FRF with the random error of every
  point and what a user should know about it (drift, mains hum, coarse encoders, aliasing): what ``samii frf``
  estimates and a diagnosis weighs residuals against.
- ``floor``: the systematic floor of a measured FRF (the estimator's bias, quantisation, a stated relative floor).
- ``records``, ``drift``, ``lines``: a time series' records found, its drift between rests, mains hum removed.
- ``linear_rig``: the notebook's transfer functions under the position loop, a
  linear stand-in used to prove the chain against an exact FRF.

(The sampled-signals value :class:`samii.timeseries.TimeSeries` and the file formats, :mod:`samii.formats`, are on
the ground floor: every stage uses them.)
"""
