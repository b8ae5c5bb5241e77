"""Real logs as they come (issue 17 item 4, issue 18 items 5 and 9, issue 20 items 1, 2 and 7): header-less
files mapped by position, motor currents with per-joint gains, the log's own time stamps kept unless re-timing
is safe, one check of a log against its robot for every command. Each test writes its own logs."""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ident_arms import SIX_DOF_TOOL, six_dof_urdf
from reflexarm import load_robot
from reflexarm.cli import main
from reflexarm.errors import ConfigError, DataError, ImplausibleDataError
from reflexarm.ident import BatchRegressor, FrictionParameters, plan_friction_experiment
from reflexarm.ident.excitation.design import FourierTrajectory
from reflexarm.logs import LogRepairWarning, RobotLog, load_log, parse_column_mapping
from reflexarm.robots.robot_model import RobotModel

#: Per-joint drive gains [Nm/A] of the current logs (motor constant x gear ratio, as a vendor lists them).
GAINS = (0.95, 1.1, 0.6, 0.23, 0.25, -0.21)
#: Every CSV here is written with 17 significant digits: a current tau / k read back and times k is tau
#: within a few ulp, so identification from it equals that from the torques to round-off of the normal
#: equations (cond^2 eps ~ 1e-10 relative at this excitation).
ROUND_OFF_RTOL = 1e-7


@pytest.fixture(scope="module")
def arm(tmp_path_factory: pytest.TempPathFactory) -> RobotModel:
    folder = tmp_path_factory.mktemp("arm")
    (folder / "arm.urdf").write_text(six_dof_urdf())
    return load_robot(folder / "arm.urdf", ee_frame=SIX_DOF_TOOL)


@pytest.fixture(scope="module")
def continuous_arm(tmp_path_factory: pytest.TempPathFactory) -> RobotModel:
    """The same arm with joints 1 and 4 continuous (no range, as the vendor Gen3's joints 1, 3, 5, 7)."""
    text = six_dof_urdf()
    for name in ("shoulder_pan_joint", "wrist_1_joint"):
        text = text.replace(f'<joint name="{name}" type="revolute">', f'<joint name="{name}" type="continuous">')
        head, tail = text.split(f'<joint name="{name}"', 1)
        tail = tail.replace('lower="-3.1" upper="3.1" ', "", 1)
        text = head + f'<joint name="{name}"' + tail
    folder = tmp_path_factory.mktemp("continuous")
    (folder / "arm.urdf").write_text(text)
    robot = load_robot(folder / "arm.urdf", ee_frame=SIX_DOF_TOOL)
    assert not np.isfinite(robot.upper_limit[0]) or robot.upper_limit[0] > 1e30  # the case under test
    return robot


def _motion(robot: RobotModel, duration: float, rate: float, amplitude: float = 0.15, seed: int = 0):
    """(t, q, dq, ddq, tau): a seeded Fourier motion with the exact torques (rigid body + the file's friction)."""
    rng = np.random.default_rng(seed)
    a, b = amplitude * rng.normal(size=(2, robot.n, 5))
    tr = FourierTrajectory(2 * np.pi * 0.1, a, b, np.zeros(robot.n))
    t = np.arange(0.0, duration, 1.0 / rate)
    q, dq, ddq = tr.evaluate(t)
    fr = FrictionParameters.from_model(robot.friction)
    tau = BatchRegressor(robot).compute_regressor(q, dq, ddq) @ robot.inertial_parameters() + fr.compute_torque(dq)
    return t, q, dq, ddq, tau


def _schema_csv(path: Path, t, q, dq, tau) -> Path:
    n = q.shape[1]
    cols = {"t": t} | {f"{s}_{j + 1}": a[:, j] for s, a in (("q", q), ("dq", dq), ("tau", tau)) for j in range(n)}
    pd.DataFrame(cols).to_csv(path, index=False, float_format="%.17g")
    return path


def _headerless_csv(path: Path, *blocks: np.ndarray) -> Path:
    """Columns side by side, no header row (as the industrial arm's published logs are)."""
    data = np.column_stack([b.reshape(b.shape[0], -1) for b in blocks])
    np.savetxt(path, data, delimiter=",", fmt="%.17g")
    return path


# ---------------------------------------------------------------------------------------------- columns
def test_a_headerless_file_mapped_by_position_reads_as_the_named_one(arm, tmp_path):
    t, q, dq, _, tau = _motion(arm, 2.0, 100.0)
    named = load_log(_schema_csv(tmp_path / "named.csv", t, q, dq, tau), joint_names=arm.joint_names)
    raw = _headerless_csv(tmp_path / "raw.csv", t, q, dq, tau)
    back = load_log(raw, joint_names=arm.joint_names, columns=parse_column_mapping("t=0,q=1:7,dq=7:13,tau=13:19"))
    for name in ("t", "q", "dq", "tau"):
        np.testing.assert_array_equal(getattr(back, name), getattr(named, name), err_msg=name)
    assert "raw.csv: no header row (the first row is numbers): columns named by position 0..18" in back.notes
    assert "raw.csv: position from columns 1:7 by position (1, 2, 3, 4, 5, 6)" in back.notes
    assert len(back) == t.size  # the first row is a sample, not a header
    # interleaved q_1, dq_1, q_2, dq_2, ...: every second column
    inter = _headerless_csv(tmp_path / "inter.csv", t, np.stack([q, dq], axis=2), tau)
    back = load_log(
        inter, joint_names=arm.joint_names, columns=parse_column_mapping("t=0,q=1:13:2,dq=2:13:2,tau=13:19")
    )
    np.testing.assert_array_equal(back.dq, named.dq)


def test_a_headerless_file_without_positions_says_how_to_map_it(arm, tmp_path):
    t, q, dq, _, tau = _motion(arm, 1.0, 100.0)
    raw = _headerless_csv(tmp_path / "raw.csv", t, q, dq, tau)
    expected = (
        r"raw\.csv: no header row \(the first row is numbers, 19 columns\): name the columns by position, 0-based "
        r"with the end excluded, e\.g\. --columns t=0,q=1:7,dq=7:13,tau=13:19; no position given for t, q, dq, tau"
    )
    with pytest.raises(DataError, match=expected):
        load_log(raw, joint_names=arm.joint_names)
    with pytest.raises(DataError, match=r"raw\.csv: column mapping q=1:8 names 7 column\(s\) \(1, 2, 3, 4, 5, 6, 7\); "
                       r"there are 6 joints"):  # fmt: skip
        load_log(raw, joint_names=arm.joint_names, columns=parse_column_mapping("t=0,q=1:8,dq=7:13,tau=13:19"))
    with pytest.raises(DataError, match=r"raw\.csv: column mapping tau=15:21 reaches column 20 \(counted from 0\); "
                       r"the file has 19 columns \(0\.\.18\)"):  # fmt: skip
        load_log(raw, joint_names=arm.joint_names, columns=parse_column_mapping("t=0,q=1:7,dq=7:13,tau=15:21"))
    with pytest.raises(ConfigError, match=r"positions START:STOP\[:STEP\] need STOP > START"):
        parse_column_mapping("q=7:1")
    with pytest.raises(ConfigError, match=r"t='0\*2': time takes no scale; give its unit"):
        parse_column_mapping("t=0*2")


def test_a_scale_converts_a_column_and_is_said(arm, tmp_path):
    t, q, dq, _, tau = _motion(arm, 1.0, 100.0)
    df = pd.DataFrame({"t": t} | {f"q_{j + 1}": q[:, j] for j in range(6)} | {f"dq_{j + 1}": dq[:, j] for j in range(6)}
                      | {f"trq_mNm_{j + 1}": 1e3 * tau[:, j] for j in range(6)})  # fmt: skip
    p = tmp_path / "mnm.csv"
    df.to_csv(p, index=False, float_format="%.17g")
    back = load_log(p, joint_names=arm.joint_names, columns=parse_column_mapping("tau=trq_mNm_{i}*0.001"))
    np.testing.assert_allclose(back.tau, tau, rtol=1e-15, atol=1e-12)
    assert "mnm.csv: measured torque from columns 'trq_mNm_{i}' (mapping), times 0.001" in back.notes


def test_repeated_column_names_are_refused_naming_the_column(tmp_path):
    """pandas renames a repeated q_2 to q_2.1 and the first one was used silently (issue 20 item 7)."""
    p = tmp_path / "dup.csv"
    rows = "\n".join(f"{k * 1e-3},0,0.1,0.2,0,0,0,{k},{k},0" for k in range(20))
    p.write_text("t,q_1,q_2,q_2,dq_1,dq_2,dq_3,tau_1,tau_2,tau_3\n" + rows + "\n")
    with pytest.raises(DataError, match=r"dup\.csv: column 'q_2' appears 2 times \(positions 2, 3, from 0\); every "
                       r"column needs its own name: rename the copies") as info:  # fmt: skip
        load_log(p)
    assert info.value.column == "q_2"  # type: ignore[attr-defined]


# ---------------------------------------------------------------------------------------------- currents
def test_torque_from_current_equals_the_torque(arm, tmp_path):
    t, q, dq, _, tau = _motion(arm, 2.0, 100.0)
    current = tau / np.asarray(GAINS)
    raw = _headerless_csv(tmp_path / "cur.csv", t, q, dq, current)
    back = load_log(raw, joint_names=arm.joint_names, columns=parse_column_mapping("t=0,q=1:7,dq=7:13,cur=13:19"),
                    torque_from="current", gains=GAINS)  # fmt: skip
    np.testing.assert_allclose(back.tau, tau, rtol=4e-16, atol=1e-13)
    assert any(n.startswith("cur.csv: measured torque = gain x motor current, gains 0.95, 1.1, 0.6, 0.23, 0.25, "
                            "-0.21 Nm/A") for n in back.notes), back.notes  # fmt: skip
    # by name: current_<i> columns are found as tau_<i> are
    cols = {"t": t} | {
        f"{s}_{j + 1}": a[:, j] for s, a in (("q", q), ("dq", dq), ("current", current)) for j in range(6)
    }
    named = pd.DataFrame(cols)
    named.to_csv(tmp_path / "named.csv", index=False, float_format="%.17g")
    back = load_log(tmp_path / "named.csv", joint_names=arm.joint_names, torque_from="current", gains=GAINS)
    np.testing.assert_allclose(back.tau, tau, rtol=4e-16, atol=1e-13)
    with pytest.raises(ConfigError, match=r"named\.csv: 2 gain\(s\) given for 6 joints: give one gain per joint"):
        load_log(tmp_path / "named.csv", joint_names=arm.joint_names, torque_from="current", gains=(0.1, 0.1))
    with pytest.raises(ConfigError, match=r"named\.csv: the torque from motor currents needs the gain of every joint"):
        load_log(tmp_path / "named.csv", joint_names=arm.joint_names, torque_from="current")
    with pytest.raises(
        ConfigError, match=r"named\.csv: the gain of joint 3 is 0\.0; gains must be finite and non-zero"
    ):
        load_log(tmp_path / "named.csv", joint_names=arm.joint_names, torque_from="current", gains=(1, 1, 0, 1, 1, 1))
    with pytest.raises(ConfigError, match=r"column mapping current='current_\{i\}' names motor currents"):
        load_log(tmp_path / "named.csv", joint_names=arm.joint_names, columns={"current": "current_{i}"})


def test_identification_from_currents_equals_identification_from_torques(arm, tmp_path, capsys):
    """Issue 17's must-show: a current-based copy of a log (torque / gain, header-less, 100 Hz) identifies to
    the same model as the torque log, on the command line."""
    t, q, dq, _, tau = _motion(arm, 30.0, 100.0)
    torque_log = _schema_csv(tmp_path / "torque.csv", t, q, dq, tau)
    current_log = _headerless_csv(tmp_path / "current.csv", t, q, dq, tau / np.asarray(GAINS))
    base = ["identify", "dynamics", "--robot", str(arm.source), "--ee-frame", SIX_DOF_TOOL, "--method", "combined",
            "--cutoff", "5", "--no-projection", "--quiet"]  # fmt: skip
    assert main([*base, "--log", str(torque_log), "--out", str(tmp_path / "a")]) == 0
    gains = ",".join(f"{g:g}" for g in GAINS)
    current_args = ["--log", str(current_log), "--columns", "t=0,q=1:7,dq=7:13,cur=13:19",
                    "--torque-from", "current", "--gains", gains, "--out", str(tmp_path / "b")]  # fmt: skip
    assert main([*base, *current_args]) == 0
    text = capsys.readouterr().out
    assert "log: current.csv: measured torque = gain x motor current (columns 13, 14, 15, 16, 17, 18)" not in text
    assert "log: current.csv: measured torque = gain x motor current, gains 0.95, 1.1, 0.6, 0.23, 0.25, -0.21" in text
    a = json.loads((tmp_path / "a" / "model_combined.json").read_text())["identification"]
    b = json.loads((tmp_path / "b" / "model_combined.json").read_text())["identification"]
    assert b["n_samples"] == a["n_samples"] > 0
    scale = np.max(np.abs(a["beta_b"]))
    np.testing.assert_allclose(b["beta_b"], a["beta_b"], rtol=ROUND_OFF_RTOL, atol=ROUND_OFF_RTOL * scale)
    for key in ("viscous", "coulomb"):
        np.testing.assert_allclose(b["friction"][key], a["friction"][key], rtol=ROUND_OFF_RTOL, err_msg=key)
    np.testing.assert_allclose(b["residual_rms"], a["residual_rms"], rtol=1e-6, atol=1e-12)
    # the gains on the command line are checked before the file is read
    assert main([*base, *current_args[:-2], "--gains", "0.1,0.1", "--out", str(tmp_path / "c")]) == 2
    assert "current.csv: 2 gain(s) given for 6 joints" in capsys.readouterr().err
    assert main([*base, "--log", str(torque_log), "--gains", gains, "--out", str(tmp_path / "d")]) == 2
    assert "--gains [Nm/A] turn motor currents into torques: give them with --torque-from current" in (
        capsys.readouterr().err
    )


# ---------------------------------------------------------------------------------------------- time stamps
def _sine(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    w = 2 * np.pi * np.array([0.3, 0.45, 0.7])
    return np.sin(np.outer(t, w)), np.cos(np.outer(t, w)) * w


def _mismatch(log: RobotLog) -> float:
    v = 0.5 * (log.dq[1:] + log.dq[:-1])
    r = np.diff(log.q, axis=0) - v * np.diff(log.t)[:, None]
    return float(np.sqrt(np.mean(r**2)) / np.sqrt(np.mean((v * log.period) ** 2)))


def test_irregular_robot_stamps_are_kept_and_the_period_is_the_median_step():
    """A controller that samples every 10, 12 or 14 ms (its stamps are right): the reader moved samples by up to
    7.8 ms onto a 10 ms grid (65 ms on the issue's log), made q/dq agree 0.000 -> 0.285 and created 365 gaps."""
    rng = np.random.default_rng(3)
    t = np.r_[0.0, np.cumsum(rng.choice([0.010, 0.010, 0.010, 0.012, 0.014], size=3000))]
    q, dq = _sine(t)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing is repaired: no warning
        log = RobotLog.from_arrays(t, q, dq, np.zeros_like(q), source="robot")
    np.testing.assert_array_equal(log.t, t)
    assert log.period == pytest.approx(0.010, rel=1e-9)
    (note,) = log.notes
    assert note.startswith("robot: time steps irregular (10 to 14 ms; period 10 ms, the median step): kept the "
                           "log's own time stamps: re-timing onto a grid would ")  # fmt: skip
    assert _mismatch(log) < 1e-3  # the exact stamps: q and dq agree to the trapezoid's error


@pytest.mark.parametrize("seed", [0, 1])
def test_host_jitter_below_half_a_period_is_removed_without_moving_or_gapping(tmp_path, seed):
    """Issue 18 item 9: epoch-us stamps with +-0.3 ms jitter at 1 kHz, a minute of slow motion and rest with
    noisy q and dq: re-timing shifted samples by up to 3.3 ms or gave up (seed 0: 804 steps of 1.5-1.6 ms kept).
    Now every sample goes to its own tick: one period per step, no gap, no shift beyond the jitter."""
    rng = np.random.default_rng(seed)
    N = 60_000
    t = np.arange(N) * 1e-3
    w = 2 * np.pi * np.array([0.05, 0.08, 0.11])
    moving = (np.sin(2 * np.pi * 0.02 * t) > 0)[:, None]
    q = np.where(moving, 0.3 * np.sin(np.outer(t, w)), 0.0) + rng.normal(0, 1e-5, (N, 3))
    dq = np.where(moving, 0.3 * np.cos(np.outer(t, w)) * w, 0.0) + rng.normal(0, 2e-3, (N, 3))
    jitter = rng.uniform(-3e-4, 3e-4, N)
    stamps = 1_795_435_200_000_000 + np.round((t + jitter) * 1e6).astype(np.int64)
    df = pd.DataFrame({"t_us": stamps} | {f"{s}_{j + 1}": a[:, j] for s, a in (("q", q), ("dq", dq)) for j in range(3)}
                      | {f"tau_{j + 1}": np.zeros(N) for j in range(3)})  # fmt: skip
    p = tmp_path / "host.csv"
    df.to_csv(p, index=False, float_format="%.17g")
    with pytest.warns(LogRepairWarning, match=r"host stamps jitter around the robot's ticks; re-timed 60,000 samples"):
        log = load_log(p, n_joints=3)
    host = (stamps - stamps[0]) * 1e-6
    steps = np.diff(log.t)
    np.testing.assert_allclose(steps, steps.mean(), rtol=0, atol=1e-12, err_msg="one grid period per step")
    assert abs(steps.mean() - 1e-3) < 1e-8  # the robot's period, from the whole minute of stamps
    # each sample on its own tick: the shift from its stamp is its jitter (up to a common offset)
    offset = np.median(log.t - host + jitter)
    shift = np.abs(log.t - host)
    assert shift.max() <= 0.5e-3  # never more than half a period
    np.testing.assert_allclose(log.t - host + jitter, offset, rtol=0, atol=2e-6)  # 1 us stamp rounding
    assert "no gaps" in log.notes[-1]


def test_real_gaps_stay_and_none_is_made_from_jitter():
    """Dropped samples (a 5-period gap) under +-0.25 ms host jitter: the gap stays, no other step changes."""
    rng = np.random.default_rng(7)
    ticks = np.r_[np.arange(0, 2000), np.arange(2005, 4000)]
    t_true = ticks * 1e-3
    q, dq = _sine(t_true)
    host = t_true + rng.uniform(-2.5e-4, 2.5e-4, t_true.size)
    with pytest.warns(LogRepairWarning, match=r"re-timed 3,995 samples .* 1 gap\(s\) the stamps show remain"):
        log = RobotLog.from_arrays(host, q, dq, np.zeros_like(q), source="gap")
    np.testing.assert_array_equal(np.round(np.diff(log.t) / 1e-3).astype(int), np.diff(ticks))
    assert np.abs(log.t - host).max() <= 0.5e-3


# ---------------------------------------------------------------------------------------------- checks
def _runs(robot: RobotModel, joint: int):
    plan = plan_friction_experiment(robot, joint, speeds=(0.2, 0.5, 1.0))
    t = np.arange(0.0, plan.duration, 1e-3)
    q, dq, ddq = plan.evaluate(t)
    fr = FrictionParameters.from_model(robot.friction)
    tau = BatchRegressor(robot).compute_regressor(q, dq, ddq) @ robot.inertial_parameters() + fr.compute_torque(dq)
    return t, q, dq, tau


@pytest.mark.parametrize(
    ("defect", "message"),
    [
        ("spike", r"runs\.csv: 1 row\(s\) with implausible tau \[Nm\] \(beyond 10 x the effort limits"),
        ("degrees", r"runs\.csv: \d[\d,]* row\(s\) with implausible (q|dq) .*"),
        ("mNm", r"runs\.csv: \d[\d,]* row\(s\) with implausible tau \[Nm\] \(beyond 10 x the effort limits"),
    ],
)
def test_identify_friction_and_validate_refuse_what_identify_dynamics_refuses(arm, tmp_path, capsys, defect, message):
    """Issue 20 items 1-2: one torque sample of 5e5 Nm, positions and velocities in degrees, torques in mNm
    passed 'identify friction --run' and 'validate' with exit 0; the same check as 'identify dynamics' now."""
    t, q, dq, tau = _runs(arm, 1)
    if defect == "spike":
        tau[len(t) // 2, 1] = 5e5
    elif defect == "degrees":
        q, dq = np.degrees(q), np.degrees(dq)
    else:
        tau = 1e3 * tau
    runs = _schema_csv(tmp_path / "runs.csv", t, q, dq, tau)
    robot = ["--robot", str(arm.source), "--ee-frame", SIX_DOF_TOOL]
    out = tmp_path / "fr"
    assert main(["identify", "friction", *robot, "--run", f"2={runs}", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert re.search("reflexarm identify: error: " + message, err), err
    assert not out.exists() or not list(out.glob("*.json"))
    # dynamics refuses the same file with the same message
    assert main(["identify", "dynamics", *robot, "--log", str(runs), "--method", "combined", "--out",
                 str(tmp_path / "dyn"), "--quiet"]) == 2  # fmt: skip
    assert re.search("reflexarm identify: error: " + message, capsys.readouterr().err)


def test_validate_refuses_a_log_in_degrees(arm, tmp_path, capsys):
    t, q, dq, _, tau = _motion(arm, 20.0, 200.0)
    good = _schema_csv(tmp_path / "good.csv", t, q, dq, tau)
    robot = ["--robot", str(arm.source), "--ee-frame", SIX_DOF_TOOL]
    out = tmp_path / "id"
    assert main(["identify", "dynamics", *robot, "--log", str(good), "--method", "combined",
                 "--out", str(out), "--quiet"]) == 0  # fmt: skip
    model = str(out / "model_combined.json")
    assert main(["validate", *robot, "--model", model, "--log", str(good), "--out", str(tmp_path / "v1")]) == 0
    capsys.readouterr()
    bad = _schema_csv(tmp_path / "deg.csv", t, np.degrees(q), np.degrees(dq), tau)
    assert main(["validate", *robot, "--model", model, "--log", str(bad), "--out", str(tmp_path / "v2")]) == 2
    assert re.search(r"reflexarm validate: error: deg\.csv: [\d,]+ row\(s\) with implausible (q|dq)",
                     capsys.readouterr().err)  # fmt: skip


def test_continuous_joints_in_degrees_are_refused_and_radians_pass(continuous_arm, tmp_path):
    """Issue 18 item 5: continuous joints (no range to leave) logged in degrees were accepted (pooled RMSE 4.14 Nm
    on the Gen3). A slow motion keeps the degrees within 10 x the velocity limit: only the torque can tell."""
    robot = continuous_arm
    t, q, dq, _, tau = _motion(robot, 10.0, 200.0, amplitude=0.05)
    assert np.abs(np.degrees(dq)).max() < 10 * robot.velocity_limit.min()  # the velocity check cannot see it
    ok = load_log(_schema_csv(tmp_path / "rad.csv", t, q, dq, tau), joint_names=robot.joint_names)
    from reflexarm.logs.plausibility import check_log_against_robot

    check_log_against_robot(ok, robot)  # radians: no refusal
    deg = np.ones(robot.n)
    deg[[0, 3]] = 180 / np.pi
    q_d, dq_d = q * deg, dq * deg
    q_d[:, 3] += 90.0  # a continuous joint logged in degrees from another zero: the range check cannot see it
    bad = load_log(_schema_csv(tmp_path / "deg.csv", t, q_d, dq_d, tau), joint_names=robot.joint_names)
    expected = (
        r"deg\.csv: the continuous joint\(s\) q_1 \(shoulder_pan_joint\), q_4 \(wrist_1_joint\) look logged in "
        r"degrees: the robot's model explains the measured torque with an RMS error of [\d.]+ Nm reading them as "
        r"radians, [\d.e-]+ Nm reading them as degrees"
    )
    with pytest.raises(ImplausibleDataError, match=expected):
        check_log_against_robot(bad, robot)
    # positions in degrees beside velocities in rad/s: q and dq disagree by 57.3
    mixed = load_log(_schema_csv(tmp_path / "mixed.csv", t, q * deg, dq, tau), joint_names=robot.joint_names)
    with pytest.raises(ImplausibleDataError, match=r"mixed\.csv: q_1 \(shoulder_pan_joint\) changes 57\.\d+ times as "
                       r"much as the integral of dq_1 .* positions in degrees, velocities in rad/s\?"):  # fmt: skip
        check_log_against_robot(mixed, robot)


def test_a_bags_effort_read_as_motor_currents(arm, tmp_path):
    """--torque-from current on a bag: the JointState effort field holds the currents."""
    from log_exports import write_bag

    t, q, dq, _, tau = _motion(arm, 1.0, 500.0)
    bag = write_bag(RobotLog(t, q, dq, tau / np.asarray(GAINS)), tmp_path / "bag", list(arm.joint_names),
                    storage="mcap", gripper=False)  # fmt: skip
    back = load_log(bag, joint_names=arm.joint_names, torque_from="current", gains=GAINS)
    np.testing.assert_allclose(back.tau, tau, rtol=4e-16, atol=1e-13)
    assert any("measured torque = gain x motor current, gains 0.95" in n for n in back.notes)


def test_a_torque_on_another_scale_than_the_models_is_refused(arm):
    """Where the effort limits cannot tell (a robot file without them), the model's torque does: mNm are 1000x."""
    from reflexarm.logs.units import check_units

    t, q, dq, ddq, tau = _motion(arm, 10.0, 200.0)
    check_units("nm", t, q, dq, tau, arm, ddq)  # the exact torques: no refusal
    expected = (
        r"mnm: the measured torque is 1000 times the robot model's torque along the log \(least squares, 9\d % "
        r"explained; expected about 1\): mNm instead of Nm\?"
    )
    with pytest.raises(ImplausibleDataError, match=expected):
        check_units("mnm", t, q, dq, 1e3 * tau, arm, ddq)
    # a current logged without its gain (0.1 Nm/A: the 'torque' is 10 x the model's)
    with pytest.raises(ImplausibleDataError, match=r"cur: the measured torque is 10 times .* a current instead of a "):
        check_units("cur", t, q, dq, tau / 0.1, arm, ddq)
