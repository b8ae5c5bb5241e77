"""The UR5-like arm reflexarm writes (robots/example_arms.py), the stand-in contact boxes of links whose
meshes are missing, and ``reflexarm robots FILE`` listing a file's frames.

References: Pinocchio's and MuJoCo's own parsers opening the written file; MuJoCo's inertia of a box
(inertiafromgeom) against the link's; the closed loop of an exact model (residual at round-off).
"""

from __future__ import annotations

import shutil
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from reflexarm.cli import main
from reflexarm.control import Controller
from reflexarm.errors import ModelError
from reflexarm.robots import RobotFileWarning, load_robot
from reflexarm.robots._urdf import inertia_box
from reflexarm.robots.example_arms import UR_LIKE_FINGERS, UR_LIKE_JOINTS, UR_LIKE_TIP, write_ur_like_arm
from reflexarm.signals import Reference
from reflexarm.sim import Plant, SensorNoise
from test_robot_cut import MENAGERIE, _quiet_load


@pytest.fixture(scope="module")
def ur_arm(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_ur_like_arm(tmp_path_factory.mktemp("arms"))


# ---------------------------------------------------------------------- the written 6-DoF arm
def test_ur_like_arm_opens_in_plain_pinocchio_and_mujoco(ur_arm: Path) -> None:
    """The file is a valid ROS description: Pinocchio's own parser and MuJoCo's (through the file's
    <mujoco> meshdir block) read the whole tree, 6 arm + 2 finger joints, and MuJoCo loads the 8 STL meshes."""
    assert pin.buildModelFromUrdf(str(ur_arm)).nq == 8
    mj = mujoco.MjModel.from_xml_path(str(ur_arm))
    assert (mj.njnt, mj.nmesh) == (8, 8)
    text = ur_arm.read_text()
    for tag in ("<ros2_control", "<gazebo", "package://ur_like_description/meshes/", "<dynamics"):
        assert tag in text


def test_ur_like_arm_needs_its_gripper_cut_off(ur_arm: Path) -> None:
    with pytest.raises(
        ModelError, match="is not a serial chain: name the arm's tip link .* gripper_left_finger, gripper_right_finger"
    ):
        _quiet_load(ur_arm)
    with pytest.warns(
        RobotFileWarning, match=r"mesh package resolved: package://ur_like_description -> .*ur_like_desc"
    ):
        robot = load_robot(ur_arm, tip=UR_LIKE_TIP)
    assert tuple(robot.joint_names) == UR_LIKE_JOINTS
    assert robot.ee_frame == robot.sensor_frame == UR_LIKE_TIP
    assert robot.cut is not None and robot.cut.base == "base_link"
    assert dict(robot.cut.locked) == dict.fromkeys(UR_LIKE_FINGERS, 0.0)
    # the moving links carry the gripper: 6 UR5 link masses + gripper body 0.45 kg + fingers 2 x 0.06 kg
    np.testing.assert_allclose(robot.inertial_parameters()[0::10].sum(), 16.9939 + 0.45 + 0.12, rtol=1e-12)
    np.testing.assert_array_equal(robot.effort_limit, [150, 150, 150, 28, 28, 28])
    assert np.all(robot.friction.coulomb > 0) and np.all(robot.friction.viscous > 0)


def test_package_uri_found_through_ros_package_path(ur_arm: Path, tmp_path: Path, monkeypatch) -> None:
    """A URDF moved away from its package finds the meshes through ROS_PACKAGE_PATH, and says so; without
    it the mesh geoms are dropped with a note (the dynamics do not change)."""
    moved = tmp_path / "elsewhere" / "arm.urdf"
    moved.parent.mkdir()
    shutil.copy(ur_arm, moved)
    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    with pytest.warns(RobotFileWarning, match=r"8 mesh file\(s\) not found .*the 8 collision geom\(s\) using them"):
        lost = load_robot(moved, tip=UR_LIKE_TIP)
    assert Plant(lost, noise=SensorNoise.none()).model.nmesh == 0  # the plant resolves when it is built
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(ur_arm.parents[2]))
    with pytest.warns(RobotFileWarning, match=r"package://ur_like_description -> .* \(ROS_PACKAGE_PATH\)"):
        found = load_robot(moved, tip=UR_LIKE_TIP)
    assert Plant(found, noise=SensorNoise.none()).model.nmesh == 8
    np.testing.assert_array_equal(found.inertial_parameters(), lost.inertial_parameters())


#: A UR5-like pose with the elbow up and the flange pointing down (every joint inside its limits).
UR_HOME = np.array([0.0, -1.2, 1.5, -1.87, -1.57, 0.0])
#: 50 N down on wrist_2_link: about 0.8 m from the shoulder, ~40 Nm on the shoulder lift against zeta = 11 Nm;
#: the first-order residual (K_o = 5 1/s) crosses after about -ln(1 - 11/40) / 5 = 0.07 s.
UR_PUSH = np.array([0.0, 0.0, -50.0])
MAX_DETECTION_TIME = 0.5


def test_cut_arm_holds_still_in_closed_loop_and_detects_a_push(ur_arm: Path) -> None:
    """With the gripper's mass on the last link in both models, the observer's residual of the arm held
    still stays at round-off (a lost gripper, 0.57 kg, changes g(q) at this pose by 3.5, 2.6 and 0.53 Nm on
    joints 2-4) until a push on the wrist, which is detected."""
    robot = _quiet_load(ur_arm, tip=UR_LIKE_TIP)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RobotFileWarning)
        plant = Plant(robot, noise=SensorNoise.none())
    plant.reset(UR_HOME)
    controller = Controller(robot)
    reference = Reference(UR_HOME, np.zeros(robot.n), np.zeros(robot.n))
    at_rest = np.zeros(robot.n)
    delay = None
    for k in range(2500):
        if k == 1500:
            np.testing.assert_allclose(plant.q, UR_HOME, atol=1e-6)  # rad: held by exact gravity compensation
            plant.apply_external_force(UR_PUSH, body="wrist_2_link")
        cmd = controller.step(plant.measure(), reference)
        assert cmd.fault == "", f"tick {k}: {cmd.fault}"
        plant.step(cmd.tau)
        if k < 1500:
            assert not cmd.collision, f"false collision at rest, tick {k}, residual {cmd.residual}"
            at_rest = np.maximum(at_rest, np.abs(cmd.residual))
        elif cmd.collision:
            delay = (k - 1500) * plant.control_period
            break
    assert at_rest.max() < 1e-6, at_rest  # Nm: the same model on both sides, only the observer's round-off
    assert delay is not None and delay < MAX_DETECTION_TIME, delay


def test_inertia_box_has_the_links_inertia() -> None:
    """The stand-in collision box of a link whose meshes are missing: MuJoCo, deriving the body's inertia
    from that box alone (uniform density, inertiafromgeom), gets back the link's mass, COM and inertia.
    The inertia is full (products of inertia) and its COM frame rotated, so axes and rpy are exercised."""
    link = ET.fromstring(
        '<link name="l"><inertial><origin xyz="0.1 -0.05 0.2" rpy="0.3 -0.4 1.1"/><mass value="2.5"/>'
        '<inertia ixx="0.04" ixy="0.004" ixz="-0.003" iyy="0.03" iyz="0.002" izz="0.02"/></inertial></link>'
    )
    box = inertia_box(link)
    assert box is not None
    xyz, rpy, size = box
    robot_text = (
        '<robot name="b"><link name="base"/><link name="l"><collision><origin xyz="{}" rpy="{}"/><geometry>'
        '<box size="{}"/></geometry></collision></link><joint name="j" type="revolute"><parent link="base"/>'
        '<child link="l"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
        '<mujoco><compiler inertiafromgeom="true" boundmass="0" boundinertia="0"/></mujoco></robot>'
    ).format(*(" ".join(f"{v:.17g}" for v in a) for a in (xyz, rpy, size)))
    spec = mujoco.MjSpec.from_string(robot_text)
    spec.geoms[0].density = 2.5 / float(np.prod(size))
    mj = spec.compile()
    d = mujoco.MjData(mj)
    mujoco.mj_forward(mj, d)
    b = mj.body("l").id
    R = d.ximat[b].reshape(3, 3)
    world_inertia = R @ np.diag(mj.body_inertia[b]) @ R.T
    expected = pin.rpy.rpyToMatrix(0.3, -0.4, 1.1)
    urdf_inertia = np.array([[0.04, 0.004, -0.003], [0.004, 0.03, 0.002], [-0.003, 0.002, 0.02]])
    np.testing.assert_allclose(mj.body_mass[b], 2.5, rtol=1e-12)
    np.testing.assert_allclose(d.xipos[b], [0.1, -0.05, 0.2], atol=1e-12)
    # MuJoCo computes a box's inertia in closed form; 1e-9 covers the eigen-decompositions on both sides
    np.testing.assert_allclose(world_inertia, expected @ urdf_inertia @ expected.T, atol=1e-9)


# ---------------------------------------------------------------------- CLI
def test_robots_command_lists_the_frames_of_a_tree(ur_arm: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["robots", str(ur_arm)]) == 0
    out = capsys.readouterr().out
    assert "12 links; choose --ee-frame (and --tip/--base for a tree)" in out
    lines = {line.split()[0]: line for line in out.splitlines()[2:] if line.startswith("  ")}
    assert "branch (2 links)" in lines["gripper_base_link"] and "(fixed on tool0)" in lines["gripper_base_link"]
    assert lines["gripper_left_finger"].split()[1:] == ["gripper_left_finger_joint", "7", "leaf"]
    assert lines["forearm_link"].split()[1:3] == ["elbow_joint", "3"]
    assert "cut the arm with --tip LINK [--base LINK]" in out
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RobotFileWarning)
        assert main(["robots", str(ur_arm), "--tip", "tool0", "--lock", f"{UR_LIKE_FINGERS[0]}=0.01"]) == 0
    out = capsys.readouterr().out
    assert "base 'base_link', tip 'tool0'; locked joints: gripper_left_finger_joint=0.01" in out
    assert "1:shoulder_pan_joint, 2:shoulder_lift_joint" in out


@pytest.mark.skipif(not MENAGERIE.is_dir(), reason=f"Menagerie files not available at {MENAGERIE}")
def test_robots_command_lists_sites_of_a_serial_mjcf(capsys: pytest.CaptureFixture[str]) -> None:
    """Without --ee-frame a serial MJCF arm is not refused: its links and sites are listed."""
    assert main(["robots", str(MENAGERIE / "panda_nohand.xml")]) == 0
    lines = {line.split()[0]: line for line in capsys.readouterr().out.splitlines()[2:] if line.startswith("  ")}
    assert lines["attachment_site"].endswith("frame on link attachment")
    assert lines["link7"].split()[1:3] == ["joint7", "7"]
