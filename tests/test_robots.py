"""RobotModel: the rigid-body model (1) of both built-in arms and of users' files.

References used here are independent of the code under test wherever possible: MuJoCo on the same
file, finite differences, Pinocchio's RNEA with external forces, hand-derived pendulum dynamics, and
numbers typed from the paper (Table I), the Atlas reference table and Franka/Gaz et al.'s publications.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from reflexarm.errors import ModelError
from reflexarm.robots import RobotFileWarning, RobotModel, builtin_robots, load_robot

BUILTINS = sorted(builtin_robots())

#: Round-off tolerance for two evaluations of the same rigid-body quantity by different O(n) recursions
#: (regressor vs RNEA, Pinocchio vs MuJoCo): double precision eps (2.2e-16) times ~10^3 accumulated
#: operations on terms of O(10) Nm / O(1) kg m^2 gives ~1e-12; 1e-10 leaves margin and is still many
#: orders of magnitude below any modelling error.
ROUND_OFF = 1e-10

#: Central-difference step and tolerance. A central difference errs by |f'''| h^2 / 6 (truncation) plus
#: eps |f| / h (cancellation). With |f'''| <~ 1e3 (M along dq for |dq| ~ 1.5 rad/s; frame poses) and
#: |f| <~ 3 (kg m^2; m) that is ~2e-10 + ~1e-9 at h = 1e-6 (measured: <= 1.1e-9); FD_TOL is 100x that.
FD_STEP = 1e-6
FD_TOL = 1e-7


@pytest.fixture(scope="module", params=BUILTINS)
def robot(request: pytest.FixtureRequest) -> RobotModel:
    return load_robot(request.param)


def random_states(robot: RobotModel, count: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Seeded (q, dq, ddq) with q inside the joint limits and O(1) velocities and accelerations."""
    rng = np.random.default_rng(seed)
    return [
        (rng.uniform(robot.lower_limit, robot.upper_limit), rng.normal(0, 1.5, robot.n), rng.normal(0, 3, robot.n))
        for _ in range(count)
    ]


def mujoco_model(robot: RobotModel) -> tuple[mujoco.MjModel, mujoco.MjData]:
    assert robot.source is not None
    m = mujoco.MjModel.from_xml_path(str(robot.source))
    return m, mujoco.MjData(m)


def vee(S: np.ndarray) -> np.ndarray:
    """The vector of a (numerically) skew-symmetric 3x3 matrix."""
    return 0.5 * np.array([S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]])


# ---------------------------------------------------------------------------------------------- dynamics


def test_regressor_times_inertial_parameters_equals_rnea(robot: RobotModel) -> None:
    pi = robot.inertial_parameters()
    assert pi.shape == (10 * robot.n,)
    assert len(robot.inertial_parameter_names()) == 10 * robot.n
    for q, dq, ddq in random_states(robot, 20):
        Y = robot.compute_regressor(q, dq, ddq)
        assert Y.shape == (robot.n, 10 * robot.n)
        tau = robot.compute_inverse_dynamics(q, dq, ddq)
        np.testing.assert_allclose(
            Y @ pi, tau, rtol=0, atol=ROUND_OFF * max(1.0, np.abs(tau).max()), err_msg="Y(q, dq, ddq) pi != RNEA"
        )


def test_inverse_dynamics_is_m_ddq_plus_nonlinear_effects(robot: RobotModel) -> None:
    for q, dq, ddq in random_states(robot, 10, seed=1):
        M = robot.compute_mass_matrix(q)
        C = robot.compute_coriolis_matrix(q, dq)
        g = robot.compute_gravity(q)
        tau = robot.compute_inverse_dynamics(q, dq, ddq)
        scale = max(1.0, np.abs(tau).max())
        np.testing.assert_allclose(M @ ddq + C @ dq + g, tau, rtol=0, atol=ROUND_OFF * scale)
        np.testing.assert_allclose(robot.compute_nonlinear_effects(q, dq), C @ dq + g, rtol=0, atol=ROUND_OFF * scale)
        np.testing.assert_allclose(
            robot.compute_motor_torque(q, dq, ddq), tau + robot.friction.compute_torque(dq), rtol=0, atol=0
        )


def test_mass_matrix_is_symmetric_positive_definite(robot: RobotModel) -> None:
    for q, _, _ in random_states(robot, 20, seed=2):
        M = robot.compute_mass_matrix(q)
        np.testing.assert_array_equal(M, M.T, err_msg="M(q) must be exactly symmetric")
        eig = np.linalg.eigvalsh(M)
        # Smallest eigenvalue over 200 random q: 5.4e-4 kg m^2 (Atlas wrist), 3.7e-3 kg m^2 (Panda).
        assert eig.min() > 1e-4, f"M(q) not positive definite at q={q}: eigenvalues {eig}"


def test_mdot_minus_2c_is_skew_symmetric_and_the_observer_identity_holds(robot: RobotModel) -> None:
    for q, dq, _ in random_states(robot, 10, seed=3):
        # Mdot = dM/dq . dq by central differences of M along dq
        Mdot = (robot.compute_mass_matrix(q + FD_STEP * dq) - robot.compute_mass_matrix(q - FD_STEP * dq)) / (
            2 * FD_STEP
        )
        C = robot.compute_coriolis_matrix(q, dq)
        g = robot.compute_gravity(q)
        N = Mdot - 2 * C
        np.testing.assert_allclose(N + N.T, 0.0, atol=FD_TOL, err_msg="Mdot - 2C not skew-symmetric")
        # The momentum observer (4)-(6) uses g - C^T dq; with C^T = Mdot - C it equals g + C dq - Mdot dq.
        np.testing.assert_allclose(g - C.T @ dq, g + C @ dq - Mdot @ dq, atol=FD_TOL, err_msg="C^T dq identity")


def test_dynamics_equal_mujoco_on_the_same_file(robot: RobotModel) -> None:
    """Pinocchio (controller) and MuJoCo (plant) read the same numbers from the same file."""
    m, d = mujoco_model(robot)
    assert m.nv == robot.n
    ee_site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, robot.ee_frame)
    jac_p = np.zeros((3, m.nv))
    jac_r = np.zeros((3, m.nv))
    for q, dq, _ in random_states(robot, 20, seed=4):
        d.qpos[:] = q
        d.qvel[:] = dq
        mujoco.mj_forward(m, d)
        M_mj = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M_mj)
        np.testing.assert_allclose(robot.compute_mass_matrix(q), M_mj, rtol=0, atol=ROUND_OFF, err_msg="M")
        np.testing.assert_allclose(
            robot.compute_nonlinear_effects(q, dq), d.qfrc_bias, rtol=0, atol=ROUND_OFF, err_msg="C dq + g"
        )
        R, p = robot.compute_frame_pose(q)
        np.testing.assert_allclose(p, d.site_xpos[ee_site], rtol=0, atol=ROUND_OFF, err_msg="ee position")
        np.testing.assert_allclose(R, d.site_xmat[ee_site].reshape(3, 3), rtol=0, atol=ROUND_OFF, err_msg="ee R")
        mujoco.mj_jacSite(m, d, jac_p, jac_r, ee_site)
        J = robot.compute_frame_jacobian(q, robot.ee_frame, world_aligned=True)
        np.testing.assert_allclose(J, np.vstack([jac_p, jac_r]), rtol=0, atol=ROUND_OFF, err_msg="ee Jacobian")
    # joint data: limits, effort limits, true friction
    np.testing.assert_array_equal(robot.lower_limit, m.jnt_range[:, 0])
    np.testing.assert_array_equal(robot.upper_limit, m.jnt_range[:, 1])
    np.testing.assert_array_equal(robot.effort_limit, m.jnt_actfrcrange[:, 1])
    np.testing.assert_array_equal(robot.friction.coulomb, m.dof_frictionloss)
    np.testing.assert_array_equal(robot.friction.viscous, m.dof_damping)
    np.testing.assert_array_equal(m.dof_armature, 0.0)  # Pinocchio's M has no rotor inertia either


# ---------------------------------------------------------------------------------------------- frames


def test_frame_jacobian_matches_finite_differences_of_the_pose(robot: RobotModel) -> None:
    for frame in (robot.sensor_frame, robot.ee_frame):
        for q, _, _ in random_states(robot, 5, seed=5):
            J = robot.compute_frame_jacobian(q, frame)  # LOCAL: twist in the frame, linear rows first
            J_world = robot.compute_frame_jacobian(q, frame, world_aligned=True)
            R, _ = robot.compute_frame_pose(q, frame)
            J_fd = np.zeros((6, robot.n))
            J_fd_world = np.zeros((6, robot.n))
            for i in range(robot.n):
                e = np.zeros(robot.n)
                e[i] = FD_STEP
                Rp, pp = robot.compute_frame_pose(q + e, frame)
                Rm, pm = robot.compute_frame_pose(q - e, frame)
                dp = (pp - pm) / (2 * FD_STEP)
                omega_world = vee((Rp - Rm) / (2 * FD_STEP) @ R.T)
                J_fd_world[:, i] = np.concatenate([dp, omega_world])
                J_fd[:, i] = np.concatenate([R.T @ dp, R.T @ omega_world])
            np.testing.assert_allclose(J, J_fd, atol=FD_TOL, err_msg=f"LOCAL Jacobian of {frame!r}")
            np.testing.assert_allclose(J_world, J_fd_world, atol=FD_TOL, err_msg=f"world Jacobian of {frame!r}")
    assert robot.compute_frame_jacobian(robot.home).shape == (6, robot.n)  # default: the sensor frame


def test_jacobian_transpose_maps_a_sensor_wrench_like_rnea_with_external_forces(robot: RobotModel) -> None:
    """J^T w (LOCAL sensor Jacobian) is the joint torque a wrench w, in and about the sensor frame, produces."""
    model = robot.pin_model
    data = model.createData()
    frame = model.frames[robot.frame_id(robot.sensor_frame)]
    rng = np.random.default_rng(6)
    for q, _, _ in random_states(robot, 10, seed=6):
        wrench = rng.normal(0, 20, 6)  # force [N], torque [Nm]
        fext = [pin.Force.Zero() for _ in range(model.njoints)]
        fext[frame.parentJoint] = frame.placement.act(pin.Force(wrench[:3], wrench[3:]))
        zero = np.zeros(robot.n)
        # rnea returns the torque that balances gravity and the applied wrench: g(q) - J^T w
        tau_from_wrench = robot.compute_gravity(q) - pin.rnea(model, data, q, zero, zero, fext)
        J = robot.compute_frame_jacobian(q)
        np.testing.assert_allclose(J.T @ wrench, tau_from_wrench, rtol=0, atol=ROUND_OFF * np.abs(wrench).max())


# ---------------------------------------------------------------------------------------------- parameters


def test_with_inertial_parameters_reproduces_the_dynamics(robot: RobotModel) -> None:
    clone = robot.with_inertial_parameters(robot.inertial_parameters())
    # The round trip about-COM -> about-joint -> about-COM inertia cancels m |c|^2 terms: a few digits lost.
    np.testing.assert_allclose(clone.inertial_parameters(), robot.inertial_parameters(), rtol=0, atol=ROUND_OFF)
    for q, dq, ddq in random_states(robot, 5, seed=7):
        tau = robot.compute_inverse_dynamics(q, dq, ddq)
        np.testing.assert_allclose(
            clone.compute_inverse_dynamics(q, dq, ddq), tau, rtol=0, atol=ROUND_OFF * max(1.0, np.abs(tau).max())
        )
        np.testing.assert_allclose(clone.compute_mass_matrix(q), robot.compute_mass_matrix(q), rtol=0, atol=ROUND_OFF)
    assert clone.friction == robot.friction
    assert clone.ee_frame == robot.ee_frame and clone.sensor_frame == robot.sensor_frame
    np.testing.assert_array_equal(clone.home, robot.home)


@pytest.mark.parametrize("link", [2, 4])
def test_scaling_a_link_mass_changes_gravity_as_the_regressor_says(robot: RobotModel, link: int) -> None:
    """Scaling link k's whole inertial block by s changes g by (s - 1) Y_k pi_k, and only on joints <= k."""
    pi = robot.inertial_parameters()
    scale = 1.1
    pi_scaled = pi.copy()
    pi_scaled[10 * link : 10 * link + 10] *= scale  # m, m c and I scaled: same COM, s times the mass
    heavier = robot.with_inertial_parameters(pi_scaled)
    assert heavier.inertial_parameters()[10 * link] == pytest.approx(scale * pi[10 * link], rel=1e-14)
    np.testing.assert_array_equal(robot.inertial_parameters(), pi, err_msg="the original must be unchanged")
    zero = np.zeros(robot.n)
    for q, _, _ in random_states(robot, 5, seed=8):
        dg = heavier.compute_gravity(q) - robot.compute_gravity(q)
        Y = robot.compute_regressor(q, zero, zero)
        np.testing.assert_allclose(
            dg, (scale - 1) * Y[:, 10 * link : 10 * link + 10] @ pi[10 * link : 10 * link + 10], rtol=0, atol=ROUND_OFF
        )
        np.testing.assert_allclose(dg[link + 1 :], 0.0, atol=ROUND_OFF, err_msg="distal joints do not feel link k")
        assert np.abs(dg).max() > 1e-3, "a 10 % heavier link must change g"


def test_copy_is_independent(robot: RobotModel) -> None:
    other = robot.copy()
    other.gravity = [0.0, 0.0, -1.62]  # the Moon
    np.testing.assert_array_equal(robot.gravity, [0.0, 0.0, -9.81])
    np.testing.assert_allclose(
        other.compute_gravity(robot.home), robot.compute_gravity(robot.home) * 1.62 / 9.81, rtol=0, atol=ROUND_OFF
    )


def test_builtin_home_is_inside_the_joint_limits(robot: RobotModel) -> None:
    assert robot.home.shape == (robot.n,)
    assert np.all(robot.home > robot.lower_limit) and np.all(robot.home < robot.upper_limit)


# ---------------------------------------------------------------------------------------------- built-in numbers


def test_atlas_left_arm_numbers() -> None:
    atlas = load_robot("atlas_v5_left_arm")
    assert atlas.n == 7
    assert atlas.joint_names == [f"l_arm_{j}" for j in ("shz", "shx", "ely", "elx", "wry", "wrx", "wry2")]
    # Masses of table A (final drcsim/IHMC values) in reference/atlas/left_arm_parameters.md; the 0.25 kg
    # padded tool rides on l_hand. The table's links sum to 19.7107 kg (the file's stated total, 19.7097,
    # is an addition slip: 4.466 + 3.899 + 4.386 + 3.248 + 2.4798 + 0.648 + 0.5839 = 19.7107).
    link_masses = [4.466, 3.899, 4.386, 3.248, 2.4798, 0.648, 0.5839 + 0.25]
    masses = atlas.inertial_parameters()[0::10]
    np.testing.assert_allclose(masses, link_masses, rtol=1e-12)
    assert masses.sum() == pytest.approx(19.7107 + 0.25, abs=1e-9)
    np.testing.assert_allclose(atlas.lower_limit, [-1.5708, -1.5708, 0, 0, -3.011, -1.7628, -2.9671])
    np.testing.assert_allclose(atlas.upper_limit, [0.785398, 1.5708, 3.14159, 2.35619, 3.011, 1.7628, 2.9671])
    np.testing.assert_allclose(atlas.effort_limit, [87, 99, 63, 112, 25, 25, 25])
    np.testing.assert_allclose(atlas.velocity_limit, [12, 12, 12, 12, 10, 10, 10])
    # Table I of the paper: single-joint friction identification.
    np.testing.assert_allclose(atlas.friction.coulomb, [2.0, 6.7, 10.3, 6.1, 0.1, 0.1, 3.1], err_msg="mu_C")
    np.testing.assert_allclose(atlas.friction.viscous, [1.3, 0.9, 1.6, 2.7, 0.5, 0.2, 0.2], err_msg="d_v")
    np.testing.assert_allclose(atlas.gravity, [0, 0, -9.81])


def test_panda_numbers() -> None:
    panda = load_robot("panda")
    assert panda.n == 7
    # Gaz et al. 2019 feasible identified masses of links 1..7; the 0.25 kg tool rides on link 7.
    link_masses = [4.970684, 0.646926, 3.228604, 3.587895, 1.225946, 1.666555, 0.735522 + 0.25]
    np.testing.assert_allclose(panda.inertial_parameters()[0::10], link_masses, rtol=1e-12)
    # Franka's limits (reference/panda_gaz2019/SOURCES.md) and effort limits.
    np.testing.assert_allclose(panda.lower_limit, [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
    np.testing.assert_allclose(panda.upper_limit, [2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
    np.testing.assert_allclose(panda.velocity_limit, [2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61])
    np.testing.assert_allclose(panda.effort_limit, [87, 87, 87, 87, 12, 12, 12])
    # Gaz's sigmoid friction goes from -A sig(alpha s) to A - A sig(alpha s): a Coulomb step of height A,
    # mu_C = A/2, rounded to 1 mNm in the file (hence atol = 0.5 mNm).
    A = np.array([0.54615, 0.87224, 0.64068, 1.2794, 0.83904, 0.30301, 0.56489])
    np.testing.assert_allclose(panda.friction.coulomb, A / 2, rtol=0, atol=5e-4)
    assert np.all(panda.friction.viscous * panda.velocity_limit < panda.friction.coulomb.min()), "d_v is small"
    # Standard Franka kinematics: at q = 0 the flange is at x = a4 + a5 + a7 = 0.0825 - 0.0825 + 0.088 m,
    # z = d1 + d3 + d5 - d_flange = 0.333 + 0.316 + 0.384 - 0.107 m, pointing down; the tool tip (ee) is
    # 0.05 m further along the flange z.
    R, p = panda.compute_frame_pose(np.zeros(7), "wrist_ft")
    np.testing.assert_allclose(p, [0.088, 0.0, 0.926], atol=1e-12)
    np.testing.assert_allclose(R, np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    _, p_ee = panda.compute_frame_pose(np.zeros(7))
    np.testing.assert_allclose(p_ee, [0.088, 0.0, 0.876], atol=1e-12)
    np.testing.assert_allclose(panda.home, [0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4], atol=1e-3)


def test_panda_flange_pose_matches_the_denavit_hartenberg_table() -> None:
    """Franka's modified DH table, chained by hand, against the model file at random configurations."""
    a = [0, 0, 0, 0.0825, -0.0825, 0, 0.088, 0]
    d = [0.333, 0, 0.316, 0, 0.384, 0, 0, 0.107]
    alpha = [0, -np.pi / 2, np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, np.pi / 2, 0]

    def craig(a_i: float, d_i: float, alpha_i: float, theta: float) -> np.ndarray:
        ca, sa, ct, st = np.cos(alpha_i), np.sin(alpha_i), np.cos(theta), np.sin(theta)
        return np.array(
            [[ct, -st, 0, a_i], [st * ca, ct * ca, -sa, -d_i * sa], [st * sa, ct * sa, ca, d_i * ca], [0, 0, 0, 1]]
        )

    panda = load_robot("panda")
    for q, _, _ in random_states(panda, 10, seed=9):
        T = np.eye(4)
        for i in range(8):
            T = T @ craig(a[i], d[i], alpha[i], q[i] if i < 7 else 0.0)
        R, p = panda.compute_frame_pose(q, "wrist_ft")
        np.testing.assert_allclose(p, T[:3, 3], atol=1e-12)
        np.testing.assert_allclose(R, T[:3, :3], atol=1e-12)


# ---------------------------------------------------------------------------------------------- user files

PENDULUM_URDF = """<?xml version="1.0"?>
<robot name="double_pendulum">
  <link name="base_link">
    <visual><geometry><mesh filename="package://foo/mesh.stl"/></geometry></visual>
  </link>
  <link name="link1">
    <inertial><origin xyz="{c1} 0 0"/><mass value="{m1}"/>
      <inertia ixx="0.001" ixy="0" ixz="0" iyy="{I1}" iyz="0" izz="0.001"/></inertial>
    <visual><geometry><mesh filename="package://foo/mesh.stl"/></geometry></visual>
  </link>
  <link name="link2">
    <inertial><origin xyz="{c2} 0 0"/><mass value="{m2}"/>
      <inertia ixx="0.001" ixy="0" ixz="0" iyy="{I2}" iyz="0" izz="0.001"/></inertial>
  </link>
  <joint name="shoulder" type="revolute">
    <parent link="base_link"/><child link="link1"/><origin xyz="0 0 1"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="50" velocity="4"/><dynamics damping="0.3" friction="1.5"/>
  </joint>
  <joint name="elbow" type="revolute">
    <parent link="link1"/><child link="link2"/><origin xyz="{L1} 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" effort="20" velocity="5"/><dynamics damping="0.1" friction="0.5"/>
  </joint>
</robot>
"""


def test_user_urdf_double_pendulum_against_hand_derived_dynamics(tmp_path: Path) -> None:
    """Planar double pendulum about y: x along the links at q = 0, gravity -z.

    A point at x = l rotated by q about y goes to (l cos q, 0, -l sin q), so with V = g0 sum m z:
        g1 = -g0 (m1 c1 cos q1 + m2 (L1 cos q1 + c2 cos(q1 + q2))),   g2 = -g0 m2 c2 cos(q1 + q2),
        M11 = I1 + I2 + m1 c1^2 + m2 (L1^2 + c2^2 + 2 L1 c2 cos q2),
        M12 = I2 + m2 (c2^2 + L1 c2 cos q2),   M22 = I2 + m2 c2^2.
    """
    m1, m2, c1, c2, L1, I1, I2, g0 = 2.0, 1.5, 0.25, 0.2, 0.5, 0.02, 0.01, 9.81
    path = tmp_path / "pendulum.urdf"
    path.write_text(PENDULUM_URDF.format(m1=m1, m2=m2, c1=c1, c2=c2, L1=L1, I1=I1, I2=I2))
    robot = load_robot(path, ee_frame="link2")
    assert robot.n == 2 and robot.joint_names == ["shoulder", "elbow"]
    assert robot.name == "pendulum" and robot.sensor_frame == "link2"
    np.testing.assert_allclose(robot.friction.coulomb, [1.5, 0.5])  # from <dynamics friction damping>
    np.testing.assert_allclose(robot.friction.viscous, [0.3, 0.1])
    np.testing.assert_allclose(robot.effort_limit, [50, 20])
    np.testing.assert_allclose(robot.velocity_limit, [4, 5])
    for q1, q2 in [(0.0, 0.0), (0.3, -0.7), (-1.2, 1.9)]:
        q = np.array([q1, q2])
        g = -g0 * np.array(
            [m1 * c1 * np.cos(q1) + m2 * (L1 * np.cos(q1) + c2 * np.cos(q1 + q2)), m2 * c2 * np.cos(q1 + q2)]
        )
        M12 = I2 + m2 * (c2**2 + L1 * c2 * np.cos(q2))
        M = np.array(
            [[I1 + I2 + m1 * c1**2 + m2 * (L1**2 + c2**2 + 2 * L1 * c2 * np.cos(q2)), M12], [M12, I2 + m2 * c2**2]]
        )
        np.testing.assert_allclose(robot.compute_gravity(q), g, rtol=0, atol=ROUND_OFF, err_msg=f"g at q={q}")
        np.testing.assert_allclose(robot.compute_mass_matrix(q), M, rtol=0, atol=ROUND_OFF, err_msg=f"M at q={q}")
        # the elbow sits at (L1 cos q1, 0, 1 - L1 sin q1)
        _, p = robot.compute_frame_pose(q)
        np.testing.assert_allclose(p, [L1 * np.cos(q1), 0.0, 1.0 - L1 * np.sin(q1)], atol=1e-12)


# ---------------------------------------------------------------------------------------------- bad input

ONE_LINK = '<inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>'

BRANCHED_URDF = f"""<robot name="forked">
  <link name="base"/><link name="a">{ONE_LINK}</link><link name="b">{ONE_LINK}</link>
  <joint name="ja" type="revolute"><parent link="base"/><child link="a"/><axis xyz="1 0 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="jb" type="revolute"><parent link="base"/><child link="b"/><axis xyz="1 0 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
</robot>"""

BRANCHED_MJCF = """<mujoco><worldbody><body name="base">
  <body name="a" pos="0 0.1 0"><joint name="ja" axis="1 0 0"/><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/>
    <site name="tip"/></body>
  <body name="b" pos="0 -0.1 0"><joint name="jb" axis="1 0 0"/><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/>
  </body></body></worldbody></mujoco>"""

FREE_MJCF = """<mujoco><worldbody><body name="b" pos="0 0 1"><freejoint/>
  <inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/>
  <body name="c" pos="0 0.1 0"><joint name="j" axis="1 0 0"/><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/>
    <site name="tip"/></body></body></worldbody></mujoco>"""


def test_unknown_robot_name_lists_the_builtins() -> None:
    with pytest.raises(ModelError, match="unknown robot 'pandas'") as err:
        load_robot("pandas")
    for name in BUILTINS:
        assert name in str(err.value)


def test_nonexistent_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.urdf"
    with pytest.raises(ModelError, match="nope.urdf' does not exist"):
        load_robot(path, ee_frame="tip")
    with pytest.raises(ModelError, match="does not exist"):  # even before asking for the frame
        load_robot(path)


@pytest.mark.parametrize(
    ("name", "text"),
    [
        ("broken.urdf", '<robot name="r"><link name="a"></robot>'),
        ("broken.xml", "<mujoco><worldbody><body name='a'><joint/>\n</worldbody></mujoco>"),
        ("not_xml.xml", "hello"),
    ],
)
def test_malformed_file(tmp_path: Path, name: str, text: str) -> None:
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(ModelError, match=f"cannot parse robot file '.*{name}'"):
        load_robot(path, ee_frame="tip")


def test_unknown_file_format(tmp_path: Path) -> None:
    path = tmp_path / "arm.sdf"
    path.write_text("<sdf/>")
    with pytest.raises(ModelError, match="unknown format '.sdf'; use .urdf or MJCF .xml"):
        load_robot(path, ee_frame="tip")


def test_user_file_needs_an_ee_frame(tmp_path: Path) -> None:
    path = tmp_path / "serial.urdf"
    path.write_text(
        BRANCHED_URDF.replace('<parent link="base"/><child link="b"/>', '<parent link="a"/><child link="b"/>')
    )
    with pytest.raises(
        ModelError, match=r"name the end-effector frame \(ee_frame=..., --ee-frame\); frames on the last "
    ):
        load_robot(path)


def test_missing_frames_are_listed() -> None:
    with pytest.raises(
        ModelError, match="unknown end-effector frame 'hand' in '.*panda.xml'; frames are: .*wrist_ft, ee"
    ):
        load_robot("panda", ee_frame="hand")
    with pytest.raises(ModelError, match="unknown sensor frame 'ft' in .*; frames are: .*l_tool"):
        load_robot("atlas_v5_left_arm", sensor_frame="ft")
    panda = load_robot("panda")
    with pytest.raises(ModelError, match="unknown frame 'flange'; frames are: .*panda_link7"):
        panda.compute_frame_pose(panda.home, "flange")


def test_free_joint_is_fixed_with_a_note(tmp_path: Path) -> None:
    """A floating base (MJCF freejoint) is fixed where the file puts it: one joint left, the base's 1 m height
    kept in the frame poses, and a note says so."""
    path = tmp_path / "floating.xml"
    path.write_text(FREE_MJCF)
    with pytest.warns(RobotFileWarning, match="the floating base joint .* is fixed at the file's pose"):
        robot = load_robot(path, ee_frame="tip")
    assert robot.joint_names == ["j"]
    assert robot.cut is not None and robot.cut.base == "b" and robot.cut.tip == "c"
    np.testing.assert_allclose(robot.compute_frame_pose([0.0], "tip")[1], [0.0, 0.1, 1.0], atol=1e-12)


@pytest.mark.parametrize(("name", "text"), [("forked.urdf", BRANCHED_URDF), ("forked.xml", BRANCHED_MJCF)])
def test_branched_tree_needs_a_tip(tmp_path: Path, name: str, text: str) -> None:
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(
        ModelError, match=r"is not a serial chain: name the arm's tip link \(tip=..., --tip\); leaf links are: a, b"
    ):
        load_robot(path, ee_frame="a")
    robot = load_robot(path, tip="b")
    assert robot.joint_names == ["jb"] and robot.ee_frame == "b"
    assert robot.cut is not None and dict(robot.cut.locked) == {"ja": 0.0}


def test_wrong_shapes_are_named(robot: RobotModel) -> None:
    n = robot.n
    with pytest.raises(ModelError, match=rf"q must have shape \({n},\); got \({n - 1},\)"):
        robot.compute_gravity(np.zeros(n - 1))
    with pytest.raises(ModelError, match=rf"dq must have shape \({n},\); got \(1, {n}\)"):
        robot.compute_coriolis_matrix(np.zeros(n), np.zeros((1, n)))
    with pytest.raises(ModelError, match=rf"ddq must have shape \({n},\)"):
        robot.compute_regressor(np.zeros(n), np.zeros(n), np.zeros(n + 1))
    with pytest.raises(ModelError, match=f"expected {10 * n} inertial parameters .* got 3"):
        robot.with_inertial_parameters(np.ones(3))
    with pytest.raises(ModelError, match="gravity must be a finite 3-vector"):
        robot.copy().gravity = [0.0, np.nan, -9.81]
