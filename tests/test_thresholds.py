"""reflexarm.tuning and ``reflexarm tune-thresholds``: the replay is the product's observer, the delay formula
matches it, the study and the command agree and number joints from 1, short logs are refused."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest

from reflexarm.cli import main
from reflexarm.errors import ConfigError, DataError
from reflexarm.experiments.collision import EE_START
from reflexarm.logs import save_log
from reflexarm.logs.robot_log import RobotLog
from reflexarm.sim import Trace
from reflexarm.tuning import (
    LogTooShortError,
    ObserverSettings,
    ThresholdWarning,
    detection_delay,
    load_free_motion_log,
    record_free_motion_log,
    replay_residual,
    tune_thresholds,
)
from reflexarm.tuning._report import format_report

DT = 1e-3


def _static_log(robot, disturbance: np.ndarray, source: str = "static") -> RobotLog:
    """The arm held still at EE_START with an external torque ``disturbance`` (N, n): at rest the motor
    torque is g(q) - tau_ext (eq. (1) with ddq = dq = 0), so the residual must follow tau_ext."""
    N = disturbance.shape[0]
    q = np.tile(EE_START, (N, 1))
    tau = robot.compute_gravity(EE_START)[None, :] - disturbance
    return RobotLog(t=np.arange(N) * DT, q=q, dq=np.zeros_like(q), tau=tau, source=source)


def _random_disturbance(n: int, seconds: float, seed: int) -> np.ndarray:
    """Per joint, a value held for 0.5 s then redrawn (N(0, 2 Nm)), plus uniform noise of 0.1 Nm."""
    rng = np.random.default_rng(seed)
    holds = int(seconds / 0.5)
    steps = rng.normal(0.0, 2.0, (holds, n))
    return np.repeat(steps, int(0.5 / DT), axis=0) + rng.uniform(-0.1, 0.1, (holds * int(0.5 / DT), n))


def test_detection_delay_formula():
    T = 0.2
    assert detection_delay(11.0, 10.0, T) is None  # a step below zeta is never detected
    assert detection_delay(11.0, 30.0, T) == pytest.approx(-T * math.log(1.0 - 11.0 / 30.0), rel=1e-12)
    # a residual already at b towards zeta shortens it; against zeta lengthens it
    assert detection_delay(11.0, 30.0, T, 5.0) < detection_delay(11.0, 30.0, T) < detection_delay(11.0, 30.0, T, -5.0)
    assert detection_delay(11.0, 30.0, T, 12.0) == 0.0


@pytest.mark.parametrize("joint, step", [(2, 30.0), (0, 15.0)])
def test_the_replayed_observer_crosses_zeta_when_the_formula_says(atlas, joint, step):
    """A torque step at rest through the Controller: the residual is ~0 before it and crosses zeta at
    t0 + t_d of the formula (to one tick: the observer sees the step one sample after it and the crossing
    is quantised to a tick; 2 ticks of tolerance)."""
    N, t0, zeta = 3000, 0.5, 11.0
    e = np.zeros((N, atlas.n))
    e[int(t0 / DT) :, joint] = step
    rep = replay_residual(_static_log(atlas, e), atlas, ObserverSettings(observer_gain=5.0))
    before = np.abs(rep.residual[: int(t0 / DT)]).max()
    assert before < 1e-6, f"exact model at rest: the residual should be 0 before the step; got {before:.2e} Nm"
    k = int(np.argmax(np.abs(rep.residual[:, joint]) > zeta))
    T_o = -DT / math.log1p(-5.0 * DT)
    predicted = detection_delay(zeta, step, T_o)
    assert predicted is not None
    np.testing.assert_allclose(rep.t[k] - t0, predicted, atol=2 * DT, err_msg="crossing time vs t_d formula")
    np.testing.assert_allclose(rep.residual[-1, joint], step, rtol=1e-3, err_msg="the residual settles at the step")


def test_replay_reproduces_the_online_residual(atlas):
    """A simulated free-motion run (noise, +-10 % model): the offline replay of its recorded measurements
    through a new Controller gives the online residual. The log does not hold the measured gravity vector
    (noise 2e-4 m/s^2, 2e-5 of g, on gravity torques below ~100 Nm, low-passed by the observer): 1e-4 Nm."""
    from reflexarm.experiments.collision import controller_model

    model, _ = controller_model(atlas, 0.1, 0)
    run = record_free_motion_log(2.0, model=model, seed=3)
    rep = replay_residual(run.log, model)
    assert rep.fault_ticks == 0
    np.testing.assert_allclose(np.abs(rep.residual).max(axis=0), run.max_abs_residual, atol=1e-4)


def test_recorded_run_s_online_detector_runs_the_settings_observers(atlas):
    """With ``settings`` the recorded run's online detector runs the observers being tuned (a 100 1/s detection
    observer, exact, its own friction band, the second stage): its residual is the replay's with those settings
    (measured 3.9e-5 Nm; 1e-4 Nm as above), where the paper's 5 1/s observer alone (what it ran before) differs by
    ~0.9 Nm."""
    from reflexarm.experiments.collision import controller_model
    from reflexarm.tuning import ObserverSettings

    model, _ = controller_model(atlas, 0.1, 0)
    s = ObserverSettings(detection_observer_gain=100.0, observer_discretization="exact", detection_friction_band=0.1,
                         detection_filter_gain=200.0)  # fmt: skip
    run = record_free_motion_log(2.0, model=model, seed=3, threshold=1e3, settings=s)
    peak = np.abs(replay_residual(run.log, model, s).residual).max(axis=0)
    np.testing.assert_allclose(peak, run.max_abs_residual, atol=1e-4)
    paper = record_free_motion_log(2.0, model=model, seed=3, threshold=1e3)
    assert np.max(np.abs(peak - paper.max_abs_residual)) > 0.1


def test_study_and_command_agree_and_number_joints_from_one(atlas, tmp_path):
    log = _static_log(atlas, _random_disturbance(atlas.n, 60.0, seed=7), source="synthetic")
    path = save_log(log, tmp_path / "free.parquet")
    kw = dict(rate_per_hour=60.0, contact_rate_per_hour=600.0, step_torque=20.0, gap_s=0.1, n_boot=50)
    prop = tune_thresholds(log, atlas, **kw)
    assert [r["joint"] for r in prop.rows()] == list(range(1, atlas.n + 1))
    assert np.all(prop.contact < prop.collision), "the contact level is the lower one"
    # the residual follows the held values: its maximum per joint is near the largest drawn value
    assert np.all(prop.collision > 0.5 * np.array([j.fit.x_max for j in prop.joints]))
    out = tmp_path / "out"
    args = f"tune-thresholds {path} --rate 60 --contact-rate 600 --step-torque 20 --step-force 50 --gap 0.1 --out {out}"
    assert main(args.split()) == 2, "a log at rest: levels of joints that did not move are refused"
    code = main([*args.split(), "--allow-unmoved"])
    assert code == 0
    doc = json.loads((out / "thresholds.json").read_text())
    assert [c["moved"] for c in doc["coverage"]] == [False] * atlas.n  # marked, as the arm never moved
    # the bootstrap draws differ (200 in the command, 50 here); the levels do not depend on them
    np.testing.assert_allclose(doc["collision_Nm"], prop.collision, rtol=1e-9)
    np.testing.assert_allclose(doc["contact_Nm"], prop.contact, rtol=1e-9)
    assert [j["joint"] for j in doc["joints"]] == list(range(1, atlas.n + 1))
    assert set(doc["fits"]) == {str(j) for j in range(1, atlas.n + 1)}
    assert doc["joints"][0]["collision_alarms_in_logs"] >= 0 and "exponential" in doc["method"]["tail"]
    assert [r["direction"] for r in doc["force_step"]["levels"]["collision"]] == ["+x", "-x", "+y", "-y", "+z", "-z"]
    np.testing.assert_allclose(doc["force_step"]["posture_rad"], EE_START, atol=1e-12)
    for name in ("thresholds.csv", "thresholds.png", "threshold_tails.png"):
        assert (out / name).is_file()


def test_a_log_too_short_for_the_rate_is_refused_with_the_minimum(atlas, tmp_path):
    log = _static_log(atlas, _random_disturbance(atlas.n, 30.0, seed=8))
    with pytest.raises(LogTooShortError) as info:
        tune_thresholds(log, atlas, rate_per_hour=1.0, contact_rate_per_hour=60.0, gap_s=0.1)
    e = info.value
    # 7 joints at 1/7 per hour each: a return period of 7 h, of which 1/10 is the minimum span
    assert e.minimum_s == pytest.approx(7 * 3600.0 / 10.0)
    assert e.duration_s == pytest.approx(30.0, abs=2 * DT)
    assert (e.rate_per_hour, e.level) == (1.0, "collision")
    assert "needs at least 42.0 min of free-motion log" in str(e) and "got 0.5 min" in str(e)
    with pytest.warns(ThresholdWarning, match="extrapolating as asked"):
        prop = tune_thresholds(
            log, atlas, rate_per_hour=1.0, contact_rate_per_hour=600.0, gap_s=0.1, allow_extrapolation=True, n_boot=20
        )
    assert any("extrapolated" in note for note in prop.notes)
    out = tmp_path / "out"
    path = save_log(log, tmp_path / "short.parquet")
    args = f"tune-thresholds {path} --rate 1 --contact-rate 600 --gap 0.1 --allow-extrapolation --no-figure --out {out}"
    assert main([*args.split(), "--allow-unmoved"]) == 0  # a log at rest
    notes = json.loads((out / "thresholds.json").read_text())["notes"]
    assert sum("needs at least 42.0 min" in note for note in notes) == 1, notes  # noted once, not twice


def test_bad_settings_are_refused(atlas):
    log = _static_log(atlas, np.zeros((100, atlas.n)))
    with pytest.raises(ConfigError, match=r"contact level needs a higher false-alarm rate than the collision level"):
        tune_thresholds(log, atlas, rate_per_hour=10.0, contact_rate_per_hour=5.0)
    with pytest.raises(ConfigError, match="rate_per_hour must be a positive number of false alarms per hour; got -1"):
        tune_thresholds(log, atlas, rate_per_hour=-1.0)
    with pytest.raises(ConfigError, match="EFC.*needs the wrist wrench; static has no fx..mz columns"):
        replay_residual(log, atlas, ObserverSettings(kappa_ext=1))


def test_a_trace_is_read_with_a_warning_about_its_true_velocities(atlas, tmp_path):
    N, n = 50, atlas.n
    rng = np.random.default_rng(0)
    q = np.tile(EE_START, (N, 1))
    z = np.zeros((N, n))
    tr = Trace(
        t=np.arange(N) * DT, q=q, dq=z, q_meas=q + rng.uniform(-1e-4, 1e-4, q.shape), q_d=q, dq_d=z, tau=z,
        tau_m=z + 1.0, residual=z, collision=np.zeros(N, bool), collided=np.zeros((N, n), bool),
        mode=np.full(N, "compliant"), fault=np.full(N, ""), wrench=np.zeros((N, 6)), f_ext_ee=np.zeros((N, 3)),
        tau_ext=z,
    )  # fmt: skip
    path = tr.save(tmp_path / "run.parquet")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        log = load_free_motion_log(path, atlas)
    assert any(issubclass(w.category, ThresholdWarning) and "true joint velocities" in str(w.message) for w in caught)
    np.testing.assert_array_equal(log.q, tr.q_meas)
    np.testing.assert_array_equal(log.tau, tr.tau_m)


def test_force_step_torques_are_the_virtual_work_of_the_force(atlas):
    """tau = J_v^T F against finite differences of the end-effector position: tau_j = F . dp/dq_j
    (central differences with h = 1e-6 rad: truncation ~h^2, round-off ~1e-10/h; 1e-6 Nm for 50 N)."""
    from reflexarm.tuning import force_step_delays

    q = EE_START + 0.1
    force, h = 50.0, 1e-6
    rows = force_step_delays(atlas, q, force, 11.0, 0.2)
    assert [r["direction"] for r in rows] == ["+x", "-x", "+y", "-y", "+z", "-z"]
    for r, axis in zip(rows[::2], range(3), strict=True):
        fd = []
        for j in range(atlas.n):
            dq = np.zeros(atlas.n)
            dq[j] = h
            p_plus, p_minus = atlas.compute_frame_pose(q + dq)[1], atlas.compute_frame_pose(q - dq)[1]
            fd.append(force * (p_plus[axis] - p_minus[axis]) / (2 * h))
        np.testing.assert_allclose(r["joint_torque_Nm"], fd, atol=1e-6, err_msg=f"J_v^T F along {r['direction']}")
        tau = np.abs(np.asarray(r["joint_torque_Nm"]))
        if tau.max() > 11.0:
            j = int(np.argmax(tau))  # equal zeta on every joint: the largest torque crosses first
            assert r["first_joint"] == j + 1
            assert r["delay_s"] == pytest.approx(detection_delay(11.0, tau[j], 0.2))
        else:
            assert r["first_joint"] is None and r["delay_s"] is None


def test_a_traces_recorded_residual_is_tuned_on_as_it_is(atlas, tmp_path, capsys):
    """``--recorded-residual``: the residual column of a trace, not a replay, goes into the study."""
    from reflexarm.tuning import recorded_residual

    r = _random_disturbance(atlas.n, 60.0, seed=9)
    N, n = r.shape
    q = np.tile(EE_START, (N, 1))
    z = np.zeros((N, n))
    tr = Trace(
        t=np.arange(N) * DT, q=q, dq=z, q_meas=q, q_d=q, dq_d=z, tau=z, tau_m=z, residual=r,
        collision=np.zeros(N, bool), collided=np.zeros((N, n), bool), mode=np.full(N, "compliant"),
        fault=np.full(N, ""), wrench=np.zeros((N, 6)), f_ext_ee=np.zeros((N, 3)), tau_ext=z,
    )  # fmt: skip
    path = tr.save(tmp_path / "run.parquet")
    rec = recorded_residual(path, n)
    np.testing.assert_array_equal(rec.residual, r)
    prop = tune_thresholds([rec], atlas, rate_per_hour=60.0, contact_rate_per_hour=600.0, gap_s=0.1, n_boot=20)
    # the held values are the residual: the collision level lies above most of them
    assert np.all(prop.collision > np.quantile(np.abs(r), 0.99, axis=0))
    out = tmp_path / "out"
    args = f"tune-thresholds {path} --recorded-residual --rate 60 --contact-rate 600 --gap 0.1 --no-figure --out {out}"
    assert main([*args.split(), "--model-error", "10"]) == 0
    doc = json.loads((out / "thresholds.json").read_text())
    np.testing.assert_allclose(doc["collision_Nm"], prop.collision, rtol=1e-12)
    assert doc["logs"] == ["run.parquet (recorded residual)"]
    assert any("--model, --model-error and the observer options were not applied" in n for n in doc["notes"])
    # the header names the model the residual came from (the run's), not the --model-error that was ignored
    printed = capsys.readouterr()
    assert (
        "controller model: the one each trace's run used (its residual was recorded online); --model and "
        "--model-error are ignored" in printed.err
    )
    assert "model errors" not in printed.err
    assert "residual recorded online by each run's controller, with the model and observer that run used" in printed.out
    assert "kappa_f" not in printed.out.splitlines()[0]
    with pytest.raises(DataError, match="a recorded residual is read from a reflexarm trace"):
        recorded_residual(save_log(_static_log(atlas, np.zeros((10, n))), tmp_path / "log.parquet"), n)


def test_the_report_prints_each_joint_with_its_full_name(atlas):
    """Long joint names (a UR arm's ``shoulder_pan_joint``) are printed whole, beside the 1-based number,
    and every row of the table is as wide as its header."""
    from dataclasses import replace

    log = _static_log(atlas, _random_disturbance(atlas.n, 60.0, seed=7))
    prop = tune_thresholds(log, atlas, rate_per_hour=60.0, contact_rate_per_hour=600.0, gap_s=0.1, n_boot=20)
    names = [f"a_rather_long_joint_name_{j + 1}_joint" for j in range(atlas.n)]
    prop.joints = [replace(jt, name=name) for jt, name in zip(prop.joints, names, strict=True)]
    table = format_report(prop).splitlines()
    header = next(i for i, line in enumerate(table) if line.lstrip().startswith("joint"))
    rows = table[header + 1 : header + 1 + atlas.n]
    for j, (row, name) in enumerate(zip(rows, names, strict=True)):
        assert row.lstrip().startswith(f"{j + 1} ({name}) "), row
    assert {len(row) for row in rows} == {len(table[header])}
