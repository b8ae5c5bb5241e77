"""Time stamps in s, ms, us, ns and from the Unix epoch: recognized, made relative to the first sample,
said so; preprocessing, --split windows and validation work on the relative times."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from reflexarm.errors import DataError
from reflexarm.ident import RobotLog, load_log, preprocess_log, save_log
from reflexarm.logs import LogRepairWarning, TimeUnitWarning
from reflexarm.logs.timestamps import relative_seconds

N = 400
#: Relative times from integer stamps are exact integers times the unit's scale: within a few ulp of
#: the 0.4 s span; float epoch seconds (1.8e9 s) hold only ~2.4e-7 s, so their relative times are
#: that coarse (see test_epoch_seconds_as_floats).
EXACT_ATOL = 1e-15
EPOCH_S = 1_795_435_200


def _log(period=1e-3, n=N):
    t = np.arange(n) * period
    w = 2 * np.pi * np.array([0.5, 0.8])
    return RobotLog(t, np.sin(np.outer(t, w)), np.cos(np.outer(t, w)) * w, np.random.default_rng(0).normal(size=(n, 2)))


def _write(tmp_path, log, stamps, name="t", file="log.csv"):
    cols = {name: stamps} | {k: v for k, v in log.to_columns().items() if k != "t"}
    p = tmp_path / file
    pd.DataFrame(cols).to_csv(p, index=False, float_format="%.17g")
    return p


@pytest.mark.parametrize(("unit", "scale"), [("ms", 10**3), ("us", 10**6), ("ns", 10**9)])  # seconds: every other test
@pytest.mark.parametrize("epoch", [False, True])
def test_integer_stamps_in_each_unit_from_zero_or_the_epoch(tmp_path, unit, scale, epoch):
    log = _log()
    start = EPOCH_S * scale if epoch else 7 * scale  # the epoch, or 7 s after a robot's boot
    stamps = start + np.round(log.t * scale).astype(np.int64)
    back = load_log(_write(tmp_path, log, stamps), n_joints=2)
    np.testing.assert_allclose(back.t, log.t, rtol=0, atol=EXACT_ATOL)
    (note,) = back.notes
    assert f"log.csv: time stamps (t): in {unit} (inferred" in note
    assert f"made relative to the first sample (subtracted {start} {unit}" in note
    assert ("a Unix epoch time" in note) == epoch
    # the failure with ns stamps: "cutoff must be below the Nyquist frequency 5e-07 Hz"
    assert preprocess_log(back).period == pytest.approx(1e-3)


def test_epoch_seconds_as_floats(tmp_path):
    log = _log()
    back = load_log(_write(tmp_path, log, EPOCH_S + 0.25 + log.t), n_joints=2)
    # float64 at 1.8e9 s resolves 2.4e-7 s: the relative times are that close, and the log stays on its grid
    np.testing.assert_allclose(back.t, log.t, rtol=0, atol=5e-7)
    assert back.t[0] == 0.0
    assert "subtracted 1795435200.25 s = 2026-11-23 12:00:00.250000 UTC, a Unix epoch time" in back.notes[0]
    pre = preprocess_log(back)  # the 10 Hz cutoff is below the 500 Hz Nyquist frequency of the 1 ms samples
    assert pre.t[0] == 0.0 and pre.period == pytest.approx(1e-3, rel=1e-3)


def test_unit_from_the_column_name_and_explicit_unit_wins(tmp_path):
    log = _log(period=0.01)  # 100 Hz
    stamps = np.round(log.t * 1e6).astype(np.int64)
    back = load_log(_write(tmp_path, log, stamps, name="time_us"), n_joints=2)
    np.testing.assert_allclose(back.t, log.t, rtol=0, atol=EXACT_ATOL)
    assert any("in us (from the column name 'time_us')" in n for n in back.notes)
    # a counter of ticks: steps of 1 are ms by inference (1 s steps, 1 Hz, are implausible); told, it is ms
    ticks = np.arange(N, dtype=np.int64)
    assert load_log(_write(tmp_path, log, ticks), n_joints=2).period == pytest.approx(1e-3)
    assert load_log(_write(tmp_path, log, ticks * 10), n_joints=2, time_unit="ms").period == pytest.approx(1e-2)


def test_ambiguous_spacing_warns_and_says_how_to_be_sure():
    # steps of 0.1: 10 Hz in seconds or 10 kHz in ms; both plausible, ms is nearer 1 ms
    with pytest.warns(TimeUnitWarning, match=r"fits more than one unit \(s, ms\); took ms"):
        t, note = relative_seconds(np.arange(100) * 0.1 + 0.05, where="x", column="t")
    assert t[1] == pytest.approx(1e-4)
    assert note is not None and "pass the time unit to be sure" in note
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        t, _ = relative_seconds(np.arange(100) * 0.1, where="x", column="t", unit="s")
    assert t[1] == pytest.approx(0.1)


def test_stamps_no_unit_explains_are_refused():
    with pytest.raises(DataError, match=r"x: cannot tell the time unit: the median step 1e\+13 is a sample period"):
        relative_seconds(np.arange(10) * 10**13, where="x", column="t")
    with pytest.raises(DataError, match=r"x: unknown time unit 'min'; choose one of s, ms, us, ns"):
        relative_seconds(np.arange(10), where="x", unit="min")


def test_split_windows_are_relative_to_the_log_start(tmp_path):
    """The issue's failure: epoch-second stamps made the validation half fall outside the preprocessed
    states ("validation times 1.7e+09..1.7e+09 s are outside the states' ..."). Now every time is from
    the log's start, and the states cover the validation samples as validate_model requires."""
    log = _log(n=3000)
    p = _write(tmp_path, log, EPOCH_S + log.t)
    back = load_log(p, n_joints=2)
    states = preprocess_log(back)
    _, val = back.split(0.6)
    assert val.t[0] == pytest.approx(1.8, abs=1e-6)
    assert states.t[0] <= val.t[0] and val.t[-1] <= states.t[-1] + 1e-9


def test_npz_and_parquet_times_are_relative_too(tmp_path):
    log = _log()
    shifted = RobotLog(log.t + 100.0, log.q, log.dq, log.tau)
    for suffix in (".npz", ".parquet"):
        back = load_log(save_log(shifted, tmp_path / f"x{suffix}"))
        np.testing.assert_allclose(back.t, log.t, rtol=0, atol=1e-12)  # 100 + t - 100 in float64
        assert "subtracted 100 s = 100 s" in back.notes[0]


def test_a_given_period_is_the_grid_and_the_notes_state_the_period():
    """With the period given, host jitter goes onto that grid (only its offset is fitted) and the note says
    'the period given'; without, the period stated is the median step."""
    rng = np.random.default_rng(11)
    t_true = np.arange(2000) * 2e-3  # 500 Hz
    jitter = rng.uniform(-0.6e-3, 0.6e-3, t_true.size)  # +-0.3 periods
    log = _log(period=2e-3, n=2000)
    with pytest.warns(LogRepairWarning, match=r"period 2 ms, the period given\): host stamps jitter"):
        given = RobotLog.from_arrays(t_true + jitter, log.q, log.dq, log.tau, period=2e-3)
    np.testing.assert_allclose(np.diff(given.t), 2e-3, rtol=0, atol=1e-15)
    assert np.abs(given.t - (t_true + jitter)).max() <= 1e-3  # at most half a period
    with pytest.warns(LogRepairWarning, match=r"period [\d.]+ ms, the median step\): host stamps jitter"):
        median = RobotLog.from_arrays(t_true + jitter, log.q, log.dq, log.tau)
    step = float(np.median(np.diff(t_true + jitter)))
    assert f"period {step * 1e3:.4g} ms, the median step" in median.notes[-1]
