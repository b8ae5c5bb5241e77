"""URDF ``<mimic>`` joints: the controller's model and the MuJoCo plant are one robot (issue 18 item 3, issue 20
item 6), and an end-effector frame past ``tip`` is explained or refused (issue 18 item 12).

MuJoCo makes a mimic an equality constraint; Pinocchio an ordinary joint. A gripper cut off with ``tip`` made
every plant fail to compile (the constraint outlived its locked joints); a mimic between two arm joints held
them together in the plant only, which the residual saw as a collision while the arm held still. Every file
is written here; the reference is MuJoCo's own reading of it, put beside Pinocchio's.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from reflexarm.control import Controller
from reflexarm.errors import ModelError
from reflexarm.robots import RobotFileWarning, load_robot
from reflexarm.sim import Plant, SensorNoise, run_closed_loop
from reflexarm.sim.trajectory import JointTrajectory

#: Pinocchio and MuJoCo evaluate the same exact expressions (see test_model_agreement.py): 1e-9 separates
#: round-off (~1e-14) from a modelling difference (a finger at the wrong angle: >= 1e-3).
ATOL = 1e-9


def _inertial(mass: float, xyz: str) -> str:
    return (
        f'<inertial><origin xyz="{xyz}"/><mass value="{mass}"/>'
        '<inertia ixx="0.002" ixy="0" ixz="0" iyy="0.002" iyz="0" izz="0.001"/></inertial>'
    )


def _revolute(name: str, parent: str, child: str, xyz: str, axis: str, extra: str = "") -> str:
    return (
        f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="{xyz}"/><axis xyz="{axis}"/><limit lower="-2" upper="2" effort="40" velocity="3"/>{extra}'
        "</joint>"
    )


def gripper_arm_urdf() -> str:
    """A 3-DoF arm with a two-finger gripper on ``tool0``: the left knuckle drives the right knuckle
    (multiplier -1) and a fingertip (multiplier 0.5, offset 0.1) through ``<mimic>``, as the Robotiq 2F-85."""
    links = "".join(
        f'<link name="{n}">{_inertial(m, xyz)}</link>'
        for n, m, xyz in (
            ("l1", 2.0, "0 0 0.1"), ("l2", 1.5, "0.15 0 0"), ("l3", 1.0, "0.1 0 0"), ("gripper", 0.4, "0 0 0.03"),
            ("left_knuckle", 0.05, "0.02 0 0.02"), ("right_knuckle", 0.05, "-0.02 0 0.02"),
            ("left_tip", 0.03, "0 0 0.02"),
        )
    )  # fmt: skip
    return (
        f'<robot name="gripper_arm"><link name="base"/>{links}<link name="tool0"/>'
        + _revolute("j1", "base", "l1", "0 0 0.2", "0 0 1")
        + _revolute("j2", "l1", "l2", "0 0 0.2", "0 1 0")
        + _revolute("j3", "l2", "l3", "0.3 0 0", "0 1 0")
        + '<joint name="flange" type="fixed"><parent link="l3"/><child link="tool0"/><origin xyz="0.2 0 0"/></joint>'
        '<joint name="mount" type="fixed"><parent link="tool0"/><child link="gripper"/></joint>'
        + _revolute("left_knuckle_joint", "gripper", "left_knuckle", "0.03 0 0.05", "0 -1 0")
        + _revolute(
            "right_knuckle_joint", "gripper", "right_knuckle", "-0.03 0 0.05", "0 -1 0",
            '<mimic joint="left_knuckle_joint" multiplier="-1"/>',
        )
        + _revolute(
            "left_tip_joint", "left_knuckle", "left_tip", "0.03 0 0.04", "0 -1 0",
            '<mimic joint="left_knuckle_joint" multiplier="0.5" offset="0.1"/>',
        )
        + "</robot>"
    )  # fmt: skip


def coupled_arm_urdf() -> str:
    """A serial 3-DoF arm whose third joint mimics the second (issue 20 item 6)."""
    links = "".join(
        f'<link name="{n}">{_inertial(m, xyz)}</link>'
        for n, m, xyz in (("l1", 2.0, "0 0 0.1"), ("l2", 1.5, "0.15 0 0"), ("l3", 1.0, "0.1 0 0"))
    )
    return (
        f'<robot name="coupled_arm"><link name="base"/>{links}<link name="tool"/>'
        + _revolute("j1", "base", "l1", "0 0 0.2", "0 0 1")
        + _revolute("j2", "l1", "l2", "0 0 0.2", "0 1 0")
        + _revolute("j3", "l2", "l3", "0.3 0 0", "0 1 0", '<mimic joint="j2" multiplier="1.5" offset="0.2"/>')
        + '<joint name="tool_joint" type="fixed"><parent link="l3"/><child link="tool"/><origin xyz="0.2 0 0"/>'
        "</joint></robot>"
    )


def _write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(text)
    return path


def _load(path: Path, **kwargs: object):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RobotFileWarning)
        return load_robot(path, **kwargs)  # type: ignore[arg-type]


def _plant(robot) -> Plant:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RobotFileWarning)
        return Plant(robot, noise=SensorNoise.none())


def test_a_gripper_with_mimic_joints_cut_off_simulates(tmp_path: Path) -> None:
    robot = _load(_write(tmp_path, "arm.urdf", gripper_arm_urdf()), tip="tool0")
    plant = _plant(robot)  # failed: "unknown element 'right_knuckle_joint' in equality constraint"
    assert plant.model.neq == 0  # the couplings went with the locked joints
    assert robot.joint_names == ["j1", "j2", "j3"]


def test_locked_followers_follow_their_leader_in_both_models(tmp_path: Path) -> None:
    """Half-closed gripper: the followers are locked where their mimic puts them, and MuJoCo (which reads the
    same locks) places every finger body where Pinocchio's reduced model places its frame."""
    path = _write(tmp_path, "arm.urdf", gripper_arm_urdf())
    robot = _load(path, tip="tool0", locked={"left_knuckle_joint": 0.4})
    assert robot.cut is not None
    assert robot.cut.locked["right_knuckle_joint"] == pytest.approx(-0.4, abs=1e-15)
    assert robot.cut.locked["left_tip_joint"] == pytest.approx(0.1 + 0.5 * 0.4, abs=1e-15)
    plant = _plant(robot)
    data = robot.pin_model.createData()
    d = mujoco.MjData(plant.model)
    for q in (np.zeros(3), np.array([0.3, -0.7, 1.1])):
        d.qpos[plant._qadr_arr] = q
        mujoco.mj_kinematics(plant.model, d)
        pin.framesForwardKinematics(robot.pin_model, data, q)
        for body in ("left_knuckle", "right_knuckle", "left_tip"):
            placement = data.oMf[robot.frame_id(body)]
            np.testing.assert_allclose(d.xpos[plant.model.body(body).id], placement.translation, atol=ATOL)
            np.testing.assert_allclose(
                d.xmat[plant.model.body(body).id].reshape(3, 3), placement.rotation, atol=ATOL, err_msg=body
            )


def test_a_lock_that_breaks_the_coupling_is_named(tmp_path: Path) -> None:
    path = _write(tmp_path, "arm.urdf", gripper_arm_urdf())
    with pytest.warns(
        RobotFileWarning,
        match=r"joint 'right_knuckle_joint' follows 'left_knuckle_joint' .* it is locked at 0.3, not at -0.4 as the "
        r"coupling gives for 'left_knuckle_joint' at 0.4",
    ):
        load_robot(path, tip="tool0", locked={"left_knuckle_joint": 0.4, "right_knuckle_joint": 0.3})


def test_a_mimic_between_arm_joints_is_independent_in_both_models(tmp_path: Path) -> None:
    """Holding still: no plant-only constraint torque, so no residual and no false collision (the plant
    held j3 to j2 and the residual reached +-72 Nm, detected at tick 201)."""
    from test_model_agreement import check_agreement

    path = _write(tmp_path, "coupled.urdf", coupled_arm_urdf())
    with pytest.warns(
        RobotFileWarning,
        match=r"joint 'j3' follows 'j2' in the file \(q = 0.2 \+ 1.5 q_j2\); the arm joint\(s\) \['j3', 'j2'\] are "
        "independent joints driven by their own motors in the controller's model and in the plant",
    ):
        robot = load_robot(path, ee_frame="tool")
    plant = _plant(robot)
    assert plant.model.neq == 0
    worst = check_agreement(robot, plant, n_states=10)
    assert max(worst.values()) <= ATOL, worst
    q0 = np.array([0.3, 0.5, -0.4])  # not on the file's coupling (0.2 + 1.5 * 0.5 = 0.95)
    plant.reset(q0)
    trace = run_closed_loop(plant, Controller(robot), JointTrajectory([q0, q0], [1.0]), 1.0)
    assert not trace.collision.any()
    assert np.abs(trace.residual).max() < 0.1  # Nm: exact model, no noise; observer transient only


def test_an_end_effector_past_the_tip_is_explained(tmp_path: Path) -> None:
    path = _write(tmp_path, "arm.urdf", gripper_arm_urdf())
    with pytest.warns(
        RobotFileWarning,
        match=r"the end-effector and sensor frame 'left_tip' lies past the tip link 'tool0', behind the locked "
        r"joint\(s\) \['left_knuckle_joint', 'left_tip_joint'\]: it moves rigidly with 'tool0'",
    ):
        robot = load_robot(path, tip="tool0", ee_frame="left_tip")
    # it moves with the arm: the frame's Jacobian is the tool's point Jacobian
    assert np.abs(robot.compute_frame_jacobian(np.array([0.2, 0.3, -0.5]))).max() > 0.1


def test_a_frame_that_does_not_move_with_the_arm_is_refused(tmp_path: Path) -> None:
    path = _write(tmp_path, "arm.urdf", gripper_arm_urdf())
    with pytest.raises(ModelError, match=r"the end-effector and sensor frame 'base' of .* does not move with the arm"):
        _load(path, tip="tool0", ee_frame="base")


# A Menagerie-style MJCF hand: two finger slides coupled by a joint equality, driven through a tendon.
TENDON_HAND_MJCF = """<mujoco model="hand_arm">
  <worldbody>
    <body name="l1" pos="0 0 0.2"><joint name="j1" axis="0 0 1" range="-3 3"/>
      <inertial pos="0 0 0.1" mass="2" diaginertia="0.02 0.02 0.005"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.2" size="0.04"/>
      <body name="l2" pos="0 0 0.2"><joint name="j2" axis="0 1 0" range="-2 2"/>
        <inertial pos="0.15 0 0" mass="1" diaginertia="0.002 0.01 0.01"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
        <body name="hand" pos="0.3 0 0"><inertial pos="0.03 0 0" mass="0.5" diaginertia="0.001 0.001 0.001"/>
          <site name="ee" pos="0.05 0 0"/>
          <body name="left_finger" pos="0.06 0.02 0">
            <joint name="finger_joint1" type="slide" axis="0 1 0" range="0 0.04"/>
            <inertial pos="0.02 0 0" mass="0.05" diaginertia="1e-5 1e-5 1e-5"/><geom type="box" size="0.02 0.005 0.01"/>
          </body>
          <body name="right_finger" pos="0.06 -0.02 0">
            <joint name="finger_joint2" type="slide" axis="0 -1 0" range="0 0.04"/>
            <inertial pos="0.02 0 0" mass="0.05" diaginertia="1e-5 1e-5 1e-5"/><geom type="box" size="0.02 0.005 0.01"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <tendon><fixed name="split"><joint joint="finger_joint1" coef="0.5"/><joint joint="finger_joint2" coef="0.5"/></fixed>
  </tendon>
  <equality><joint joint1="finger_joint1" joint2="finger_joint2"/></equality>
  <actuator><general name="grip" tendon="split" gainprm="0.0157" biastype="affine" biasprm="0 -100 -10"/></actuator>
  <sensor><tendonpos name="opening" tendon="split"/></sensor>
</mujoco>
"""


def test_an_mjcf_hand_with_a_coupling_tendon_cut_off_simulates(tmp_path: Path) -> None:
    """The MJCF counterpart: the tendon over the locked fingers, its actuator, sensor and equality go with
    them (the plant failed: "joint 'finger_joint1' not found in tendon 0"); an arm whose first body moves
    starts at the world (its first joint was locked as the "root link"'s)."""
    from test_model_agreement import check_agreement

    robot = _load(_write(tmp_path, "hand_arm.xml", TENDON_HAND_MJCF), tip="hand", ee_frame="ee")
    assert robot.joint_names == ["j1", "j2"]
    plant = _plant(robot)
    assert (plant.model.neq, plant.model.ntendon) == (0, 0)
    worst = check_agreement(robot, plant, n_states=10)
    assert max(worst.values()) <= ATOL, worst
