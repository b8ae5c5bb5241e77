"""Identification on an arm that is not the Atlas arm (a 6-DoF file written here), and the friction
plausibility warnings (negative or implausibly large coefficients, joints 1-based in the message)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from ident_arms import SIX_DOF_TOOL, write_six_dof_urdf
from reflexarm import load_robot
from reflexarm.cli import main
from reflexarm.experiments.identification import hydraulic_joints, run_friction_experiments
from reflexarm.ident import BatchRegressor, FrictionParameters, RobotLog, identify_dynamics
from reflexarm.ident.excitation.design import FourierTrajectory
from reflexarm.ident.friction.joint_friction import FrictionPoint, fit_friction
from reflexarm.ident.friction.parameters import (
    ImplausibleFrictionWarning,
    check_friction_against_robot,
    check_friction_plausibility,
)
from reflexarm.robots.robot_model import RobotModel


@pytest.fixture(scope="module")
def six_dof(tmp_path_factory: pytest.TempPathFactory) -> RobotModel:
    return load_robot(write_six_dof_urdf(tmp_path_factory.mktemp("arm")), ee_frame=SIX_DOF_TOOL)


def test_hydraulic_joints_are_found_by_name_on_atlas_only(atlas: RobotModel, six_dof: RobotModel) -> None:
    assert hydraulic_joints(atlas) == (0, 1, 2, 3)
    assert hydraulic_joints(six_dof) == ()


def test_friction_runs_default_to_every_joint_of_another_arm_and_refuse_a_joint_it_lacks(six_dof: RobotModel) -> None:
    with pytest.raises(Exception, match=r"friction joints \[7\] \(1-based\) are not joints of 'ur_like_6dof'"):
        run_friction_experiments(six_dof, joints=(6,))


def test_negative_coulomb_friction_warns_with_the_joint_1_based_and_the_value(six_dof: RobotModel) -> None:
    fr = FrictionParameters(np.full(6, 0.2), np.array([1.0, 1.0, -0.46, 1.0, 1.0, 1.0]))
    with pytest.warns(ImplausibleFrictionWarning, match=r"joint 3 \(elbow_joint\) coulomb friction mu_C = -0\.46 Nm"):
        issued = check_friction_against_robot(fr, six_dof)
    assert [(w.joint, w.parameter, w.value, w.bound) for w in issued] == [(2, "coulomb", -0.46, 0.0)]
    assert "is negative" in str(issued[0])


def test_implausibly_large_friction_warns_against_the_effort_limit(six_dof: RobotModel) -> None:
    # joint 4 has effort 28 Nm and velocity limit 3.15 rad/s: mu_C 20 Nm > 0.5 x 28; d_v 10 x 3.15 > 28
    fr = FrictionParameters(np.array([0.2, 0.2, 0.2, 10.0, 0.2, 0.2]), np.array([1.0, 1.0, 1.0, 20.0, 1.0, 1.0]))
    with pytest.warns(ImplausibleFrictionWarning) as record:
        check_friction_against_robot(fr, six_dof)
    texts = [str(r.message) for r in record]
    assert any("joint 4 (wrist_1_joint) coulomb friction mu_C = 20 Nm is implausibly large" in t for t in texts)
    assert any("joint 4 (wrist_1_joint) viscous friction d_v = 10 Nms/rad is implausibly large" in t for t in texts)


def test_plausible_friction_gives_no_warning(six_dof: RobotModel) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error", ImplausibleFrictionWarning)
        assert check_friction_against_robot(FrictionParameters.from_model(six_dof.friction), six_dof) == []


def test_a_single_joint_fit_with_negative_coulomb_warns() -> None:
    # torque falls with speed in both directions: mu_C = -0.5, d_v = 1 (joint index 1 -> "joint 2")
    speeds = (-1.0, -0.5, -0.2, 0.2, 0.5, 1.0)
    pts = [FrictionPoint(1, v, 1.0 * v - 0.5 * np.sign(v), 0.01, 100, 0.0, 1.0) for v in speeds]
    with pytest.warns(ImplausibleFrictionWarning, match=r"joint 2 \(joint 2\) coulomb friction mu_C = -0\.5 Nm"):
        fit = fit_friction(pts)
    assert fit.coulomb == pytest.approx(-0.5)


def _exact_log(robot: RobotModel, seed: int = 0, duration: float = 20.0) -> RobotLog:
    rng = np.random.default_rng(seed)
    tr = FourierTrajectory(2 * np.pi * 0.1, 0.15 * rng.normal(size=(robot.n, 5)), 0.15 * rng.normal(size=(robot.n, 5)),
                           np.zeros(robot.n))  # fmt: skip
    t = np.arange(0.0, duration, 1e-3)
    q, dq, ddq = tr.evaluate(t)
    fr = FrictionParameters.from_model(robot.friction)
    tau = BatchRegressor(robot).compute_regressor(q, dq, ddq) @ robot.inertial_parameters() + fr.compute_torque(dq)
    return RobotLog(t, q, dq, tau, ddq=ddq, source="exact")


def test_combined_identification_on_six_joints_recovers_the_files_friction(six_dof: RobotModel) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error", ImplausibleFrictionWarning)  # the file's friction is plausible
        res = identify_dynamics(six_dof, _exact_log(six_dof), method="combined", noise_variance=None)
    # noise-free data with the exact ddq: only round-off of the normal equations (cond^2 eps ~ 1e-10
    # relative at the condition numbers of this random trajectory) separates the estimate from the file
    np.testing.assert_allclose(res.friction.coulomb, six_dof.friction.coulomb, rtol=1e-6, err_msg="mu_C")
    np.testing.assert_allclose(res.friction.viscous, six_dof.friction.viscous, rtol=1e-6, err_msg="d_v")


@pytest.mark.slow  # ~50 s: friction runs of six joints, excitation and validation runs on the plant
def test_identify_dynamics_study_runs_on_a_six_joint_arm_without_atlas_wording(tmp_path: Path, capsys) -> None:
    path = write_six_dof_urdf(tmp_path)
    out = tmp_path / "id"
    # a few iterations: the unoptimized start of this arm, stretched along its base plane, is nearly still (the
    # floor bound shrinks its amplitudes to ~3 % of the joint ranges: no sample of joint 1 reaches 0.055 rad/s)
    code = main(["identify", "dynamics", "--robot", str(path), "--ee-frame", SIX_DOF_TOOL, "--maxiter", "5",
                 "--quiet", "--out", str(out)])  # fmt: skip
    assert code == 0
    text = capsys.readouterr().out
    assert "hydraulic" not in text.lower()
    assert "all 6 joints, sequential against combined" in text
    study = json.loads((out / "study.json").read_text())
    assert study["compared_joints"] == [1, 2, 3, 4, 5, 6]
    table = (out / "table1_mse.csv").read_text().splitlines()
    header = table[0].split(",")
    moving = [float(row.split(",")[header.index("mse_moving_combined")]) for row in table[1:7]]
    assert all(m > 0 for m in moving), moving  # every joint moved in the validation run
    assert len(study["friction_fits"]) == 6
    for method in ("combined", "sequential"):  # the robot copies load as the arm they were identified for
        assert (
            load_robot(out / f"robot_{method}.urdf", ee_frame=SIX_DOF_TOOL).joint_names
            == load_robot(path, ee_frame=SIX_DOF_TOOL).joint_names
        )


def test_a_negative_value_within_two_standard_deviations_or_round_off_of_zero_is_not_reported() -> None:
    fr = FrictionParameters(np.array([-1e-12, -0.01, -0.05]), np.array([0.3, -0.02, 0.3]))
    std = FrictionParameters(np.array([0.0, 0.01, 0.01]), np.array([0.0, 0.015, 0.0]))
    with pytest.warns(ImplausibleFrictionWarning) as record:
        issued = check_friction_plausibility(fr, std=std)
    # -1e-12: round-off; -0.01 +- 0.01 and -0.02 +- 0.015: within 2 sigma; -0.05 +- 0.01: 5 sigma below 0
    assert [(w.joint, w.parameter) for w in issued] == [(2, "viscous")]
    assert "(5.0 standard deviations below 0)" in str(record[0].message)


def test_the_mse_over_moving_samples_of_a_joint_that_never_moves_is_nan_not_zero() -> None:
    from reflexarm.ident import TorqueValidation

    t = np.arange(4) * 1e-3
    measured = np.array([[1.0, 2.0], [1.5, 2.0], [2.0, 2.0], [2.5, 2.0]])
    predicted = measured + np.array([[0.1, 0.3], [0.1, 0.3], [-0.1, 0.3], [-0.1, 0.3]])
    dq = np.array([[0.5, 0.0], [0.5, 0.01], [0.0, 0.0], [0.5, 0.0]])  # joint 2 never reaches 0.055 rad/s
    mse = TorqueValidation(t, measured, predicted, "x", dq=dq).mse_moving(0.055)
    assert mse[0] == pytest.approx(0.01)  # (0.1^2 * 3) / 3 samples with |dq| >= 0.055
    assert np.isnan(mse[1])
