"""BLAS in one thread: a sum split over threads rounds differently, so results that must agree bit for bit between
a process pool, a Dask worker and the command's own process are computed with one."""

from __future__ import annotations

__all__ = ["one_blas_thread"]

_CONTROLLER = []


def one_blas_thread():
    """A context in which BLAS uses one thread (threadpoolctl). Its scan of the loaded libraries (about 1 ms) is made
    once per process, after scipy is imported so that scipy's own BLAS (a wheel's, beside numpy's) is among them."""
    if not _CONTROLLER:
        import scipy.linalg  # noqa: F401  (lazy: imports scipy, only when called; its BLAS is loaded to be limited too)
        from threadpoolctl import ThreadpoolController  # (lazy: imports threadpoolctl, only when called)

        _CONTROLLER.append(ThreadpoolController())
    return _CONTROLLER[0].limit(limits=1, user_api="blas")
