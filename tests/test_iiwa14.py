"""The built-in KUKA LBR iiwa 14 R820 (``robots/assets/iiwa14.xml``).

References independent of the file: KUKA's published numbers typed here (link lengths, joint, velocity and
torque limits), the arm's standard Denavit-Hartenberg table chained by hand, Drake's published link masses,
and MuJoCo on the same file (the generic Pinocchio-vs-MuJoCo checks of every built-in run in
tests/test_model_agreement.py and tests/test_robots.py; the one below names the iiwa14 so that a missing
file fails here instead of being skipped there).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from reflexarm.experiments.any_arm import ee_swing_plan
from reflexarm.experiments.block_placement import place_cinderblock
from reflexarm.experiments.collision import EE_SETTINGS, LINK_SETTING, run_ee_collision, run_link_collision
from reflexarm.experiments.collision_summary import CONTACT_FORCE_N, summarize_ee_collision, summarize_link_collision
from reflexarm.experiments.link_push import link_push_plan
from reflexarm.robots import builtin_robots, load_robot
from reflexarm.sim import Cinderblock, Plant, SensorNoise
from test_model_agreement import ATOL as AGREEMENT_ATOL
from test_model_agreement import check_agreement

DEG = np.pi / 180.0

#: Two evaluations of the same kinematic chain (a hand-chained DH product vs Pinocchio's placements),
#: entries of O(1) m / O(1): double-precision round-off over 7 products is ~1e-15; 1e-12 leaves margin.
#: A wrong frame (a sign, a swapped offset) errs by centimetres or by O(1) in a rotation entry.
KINEMATICS_ATOL = 1e-12


@pytest.fixture(scope="module")
def iiwa():
    return load_robot("iiwa14")


def test_iiwa14_is_a_builtin_with_its_file():
    b = builtin_robots()["iiwa14"]
    assert b.path.is_file()
    assert (b.ee_frame, b.sensor_frame) == ("ee", "wrist_ft")


def test_published_limits(iiwa):
    lim = np.array([170, 120, 170, 120, 170, 120, 175]) * DEG
    np.testing.assert_allclose(iiwa.upper_limit, lim, rtol=1e-12)
    np.testing.assert_allclose(iiwa.lower_limit, -lim, rtol=1e-12)
    np.testing.assert_allclose(iiwa.velocity_limit, np.array([85, 85, 100, 75, 130, 135, 135]) * DEG, rtol=1e-12)
    np.testing.assert_allclose(iiwa.effort_limit, [320, 320, 176, 176, 110, 40, 40])
    assert np.all(iiwa.home > iiwa.lower_limit) and np.all(iiwa.home < iiwa.upper_limit)


def test_masses_are_drakes_and_friction_is_small(iiwa):
    # Drake's iiwa14 description, links 1..7; the 0.25 kg tool rides on link 7
    masses = [5.76, 6.35, 3.5, 3.5, 3.5, 1.8, 1.2 + 0.25]
    np.testing.assert_allclose(iiwa.inertial_parameters()[0::10], masses, rtol=1e-12)
    np.testing.assert_allclose(iiwa.friction.coulomb, [0.5, 0.5, 0.4, 0.4, 0.2, 0.15, 0.15])
    np.testing.assert_allclose(iiwa.friction.viscous, 0.1)
    # a low-friction arm: every joint's Coulomb level below 1 % of its torque limit
    assert np.all(iiwa.friction.coulomb < 0.01 * iiwa.effort_limit)


def test_link_lengths_are_kukas(iiwa):
    """Base-shoulder 0.36, shoulder-elbow 0.42, elbow-wrist 0.40, wrist-flange 0.126 m at any posture:
    distances between the centres of joints 2, 4, 6 (which lie on the arm's axis) and the flange."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = rng.uniform(iiwa.lower_limit, iiwa.upper_limit)
        p = {f: iiwa.compute_frame_pose(q, f)[1] for f in ("iiwa_link_2", "iiwa_link_4", "iiwa_link_6", "wrist_ft")}
        np.testing.assert_allclose(p["iiwa_link_2"], [0, 0, 0.36], atol=KINEMATICS_ATOL)
        np.testing.assert_allclose(np.linalg.norm(p["iiwa_link_4"] - p["iiwa_link_2"]), 0.42, atol=KINEMATICS_ATOL)
        np.testing.assert_allclose(np.linalg.norm(p["iiwa_link_6"] - p["iiwa_link_4"]), 0.40, atol=KINEMATICS_ATOL)
        np.testing.assert_allclose(np.linalg.norm(p["wrist_ft"] - p["iiwa_link_6"]), 0.126, atol=KINEMATICS_ATOL)


def test_flange_pose_matches_the_standard_denavit_hartenberg_table(iiwa):
    """KUKA's LBR iiwa 14 in standard DH (a = 0 on every joint; d = 0.36, 0, 0.42, 0, 0.40, 0, 0.126 m;
    alpha = -90, 90, 90, -90, -90, 90, 0 deg), chained by hand: position and orientation of the flange."""
    d = [0.36, 0.0, 0.42, 0.0, 0.40, 0.0, 0.126]
    alpha = np.array([-90, 90, 90, -90, -90, 90, 0]) * DEG

    def dh(d_i: float, alpha_i: float, theta: float) -> np.ndarray:
        ca, sa, ct, st = np.cos(alpha_i), np.sin(alpha_i), np.cos(theta), np.sin(theta)
        return np.array([[ct, -st * ca, st * sa, 0.0], [st, ct * ca, -ct * sa, 0.0], [0.0, sa, ca, d_i], [0, 0, 0, 1]])

    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.uniform(iiwa.lower_limit, iiwa.upper_limit)
        T = np.eye(4)
        for i in range(7):
            T = T @ dh(d[i], alpha[i], q[i])
        R, p = iiwa.compute_frame_pose(q, "wrist_ft")
        np.testing.assert_allclose(p, T[:3, 3], atol=KINEMATICS_ATOL, err_msg=f"flange position at q = {q}")
        np.testing.assert_allclose(R, T[:3, :3], atol=KINEMATICS_ATOL, err_msg=f"flange orientation at q = {q}")
        _, p_ee = iiwa.compute_frame_pose(q)
        np.testing.assert_allclose(p_ee, T[:3, 3] + 0.05 * T[:3, 2], atol=KINEMATICS_ATOL)


def test_pinocchio_and_mujoco_agree_on_the_iiwa14(iiwa):
    worst = check_agreement(iiwa, Plant(iiwa, noise=SensorNoise.none()))
    for key, err in worst.items():
        assert err <= AGREEMENT_ATOL, f"max |{key}_pinocchio - {key}_mujoco| = {err:.3g}"


def test_every_moving_link_has_collision_geometry(iiwa):
    plant = Plant(iiwa, noise=SensorNoise.none())
    m = plant.model
    for k in range(1, 8):
        body = m.body(f"iiwa_link_{k}").id
        geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] == body and m.geom_contype[g] != 0]
        assert geoms, f"iiwa_link_{k} has no collision geometry"
        # capsules of the real housings' size: radius 4.5-7 cm
        assert all(0.045 <= m.geom_size[g][0] <= 0.07 for g in geoms), f"iiwa_link_{k}"


def test_the_demo_block_stands_across_the_path_and_the_tool_meets_it_first(iiwa):
    traj = ee_swing_plan(iiwa).trajectory()
    place = place_cinderblock(iiwa, traj, depth=0.12)
    kwargs = {k: v for k, v in place.items() if k not in ("contact_time_s", "depth", "ee_height_m")}
    plant = Plant(iiwa, scene=Cinderblock(**kwargs), noise=SensorNoise.none())
    m, d = plant.model, plant.data
    scene_bodies = {m.body("cinderblock").id, 0}
    first = None
    for t in np.linspace(0.0, traj.duration, 600):
        plant.reset(traj.sample(float(t)).q_d)
        mujoco.mj_forward(m, d)
        touching = set()
        for c in d.contact[: d.ncon]:
            b1, b2 = int(m.geom_bodyid[c.geom1]), int(m.geom_bodyid[c.geom2])
            if (b1 in scene_bodies) != (b2 in scene_bodies):
                touching.add(m.body(b2 if b1 in scene_bodies else b1).name)
        if touching:
            first = (float(t), touching)
            break
    assert first is not None, "the arm never touches the block"
    assert first[1] == {"tool"}, first  # beyond the wrist sensor: an end-effector contact


def test_demo_coll_det_on_the_iiwa14_touches_then_detects():
    robot = load_robot("iiwa14")
    setting = next(s for s in EE_SETTINGS if s.name == "Coll.Det")
    row = summarize_ee_collision(run_ee_collision(setting, robot=robot))
    assert row["peak_force_N"] > CONTACT_FORCE_N and row["first_contact_s"] is not None, row
    assert row["detection_s"] is not None and row["detection_s"] >= row["first_contact_s"], row


def test_link_collision_on_the_iiwa14_pushes_the_mid_chain_link_and_detects_it():
    robot = load_robot("iiwa14")
    plan = link_push_plan(robot)
    assert plan.body == "iiwa_link_4"  # joint ceil(7/2) = 4 moves link 4
    tr = run_link_collision(robot=robot, setting=LINK_SETTING)
    row = summarize_link_collision(tr)
    assert row["contact_start_s"] is not None and row["detection_s"] is not None, row
    assert row["detection_s"] >= row["contact_start_s"], row
    # the stick pushes link 4: joints 5-7 see at most what grazing the next link gives (half, as in
    # tests/test_any_arm_experiments.py)
    assert np.abs(tr.tau_ext[:, 4:]).max() < 0.5 * np.abs(tr.tau_ext[:, :4]).max()
