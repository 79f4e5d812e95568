"""The main job's report: ``report.html``, one self-contained page read in a browser.

It renders a :class:`samii.pipeline.Run` (``Run.load`` reads a main job's folder): :mod:`samii.report.content` holds
what the page adds to it (the stages' figures present, what the folder lacks, the parameters beside eq 9.4, the log of
the fields read), :mod:`samii.report.figures` draws the closed-loop figures, :mod:`samii.report.page` writes the page,
:mod:`samii.report.browser` takes a screenshot of it in a headless Chromium, and ``samii report DIR``
(:mod:`samii.report.cli`) rewrites it from a folder.
"""
