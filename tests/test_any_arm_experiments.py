"""The experiment commands on arms other than Atlas: Panda (built-in), the Menagerie iiwa14 (no effort
limits: the controller warns) and the UR5-like 6-DoF arm the project writes (a gripper cut off with
``--tip tool0``). The scenes place themselves from each arm's kinematics (any_arm); each command runs
from the CLI and the contact happens (true force/torque > 0) and is detected.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest

from conftest import SHARED
from reflexarm.cli import main
from reflexarm.errors import ConfigError
from reflexarm.experiments.any_arm import (
    EE_PEAK_SPEED,
    VELOCITY_SHARE,
    ee_swing_plan,
    is_paper_arm,
    start_posture,
    work_posture,
)
from reflexarm.experiments.block_placement import place_cinderblock
from reflexarm.experiments.collision import free_motion_trajectory
from reflexarm.experiments.collision_summary import (
    CONTACT_FORCE_N,
    summarize_ee_collision,
    summarize_link_collision,
    write_outputs,
)
from reflexarm.experiments.compensation import CompensationSetup, held_posture, robot_options, true_robot
from reflexarm.experiments.link_push import STICK_GAP_M, link_body, link_push_plan
from reflexarm.experiments.velocity_tracking import VelocityTrackingSetup
from reflexarm.robots import load_robot
from reflexarm.robots.example_arms import UR_LIKE_TIP, write_ur_like_arm
from reflexarm.sim import Cinderblock, JointTrajectory, Plant, Trace, run_closed_loop

IIWA = SHARED / "reference" / "menagerie" / "iiwa14.xml"
ARMS = ("panda", "iiwa14", "ur_like")


def robot_args(arm: str, folder: Path) -> list[str]:
    """The robot options of ``arm`` on the command line."""
    if arm == "panda":
        return ["--robot", "panda"]
    if arm == "iiwa14":
        if not IIWA.is_file():
            pytest.skip(f"{IIWA} is absent")
        return ["--robot", str(IIWA), "--ee-frame", "attachment_site"]
    return ["--robot", str(write_ur_like_arm(folder)), "--tip", UR_LIKE_TIP]


def load(arm: str, folder: Path):
    args = robot_args(arm, folder)
    kwargs: dict[str, Any] = {}
    if arm == "iiwa14":
        kwargs["ee_frame"] = args[3]
    elif arm == "ur_like":
        kwargs["tip"] = UR_LIKE_TIP
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_robot(args[1], **kwargs)


def run_cli(argv: list[str], caught: list[str] | None = None) -> int:
    """``reflexarm ARGV``; the warnings' messages are appended to ``caught``."""
    with warnings.catch_warnings(record=True) as records:
        warnings.simplefilter("always")
        code = main(argv)
    if caught is not None:
        caught.extend(str(w.message) for w in records)
    return code


@pytest.mark.slow
@pytest.mark.parametrize("arm", ARMS)
def test_demo_hits_the_self_placed_block_with_the_wrist_and_detects_it(arm, tmp_path):
    out = tmp_path / "demo"
    assert run_cli(["demo", *robot_args(arm, tmp_path), "--out", str(out), "--quiet"]) == 0
    rows = {r["run"]: r for r in json.loads((out / "ee_collision_summary.json").read_text())}
    assert set(rows) == {"Stiff", "Compliant", "Coll.Det"}
    for name, row in rows.items():
        # the block stands on the end effector's path: the wrist (bodies beyond the sensor) touches it
        assert row["peak_force_N"] > CONTACT_FORCE_N, (name, row)
        assert row["first_contact_s"] is not None, (name, row)
    det = rows["Coll.Det"]
    assert det["detection_s"] is not None, det
    # detected because of the contact: not before it (no false alarm on the way)
    assert det["detection_s"] >= det["first_contact_s"], det
    assert rows["Stiff"]["detection_s"] is None  # detection off


@pytest.mark.slow
@pytest.mark.parametrize("arm", ARMS)
def test_link_collision_pushes_the_mid_chain_link_and_detects_it(arm, tmp_path):
    out = tmp_path / "link"
    assert run_cli(["simulate", "link-collision", *robot_args(arm, tmp_path), "--out", str(out), "--quiet"]) == 0
    (row,) = json.loads((out / "link_collision_summary.json").read_text())
    assert row["contact_start_s"] is not None, row
    assert row["peak_external_torque_Nm"] > 1.0, row  # the contact threshold of the summary [Nm]
    assert row["detection_s"] is not None and row["detection_s"] >= row["contact_start_s"], row
    tr = Trace.load(next(out.glob("link_collision_*.npz")))
    robot = load(arm, tmp_path)
    k = (robot.n + 1) // 2  # the default link: joint ceil(n/2)
    assert tr.meta["placement"]["link"] == k
    # the stick pushes link k: the joints after it see no torque of that push (it acts on their parent);
    # the 0.6 m stick may graze the next link, hence half, not zero
    assert np.abs(tr.tau_ext[:, k:]).max() < 0.5 * np.abs(tr.tau_ext[:, :k]).max()


@pytest.mark.slow
@pytest.mark.parametrize("arm", ARMS)
def test_efc_step_on_the_arm(arm, tmp_path):
    out = tmp_path / "efc"
    caught: list[str] = []
    assert run_cli(["efc-step", *robot_args(arm, tmp_path), "--out", str(out), "--quiet"], caught) == 0
    # the Menagerie iiwa14 has no effort limits: the controller says its torque is not saturated
    unsaturated = [m for m in caught if "has no finite positive effort limit" in m]
    assert bool(unsaturated) == (arm == "iiwa14"), unsaturated
    doc = json.loads((out / "efc_step.json").read_text())
    rows = {r["run"]: r for r in doc["rows"]}
    assert doc["setup"]["robot"] != "atlas_v5_left_arm"
    # the 50 N step acts (the true external torque is not zero) and the arm yields to it without DC
    tr = Trace.load(out / "efc_step_no_dc.npz")
    assert np.abs(tr.tau_ext).max() > 1.0
    assert rows["no DC"]["ee_displacement_mm"] > 1.0
    # DC stiffens the arm (10) and EFC gives the compliance back (11): the paper's Fig. 12 on this arm.
    # Tolerances: DC keeps below 10 % of the displacement, EFC within 25 % of it (sensor noise of 2.3 N
    # on a 50 N step and +-10 % model errors).
    s = doc["summary"]
    assert s["dc_vs_nodc_displacement"] < 0.1, s
    assert 0.75 < s["efc_vs_nodc_displacement"] < 1.25, s


def test_start_posture_reads_the_home_keyframe_of_an_mjcf():
    if not IIWA.is_file():
        pytest.skip(f"{IIWA} is absent")
    robot = load("iiwa14", Path("."))
    # the file's <key name="home" qpos="0 0.785398 0 -1.5708 0 0 0"/>
    np.testing.assert_allclose(start_posture(robot), [0, 0.785398, 0, -1.5708, 0, 0, 0], atol=1e-12)


def test_start_posture_keeps_a_built_in_home(atlas):
    np.testing.assert_array_equal(start_posture(atlas), atlas.home)
    assert is_paper_arm(atlas) and not is_paper_arm(load_robot("panda"))


def test_work_posture_of_an_arm_without_home_points_the_tool_down(tmp_path):
    robot = load("ur_like", tmp_path)
    assert not np.any(robot.home)  # a URDF has no home: the working posture is derived
    q = work_posture(robot)
    R, p = robot.compute_frame_pose(q)
    # the tool axis (tool0's z, the sensor is at tool0) points down within 1 degree (IK converged)
    assert R[:, 2] @ np.array([0.0, 0.0, -1.0]) > np.cos(np.radians(1.0))
    assert p[2] > 0.0  # above the floor the scenes stand on
    np.testing.assert_array_equal(start_posture(robot), q)


#: The body that should meet the block first on each arm: the one beyond the wrist sensor.
WRIST_BODY = {"panda": "tool", "iiwa14": "link7", "ur_like": "gripper_base_link"}


@pytest.mark.parametrize("arm", ARMS)
def test_the_block_stands_across_the_end_effector_path_and_the_wrist_meets_it_first(arm, tmp_path):
    robot = load(arm, tmp_path)
    plan = ee_swing_plan(robot)
    traj = plan.trajectory()
    place = place_cinderblock(robot, traj, depth=0.12)
    # the end effector at the contact time is half a block width + padding from the block's centre,
    # horizontally along the path (the block's y axis)
    p = robot.compute_frame_pose(traj.sample(place["contact_time_s"]).q_d)[1]
    yaw = place["yaw"]
    y_axis = np.array([-np.sin(yaw), np.cos(yaw)])
    along = (np.asarray(place["position"]) - p[:2]) @ y_axis
    np.testing.assert_allclose(along, place["size"][1] / 2 + place["padding"], atol=1e-9)
    # the unobstructed reference, replayed kinematically (the plant reset at each sample): the first arm
    # geom that touches the block or its table is on the wrist, beyond the force/torque sensor
    kwargs = {k: v for k, v in place.items() if k not in ("contact_time_s", "depth", "ee_height_m")}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plant = Plant(robot, scene=Cinderblock(**kwargs))
    m, d = plant.model, plant.data
    scene_bodies = {m.body("cinderblock").id, 0}  # the block, and the world that holds the table
    first = None
    for t in np.linspace(0.0, traj.duration, 600):
        plant.reset(traj.sample(float(t)).q_d)
        mujoco.mj_forward(m, d)
        touching = []
        for c in d.contact[: d.ncon]:
            b1, b2 = int(m.geom_bodyid[c.geom1]), int(m.geom_bodyid[c.geom2])
            if b1 in scene_bodies and b2 not in scene_bodies:
                touching.append(m.body(b2).name)
            elif b2 in scene_bodies and b1 not in scene_bodies:
                touching.append(m.body(b1).name)
        if touching:
            first = (float(t), touching)
            break
    assert first is not None, "the arm never touches the block"
    assert set(first[1]) == {WRIST_BODY[arm]}, first
    # ... before the path would have run the whole depth into it
    assert first[0] < traj.duration


def test_free_motion_hydraulic_is_atlas_only(atlas):
    panda = load_robot("panda")
    with pytest.raises(ConfigError, match="free motion 'hydraulic' names Atlas' hydraulic joints; on 'panda' use"):
        free_motion_trajectory(10.0, "hydraulic", panda)
    traj = free_motion_trajectory(10.0, "loaded", panda)
    assert traj.duration >= 10.0
    same = free_motion_trajectory(10.0, "hydraulic", atlas)
    np.testing.assert_array_equal(free_motion_trajectory(10.0, "loaded", atlas).waypoints, same.waypoints)


def test_link_choice_is_checked():
    panda = load_robot("panda")
    assert link_body(panda, 4) == (3, "panda_link4")
    assert link_body(panda, "panda_link2") == (1, "panda_link2")
    with pytest.raises(ConfigError, match="link must be a joint number in 1..7 or a link name; got 9"):
        link_body(panda, 9)
    with pytest.raises(ConfigError, match="unknown link 'hand'; links are: panda_link1"):
        link_body(panda, "hand")


def test_summaries_of_a_users_own_trace_without_experiment_metadata(tmp_path):
    robot = load_robot("panda")
    from reflexarm.control import Controller

    plant = Plant(robot, seed=0)
    plant.reset(robot.home)
    ctrl = Controller(robot, stiffness=300.0, threshold=11.0, reaction="gravity")
    tr = run_closed_loop(plant, ctrl, JointTrajectory.hold(robot.home, 0.3), 0.3)
    assert "setting" not in tr.meta
    row = summarize_ee_collision(tr)  # raised KeyError 'setting' before
    assert row["run"] == "run"
    assert row["block_displacement_m"] is None and row["block_tipped"] is None
    assert row["first_contact_s"] is None and row["peak_force_N"] < CONTACT_FORCE_N
    assert summarize_link_collision(tr)["contact_start_s"] is None
    write_outputs(tmp_path, "mine", [tr], [row])
    assert (tmp_path / "mine_run1.npz").is_file()
    tr.meta["name"] = "my run"
    assert summarize_ee_collision(tr)["run"] == "my run"


@pytest.mark.parametrize("arm", ARMS)
def test_derived_motions_stay_inside_the_arms_limits(arm, tmp_path):
    robot = load(arm, tmp_path)
    lo, hi, vmax = robot.lower_limit, robot.upper_limit, robot.velocity_limit
    vmax = np.where(np.isfinite(vmax), vmax, np.inf)
    plan = ee_swing_plan(robot)
    link = link_push_plan(robot)
    setup = VelocityTrackingSetup.for_robot(robot)
    motion = setup.motion()
    for name, traj, duration in (
        ("ee swing", plan.trajectory(), plan.trajectory().duration),
        ("link push", link.trajectory, link.trajectory.duration),
        ("velocity tracking", motion, motion.duration),
    ):
        samples = [traj.sample(float(t)) for t in np.linspace(0.0, duration, 300)]
        q = np.array([s.q_d for s in samples])
        dq = np.array([s.dq_d for s in samples])
        assert np.all(q >= lo - 1e-9) and np.all(q <= hi + 1e-9), name
        # at most half the velocity limit (VELOCITY_SHARE); 1e-9 for the sampled quintic's round-off
        assert np.all(np.abs(dq) <= VELOCITY_SHARE * vmax + 1e-9), name
    # the swing's end effector peaks at the paper's moderate speed unless a velocity limit slows it
    traj = plan.trajectory()
    ts = np.linspace(0.0, traj.duration, 2000)
    P = np.array([robot.compute_frame_pose(traj.sample(float(t)).q_d)[1] for t in ts])
    peak = float(np.max(np.linalg.norm(np.diff(P, axis=0), axis=1) / np.diff(ts)))
    assert peak <= EE_PEAK_SPEED * 1.01  # 1 %: finite differences of the sampled path
    assert peak >= 0.5 * EE_PEAK_SPEED


def test_velocity_tracking_keeps_the_papers_setup_on_atlas(atlas):
    assert VelocityTrackingSetup.for_robot(atlas) == VelocityTrackingSetup()
    assert VelocityTrackingSetup.for_robot(atlas, 1).joint == 1
    with pytest.raises(ConfigError, match=r"joint must be in 1..7 \(1-based\); got 8"):
        VelocityTrackingSetup.for_robot(atlas, 7)


def test_a_link_chosen_on_atlas_uses_the_derived_push(atlas):
    plan = link_push_plan(atlas, 4)
    assert plan.body == "l_larm" and plan.link_joint == 3
    assert plan.standoff > STICK_GAP_M  # the gap plus the link's own extent along its motion


def test_compensation_setup_loads_the_users_arm_with_its_options(tmp_path):
    path = write_ur_like_arm(tmp_path)
    options = robot_options({"tip": UR_LIKE_TIP, "ee_frame": None, "locked": {"b": 0.0, "a": 0.1}})
    assert options == (("locked", (("a", 0.1), ("b", 0.0))), ("tip", UR_LIKE_TIP))
    setup = CompensationSetup(robot=str(path), robot_options=robot_options({"tip": UR_LIKE_TIP}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        robot = true_robot(setup)
    assert robot.n == 6 and robot.ee_frame == UR_LIKE_TIP
    np.testing.assert_array_equal(held_posture(setup, robot), start_posture(robot))


def test_block_depth_is_checked():
    panda = load_robot("panda")
    traj = ee_swing_plan(panda).trajectory()
    with pytest.raises(ConfigError, match=r"depth must be a positive distance \[m\]; got -0.1"):
        place_cinderblock(panda, traj, depth=-0.1)
    with pytest.raises(ConfigError, match=r"path is 0.\d+ m long; the block needs more than depth 5"):
        place_cinderblock(panda, traj, depth=5.0)
