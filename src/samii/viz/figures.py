"""The figure helpers every plotting module shares: pyplot (on the Agg backend for files), a column of panels
sharing their x axis, and saving a figure and closing it. matplotlib is imported on first use: a command that draws
nothing does not load it."""

from __future__ import annotations

__all__ = ["pyplot", "panels", "save_figure"]


def pyplot(*, agg: bool = True):
    """``matplotlib.pyplot``, on the Agg backend (files, no screen) when ``agg``; ``agg=False`` keeps the session's
    backend (a figure only returned, for a notebook to show)."""
    import matplotlib  # (lazy: imports matplotlib, only when called)

    if agg:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # (lazy: imports matplotlib, only when called)

    return plt


def panels(rows: int, height: float, *, width: float = 9.0):
    """``(fig, axes)``: ``rows`` panels one above the other sharing their x axis, ``height`` [in] each; ``axes`` 1-D."""
    fig, ax = pyplot().subplots(rows, 1, figsize=(width, height * rows), sharex=True, squeeze=False)
    return fig, ax[:, 0]


def save_figure(fig, path, *, dpi: int = 110) -> None:
    """Save ``fig`` to ``path`` and close it (PNG at a modest dpi keeps committed figures small)."""
    try:
        fig.savefig(path, dpi=dpi)
    finally:
        pyplot(agg=False).close(fig)
