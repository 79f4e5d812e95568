"""The main job's report: ``report.html``, one self-contained page read in a browser.

:mod:`samii.report.content` reads a main job's folder, :mod:`samii.report.figures` draws the
closed-loop figures, :mod:`samii.report.page` writes the page, :mod:`samii.report.browser` takes a
screenshot of it in a headless Chromium, and ``samii report DIR`` (:mod:`samii.report.cli`) rewrites
it from a folder.
"""
