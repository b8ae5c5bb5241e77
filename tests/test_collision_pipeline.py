"""The collision pipeline end to end in the closed loop: a detection classified, located and reacted to, on an
arm without joint friction (where gravity compensation alone leaves the arm moving) and on the Panda.

Each test fails on the code before the pipeline (no ``brake``/``retract`` reaction, no event record, no
contact estimate) and on a broken variant named in its comment.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from reflexarm import load_robot
from reflexarm.control.collision import CollisionEvent, Determined
from reflexarm.experiments.collision import CollisionSetting, run_ee_collision
from reflexarm.experiments.collision_events import collision_outcome

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")


def _demo(robot, reaction: str, plant_friction: str = "none"):
    setting = CollisionSetting("Coll.Det", stiffness=300.0, observer_gain=5.0, threshold=11.0, reaction=reaction)
    trace = run_ee_collision(setting, robot=robot, plant_friction=plant_friction)
    return trace, collision_outcome(trace, robot)


@pytest.fixture(scope="module")
def iiwa():
    return load_robot("iiwa14")


@pytest.fixture(scope="module")
def gravity_run(iiwa):
    return _demo(iiwa, "gravity")


@pytest.fixture(scope="module")
def brake_run(iiwa):
    return _demo(iiwa, "brake")


def test_gravity_reaction_on_frictionless_arm_is_reported_as_moving(iiwa, gravity_run):
    # the finding: gravity compensation (13) keeps the momentum of an arm without joint friction; the
    # guard must say so (fails if the guard is removed or its energy is not the arm's)
    trace, outcome = gravity_run
    event = CollisionEvent.from_dict(trace.meta["collision_event"])
    assert event.reaction == "gravity" and event.phase == "gravity"
    assert outcome.kinetic_energy_ratio is not None and outcome.kinetic_energy_ratio > 0.5  # truth: still moving
    assert event.still_moving and event.guard_checked
    assert event.text.startswith("reaction gravity left the arm moving: kinetic energy")


def test_brake_brings_frictionless_arm_to_rest_without_second_strike(gravity_run, brake_run):
    # the same contact with "brake": damping injection then hold. Truth from the plant: the kinetic energy
    # 0.5 s after detection is a small fraction of the one at detection and of the gravity run's (measured
    # 1.6 % on this arm: the guard's floor, not the 1 % of the issue, is what the in-controller guard uses),
    # no re-contact, no joint above its velocity limit (fails with brake_time 100x larger: the arm drifts on)
    _, grav = gravity_run
    trace, out = brake_run
    event = CollisionEvent.from_dict(trace.meta["collision_event"])
    assert event.reaction == "brake" and event.phase == "holding" and not event.still_moving
    assert out.kinetic_energy_ratio is not None and out.kinetic_energy_ratio < 0.05
    assert grav.kinetic_energy_ratio is not None and out.kinetic_energy_ratio < 0.01 * grav.kinetic_energy_ratio
    assert not out.recontact
    assert out.peak_speed_ratio is not None and out.peak_speed_ratio < 1.0
    assert out.moved_after_detection_m is not None and out.moved_after_detection_m < 0.01  # [m] stopped within 1 cm
    assert set(trace.mode[trace.collision]) <= {"braking", "holding", "precise_stiff", "compliant"}


def test_measured_contact_is_classified_and_located_by_the_wrist_sensor(iiwa, brake_run):
    # the demo's block is touched by the tool, beyond the wrist sensor: class "contact"; the estimate's force is
    # the measured one in the world frame, within the sensor noise (2.3 N per component, uniform) of the true
    # force on the bodies beyond the sensor (fails if the sensor's rotation is dropped: x then differs by 5.9 N)
    trace, _ = brake_run
    event = CollisionEvent.from_dict(trace.meta["collision_event"])
    assert event.contact_class == "contact" and event.wrist_force > 10.0
    est = trace.meta["contact_estimate"]
    assert est["determined"] == Determined.POINT_AND_FORCE.value and est["link_name"] == iiwa.sensor_frame
    i = int(np.searchsorted(trace.t, event.t_detect))
    f_true = trace.f_ext_ee[i]
    np.testing.assert_allclose(est["force"], f_true, atol=2.3 * np.sqrt(3) + 0.5)
    # the line of action passes within the tool's reach of the sensor (the point is on that line)
    _, p_sensor = iiwa.compute_frame_pose(event.q_detect, iiwa.sensor_frame)
    assert np.linalg.norm(np.asarray(est["point"]) - p_sensor) < 0.3


def test_held_stick_is_a_static_obstacle_the_link_runs_into():
    # the link collision with stick="held": the stick's tip does not move while it stands in the way, the moving
    # link runs into it and the collision is detected, classified as a collision (the wrist measures nothing)
    from reflexarm.experiments.collision import LINK_SETTING, run_link_collision

    trace = run_link_collision(setting=LINK_SETTING, stick="held")
    tip = trace.extras["elbow_stick_tip"]
    present = np.linalg.norm(tip, axis=1) < 10.0  # parked 50 m away otherwise
    assert present.sum() > 1000 and np.ptp(tip[present], axis=0).max() < 1e-9  # [m] it stands still
    event = CollisionEvent.from_dict(trace.meta["collision_event"])
    assert event.contact_class == "collision" and trace.meta["stick"] == "held"
    assert np.abs(trace.tau_ext[trace.collision.argmax()]).max() > 11.0  # true contact torque at detection
    with pytest.raises(Exception, match="unknown stick 'thrown'; choose one of: pushed, held"):
        run_link_collision(setting=LINK_SETTING, stick="thrown")


def test_a_held_stick_stands_on_the_path_of_a_link_swung_on_a_tight_circle():
    # the Panda's link 4 swings about joint 3 on a circle of a few cm: a stick on the tangent at the pushed stick's
    # start never touched it (the reaction study read "no detection"); the held stick stands where the link's
    # leading surface will pass, so the link runs into it and the collision is detected
    from reflexarm import load_robot
    from reflexarm.experiments.collision import LINK_SETTING, run_link_collision
    from reflexarm.experiments.link_push import held_stick_tip, link_push_plan

    panda = load_robot("panda")
    plan = link_push_plan(panda)
    trace = run_link_collision(setting=LINK_SETTING, stick="held", robot=panda)
    placement = trace.meta["placement"]
    assert 1.0 <= placement["held_stick_from_s"] < 1.01  # [s] the reference starts to move at 1 s
    tip, direction = held_stick_tip(panda, plan.body, plan.trajectory, placement["held_stick_from_s"])
    assert abs(np.linalg.norm(direction) - 1.0) < 1e-12
    np.testing.assert_allclose(placement["held_stick_tip_m"], tip, atol=1e-12)
    assert np.abs(trace.tau_ext).max() > 5.0 and trace.collision.any()  # [Nm] a real contact, detected


MENAGERIE_IIWA = Path(__file__).resolve().parents[1].parent / "shared" / "reference" / "menagerie" / "iiwa14.xml"


@pytest.fixture(scope="module")
def menagerie_iiwa():
    if not MENAGERIE_IIWA.is_file():
        pytest.skip(f"{MENAGERIE_IIWA} not found (../shared beside the project)")
    from reflexarm.robots import RobotModel

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return RobotModel.from_file(MENAGERIE_IIWA, ee_frame="attachment_site")


@pytest.mark.parametrize("reaction", ["gravity", "brake", "retract", "compliant"])
def test_the_vendor_iiwa14_second_strike_is_gone(menagerie_iiwa, reaction):
    # the finding on the vendor's (MuJoCo Menagerie) iiwa14 as shipped, whose joints have no friction:
    # after (13) the arm drifts and strikes the block again at ~178 N; brake / retract / compliant end it: no
    # re-contact, no force after detection above the largest before it (fails with any of them replaced by (13))
    trace, out = _demo(menagerie_iiwa, reaction, plant_friction="file")
    i = int(trace.collision.argmax())
    f = np.linalg.norm(trace.f_ext_ee, axis=1)
    if reaction == "gravity":
        assert out.recontact and f[i:].max() > 100.0  # [N] the second strike
        return
    assert not out.recontact
    assert f[i:].max() <= f[: i + 1].max() + 1.0  # [N] (1 N: the padding's rebound within the tick)
