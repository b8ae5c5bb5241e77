"""BLAS thread count during identification (threadpoolctl).

The identification's dense algebra (the per-joint Gram products of ``_GramAccumulator``, the small
eigen-decompositions and solves, the consistency projection) works on matrices of a few hundred columns.
Multi-threaded BLAS gains little on them and, when another process keeps a core busy, its threads spin
and wait on each other: 0.34 s per 100k samples on a quiet machine became up to 18.7 s with the other of
two cores busy (issue 10). :func:`blas_threads` therefore limits BLAS to one thread by default.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from reflexarm.errors import ConfigError

__all__ = ["DEFAULT_BLAS_THREADS", "blas_threads", "check_threads"]

#: BLAS threads used by identification unless told otherwise (``threads=`` / ``--threads``).
DEFAULT_BLAS_THREADS = 1


def check_threads(threads: int | None) -> int | None:
    """``threads`` if it is None (leave BLAS as it is) or a positive int; else ConfigError."""
    if threads is None:
        return None
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ConfigError(
            f"threads must be a positive number of BLAS threads or None (leave BLAS as configured); got {threads!r}"
        )
    return threads


@contextmanager
def blas_threads(threads: int | None = DEFAULT_BLAS_THREADS) -> Iterator[None]:
    """Limit the BLAS libraries loaded in this process to ``threads`` threads inside the block.

    ``None`` leaves them as configured (e.g. by ``OPENBLAS_NUM_THREADS``). The previous limits are
    restored on exit.
    """
    limit = check_threads(threads)
    if limit is None:
        yield
        return
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=limit, user_api="blas"):
        yield
