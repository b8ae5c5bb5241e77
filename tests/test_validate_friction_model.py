"""validate scores the model as the controller uses it (issue 9, finding F6): the controller's friction model
smooths the Coulomb torque over a velocity band (``CoulombViscousFriction.velocity_band``, 0.02 rad/s by default),
the identification's has the exact sign.

The arm is the UR-like one (Coulomb friction up to 2.5 Nm). The model is identified on exact data (exact-sign
friction, no noise: the file's parameters to round-off); the validation log is made with the friction as the
controller computes it, so only the model scored the controller's way explains it.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from reflexarm.cli import main
from reflexarm.ident import BatchRegressor, RobotLog, identify_dynamics, save_log
from reflexarm.ident.estimation.validation import EXACT_SIGN, validate_model
from reflexarm.ident.excitation.design import FourierTrajectory
from reflexarm.ident.export.model_file import save_identified_model
from reflexarm.robots import load_robot, write_ur_like_arm
from reflexarm.robots.robot_model import RobotModel


def _log(robot: RobotModel, seed: int, *, controller_friction: bool) -> RobotLog:
    rng = np.random.default_rng(seed)
    a, b = 0.15 * rng.normal(size=(2, robot.n, 5))
    t = np.arange(0.0, 20.0, 1e-3)
    q, dq, ddq = FourierTrajectory(2 * np.pi * 0.1, a, b, np.zeros(robot.n)).evaluate(t)
    fr = robot.friction
    friction = fr.compute_torque(dq) if controller_friction else fr.viscous * dq + fr.coulomb * np.sign(dq)
    tau = BatchRegressor(robot).compute_regressor(q, dq, ddq) @ robot.inertial_parameters() + friction
    return RobotLog(t, q, dq, tau, ddq=ddq, source="exact")


@pytest.fixture(scope="module")
def setup(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    root = tmp_path_factory.mktemp("f6")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the package's file notes
        robot = load_robot(write_ur_like_arm(root / "robot"), tip="tool0")
        result = identify_dynamics(
            robot, _log(robot, 0, controller_friction=False), method="combined", noise_variance=None
        )
        model = save_identified_model(result, robot, root / "model.json")
    return robot, result, model, root


def test_validate_model_scores_the_given_friction_model(setup) -> None:  # type: ignore[no-untyped-def]
    robot, result, _, _ = setup
    band = robot.friction.velocity_band
    assert band == pytest.approx(0.02)  # the default the controller uses; the log below is made with it
    log = _log(robot, 1, controller_friction=True)
    exact = validate_model(result, robot, log)
    as_used = validate_model(result, robot, log, friction=result.friction.to_model(band))
    assert exact.friction_model == EXACT_SIGN and "0.02 rad/s" in as_used.friction_model
    # the model is the file's to round-off: scored with the controller's friction it explains the log (1e-6 Nm:
    # round-off of the least squares on exact data), with the exact sign it is off by mu_C near velocity reversals
    assert as_used.pooled_rmse < 1e-6
    assert exact.pooled_rmse > 1e-2
    slow = np.abs(log.dq) < band
    np.testing.assert_allclose(exact.error[~slow], as_used.error[~slow], atol=1e-9)  # the same outside the band


def test_validate_command_scores_as_the_controller_and_says_so(setup, capsys) -> None:  # type: ignore[no-untyped-def]
    robot, _, model, root = setup
    path = save_log(_log(robot, 1, controller_friction=True), root / "val.npz")
    rmse = {}
    for how in ("controller", "identified"):
        out = root / f"v_{how}"
        argv = ["validate", "--robot", str(root / "robot" / "ur_like_description" / "urdf" / "ur_like.urdf"), "--tip",
                "tool0", "--model", str(model), "--log", str(path), "--out", str(out), "--quiet"]  # fmt: skip
        if how == "identified":
            argv += ["--friction-model", "identified"]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            assert main(argv) == 0
        doc = json.loads((out / "validate.json").read_text())["validation"]
        rmse[how] = doc["pooled_rmse"]
        text = capsys.readouterr().out
        if how == "controller":
            assert "0.02 rad/s" in doc["friction_model"] and "0.02 rad/s" in text
        else:
            assert doc["friction_model"] == EXACT_SIGN and "exact sign" in text
    # the states are low-passed at 10 Hz (validate's default), which leaves a floor of a few 0.01 Nm; the
    # exact-sign friction adds mu_C (up to 2.5 Nm) near the reversals on top
    assert rmse["controller"] < 0.5 * rmse["identified"]
