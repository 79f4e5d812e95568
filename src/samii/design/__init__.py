"""samii.design: control design on transfer-function and state-space models (notebook chapters 2-3, 5-8, 10).

Modules (import what you need; this package imports nothing heavy):

* ``rootlocus``: the mass-damping acceleration-feedback loop, exact stable K_a intervals, damping summary;
* ``canonical``: controllable canonical forms derived with sympy, numeric matrices, checks, LaTeX;
* ``placement``: the desired-pole rule, ZOH discretisation, state feedback, observer at 2x or Kalman;
* ``cancel``: the pole-cancelling compensator and the loop it closes;
* ``seed_report``: the notebook's design tables recomputed and compared;
* ``rlocus_study``: the root-locus study of every variant on every model, its tables and figures (``samii design rlocus``);
* ``notebook_designs``: chapter 8's placement on eq 1.4 and chapter 10's compensator on eq 9.4 with their documents and
  runnable controllers (``samii design place`` and ``cancel``);
* ``cli``: ``samii design ...``.

The designs return runnable controllers of :mod:`samii.controller` (the ``Controller`` interface and
``LinearController``), which the closed loop (:mod:`samii.closedloop`) runs: it sits below both.
"""

__all__ = ["rootlocus", "canonical", "placement", "cancel", "seed_report", "rlocus_study", "notebook_designs"]
