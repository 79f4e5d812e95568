"""BLAS in one thread: a sum split over threads rounds differently, so results that must agree bit for bit between
a process pool, a Dask worker and the command's own process are computed with one."""

from __future__ import annotations

import functools

__all__ = ["one_blas_thread"]


@functools.cache
def _controller():
    """threadpoolctl's view of the loaded libraries: its scan (about 1 ms) made once per process, after scipy is
    imported so that scipy's own BLAS (a wheel's, beside numpy's) is among them."""
    import scipy.linalg  # noqa: F401  (lazy: imports scipy, only when called; its BLAS is loaded to be limited too)
    from threadpoolctl import ThreadpoolController  # (lazy: imports threadpoolctl, only when called)

    return ThreadpoolController()


def one_blas_thread():
    """A context in which BLAS uses one thread (threadpoolctl)."""
    return _controller().limit(limits=1, user_api="blas")
