"""Pinocchio's MJCF parser drops a joint-less root body's placement; RobotModel restores it."""

from __future__ import annotations

import mujoco
import numpy as np

from reflexarm.robots import load_robot

ROTATED_ROOT = """<mujoco><compiler angle="radian"/><worldbody>
<body name="base" pos="0.2 0 1" euler="0.3 -0.2 0.1"><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/>
<body name="link1" pos="0 0.1 0"><joint name="j1" axis="1 0 0"/>
<inertial pos="0 0.2 0" mass="1" diaginertia=".1 .1 .1"/>
<site name="tip" pos="0 0.4 0"/>
<body name="link2" pos="0 0.4 0"><joint name="j2" axis="0 0 1"/>
<inertial pos="0.1 0.2 0" mass="0.5" diaginertia=".01 .02 .03"/>
</body></body></body></worldbody></mujoco>"""


def test_rotated_root_body_matches_mujoco(tmp_path):
    path = tmp_path / "arm.xml"
    path.write_text(ROTATED_ROOT)
    robot = load_robot(path, ee_frame="tip")
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    for _ in range(10):
        q = rng.uniform(-2, 2, 2)
        d.qpos[:] = q
        d.qvel[:] = 0
        mujoco.mj_forward(m, d)
        # gravity torques and site position: exact agreement up to round-off
        np.testing.assert_allclose(robot.compute_gravity(q), d.qfrc_bias, atol=1e-12)
        np.testing.assert_allclose(robot.compute_frame_pose(q)[1], d.site_xpos[0], atol=1e-12)


def test_atlas_frames_are_in_the_mujoco_world(atlas):
    m = mujoco.MjModel.from_xml_path(str(atlas.source))
    d = mujoco.MjData(m)
    q = atlas.home
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "ee")
    np.testing.assert_allclose(atlas.compute_frame_pose(q)[1], d.site_xpos[sid], atol=1e-12)
