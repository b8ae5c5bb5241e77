"""Scenes: contacts stay physical and the plant's true external quantities are exact.

The reference for contact torques is computed independently from MuJoCo's per-contact forces
(``mj_contactForce`` in the contact frame) and point Jacobians (``mj_jac``), not from ``cfrc_ext``.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from reflexarm.errors import ConfigError, SimulationError
from reflexarm.robots import load_robot
from reflexarm.sim import (
    Cinderblock,
    ElbowStick,
    EndEffectorForce,
    JointTrajectory,
    Plant,
    SensorNoise,
    run_closed_loop,
)
from reflexarm.sim.scene import CONTACT_ARM, CONTACT_WORLD
from test_sim_runner import PDGravity

#: Contact torques of ~10-100 Nm summed from the same constraint forces in a different order: round-off
#: is ~1e-13; any missing contact, wrong sign or wrong point is >= 1e-2.
EXACT = 1e-9


@pytest.fixture(scope="module")
def robot():
    return load_robot("atlas_v5_left_arm")


def contact_reference(plant):
    """sum over arm contacts of J_point^T f_world (force on the arm geom), from mj_contactForce + mj_jac."""
    m, d = plant.model, plant.data
    arm = set(plant._arm_bodies.tolist())
    tau = np.zeros(m.nv)
    f_on_arm = np.zeros(3)
    f6 = np.zeros(6)
    jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for i in range(d.ncon):
        c = d.contact[i]
        mujoco.mj_contactForce(m, d, i, f6)
        f_world = c.frame.reshape(3, 3).T @ f6[:3]  # force of geom1 on geom2 (contact-frame rows are axes)
        for geom, sign in ((c.geom1, -1.0), (c.geom2, 1.0)):
            body = int(m.geom_bodyid[geom])
            if body in arm:
                mujoco.mj_jac(m, d, jacp, jacr, c.pos, body)
                tau += sign * jacp.T @ f_world
                f_on_arm += sign * f_world
    return tau[plant._arm_dofs], f_on_arm


def press_on_block(robot, force=80.0, ticks=400):
    """Atlas at home pressing its tool down onto a padded block placed 1 cm below it."""
    _, p_ee = robot.compute_frame_pose(robot.home, "ee")
    tool_bottom = p_ee[2] - 0.05
    block = Cinderblock(position=(p_ee[0], p_ee[1]), table_height=tool_bottom - 0.01 - 0.19 - 0.03)
    plant = Plant(robot, scene=block, noise=SensorNoise.none())
    F = np.array([0.0, 0.0, -force])
    for _ in range(ticks):
        q = plant.q
        plant.step(robot.compute_gravity(q) + robot.compute_frame_jacobian(q, "ee", world_aligned=True)[:3].T @ F)
    return plant, block


def test_contact_external_torque_matches_per_contact_forces(robot):
    plant, block = press_on_block(robot)
    m, d = plant.model, plant.data
    pairs = {(m.geom(c.geom1).name, m.geom(c.geom2).name) for c in d.contact[: d.ncon]}
    assert ("l_tool_col", "cinderblock_padding") in pairs, pairs
    tau_ref, f_on_arm = contact_reference(plant)
    assert f_on_arm[2] > 50.0, f"the block must push the hand up: {f_on_arm}"
    np.testing.assert_allclose(plant.true_external_torque(), tau_ref, atol=EXACT)
    # the tool is the only arm body in contact, so the force beyond the sensor is the whole contact force
    np.testing.assert_allclose(plant.ee_contact_force(), f_on_arm, atol=EXACT)
    # and the wrist sensor sees the same contact: J_sensor^T wrench == tau_ext
    J_s = robot.compute_frame_jacobian(plant.q)
    # the arm is at rest (stiction + contact) so the Jacobian at the current q is the one MuJoCo used
    assert np.abs(plant.dq).max() < 1e-3
    np.testing.assert_allclose(J_s.T @ plant.measure().wrench, tau_ref, atol=1e-3 * np.abs(tau_ref).max())


def test_cinderblock_rests_and_tips(robot):
    block = Cinderblock(position=(0.6, -0.5), table_height=0.6)
    plant = Plant(robot, scene=block, noise=SensorNoise.none())
    pos0, _ = block.pose(plant)
    np.testing.assert_allclose(pos0, [0.6, -0.5, 0.6 + 0.095], atol=1e-12)  # standing on the table top
    for _ in range(300):
        plant.step(robot.compute_gravity(plant.q))
    # at rest: it sinks micrometres into the table (hard contact), nothing else
    assert np.linalg.norm(block.displacement(plant)) < 1e-5
    assert not block.tipped(plant)
    # 120 N at the top edge for 0.16 s: 23 Nm about the bottom edge > the 14 Nm of its weight: it falls over
    handle = plant.apply_external_force([0.0, 120.0, 0.0], point_world=pos0 + [0.0, 0.0, 0.095], body="cinderblock")
    for _ in range(160):
        plant.step(robot.compute_gravity(plant.q))
    plant.clear_external_force(handle)
    for _ in range(1000):
        plant.step(robot.compute_gravity(plant.q))
    assert block.tipped(plant)
    assert block.tilt(plant) == pytest.approx(math.pi / 2, abs=0.05)  # lying on its side
    assert block.displacement(plant)[1] > 0.1
    assert np.abs(plant.true_external_torque()).max() == 0.0  # the arm was never touched
    plant.reset()
    np.testing.assert_allclose(block.displacement(plant), 0.0, atol=0.0)


def test_collision_masks(robot):
    """Arm vs padding and table: contact; arm vs floor and block core: none; block core vs table: contact."""
    plant = Plant(robot, scene=Cinderblock(position=(0.6, -0.5)), noise=SensorNoise.none())
    m = plant.model

    def collide(a, b):
        ga, gb = m.geom(a), m.geom(b)
        return bool((ga.contype & gb.conaffinity) or (gb.contype & ga.conaffinity))

    arm = [m.geom(g).name for g in range(m.ngeom) if m.geom_bodyid[g] in plant._arm_bodies and m.geom_contype[g]]
    assert arm, "the arm has collision geoms"
    for g in arm:
        assert collide(g, "cinderblock_padding") and collide(g, "cinderblock_table")
        assert not collide(g, "floor") and not collide(g, "cinderblock_core")
    assert collide("cinderblock_core", "cinderblock_table") and collide("cinderblock_core", "floor")
    assert not any(collide(a, b) for a in arm for b in arm)  # the built-in arm does not self-collide
    assert CONTACT_ARM & m.geom("cinderblock_padding").contype and CONTACT_WORLD & m.geom("floor").contype


def test_cinderblock_arguments():
    with pytest.raises(ConfigError, match=r"position must be \(x, y\) or \(x, y, z\) \[m\]; got shape \(4,\)"):
        Cinderblock(position=(0, 0, 0, 0))
    with pytest.raises(ConfigError, match=r"size must be three positive edge lengths \[m\]; got \[0.39, -0.19, 0.19\]"):
        Cinderblock(position=(0, 0), size=(0.39, -0.19, 0.19))
    with pytest.raises(ConfigError, match=r"mass must be a positive number; got 0"):
        Cinderblock(position=(0, 0), mass=0)
    with pytest.raises(ConfigError, match=r"friction must be a positive coefficient \[-\]; got -0.5"):
        Cinderblock(position=(0, 0), friction=-0.5)
    assert Cinderblock(position=(0, 0), friction=0.9).describe()["friction"] == 0.9


@pytest.mark.parametrize(("friction", "slides"), [(0.6, True), (0.9, False)])
def test_cinderblock_friction_decides_slide_or_hold(robot, friction, slides):
    """110 N pushing the 15 kg block along its long axis at the height of its centre: Coulomb's law with
    mu m g = 88 N (mu = 0.6) < 110 N < 132 N (mu = 0.9) says it slides on the first table and holds on the
    second; it cannot tip (110 N * 0.095 m = 10 Nm < m g * 0.195 m = 29 Nm about the bottom edge)."""
    block = Cinderblock(position=(0.6, -0.5), table_height=0.6, friction=friction)
    plant = Plant(robot, scene=block, noise=SensorNoise.none())
    pos0, _ = block.pose(plant)
    handle = plant.apply_external_force([110.0, 0.0, 0.0], point_world=pos0, body="cinderblock")
    for _ in range(300):
        plant.step(robot.compute_gravity(plant.q))
    plant.clear_external_force(handle)
    moved = float(block.displacement(plant)[0])
    # sliding for 0.3 s under a net (110 - 88) N on 15 kg travels ~0.5 * 1.5 m/s^2 * 0.09 s^2 = 7 cm;
    # holding leaves only the contact's elastic creep (micrometres, see test_cinderblock_rests_and_tips)
    if slides:
        assert moved > 0.02
    else:
        assert abs(moved) < 1e-3
    assert not block.tipped(plant)


def test_end_effector_force_step(robot):
    """The Fig. 12 step: 50 N at the ee point between t_on and t_off, world-fixed direction "against the
    end effector" (from the ee point towards the wrist sensor at t_on). The true force and, with exact
    sensors, the wrist sensor's J^T wrench equal what was applied."""
    scene = EndEffectorForce(magnitude=50.0, t_on=0.1, t_off=0.3)
    plant = Plant(robot, scene=scene, noise=SensorNoise.none())
    traj = JointTrajectory.hold(robot.home, 0.5)
    trace = run_closed_loop(plant, PDGravity(robot), traj, 0.4)
    f = np.linalg.norm(trace.f_ext_ee, axis=1)
    on = (trace.t > 0.1005) & (trace.t < 0.3005)  # applied in the step at t_on, seen from the next tick
    np.testing.assert_allclose(f[on], 50.0, atol=EXACT)
    np.testing.assert_allclose(f[~on], 0.0, atol=0.0)
    applied = trace.extras["ee_force_force"]
    np.testing.assert_allclose(trace.f_ext_ee[on], applied[on], atol=EXACT)
    k_on = int(np.flatnonzero(on)[0])
    direction = trace.f_ext_ee[k_on] / 50.0
    np.testing.assert_allclose(trace.f_ext_ee[on], np.tile(50.0 * direction, (on.sum(), 1)), atol=EXACT)
    R, p_s = robot.compute_frame_pose(trace.q[k_on - 1], "wrist_ft")
    _, p_ee = robot.compute_frame_pose(trace.q[k_on - 1], "ee")
    expected_dir = (p_s - p_ee) / np.linalg.norm(p_s - p_ee)
    np.testing.assert_allclose(direction, expected_dir, atol=1e-3)  # resolved 1 ms earlier than k_on - 1 state
    # the wrist sensor sees it: J^T w = tau_ext (the arm moves slowly, J from 0.5 ms earlier: 1e-3 relative)
    for k in np.flatnonzero(on)[::20]:
        tau_ee = robot.compute_frame_jacobian(trace.q[k]).T @ trace.wrench[k]
        np.testing.assert_allclose(tau_ee, trace.tau_ext[k], atol=2e-3 * np.abs(trace.tau_ext[k]).max())


def test_end_effector_force_arguments():
    with pytest.raises(ConfigError, match=r"unknown frame 'tool'; choose one of: ee, world"):
        EndEffectorForce(frame="tool")
    with pytest.raises(ConfigError, match=r"need 0 <= t_on < t_off \[s\]; got t_on=2.0, t_off=1.0"):
        EndEffectorForce(t_on=2.0, t_off=1.0)


def elbow_trajectory(robot):
    a = robot.home.copy()
    b = a + np.array([0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # shz swings the elbow sideways
    return JointTrajectory([a, b], [2.0])


def test_elbow_stick_pushes_the_link_not_the_wrist(robot):
    """The stick meets link 4 against its motion: tau_ext appears on the shoulder joints while the wrist
    sensor and the true ee force stay exactly zero (tau_ext,links of eq. (7))."""
    stick = ElbowStick(body="l_larm", t_start=0.5, speed=0.05, duration=0.6)
    plant = Plant(robot, scene=stick, noise=SensorNoise.none())
    traj = elbow_trajectory(robot)
    trace = run_closed_loop(plant, PDGravity(robot), traj, 2.0)
    contact = np.abs(trace.tau_ext).max(axis=1) > 0.0
    t_first = trace.first_time(contact)
    assert t_first is not None and 0.5 < t_first < 1.1, t_first
    assert not contact[trace.t > 0.5 + 2 * 0.6 + 0.01].any(), "the stick retracted: no contact afterwards"
    assert np.abs(trace.tau_ext[:, 0]).max() > 1.0  # shz feels it
    np.testing.assert_allclose(trace.f_ext_ee, 0.0, atol=0.0)
    np.testing.assert_allclose(trace.wrench, 0.0, atol=EXACT)
    # the stick moved against the elbow's motion
    tip = trace.extras["elbow_stick_tip"]
    k0, k1 = np.searchsorted(trace.t, [0.6, 0.9])
    stick_motion = tip[k1] - tip[k0]
    k = int(np.searchsorted(trace.t, 0.5))
    J = robot.compute_frame_jacobian(trace.q[k], "l_larm", world_aligned=True)[:3]
    assert float(stick_motion @ (J @ trace.dq[k])) < 0.0
    np.testing.assert_allclose(np.linalg.norm(stick_motion), 0.05 * 0.3, rtol=1e-6)


def test_elbow_stick_needs_motion_or_direction(robot):
    stick = ElbowStick(t_start=0.0)
    plant = Plant(robot, scene=stick, noise=SensorNoise.none())
    with pytest.raises(SimulationError, match=r"ElbowStick: the target point on 'l_larm' moves at 0 m/s"):
        plant.step(robot.compute_gravity(plant.q))
    with pytest.raises(ConfigError, match=r"ElbowStick: unknown arm body 'l_elbow'; bodies are: .*l_larm"):
        Plant(robot, scene=ElbowStick(body="l_elbow"))
    # an explicit direction works at rest
    plant = Plant(robot, scene=ElbowStick(t_start=0.0, direction=[0.0, 0.0, 1.0]), noise=SensorNoise.none())
    plant.step(robot.compute_gravity(plant.q))
    pos, _ = plant.body_pose("elbow_stick")
    assert pos[2] > 0.0  # out of the parking position
