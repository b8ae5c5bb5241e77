"""Identification refuses garbage (issue 8, findings 12-14): each test writes its own bad log (seeded)."""

from __future__ import annotations

import re
import tracemalloc
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from reflexarm.cli import main
from reflexarm.errors import DataError, IdentificationError, ImplausibleDataError, NonFiniteEstimateError
from reflexarm.ident import (
    BatchRegressor,
    FrictionParameters,
    RobotLog,
    identify_dynamics,
    identify_joint_friction,
    load_log,
    plan_friction_experiment,
    preprocess_log,
    project_physically_consistent,
    save_log,
)
from reflexarm.ident.excitation.design import FourierTrajectory

#: the bad cell: row and joint (0-based) of the corrupted torque
BAD_ROW, BAD_JOINT = 500, 2


def _exact_log(robot, duration=2.0, seed=0):
    """A log of a smooth random Fourier motion with the exact torques, eq. (14) (seeded)."""
    rng = np.random.default_rng(seed)
    tr = FourierTrajectory(2 * np.pi * 0.2, 0.1 * rng.normal(size=(7, 3)), 0.1 * rng.normal(size=(7, 3)), robot.home)
    t = np.arange(0.0, duration, 1e-3)
    q, dq, ddq = tr.evaluate(t)
    fr = FrictionParameters.from_model(robot.friction)
    tau = BatchRegressor(robot).compute_regressor(q, dq, ddq) @ robot.inertial_parameters() + fr.compute_torque(dq)
    return t, q, dq, ddq, tau


# ------------------------------------------------------------------ finding 12: absurd values
def test_absurd_torque_cell_is_refused_with_its_row_instead_of_nan_parameters(atlas, tmp_path, capsys):
    """One tau = 1e300 cell gave 43/43 NaN base parameters silently; now loading names the row."""
    t, q, dq, _, tau = _exact_log(atlas)
    tau[BAD_ROW, BAD_JOINT] = 1e300
    p = tmp_path / "bad.csv"
    pd.DataFrame(
        {"t": t} | {f"{g}_{j + 1}": a[:, j] for g, a in (("q", q), ("dq", dq), ("tau", tau)) for j in range(7)}
    ).to_csv(p, index=False, float_format="%.17g")
    expected = r"bad\.csv: 1 row\(s\) with implausible tau \[Nm\] \(\|tau\| > 1e\+06 for any robot\): row 500 "
    with pytest.raises(ImplausibleDataError, match=expected + r"\(t = 0\.5 s\) tau_3 = 1e\+300") as info:
        load_log(p, n_joints=7)
    (sample,) = info.value.samples
    assert (sample.row, sample.column, sample.value) == (BAD_ROW, "tau_3", 1e300)
    # the CLI ends with that message, not with a scipy error ("coulomb must be finite")
    assert main(["identify", "dynamics", "--log", str(p), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert re.search("reflexarm identify: error: " + expected, capsys.readouterr().err)


def test_torque_far_beyond_the_robots_limits_is_refused_by_identification(atlas):
    """5e4 Nm passes the absolute bound but is 800 x joint 3's effort limit (63 Nm): refused, row named."""
    t, q, dq, ddq, tau = _exact_log(atlas)
    tau[BAD_ROW, BAD_JOINT] = 5e4
    log = RobotLog(t, q, dq, tau, ddq=ddq, source="glitch")
    with pytest.raises(ImplausibleDataError, match=r"glitch: 1 row\(s\) with implausible tau .*beyond 10 x the "
                       r"effort limits .* row 500 \(t = 0\.5 s\) tau_3 = 50000"):  # fmt: skip
        identify_dynamics(atlas, log, method="combined")
    tau[BAD_ROW, BAD_JOINT] = 0.0
    degrees = RobotLog(t, np.degrees(q), dq, tau, ddq=ddq, source="deg")
    with pytest.raises(ImplausibleDataError, match=r"deg: .* implausible q .* degrees instead of radians\?"):
        identify_dynamics(atlas, degrees, method="combined")


def test_non_finite_estimate_raises_and_names_the_likely_bad_row(atlas):
    """A log corrupted after validation (a frozen dataclass bypassed) still cannot give NaN parameters."""
    t, q, dq, ddq, tau = _exact_log(atlas)
    log = RobotLog(t, q, dq, tau, ddq=ddq, source="corrupt")
    tau = tau.copy()
    tau[BAD_ROW, BAD_JOINT] = 1e300
    object.__setattr__(log, "tau", tau)
    with pytest.raises(NonFiniteEstimateError, match=r"non-finite results .*likely bad rows\): corrupt row 500 "
                       r"\(t = 0\.5 s\) tau_3 = 1e\+300") as info:  # fmt: skip
        identify_dynamics(atlas, log, method="combined", check_limits=False)
    assert isinstance(info.value, IdentificationError)
    # only the bad cell stands out (>= 100 x its column's 99th percentile); the clean rows are not accused
    assert [(s.row, s.column) for s in info.value.samples] == [(BAD_ROW, "tau_3")]


@pytest.mark.filterwarnings("ignore::reflexarm.ident.IllConditionedWarning")  # a short, unoptimized motion
def test_consistency_projection_of_a_nan_result_raises_the_packages_error(atlas):
    """It raised scipy's raw 'Residuals are not finite in the initial point' ValueError."""
    t, q, dq, ddq, tau = _exact_log(atlas)
    res = identify_dynamics(atlas, RobotLog(t, q, dq, tau, ddq=ddq), method="combined")
    bad = replace(res, beta_b=np.full_like(res.beta_b, np.nan))
    with pytest.raises(IdentificationError, match=r"cannot project a combined identification with non-finite "
                       r"beta_b \(43 of 43 entries NaN/inf\)"):  # fmt: skip
        project_physically_consistent(bad, atlas)


# ------------------------------------------------------------------ finding 13: long gaps
def test_long_gap_splits_the_log_without_an_unbounded_grid():
    """A 1e5 s gap made preprocess_log allocate a 100-million-sample grid (MemoryError)."""
    rng = np.random.default_rng(1)
    t = np.arange(4000) * 1e-3
    t[2000:] += 1e5
    w = 2 * np.pi * np.array([0.5, 0.8, 1.1])
    q, dq = np.sin(np.outer(t, w)), np.cos(np.outer(t, w)) * w
    log = RobotLog(t, q, dq, rng.normal(size=q.shape), source="gap")
    tracemalloc.start()
    try:
        proc = preprocess_log(log)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # the two 2 s segments need ~4000 x 3 joints x a dozen float arrays (~1 MB); 50 MB leaves room for
    # scipy's work arrays and is 400 x below what the 1e8-sample grid of one array alone would take
    assert peak < 50e6
    assert len(proc) == 4000 and proc.t[1999] == pytest.approx(1.999) and proc.t[2000] == pytest.approx(1e5 + 2.0)
    assert any("split at 1 gap(s) longer than 0.025 s" in n for n in proc.notes)
    # each segment filtered on its own: ddq matches the analytic one inside both (not smeared over the gap);
    # 10 Hz zero-phase filter on 0.5..1.1 Hz, away from the segment edges (filter transient)
    ddq_true = -np.sin(np.outer(t, w)) * w**2
    inner = np.r_[200:1800, 2200:3800]
    np.testing.assert_allclose(proc.ddq[inner], ddq_true[inner], atol=1e-3 * np.abs(ddq_true).max())
    # a grid period far below the log's own is refused before allocating
    with pytest.raises(DataError, match=r"gap: resampling 4,000 samples at a 1e-07 s period would need a grid"):
        preprocess_log(log, period=1e-7, cutoff_hz=None, max_gap=1.0)


# ------------------------------------------------------------------ finding 14: non-numeric dtypes
# (a CSV file has no dtypes: numbers written as text are numbers there, so CSV is tested with booleans)
@pytest.mark.parametrize(("suffix", "kind"), [(".parquet", "bool"), (".parquet", "text"), (".npz", "bool"),
                                             (".npz", "text"), (".csv", "bool")])  # fmt: skip
def test_non_numeric_column_is_refused_with_its_name(tmp_path, suffix, kind):
    """A boolean Parquet column was taken as 0/1 joint values."""
    rng = np.random.default_rng(2)
    n = 50
    t = np.arange(n) * 1e-3
    q, dq, tau = (rng.normal(size=(n, 2)) for _ in range(3))
    flag = rng.normal(size=n) > 0
    bad = flag if kind == "bool" else np.where(flag, "1.5", "2.5")
    p = tmp_path / f"log{suffix}"
    if suffix == ".npz":
        np.savez(p, t=t, q=np.column_stack([bad, bad]), dq=dq, tau=tau)
        what = r"array 'q'"
    else:
        save_log(RobotLog(t, q, dq, tau), p)
        df = pd.read_parquet(p) if suffix == ".parquet" else pd.read_csv(p)
        df["q_2"] = bad
        df.to_parquet(p) if suffix == ".parquet" else df.to_csv(p, index=False)
        what = r"column 'q_2'"
    with pytest.raises(DataError, match=rf"log{suffix}: {what} has dtype .* log values must be integers or floats"):
        load_log(p)
    with pytest.raises(DataError, match=r"array 'tau' has dtype bool"):
        RobotLog.from_arrays(t, q, dq, tau > 0)


def _friction_runs(robot, joint=2):
    """Exact constant-velocity runs of one joint (rigid body + the robot's friction, no noise)."""
    plan = plan_friction_experiment(robot, joint, speeds=(0.2, 0.5, 1.0))
    t = np.arange(0.0, plan.duration, 1e-3)
    q, dq, ddq = plan.evaluate(t)
    fr = FrictionParameters.from_model(robot.friction)
    tau = BatchRegressor(robot).compute_regressor(q, dq, ddq) @ robot.inertial_parameters() + fr.compute_torque(dq)
    return plan, t, q, dq, tau


def test_friction_runs_far_beyond_the_robots_limits_are_refused_like_the_dynamics_log(atlas):
    """identify_joint_friction applies the robot-relative bounds of identify_dynamics (same message)."""
    joint = 2
    plan, t, q, dq, tau = _friction_runs(atlas, joint)
    kw = {"windows": plan.windows, "position_window": plan.position_window(0.1), "settle": 0.1}
    clean = identify_joint_friction(atlas, joint, t, q, dq, tau, **kw)
    assert clean.coulomb == pytest.approx(atlas.friction.coulomb[joint], rel=1e-3)  # the data are sound
    row = int(np.searchsorted(t, plan.windows[1, :2].mean()))  # mid-interval: inside the averaged samples
    tau[row, joint] = 5e4  # passes the absolute bound (1e6 Nm), 800 x joint 3's effort limit (63 Nm)
    expected = (
        rf"joint 3 friction runs: 1 row\(s\) with implausible tau .*beyond 10 x the effort limits .* row {row} "
        rf"\(t = {t[row]:g} s\) tau_3 = 50000"
    )
    with pytest.raises(ImplausibleDataError, match=expected):
        identify_joint_friction(atlas, joint, t, q, dq, tau, **kw)
    # without the check the glitch reaches the fit and moves it: the check is what stops it
    glitched = identify_joint_friction(atlas, joint, t, q, dq, tau, check_limits=False, **kw)
    assert abs(glitched.coulomb - clean.coulomb) > 1.0
    tau[row, joint] = clean.compute_torque(dq[row, joint])  # repaired
    with pytest.raises(ImplausibleDataError, match=r"joint 3 friction runs: .* implausible q .* degrees"):
        identify_joint_friction(atlas, joint, t, np.degrees(q), dq, tau, **kw)
    with pytest.raises(DataError, match=r"joint 3 friction runs: q must have shape \(\d+, 7\)"):
        identify_joint_friction(atlas, joint, t, q[:, :3], dq, tau, **kw)
