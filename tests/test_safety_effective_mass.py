"""m_R(q, u) = 1/(u^T J M^-1 J^T u) against independent references: a 2-link planar arm written out by hand, and
MuJoCo's own mass matrix and Jacobian of the same robot file; the permissible speed against the A.3 formula
evaluated here; the trajectory check reports every sample over the limit."""

from __future__ import annotations

import math
import warnings

import mujoco
import numpy as np
import pytest

from reflexarm.errors import ConfigError
from reflexarm.robots import load_robot
from reflexarm.safety import (
    check_trajectory_speed,
    effective_mass,
    moving_mass,
    permissible_speed,
    permissible_speed_for_mass,
    standard_robot_mass,
)
from reflexarm.sim import Plant

L1, L2, M1, M2 = 0.5, 0.4, 3.0, 2.0  # [m], [kg]: point masses at the link ends

TWO_LINK = f"""<mujoco model="two_link">
  <worldbody>
    <body name="link1">
      <joint name="j1" type="hinge" axis="0 0 1"/>
      <inertial pos="{L1} 0 0" mass="{M1}" diaginertia="1e-6 1e-6 1e-6"/>
      <body name="link2" pos="{L1} 0 0">
        <joint name="j2" type="hinge" axis="0 0 1"/>
        <inertial pos="{L2} 0 0" mass="{M2}" diaginertia="1e-6 1e-6 1e-6"/>
        <site name="tip" pos="{L2} 0 0"/>
      </body>
    </body>
  </worldbody>
</mujoco>"""

#: Relative tolerance against the hand-written arm: its links carry 1e-6 kg m^2 of rotational inertia that the
#: point-mass formula leaves out (relative effect < 1e-5).
POINT_MASS_RTOL = 1e-4


def _two_link_mass(q: np.ndarray, u: np.ndarray) -> float:
    c2 = math.cos(q[1])
    M = np.array(
        [
            [M1 * L1**2 + M2 * (L1**2 + L2**2 + 2 * L1 * L2 * c2), M2 * (L2**2 + L1 * L2 * c2)],
            [M2 * (L2**2 + L1 * L2 * c2), M2 * L2**2],
        ]
    )
    s1, c1, s12, c12 = math.sin(q[0]), math.cos(q[0]), math.sin(q[0] + q[1]), math.cos(q[0] + q[1])
    J = np.array([[-L1 * s1 - L2 * s12, -L2 * s12], [L1 * c1 + L2 * c12, L2 * c12], [0.0, 0.0]])
    return 1.0 / float(u @ J @ np.linalg.solve(M, J.T @ u))


@pytest.mark.parametrize("q", [(0.3, 0.9), (-1.0, 2.0), (0.0, 0.2)])
@pytest.mark.parametrize("u", [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.6, -0.8, 0.0)])
def test_two_link_arm_against_the_hand_written_formula(tmp_path, q, u):
    path = tmp_path / "two_link.xml"
    path.write_text(TWO_LINK)
    robot = load_robot(path, ee_frame="link2")
    qa, ua = np.array(q), np.array(u)
    got = effective_mass(robot, qa, "link2", (L2, 0.0, 0.0), ua)
    np.testing.assert_allclose(got, _two_link_mass(qa, ua), rtol=POINT_MASS_RTOL)
    assert moving_mass(robot) == pytest.approx(M1 + M2)


def test_a_direction_the_arm_cannot_move_has_infinite_mass(tmp_path):
    path = tmp_path / "two_link.xml"
    path.write_text(TWO_LINK)
    robot = load_robot(path, ee_frame="link2")
    assert effective_mass(robot, np.zeros(2), "link2", (L2, 0.0, 0.0), (0.0, 0.0, 1.0)) == math.inf
    with pytest.raises(ConfigError, match="direction must be a non-zero 3-vector"):
        effective_mass(robot, np.zeros(2), "link2", (L2, 0.0, 0.0), (0.0, 0.0, 0.0))


#: Relative tolerance against MuJoCo: the same file, two rigid-body libraries; both are exact to round-off.
MUJOCO_RTOL = 1e-9


@pytest.mark.parametrize("name", ["panda", "atlas_v5_left_arm", "iiwa14"])
def test_against_mujoco_mass_matrix_and_jacobian(name):
    robot = load_robot(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plant = Plant(robot)
    m, d = plant.model, plant.data
    rng = np.random.default_rng(3)
    dofs = np.asarray(plant._arm_dofs)
    site = m.site(robot.ee_frame).id if robot.ee_frame in [m.site(i).name for i in range(m.nsite)] else plant._ee_site
    for _ in range(4):
        q = robot.home + rng.uniform(-0.3, 0.3, robot.n)
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        d.qpos[plant._qadr_arr] = q
        mujoco.mj_forward(m, d)
        jacp = np.zeros((3, m.nv))
        mujoco.mj_jacSite(m, d, jacp, None, site)
        minv = np.zeros((m.nv, m.nv))
        mujoco.mj_solveM(m, d, minv, np.eye(m.nv))
        J = jacp[:, dofs]
        reference = 1.0 / float(u @ J @ minv[np.ix_(dofs, dofs)] @ J.T @ u)
        got = effective_mass(robot, q, robot.ee_frame, (0.0, 0.0, 0.0), u)
        np.testing.assert_allclose(got, reference, rtol=MUJOCO_RTOL, err_msg=f"{name} at q={q.tolist()}")


def test_standard_mass_is_half_the_moving_mass_read_by_mujoco():
    robot = load_robot("panda")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plant = Plant(robot)
    arm_mass = float(plant.model.body_mass[np.asarray(plant._arm_bodies)].sum())
    assert standard_robot_mass(robot, payload=1.5) == pytest.approx(arm_mass / 2 + 1.5, rel=1e-12)
    with pytest.raises(ConfigError, match="payload must be a non-negative mass"):
        standard_robot_mass(robot, payload=-1.0)


def test_permissible_speed_is_the_a3_formula():
    # chest: F_T = 280 N, k = 25 N/mm, m_H = 40 kg (Annex A), m_R = 2 kg: v = 280 / sqrt(mu k)
    mu = 1.0 / (1.0 / 40.0 + 1.0 / 2.0)
    assert permissible_speed_for_mass(2.0, "chest") == pytest.approx(280.0 / math.sqrt(mu * 25000.0), rel=1e-12)
    robot = load_robot("panda")
    q, u = robot.home, np.array([0.0, 1.0, 0.0])
    m_r = effective_mass(robot, q, "ee", (0.0, 0.0, 0.0), u)
    mu_h = 1.0 / (1.0 / 0.6 + 1.0 / m_r)  # hand: F_T 280 N, k 75 N/mm, m_H 0.6 kg
    expected = 280.0 / math.sqrt(mu_h * 75000.0)
    assert permissible_speed(robot, q, "ee", (0.0, 0.0, 0.0), u, "hand") == pytest.approx(expected, rel=1e-12)


def test_a_trajectory_faster_than_any_limit_is_reported_per_sample():
    robot = load_robot("panda")
    t = np.linspace(0.0, 0.5, 51)
    dq = np.zeros((t.size, robot.n))
    dq[:, 0] = 6.0  # [rad/s]: the end effector at several m/s
    q = robot.home + dq * t[:, None]
    check = check_trajectory_speed(robot, t, q, dq, "skull")
    assert check.exceeded.all()
    v = check.violations()
    assert [x["sample"] for x in v] == list(range(t.size))
    assert all(x["speed_m_s"] > x["permissible_speed_m_s"] for x in v)  # reported as moved, never clipped
    # the end effector's speed against central differences of its positions (h = 1e-6 s: truncation ~1e-10 m/s)
    ee, h = check.points.index("ee"), 1e-6
    fd = [
        np.linalg.norm(robot.compute_frame_pose(qk + h * dk)[1] - robot.compute_frame_pose(qk - h * dk)[1]) / (2 * h)
        for qk, dk in zip(q, dq, strict=True)
    ]
    np.testing.assert_allclose(check.speed[:, ee], fd, rtol=1e-6)
    assert check.summary()["samples_over_limit"] == t.size
    with pytest.raises(ConfigError, match=r"q is not finite at sample\(s\) \[3\]"):
        q[3, 2] = np.nan
        check_trajectory_speed(robot, t, q, dq, "skull")
