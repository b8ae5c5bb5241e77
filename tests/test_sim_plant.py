"""The simulated plant: true friction, the wrist force/torque sensor, true external torques, noise, errors.

References are independent of the code under test: Pinocchio's dynamics and Jacobians (a different
library reading the same file), applied forces whose value we choose, and the friction law of Table I.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from reflexarm.errors import ConfigError, ModelError, SimulationError
from reflexarm.robots import builtin_robots, load_robot
from reflexarm.sim import PAPER_NOISE, Plant, SensorNoise

#: Statics and load compensation are exact algebra on MuJoCo's own quantities and on Pinocchio's
#: equal model (agreement ~1e-14, see test_model_agreement): 1e-9 N / Nm leaves a wide margin for
#: round-off in forces of tens of newtons while any sign, frame or lever-arm slip shows up at >= 1e-2.
EXACT = 1e-9


@pytest.fixture(scope="module")
def robot():
    return load_robot("atlas_v5_left_arm")


@pytest.fixture
def plant(robot):
    return Plant(robot, noise=SensorNoise.none())


def hold_with_force(plant, robot, force, ticks=20):
    """Apply ``force`` [N] (world) at the end effector and cancel it and gravity with the motors, so that
    the arm stays at rest: tau = g(q) - J_ee^T F (Pinocchio). Returns the state after the hold and J_ee
    there (the friction-loss constraint lets the held arm creep by ~1e-11 rad; expectations are taken at
    the final state so that only round-off remains)."""
    q0 = plant.q
    plant.apply_external_force(force)
    J0 = robot.compute_frame_jacobian(q0, robot.ee_frame, world_aligned=True)[:3]
    tau = robot.compute_gravity(q0) - J0.T @ force
    for _ in range(ticks):
        plant.step(tau)
    q = plant.q
    return q, robot.compute_frame_jacobian(q, robot.ee_frame, world_aligned=True)[:3]


# ---------------------------------------------------------------------- wrist force/torque sensor
def test_wrench_sensor_reads_the_applied_force_in_the_sensor_frame(robot, plant):
    """A force F on the tool at the ee point reads (R^T F, R^T (p_ee - p_s) x F) in the sensor frame.

    Sign convention: the wrench the environment applies to the arm (MuJoCo's raw sensor reports the
    opposite: the wrench the hand exerts on the tool), so that tau_ext = J_sensor^T wrench.
    """
    F = np.array([12.0, -30.0, 25.0])
    q, _ = hold_with_force(plant, robot, F)
    np.testing.assert_allclose(plant.dq, 0.0, atol=1e-9)  # the arm is really at rest
    R, p_s = robot.compute_frame_pose(q, "wrist_ft")
    _, p_ee = robot.compute_frame_pose(q, "ee")
    expected = np.concatenate([R.T @ F, R.T @ np.cross(p_ee - p_s, F)])
    np.testing.assert_allclose(plant.measure().wrench, expected, atol=EXACT)
    np.testing.assert_allclose(plant.ee_contact_force(), F, atol=EXACT)


def test_wrench_sensor_is_zero_in_free_motion(robot, plant):
    """Fast free motion: the raw sensor feels the tool's weight and inertia (several N); the
    load-compensated reading must be ~0. Exact up to round-off since the compensation uses the same
    rigid-body quantities MuJoCo used to integrate."""
    rng = np.random.default_rng(3)
    raw_peak, comp_peak = 0.0, 0.0
    plant.reset(robot.home, rng.normal(0.0, 1.0, 7))
    for k in range(300):
        tau = robot.compute_gravity(plant.q) + 5.0 * np.sin(0.02 * k + np.arange(7)) * [8, 8, 8, 8, 1, 1, 1]
        plant.step(tau)
        raw_peak = max(raw_peak, float(np.abs(plant.data.sensordata).max()))
        comp_peak = max(comp_peak, float(np.abs(plant.measure().wrench).max()))
    assert raw_peak > 1.0, "the raw sensor should see the 0.25 kg tool's weight and inertia"
    assert comp_peak < EXACT, f"load-compensated wrench in free motion: {comp_peak:.3g}"


def test_jacobian_transpose_of_wrench_is_the_true_external_torque(robot, plant):
    """tau_ext_EE = J_sensor_LOCAL^T wrench (eq. (6)) equals the plant's true tau_ext, and both equal
    J_ee^T F computed by Pinocchio for the applied force."""
    F = np.array([-20.0, 15.0, -40.0])
    q, J_ee = hold_with_force(plant, robot, F)
    J_s = robot.compute_frame_jacobian(q)  # LOCAL, sensor frame
    tau_ext = plant.true_external_torque()
    np.testing.assert_allclose(J_s.T @ plant.measure().wrench, tau_ext, atol=EXACT)
    np.testing.assert_allclose(tau_ext, J_ee.T @ F, atol=EXACT)
    plant.clear_external_force()
    plant.step(robot.compute_gravity(plant.q))
    np.testing.assert_allclose(plant.true_external_torque(), 0.0, atol=0.0)


@pytest.mark.parametrize("name", sorted(builtin_robots()))
def test_wrist_sensor_on_every_builtin(name):
    """The same static check on each shipped robot (the sensor site, load and frames come from its file)."""
    if not builtin_robots()[name].path.exists():
        pytest.skip(f"{name} file not written yet")
    robot = load_robot(name)
    plant = Plant(robot, noise=SensorNoise.none())
    F = np.array([5.0, -10.0, 20.0])
    q, J_ee = hold_with_force(plant, robot, F)
    np.testing.assert_allclose(robot.compute_frame_jacobian(q).T @ plant.measure().wrench, J_ee.T @ F, atol=EXACT)
    np.testing.assert_allclose(plant.true_external_torque(), J_ee.T @ F, atol=EXACT)


def test_force_on_a_link_before_the_sensor_is_not_seen_by_it(robot, plant):
    """A push on the forearm (link 4) gives tau_ext but no wrist wrench: tau_ext,links of eq. (7)."""
    plant.apply_external_force([0.0, 0.0, -30.0], body="l_larm")
    plant.step(robot.compute_gravity(plant.q))
    assert np.abs(plant.true_external_torque()).max() > 1.0
    np.testing.assert_allclose(plant.measure().wrench, 0.0, atol=EXACT)
    np.testing.assert_allclose(plant.ee_contact_force(), 0.0, atol=0.0)


# ---------------------------------------------------------------------- measurement and noise
def test_measurement_without_noise_is_the_true_state(robot, plant):
    tau = robot.compute_gravity(plant.q) + 1.0
    for _ in range(10):
        plant.step(tau)
    m = plant.measure()
    assert m.t == pytest.approx(10 * plant.control_period, abs=1e-12)
    np.testing.assert_array_equal(m.q, plant.q)
    np.testing.assert_array_equal(m.dq, plant.dq)
    np.testing.assert_array_equal(m.tau_m, tau)
    np.testing.assert_array_equal(m.gravity, [0.0, 0.0, -9.81])


def test_noise_is_seeded_uniform_and_within_bounds(robot):
    levels = PAPER_NOISE
    a = Plant(robot, seed=7)
    b = Plant(robot, seed=7)
    c = Plant(robot, seed=8)
    ms_a = [a.measure() for _ in range(2000)]
    ms_b = [b.measure() for _ in range(2000)]
    assert all(np.array_equal(x.q, y.q) and np.array_equal(x.wrench, y.wrench) for x, y in zip(ms_a, ms_b, strict=True))
    assert not np.array_equal(c.measure().q, ms_a[0].q)
    truth = a.q
    noise = {
        "q": np.array([m.q - truth for m in ms_a]),
        "dq": np.array([m.dq for m in ms_a]),
        "tau_m": np.array([m.tau_m for m in ms_a]),
        "force": np.array([m.wrench[:3] for m in ms_a]),
        "torque": np.array([m.wrench[3:] for m in ms_a]),
        "gravity": np.array([m.gravity - [0, 0, -9.81] for m in ms_a]),
    }
    for name, e in noise.items():
        level = getattr(levels, name)
        assert np.abs(e).max() <= level, name
        # 2000 uniform samples per component: the extremes come within 1 % of the bound (P(miss) ~ 2e-9)
        # and the mean is 0 within 5 standard errors (level / sqrt(3 * 2000) * 5 = 0.065 level).
        assert np.abs(e).max(axis=0).min() > 0.99 * level, name
        assert np.abs(e.mean(axis=0)).max() < 0.065 * level, name
    # reset restarts the sequence from the seed
    a.reset()
    np.testing.assert_array_equal(a.measure().q, ms_a[0].q)


def test_sensor_noise_levels_and_scaling():
    assert PAPER_NOISE == SensorNoise(q=3.4e-4, dq=5.5e-2, gravity=2e-4, tau_m=7.3e-2, force=2.3, torque=0.23)
    assert SensorNoise.none().is_zero
    assert PAPER_NOISE.scaled(10).force == pytest.approx(23.0)
    assert PAPER_NOISE.scaled(0).is_zero
    with pytest.raises(ConfigError, match=r"noise scale must be a non-negative number; got -1"):
        PAPER_NOISE.scaled(-1)
    with pytest.raises(ConfigError, match=r"noise level dq must be a non-negative number; got -0.1"):
        SensorNoise(dq=-0.1)


# ---------------------------------------------------------------------- URDF with package:// meshes
TINY_URDF = """<?xml version="1.0"?>
<robot name="tiny">
  <link name="base_link">
    <inertial><mass value="2.0"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
    <visual><geometry><mesh filename="package://tiny_description/meshes/base.stl"/></geometry></visual>
  </link>
  <link name="link1">
    <inertial><origin xyz="0 0 0.15"/><mass value="1.5"/>
      <inertia ixx="0.02" ixy="0.001" ixz="0" iyy="0.02" iyz="0" izz="0.005"/></inertial>
    <visual><geometry><mesh filename="package://tiny_description/meshes/link1.dae"/></geometry></visual>
    <collision><geometry><mesh filename="package://tiny_description/meshes/link1.stl"/></geometry></collision>
    <collision><origin xyz="0 0 0.15"/><geometry><cylinder radius="0.04" length="0.3"/></geometry></collision>
  </link>
  <link name="link2">
    <inertial><origin xyz="0.1 0 0.02"/><mass value="1.0"/>
      <inertia ixx="0.01" ixy="0" ixz="0.001" iyy="0.012" iyz="0" izz="0.004"/></inertial>
    <visual><geometry><mesh filename="package://tiny_description/meshes/link2.dae"/></geometry></visual>
  </link>
  <link name="tool">
    <inertial><origin xyz="0.02 0 0"/><mass value="0.3"/>
      <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial>
  </link>
  <joint name="j1" type="revolute"><parent link="base_link"/><child link="link1"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-2.9" upper="2.9" effort="50" velocity="2"/>
    <dynamics damping="0.5" friction="1.0"/></joint>
  <joint name="j2" type="revolute"><parent link="link1"/><child link="link2"/><origin xyz="0 0 0.3" rpy="0.3 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="30" velocity="2"/>
    <dynamics damping="0.2" friction="0.5"/></joint>
  <joint name="ft_joint" type="fixed"><parent link="link2"/><child link="tool"/>
    <origin xyz="0.25 0 0" rpy="0 0.2 0.1"/></joint>
</robot>
"""


@pytest.fixture
def tiny_urdf(tmp_path):
    path = tmp_path / "tiny.urdf"
    path.write_text(TINY_URDF)
    return path


@pytest.mark.parametrize("sensor_frame", ["tool", "link2"])
def test_urdf_with_package_meshes_loads_and_agrees(tiny_urdf, sensor_frame):
    """MuJoCo cannot open package:// meshes: the plant drops mesh geometry, keeps the fixed tool link as a
    body, and the two models agree. With the sensor on the welded tool the MuJoCo F/T sensor is used; on a
    moving link (link2) the plant falls back to an ideal sensor (external wrenches summed); both must read
    an applied force exactly."""
    from test_model_agreement import ATOL, check_agreement

    robot = load_robot(tiny_urdf, ee_frame="tool", sensor_frame=sensor_frame)
    plant = Plant(robot, noise=SensorNoise.none())
    assert plant.is_urdf
    assert plant._physical_sensor == (sensor_frame == "tool")
    worst = check_agreement(robot, plant, n_states=30)
    assert max(worst.values()) <= ATOL, worst
    np.testing.assert_array_equal(plant.true_friction.coulomb, [1.0, 0.5])
    np.testing.assert_array_equal(plant.true_friction.viscous, [0.5, 0.2])
    # the ee site sits where Pinocchio puts the frame
    plant.reset([0.4, -0.7])
    np.testing.assert_allclose(plant.ee_position(), robot.compute_frame_pose([0.4, -0.7], "tool")[1], atol=ATOL)
    # a force at the ee point, held statically
    F = np.array([3.0, -4.0, 6.0])
    q, J_ee = hold_with_force(plant, robot, F)
    J_s = robot.compute_frame_jacobian(q)
    np.testing.assert_allclose(J_s.T @ plant.measure().wrench, J_ee.T @ F, atol=EXACT)
    np.testing.assert_allclose(plant.true_external_torque(), J_ee.T @ F, atol=EXACT)


# ---------------------------------------------------------------------- bad input
def test_bad_timing_is_rejected(robot):
    with pytest.raises(ConfigError, match=r"control_period \(0.00125 s\) must be an integer multiple of timestep"):
        Plant(robot, control_period=1.25e-3)
    with pytest.raises(ConfigError, match=r"timestep must be a positive number of seconds; got -0.001"):
        Plant(robot, timestep=-1e-3)


def test_unknown_robot_and_malformed_file(robot, tmp_path):
    with pytest.raises(ModelError, match=r"unknown robot 'atlas_v6'; built-in robots are: atlas_v5_left_arm"):
        Plant("atlas_v6")
    bad = tmp_path / "broken.xml"
    bad.write_text("<mujoco><worldbody><body name='a'></bodyy></worldbody></mujoco>")
    clone = robot.copy()
    clone.source = bad  # Pinocchio read a good file; MuJoCo gets a broken one
    with pytest.raises(ModelError, match=r"MuJoCo cannot parse robot file '.*broken.xml'"):
        Plant(clone)


def test_non_finite_torque_is_refused_naming_the_joints(plant):
    tau = np.zeros(7)
    tau[2] = np.nan
    tau[5] = np.inf
    q0 = plant.q
    with pytest.raises(SimulationError, match=r"non-finite motor torque on joint\(s\) \['l_arm_ely', 'l_arm_wrx'\]"):
        plant.step(tau)
    assert plant.time == 0.0 and np.array_equal(plant.q, q0)  # nothing was integrated
    with pytest.raises(SimulationError, match=r"tau must have shape \(7,\); got \(6,\)"):
        plant.step(np.zeros(6))


def test_divergence_is_detected_and_blocks_further_steps(plant):
    # a speed beyond any physical arm (the wrist reaches > 1000 rad/s within a few ticks)
    with pytest.raises(SimulationError, match=r"simulation diverged near t = .* exceeds 1000 rad/s or m/s"):
        for _ in range(50):
            plant.step(np.full(7, 1e4))
    with pytest.raises(SimulationError, match=r"call reset\(\) first"):
        plant.step(np.zeros(7))
    plant.reset()
    # huge accelerations: MuJoCo flags them (and must not silently restart from qpos0); the plant says so
    with pytest.raises(SimulationError, match=r"MuJoCo found NaN/inf/huge values in .*accelerations \(qacc\)"):
        plant.step(np.full(7, 1e12))
    with pytest.raises(SimulationError, match=r"call reset\(\) first"):
        plant.step(np.zeros(7))
    plant.reset()
    plant.step(np.zeros(7))  # usable again


def test_bad_reset_state_and_unknown_body(plant):
    with pytest.raises(ConfigError, match=r"q0 must be a finite \(7,\) array; got shape \(3,\)"):
        plant.reset(np.zeros(3))
    with pytest.raises(ConfigError, match=r"unknown body 'hand'; bodies are: world, utorso, l_clav"):
        plant.body_pose("hand")
    with pytest.raises(ConfigError, match=r"force_world must be a finite 3-vector"):
        plant.apply_external_force([1.0, math.nan, 0.0])


def test_extra_joint_torque_must_be_finite(robot):
    p = Plant(robot, noise=SensorNoise.none(), extra_joint_torque=lambda q, dq, t: np.full(7, np.nan))
    with pytest.raises(SimulationError, match=r"extra_joint_torque returned \[nan"):
        p.step(np.zeros(7))
