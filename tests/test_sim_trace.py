"""Trace: validation, save/load roundtrip (npz, parquet), first_time."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from reflexarm.errors import DataError
from reflexarm.sim import Trace


def make_trace(N=50, n=3, seed=0):
    rng = np.random.default_rng(seed)

    def f(*shape):
        return rng.normal(size=(N, *shape))

    collided = np.zeros((N, n), dtype=bool)
    collided[30:, 1] = True
    return Trace(
        t=np.arange(N) * 1e-3,
        q=f(n),
        dq=f(n),
        q_meas=f(n),
        q_d=f(n),
        dq_d=f(n),
        tau=f(n),
        tau_m=f(n),
        residual=f(n),
        collision=np.arange(N) >= 30,
        collided=collided,
        mode=np.where(np.arange(N) < 30, "compliant", "gravity_compensation"),
        fault=np.where(np.arange(N) == N - 1, "nan in q", ""),
        wrench=f(6),
        f_ext_ee=f(3),
        tau_ext=f(n),
        extras={"block_pos": f(3), "tipped": np.arange(N) > 40},
        meta={"robot": "atlas_v5_left_arm", "seed": 3, "gains": {"stiffness": [300.0] * 3}},
    )


def assert_traces_equal(a: Trace, b: Trace) -> None:
    for field in dataclasses.fields(Trace):
        if field.name in ("extras", "meta"):
            continue
        x, y = getattr(a, field.name), getattr(b, field.name)
        assert x.dtype.kind == y.dtype.kind, field.name
        np.testing.assert_array_equal(x, y, err_msg=field.name)
    assert sorted(a.extras) == sorted(b.extras)
    for key in a.extras:
        np.testing.assert_array_equal(a.extras[key], b.extras[key], err_msg=key)
    assert a.meta == b.meta


@pytest.mark.parametrize("suffix", [".npz", ".parquet"])
def test_save_load_roundtrip(tmp_path, suffix):
    trace = make_trace()
    path = trace.save(tmp_path / f"run{suffix}")
    assert_traces_equal(Trace.load(path), trace)


@pytest.mark.parametrize("suffix", [".npz", ".parquet"])
def test_empty_trace_roundtrip(tmp_path, suffix):
    """A run that failed on its first tick still saves and loads (partial traces are never lost)."""
    trace = make_trace(N=0)
    assert len(trace) == 0 and trace.first_time(np.zeros(0, dtype=bool)) is None
    assert_traces_equal(Trace.load(trace.save(tmp_path / f"empty{suffix}")), trace)


def test_parquet_columns_are_readable_with_pandas(tmp_path):
    import pandas as pd

    trace = make_trace()
    df = pd.read_parquet(trace.save(tmp_path / "run.parquet"))
    assert {"t", "q_0", "q_2", "wrench_5", "mode", "extras/block_pos_2"} <= set(df.columns)
    np.testing.assert_array_equal(df["q_1"].to_numpy(), trace.q[:, 1])


def test_first_time():
    trace = make_trace()
    assert trace.first_time(trace.collision) == pytest.approx(0.030)
    assert trace.first_time(trace.t > 1.0) is None
    with pytest.raises(DataError, match=r"mask must have shape \(50,\); got \(3,\)"):
        trace.first_time([True, False, True])


def test_validation_errors():
    good = make_trace()
    t = good.t.copy()
    t[10] = t[9]
    with pytest.raises(DataError, match=r"trace time must be strictly increasing; t\[9\] = 0.009 >= t\[10\] = 0.009"):
        dataclasses.replace(good, t=t)
    with pytest.raises(DataError, match=r"trace field tau must have shape \(50, 3\); got \(49, 3\)"):
        dataclasses.replace(good, tau=good.tau[:-1])
    with pytest.raises(DataError, match=r"trace field wrench must have shape \(50, 6\); got \(50, 3\)"):
        dataclasses.replace(good, wrench=good.f_ext_ee)
    q = good.q.copy()
    q[5, 0] = np.nan
    with pytest.raises(DataError, match=r"trace field q \(true state\) has NaN/inf entries"):
        dataclasses.replace(good, q=q)
    with pytest.raises(DataError, match=r"trace extra 'x' must have 50 rows; got shape \(3,\)"):
        dataclasses.replace(good, extras={"x": np.zeros(3)})
    with pytest.raises(DataError, match=r"trace meta must be JSON-serialisable"):
        dataclasses.replace(good, meta={"a": object()})


def test_load_errors(tmp_path):
    with pytest.raises(DataError, match=r"trace file '.*missing.npz' does not exist"):
        Trace.load(tmp_path / "missing.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(DataError, match=r"cannot read trace file '.*bad.npz'"):
        Trace.load(bad)
    with pytest.raises(DataError, match=r"unknown trace file type '.csv'"):
        make_trace().save(tmp_path / "run.csv")
