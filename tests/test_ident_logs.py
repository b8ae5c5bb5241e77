"""Robot logs: schema validation with precise messages, repairs (repeats, jittery time), preprocessing."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pandas as pd
import pytest

from reflexarm.errors import DataError
from reflexarm.ident import LogRepairWarning, RobotLog, load_log, preprocess_log, save_log

N_JOINTS = 3


def _clean(n=400, n_joints=N_JOINTS, dt=1e-3, seed=0):
    t = np.arange(n) * dt
    w = 2 * np.pi * np.array([0.5, 0.8, 1.1])[:n_joints]
    q = np.sin(np.outer(t, w))
    dq = np.cos(np.outer(t, w)) * w
    tau = np.random.default_rng(seed).normal(size=(n, n_joints))
    return t, q, dq, tau


def _frame(n=50):
    t, q, dq, tau = _clean(n)
    cols = {"t": t}
    for name, arr in (("q", q), ("dq", dq), ("tau", tau)):
        for j in range(N_JOINTS):
            cols[f"{name}_{j + 1}"] = arr[:, j]
    return pd.DataFrame(cols)


@pytest.mark.parametrize("suffix", [".csv", ".parquet", ".npz"])
def test_save_and_load_roundtrip(tmp_path, suffix):
    t, q, dq, tau = _clean()
    wrench = np.random.default_rng(1).normal(size=(t.size, 6))
    log = RobotLog(t, q, dq, tau, ddq=-q, wrench=wrench, source="x")
    p = save_log(log, tmp_path / f"log{suffix}")
    back = load_log(p, n_joints=N_JOINTS)
    # CSV stores 10 significant digits; binary formats are exact
    tol = 1e-9 if suffix == ".csv" else 0.0
    for name in ("t", "q", "dq", "tau", "ddq", "wrench"):
        np.testing.assert_allclose(getattr(back, name), getattr(log, name), atol=tol, err_msg=name)
    assert back.source == f"log{suffix}"


def _write(tmp_path, df, name="log.csv"):
    p = tmp_path / name
    df.to_csv(p, index=False)
    return p


def test_missing_column_is_named(tmp_path):
    p = _write(tmp_path, _frame().drop(columns=["tau_3"]))
    with pytest.raises(DataError, match=r"log\.csv: column 'tau_3' missing; found: t, q_1, q_2, q_3, dq_1"):
        load_log(p)


def test_extra_columns_are_ignored_with_a_note_naming_them(tmp_path):
    df = _frame()
    df["temperature"] = 20.0
    df["seq"] = np.arange(len(df))
    df["ddq_4"] = 0.0  # beyond the 3 joints: nothing needs it
    p = _write(tmp_path, df)
    log = load_log(p, n_joints=N_JOINTS)
    assert "log.csv: ignored 3 column(s) no signal needs: temperature, seq, ddq_4" in log.notes
    np.testing.assert_array_equal(log.q[:, 2], df["q_3"].to_numpy())


def test_joint_count_must_match_the_robot(tmp_path):
    p = _write(tmp_path, _frame())
    with pytest.raises(DataError, match=r"log\.csv: the log has 3 joints \(q_1\.\.q_3\); the robot has 7") as info:
        load_log(p, n_joints=7)
    assert (info.value.value, info.value.expected) == (3, 7)


@pytest.mark.parametrize(("value", "word"), [(np.nan, "NaN"), (np.inf, r"\+inf"), (-np.inf, "-inf")])
def test_non_finite_value_names_column_and_row(tmp_path, value, word):
    df = _frame()
    df.loc[17, "dq_2"] = value
    p = _write(tmp_path, df)
    with pytest.raises(DataError, match=rf"log\.csv: column 'dq_2' row 17 is {word}") as info:
        load_log(p)
    assert (info.value.column, info.value.row) == ("dq_2", 17)
    np.testing.assert_array_equal(info.value.value, value)


def test_non_number_names_column_and_row(tmp_path):
    df = _frame().astype(object)
    df.loc[3, "q_1"] = "abc"
    p = _write(tmp_path, df)
    with pytest.raises(DataError, match=r"log\.csv: column 'q_1' row 3: 'abc' is not a number"):
        load_log(p)


def test_time_going_backwards_names_the_row(tmp_path):
    df = _frame()
    df.loc[10, "t"] = df.loc[8, "t"]
    p = _write(tmp_path, df)
    with pytest.raises(DataError, match=r"log\.csv: time goes backwards at row 10: t = 0\.008 s after 0\.009 s"):
        load_log(p)


def test_npz_missing_and_unknown_arrays(tmp_path):
    t, q, dq, tau = _clean(20)
    p = tmp_path / "log.npz"
    np.savez(p, t=t, q=q, dq=dq)
    with pytest.raises(DataError, match=r"log\.npz: array 'tau' missing; found: t, q, dq"):
        load_log(p)
    np.savez(p, t=t, q=q, dq=dq, tau=tau, current=tau)
    with pytest.raises(DataError, match=r"log\.npz: unexpected array\(s\) 'current'"):
        load_log(p)


def test_unknown_format_and_missing_file(tmp_path):
    with pytest.raises(DataError, match=r"log file '.*nope\.csv' does not exist"):
        load_log(tmp_path / "nope.csv")
    p = tmp_path / "log.txt"
    p.write_text("1 2 3")
    with pytest.raises(
        DataError, match=r"log\.txt: unknown log format '\.txt'; use \.csv, \.parquet, \.npz, or a ROS 2 bag"
    ):
        load_log(p)


def test_exact_repeats_are_dropped_with_a_warning(tmp_path):
    df = _frame(60)
    rows = [df.iloc[[k]] for k in range(60)]
    dup = df.iloc[[20]].copy()
    dup["t"] += 0.0004  # the host stamped the same sample again
    df2 = pd.concat(rows[:21] + [dup] + rows[21:], ignore_index=True)
    p = _write(tmp_path, df2)
    with pytest.warns(
        LogRepairWarning, match=r"log\.csv: dropped 1 rows that exactly repeat the previous row.*60 of 61"
    ):
        log = load_log(p)
    assert len(log) == 60
    with pytest.raises(DataError, match=r"log\.csv: row 21 repeats row 20 exactly \(1 such rows\)"):
        load_log(p, repair=False)


def test_jitter_beyond_half_a_period_keeps_the_logs_own_stamps():
    """A 1 kHz robot, 8 % of its samples lost, host stamps late by 0..2 ms (jitter larger than the period):
    re-timing would move samples by more than half a period, so the stamps are kept as they are (issue 17
    item 4); only stamps the host repeated are spread up to the next stamp, and the warning says so."""
    rng = np.random.default_rng(5)
    ticks = np.sort(rng.choice(np.arange(6000), size=5500, replace=False))
    t_true = ticks * 1e-3
    w = 2 * np.pi * np.array([0.3, 0.45, 0.7])
    q = np.sin(np.outer(t_true, w))
    dq = np.cos(np.outer(t_true, w)) * w
    host = t_true + rng.uniform(0.0, 2e-3, t_true.size)
    host = np.maximum.accumulate(host)  # a host clock never runs backwards
    repeated = np.r_[False, np.diff(host) == 0]
    assert repeated.sum() > 100  # the case under test: many repeated stamps
    with pytest.warns(
        LogRepairWarning,
        match=r"jitter: time steps irregular .*: kept the log's own time stamps: "
        r"re-timing onto a grid would put rows \d+ and \d+ on one tick .* repeated stamp\(s\) spread",
    ):
        log = RobotLog.from_arrays(host, q, dq, np.zeros_like(q), source="jitter")
    np.testing.assert_array_equal(log.t[~repeated], host[~repeated])  # every other sample keeps its stamp
    assert np.all(np.diff(log.t) > 0)
    # the period stated is the median step of the (spread) stamps
    assert f"period {np.median(np.diff(log.t)) * 1e3:.4g} ms, the median step" in log.notes[-1]
    # without repair the first defect found is reported: two samples with the same host stamp
    with pytest.raises(DataError, match=r"jitter: time does not increase at row \d+: t = .* s twice"):
        RobotLog.from_arrays(host, q, dq, np.zeros_like(q), source="jitter", repair=False)


def test_robotlog_rejects_bad_arrays():
    t, q, dq, tau = _clean(10)
    with pytest.raises(DataError, match=r"x: time is not strictly increasing at row 3"):
        RobotLog(np.r_[t[:3], t[2], t[4:]], q, dq, tau, source="x")
    with pytest.raises(DataError, match=r"x: tau has 2 joints; q has 3"):
        RobotLog(t, q, dq, tau[:, :2], source="x")
    bad = dq.copy()
    bad[4, 1] = np.nan
    with pytest.raises(DataError, match=r"x: dq\[:, 1\] is NaN at row 4"):
        RobotLog(t, q, bad, tau, source="x")


def test_preprocess_differentiates_a_sinusoid_and_fills_gaps():
    t, q, dq, tau = _clean(4000)
    keep = np.ones(t.size, dtype=bool)
    keep[1000:1005] = False  # a gap of 5 samples
    log = RobotLog(t[keep], q[keep], dq[keep], tau[keep], source="s")
    proc = preprocess_log(log)
    assert proc.is_uniform and len(proc) == 4000
    assert any(re.search(r"resampled 3,995 samples to a uniform 1 ms grid of 4,000 samples", s) for s in proc.notes)
    w = 2 * np.pi * np.array([0.5, 0.8, 1.1])
    ddq_true = -np.sin(np.outer(t, w)) * w**2
    # the 10 Hz zero-phase filter leaves 0.5..1.1 Hz untouched (gain error < 1e-6); the central
    # difference errs by (w T)^2 / 6 < 1e-5 relative; ends are affected by the filter's edge handling
    inner = slice(200, -200)
    np.testing.assert_allclose(proc.ddq[inner], ddq_true[inner], atol=1e-3 * np.max(np.abs(ddq_true)))
    # the raw torque is kept (unfiltered) at the original samples, up to the grid's round-off in time
    np.testing.assert_allclose(proc.tau_raw[keep][inner], tau[keep][inner], atol=1e-9)


def test_resampled_states_span_every_sample_of_a_jittery_log():
    """Host jitter below the re-timing tolerance is resampled; the grid spans the log from its first to its
    last sample, so a validation half (--split) lies inside the states (it ended up to a period short)."""
    rng = np.random.default_rng(0)
    t, q, dq, tau = _clean(3000)
    t = t + np.r_[0.0, rng.uniform(-1e-4, 1e-4, t.size - 1)]  # +-0.1 ms on 1 ms steps
    q, dq = np.sin(np.outer(t, [3.1, 5.0, 6.9])), np.cos(np.outer(t, [3.1, 5.0, 6.9])) * [3.1, 5.0, 6.9]
    log = RobotLog.from_arrays(t, q, dq, tau)
    assert not log.is_uniform and log.notes == ()
    states = preprocess_log(log)
    _, val = log.split(0.6)
    assert states.t[0] == log.t[0]
    # float rounding of t0 + T_seg * (k - 1) only: far below the 1e-9 s validate_model allows
    assert abs(states.t[-1] - val.t[-1]) < 1e-12
    # the span over a whole number of the log's median periods: within half a period over the 3 s span
    assert states.period == pytest.approx(log.period, rel=0.5 / 3000)
    assert "each segment's grid spans it from its first to its last sample" in states.notes[0]


def test_preprocess_rejects_cutoff_above_nyquist():
    t, q, dq, tau = _clean(100)
    with pytest.raises(DataError, match=r"s: filter cutoff 600 Hz must be between 0 and the Nyquist frequency 500 Hz"):
        preprocess_log(RobotLog(t, q, dq, tau, source="s"), cutoff_hz=600)


def test_split_keeps_order():
    t, q, dq, tau = _clean(100)
    a, b = RobotLog(t, q, dq, tau).split(0.6)
    assert len(a) == 60 and len(b) == 40 and b.t[0] > a.t[-1]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        RobotLog.from_arrays(t, q, dq, tau)  # a clean log raises no repair warning
