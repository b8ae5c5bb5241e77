"""Friction from ordinary motion (issue 17, item 4): no constant-velocity runs, Coulomb + viscous recovered.

Recovery on the MuJoCo plant of the UR-like 6-DoF arm (``ident_arms``), whose joint friction (MuJoCo
``frictionloss`` = mu_C, ``damping`` = d_v) is the file's: the truth is the generator's table
``SIX_DOF_LINKS``, never the code under test.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from ident_arms import SIX_DOF_LINKS, SIX_DOF_TOOL, write_six_dof_urdf
from reflexarm import load_robot
from reflexarm.cli import main
from reflexarm.errors import IdentificationError
from reflexarm.experiments.identification import simulate_log
from reflexarm.ident import BatchRegressor, FrictionParameters, RobotLog, preprocess_log, save_log
from reflexarm.ident.excitation.design import FourierTrajectory
from reflexarm.ident.friction.from_motion import identify_friction_from_motion
from reflexarm.robots.robot_model import RobotModel

TRUE_COULOMB = np.array([link[6] for link in SIX_DOF_LINKS])
TRUE_VISCOUS = np.array([link[7] for link in SIX_DOF_LINKS])
#: The issue's requirement: friction within 10 %. Measured (seeds 0-3 of this motion): Coulomb within 3.2 %,
#: viscous within 8.3 % on joints 1-5 with the combined method.
RECOVERY_RTOL = 0.10
#: Joints 1-5 move enough and are recovered. Joint 6 moves (up to 2 rad/s) but its plant friction is not
#: Coulomb + viscous: MuJoCo's soft frictionloss constraint on the 2e-4 kg m^2 wrist link reaches mu_C only
#: above ~0.5 rad/s (see the test below), so its Coulomb comes out 10-17 % low and its viscous 15-40 % high.
RECOVERED_JOINTS = [0, 1, 2, 3, 4]
#: Peak speed of every joint in the ordinary motion [rad/s] (the arm's limit is 3.15).
PEAK_SPEED = 2.0


def ordinary_motion(n: int, seed: int) -> FourierTrajectory:
    """One period (10 s) of a random 5-harmonic Fourier motion, each joint scaled to PEAK_SPEED: no
    constant-velocity interval anywhere."""
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=(n, 5)), rng.normal(size=(n, 5))
    tr = FourierTrajectory.from_hz(0.1, a, b, np.zeros(n))
    _, dq, _ = tr.evaluate(np.arange(0.0, tr.period, 1e-2))
    s = PEAK_SPEED / np.abs(dq).max(axis=0)
    return FourierTrajectory.from_hz(0.1, a * s[:, None], b * s[:, None], np.zeros(n))


@pytest.fixture(scope="module")
def six_dof(tmp_path_factory: pytest.TempPathFactory) -> RobotModel:
    return load_robot(write_six_dof_urdf(tmp_path_factory.mktemp("arm")), ee_frame=SIX_DOF_TOOL)


@pytest.fixture(scope="module")
def raw_log(six_dof: RobotModel) -> RobotLog:
    tr = ordinary_motion(six_dof.n, seed=1)
    raw, _ = simulate_log(six_dof, tr, tr.duration, seed=1)  # paper noise, controller with the true model
    return raw


@pytest.fixture(scope="module")
def plant_log(raw_log: RobotLog) -> RobotLog:
    return preprocess_log(raw_log)


def test_the_generated_motion_has_no_constant_velocity_interval(six_dof: RobotModel, plant_log: RobotLog) -> None:
    from reflexarm.ident import segment_constant_velocity

    for j in range(six_dof.n):
        assert segment_constant_velocity(plant_log.t, plant_log.dq[:, j]) == [], f"joint {j + 1}"


def test_combined_friction_from_ordinary_motion_recovers_the_plants_friction(
    six_dof: RobotModel, plant_log: RobotLog
) -> None:
    res = identify_friction_from_motion(six_dof, plant_log)
    assert res.method == "combined"
    assert "method 'combined'" in res.describe()
    assert res.not_identified == {}
    j = RECOVERED_JOINTS
    np.testing.assert_allclose(res.friction.coulomb[j], TRUE_COULOMB[j], rtol=RECOVERY_RTOL, err_msg="mu_C")
    np.testing.assert_allclose(res.friction.viscous[j], TRUE_VISCOUS[j], rtol=RECOVERY_RTOL, err_msg="d_v")


def test_joint_6_is_left_out_because_the_plants_friction_there_is_not_coulomb_plus_viscous(
    six_dof: RobotModel, plant_log: RobotLog
) -> None:
    # the torque the plant's friction takes, with the generator's (exact) rigid-body torque removed
    Y = BatchRegressor(six_dof).compute_regressor(plant_log.q, plant_log.dq, plant_log.ddq)
    f6 = (plant_log.tau - Y @ six_dof.inertial_parameters())[:, 5]
    v6 = plant_log.dq[:, 5]
    band = (np.abs(v6) > 0.1) & (np.abs(v6) < 0.2)
    law = TRUE_COULOMB[5] * np.sign(v6[band]) + TRUE_VISCOUS[5] * v6[band]
    # the plant's friction at 0.1-0.2 rad/s is more than 10 % below the file's law (measured: about 15 %)
    assert np.mean(np.abs(f6[band])) < 0.9 * np.mean(np.abs(law))


def test_steady_fit_with_the_exact_model_recovers_the_friction_and_a_wrong_model_does_not(
    six_dof: RobotModel, plant_log: RobotLog
) -> None:
    from reflexarm.robots import perturb_model

    exact = identify_friction_from_motion(six_dof, plant_log, method="steady")
    j = RECOVERED_JOINTS
    np.testing.assert_allclose(exact.friction.coulomb[j], TRUE_COULOMB[j], rtol=RECOVERY_RTOL, err_msg="mu_C")
    np.testing.assert_allclose(exact.friction.viscous[j], TRUE_VISCOUS[j], rtol=RECOVERY_RTOL, err_msg="d_v")
    # why "combined" is the default: with a +-10 % nominal model the gravity error is read as friction
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        wrong = identify_friction_from_motion(six_dof, plant_log, method="steady", model=perturb_model(six_dof, 0.1))
    err = np.abs(wrong.friction.viscous[j] / TRUE_VISCOUS[j] - 1)
    assert err.max() > 2 * RECOVERY_RTOL, err


def _exact_log(robot: RobotModel, joint_speed: np.ndarray) -> RobotLog:
    tr = ordinary_motion(robot.n, seed=4)
    t = np.arange(0.0, tr.period, 2e-3)
    q, dq, ddq = tr.evaluate(t)
    q, dq, ddq = q * joint_speed, dq * joint_speed, ddq * joint_speed  # scale some joints to (nearly) still
    fr = FrictionParameters.from_model(robot.friction)
    tau = BatchRegressor(robot).compute_regressor(q, dq, ddq) @ robot.inertial_parameters() + fr.compute_torque(dq)
    return RobotLog(t, q, dq, tau, ddq=ddq, source="exact")


def test_a_joint_that_does_not_move_enough_is_not_identified_and_says_why(six_dof: RobotModel) -> None:
    log = _exact_log(six_dof, np.array([1.0, 1.0, 1.0, 1.0, 1.0, 0.05]))  # joint 6 peaks at 0.1 rad/s
    res = identify_friction_from_motion(six_dof, log)
    assert res.friction.missing == (5,)
    assert "joint 6" in res.describe(six_dof.joint_names) and "wrist_3_joint" in res.describe(six_dof.joint_names)
    # exact data: the moving joints' friction to round-off of the normal equations
    np.testing.assert_allclose(res.friction.coulomb[:5], TRUE_COULOMB[:5], rtol=1e-6)


def test_unknown_method_is_refused_with_the_choices(six_dof: RobotModel) -> None:
    log = _exact_log(six_dof, np.ones(6))
    with pytest.raises(IdentificationError, match=r"unknown friction method 'fast'; choose one of: combined, steady"):
        identify_friction_from_motion(six_dof, log, method="fast")


def test_identify_friction_on_a_log_of_ordinary_motion_names_the_method(
    six_dof: RobotModel, raw_log: RobotLog, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = save_log(raw_log, tmp_path / "ordinary.npz")
    arm = ["--robot", str(six_dof.source), "--ee-frame", SIX_DOF_TOOL, "--quiet"]
    # as constant-velocity runs it is refused, pointing to --log
    assert main(["identify", "friction", *arm, "--run", f"1={log}", "--out", str(tmp_path / "runs")]) != 0
    assert (
        f"ordinary.npz: no constant-velocity interval of joint 1 found; for a log of ordinary motion give it as "
        f"--log {log} (friction from the combined regression)" in capsys.readouterr().err
    )
    assert main(["identify", "friction", *arm, "--log", str(log), "--no-offset", "--out", str(tmp_path / "fr")]) == 0
    text = capsys.readouterr().out
    assert "friction from ordinary motion by method 'combined'" in text
    doc = json.loads((tmp_path / "fr" / "friction.json").read_text())
    assert doc["method"] == "from ordinary motion: combined"
    j = RECOVERED_JOINTS
    np.testing.assert_allclose(np.array(doc["coulomb"])[j], TRUE_COULOMB[j], rtol=RECOVERY_RTOL)


@pytest.mark.slow  # ~40 s: two identifications with projection, validation and robot copies
def test_identify_dynamics_both_says_when_sequential_cannot_run_and_runs_it_with_friction_from_motion(
    six_dof: RobotModel, raw_log: RobotLog, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = save_log(raw_log, tmp_path / "ordinary.npz")
    arm = ["--robot", str(six_dof.source), "--ee-frame", SIX_DOF_TOOL, "--quiet"]
    assert main(["identify", "friction", *arm, "--log", str(log), "--no-offset", "--out", str(tmp_path / "fr")]) == 0
    # the friction file is the sequential method's first step; without it 'both' says what it did
    out = tmp_path / "id"
    assert main(["identify", "dynamics", *arm, "--log", str(log), "--min-speed", "0.055", "--out", str(out)]) == 0
    assert "--method both: only the combined model is written; sequential not run: it needs the friction" in (
        capsys.readouterr().out
    )
    assert "sequential" in json.loads((out / "identification.json").read_text())["not_run"]
    fr = str(tmp_path / "fr" / "friction.json")
    assert main(["identify", "dynamics", *arm, "--log", str(log), "--friction", fr, "--out", str(out)]) == 0
    assert (out / "model_sequential.json").exists() and (out / "model_combined.json").exists()
