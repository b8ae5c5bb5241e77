"""Model files refer to the robot file relatively (the folder can move with it), old absolute ones still
load; ``identify dynamics --log`` on a 6-DoF file writes the model file and a copy of the robot file that
load as the same model."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from ident_arms import SIX_DOF_TOOL, write_six_dof_urdf
from reflexarm import load_robot
from reflexarm.cli import main
from reflexarm.ident import (
    BatchRegressor,
    FrictionParameters,
    RobotLog,
    identify_dynamics,
    load_identified_model,
    save_identified_model,
    save_log,
)
from reflexarm.ident.excitation.design import FourierTrajectory
from reflexarm.robots.robot_model import RobotModel

#: Agreement of two loads of the same stored parameters (JSON keeps doubles exactly; the URDF copy 12
#: significant digits): 1e-9 absolute on M entries of order 0.01..10, as tests/test_write_back.py.
ATOL = 1e-9


def _exact_log(robot: RobotModel, seed: int = 0) -> RobotLog:
    rng = np.random.default_rng(seed)
    a, b = 0.15 * rng.normal(size=(2, robot.n, 5))
    tr = FourierTrajectory(2 * np.pi * 0.1, a, b, np.zeros(robot.n))
    t = np.arange(0.0, 20.0, 1e-3)
    q, dq, ddq = tr.evaluate(t)
    fr = FrictionParameters.from_model(robot.friction)
    tau = BatchRegressor(robot).compute_regressor(q, dq, ddq) @ robot.inertial_parameters() + fr.compute_torque(dq)
    return RobotLog(t, q, dq, tau, ddq=ddq, source="exact")


@pytest.fixture(scope="module")
def saved(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """project/robot/ur_like_6dof.urdf and project/results/model.json identified on it."""
    root = tmp_path_factory.mktemp("project")
    robot = load_robot(write_six_dof_urdf(root / "robot"), ee_frame=SIX_DOF_TOOL)
    res = identify_dynamics(robot, _exact_log(robot), method="combined", noise_variance=None)
    save_identified_model(res, robot, root / "results" / "model.json")
    return root


def test_the_robot_file_is_stored_relative_to_the_model_file(saved: Path) -> None:
    doc = json.loads((saved / "results" / "model.json").read_text())
    assert doc["version"] == 2
    assert doc["robot"]["source"] == "../robot/ur_like_6dof.urdf"
    assert not any(k in doc["robot"] for k in ("base", "tip", "locked"))  # not a cut arm


def test_a_moved_project_folder_still_loads(saved: Path, tmp_path: Path) -> None:
    moved = tmp_path / "elsewhere"
    shutil.copytree(saved, moved)
    model = load_identified_model(moved / "results" / "model.json")
    assert Path(model.source).resolve() == (moved / "robot" / "ur_like_6dof.urdf").resolve()  # type: ignore[arg-type]
    original = load_identified_model(saved / "results" / "model.json")
    q = np.linspace(-1.0, 1.0, 6)
    np.testing.assert_allclose(model.compute_mass_matrix(q), original.compute_mass_matrix(q), atol=ATOL)


def test_a_version_1_file_with_an_absolute_path_still_loads(saved: Path, tmp_path: Path) -> None:
    doc = json.loads((saved / "results" / "model.json").read_text())
    doc["version"] = 1
    doc["robot"]["source"] = str((saved / "robot" / "ur_like_6dof.urdf").resolve())
    old = tmp_path / "somewhere" / "model_v1.json"
    old.parent.mkdir()
    old.write_text(json.dumps(doc))
    model = load_identified_model(old)
    assert model.joint_names == load_robot(doc["robot"]["source"], ee_frame=SIX_DOF_TOOL).joint_names


def test_identify_dynamics_from_a_log_writes_a_robot_copy_with_the_same_model(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    path = write_six_dof_urdf(tmp_path / "robot")
    robot = load_robot(path, ee_frame=SIX_DOF_TOOL)
    log = save_log(_exact_log(robot, seed=1), tmp_path / "log.npz")
    out = tmp_path / "id"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # filter/repair notes of the log reader
        code = main(["identify", "dynamics", "--robot", str(path), "--ee-frame", SIX_DOF_TOOL, "--log", str(log),
                     "--method", "combined", "--quiet", "--out", str(out)])  # fmt: skip
    assert code == 0
    assert "robot_combined.urdf" in capsys.readouterr().out
    copy = json.loads((out / "identification.json").read_text())["methods"]["combined"]["robot_copy"]
    assert copy["file"] == "robot_combined.urdf"
    # how the links were chosen: realising beta_b near the file's inertias, or (here, from filtered data
    # whose nearest realisation has a link with no physical inertia) the projection, with its cost
    assert copy["notes"][0].startswith(("link parameters realising", "projected onto physically consistent"))
    from_model_file = load_identified_model(out / "model_combined.json")
    from_copy = load_robot(out / "robot_combined.urdf", ee_frame=SIX_DOF_TOOL)
    rng = np.random.default_rng(2)
    for _ in range(10):
        q = rng.uniform(-3.0, 3.0, 6)
        np.testing.assert_allclose(from_copy.compute_mass_matrix(q), from_model_file.compute_mass_matrix(q), atol=ATOL)
        np.testing.assert_allclose(from_copy.compute_gravity(q), from_model_file.compute_gravity(q), atol=ATOL)
    np.testing.assert_allclose(from_copy.friction.coulomb, from_model_file.friction.coulomb, rtol=1e-11)
    np.testing.assert_allclose(from_copy.friction.viscous, from_model_file.friction.viscous, rtol=1e-11)


def test_a_cut_arm_is_stored_with_its_base_tip_and_locks_and_reloads_cut(tmp_path: Path) -> None:
    from reflexarm.robots.example_arms import write_ur_like_arm

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the file's notes (ros2_control, gazebo, meshes)
        robot = load_robot(write_ur_like_arm(tmp_path / "user"), tip="tool0")
        res = identify_dynamics(robot, _exact_log(robot), method="combined", noise_variance=None)
        save_identified_model(res, robot, tmp_path / "results" / "model.json")
        doc = json.loads((tmp_path / "results" / "model.json").read_text())
        assert doc["robot"]["source"] == "../user/ur_like_description/urdf/ur_like.urdf"
        assert doc["robot"]["base"] == "base_link" and doc["robot"]["tip"] == "tool0"
        assert doc["robot"]["locked"] == {"gripper_left_finger_joint": 0.0, "gripper_right_finger_joint": 0.0}
        model = load_identified_model(tmp_path / "results" / "model.json")
    assert model.cut is not None and model.cut.tip == "tool0" and model.joint_names == robot.joint_names


def test_validate_without_robot_options_uses_the_robot_the_model_file_names(saved: Path, tmp_path: Path) -> None:
    robot = load_robot(saved / "robot" / "ur_like_6dof.urdf", ee_frame=SIX_DOF_TOOL)
    log = save_log(_exact_log(robot, seed=4), tmp_path / "val.npz")
    # the log's friction has the exact sign (the identification's model), so it is scored that way (F6)
    code = main(["validate", "--model", str(saved / "results" / "model.json"), "--log", str(log),
                 "--friction-model", "identified", "--out", str(tmp_path / "val"), "--quiet"])  # fmt: skip
    assert code == 0
    doc = json.loads((tmp_path / "val" / "validate.json").read_text())
    assert doc["robot"] == "ur_like_6dof"
    # exact data of the model's own arm: what is left is the 10 Hz low-pass of the validation states
    # (0.03 Nm measured, on torques of up to ~50 Nm); a model of another arm would be off by Nm
    assert doc["validation"]["pooled_rmse"] < 0.1
