"""Monte Carlo robustness of a controller (``samii robust``).

:mod:`samii.robust.sampling` draws the plants, :mod:`samii.robust.task` runs one closed loop on a
plant built inside the task, :mod:`samii.robust.engine` runs the tasks in this process, in forked worker
processes or on a user's Dask cluster,
:mod:`samii.robust.study` reduces the results, :mod:`samii.robust.plots` draws them.
"""
