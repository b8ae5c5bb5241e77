"""Identification runs its BLAS on one thread unless told otherwise (threadpoolctl), and restores it."""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from reflexarm.errors import ConfigError
from reflexarm.ident import BatchRegressor, RobotLog, identify_dynamics
from reflexarm.ident._blas_threads import blas_threads
from reflexarm.ident.excitation.design import FourierTrajectory


def _blas_threads_now() -> list[int]:
    return [int(i["num_threads"]) for i in threadpool_info() if i["user_api"] == "blas"]


def test_blas_threads_limits_inside_and_restores_after() -> None:
    with threadpool_limits(limits=2, user_api="blas"):  # a known starting point on any machine
        before = _blas_threads_now()
        with blas_threads(1):
            assert set(_blas_threads_now()) == {1}
        assert _blas_threads_now() == before
        with blas_threads(None):  # leave BLAS as configured
            assert _blas_threads_now() == before


@pytest.mark.parametrize("bad", [0, -1, 1.5, True])
def test_a_bad_thread_count_is_refused_with_the_value(bad: object) -> None:
    message = rf"threads must be a positive number of BLAS threads or None .*; got {bad!r}"
    with pytest.raises(ConfigError, match=message):
        with blas_threads(bad):  # type: ignore[arg-type]
            pass


def test_identify_dynamics_uses_one_thread_by_default(atlas, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The Gram accumulation sees one BLAS thread (default) or the configured ones (threads=None)."""
    from reflexarm.ident.estimation import _weighted_least_squares as wls

    seen: list[list[int]] = []
    original = wls._GramAccumulator.add

    def spy(self, M, keep=None):  # type: ignore[no-untyped-def]
        seen.append(_blas_threads_now())
        return original(self, M, keep)

    monkeypatch.setattr(wls._GramAccumulator, "add", spy)
    rng = np.random.default_rng(0)
    tr = FourierTrajectory(2 * np.pi * 0.1, 0.1 * rng.normal(size=(7, 4)), 0.1 * rng.normal(size=(7, 4)), atlas.home)
    t = np.arange(0.0, 2.0, 1e-3)
    q, dq, ddq = tr.evaluate(t)
    tau = BatchRegressor(atlas).compute_regressor(q, dq, ddq) @ atlas.inertial_parameters()
    log = RobotLog(t, q, dq, tau, ddq=ddq)
    with threadpool_limits(limits=2, user_api="blas"):
        identify_dynamics(atlas, log, method="combined", noise_variance=None, condition_limit=np.inf)
        assert seen and all(set(s) == {1} for s in seen)
        seen.clear()
        identify_dynamics(atlas, log, method="combined", noise_variance=None, condition_limit=np.inf, threads=None)
        assert seen and all(set(s) == {2} for s in seen)
