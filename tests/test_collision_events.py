"""CollisionOutcome from traces this test builds itself: known contact times, forces, motions, on a planar
two-link arm whose kinetic energy and link positions are written down by hand.

The arm: two hinges about the vertical z axis (gravity plays no part), link lengths l1 = 1 m, the end
effector at 1 m along link 2; link i has mass m_i at lc_i = 0.5 m along it and a central inertia I = 0.01 kg
m^2 about z. Its mass matrix (textbook planar two-link):
    M11 = I + m1 lc^2 + I + m2 (l1^2 + lc^2 + 2 l1 lc cos q2),  M12 = I + m2 (lc^2 + l1 lc cos q2),
    M22 = I + m2 lc^2.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from reflexarm.errors import ConfigError, DataError
from reflexarm.experiments.collision_events import (
    KE_RESIDUAL_SHARE,
    KE_WINDOW_S,
    RELEASE_MIN_S,
    RELEASE_SHARE,
    CollisionOutcome,
    collision_outcome,
    write_outcomes,
)
from reflexarm.robots import load_robot
from reflexarm.sim import Trace

M1, M2, LC, L1, INERTIA = 2.0, 1.0, 0.5, 1.0, 0.01
V_LIMIT = (2.0, 4.0)
DT = 1e-3

ARM = f"""<mujoco model="planar2">
  <compiler angle="radian" inertiafromgeom="false"/>
  <worldbody>
    <body name="b1">
      <joint name="j1" type="hinge" axis="0 0 1"/>
      <inertial pos="{LC} 0 0" mass="{M1}" diaginertia="{INERTIA} {INERTIA} {INERTIA}"/>
      <body name="b2" pos="{L1} 0 0">
        <joint name="j2" type="hinge" axis="0 0 1"/>
        <inertial pos="{LC} 0 0" mass="{M2}" diaginertia="{INERTIA} {INERTIA} {INERTIA}"/>
        <site name="ee" pos="1 0 0"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

#: Rounding of the sums and products below (energies of O(1) J, distances of O(1) m): 1e-12 is far above
#: double round-off and far below any mistaken sample (one tick moves the arm by ~1e-4).
TOL = 1e-12


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    path = tmp_path_factory.mktemp("arm") / "planar2.xml"
    path.write_text(ARM)
    robot = load_robot(path, ee_frame="ee")
    robot.pin_model.velocityLimit = np.array(V_LIMIT)
    return robot


def mass_matrix(q2: float) -> np.ndarray:
    c = math.cos(q2)
    m11 = INERTIA + M1 * LC**2 + INERTIA + M2 * (L1**2 + LC**2 + 2 * L1 * LC * c)
    m12 = INERTIA + M2 * (LC**2 + L1 * LC * c)
    return np.array([[m11, m12], [m12, INERTIA + M2 * LC**2]])


def make_trace(q, dq, force, tau_ext, detect_at, crossed=(0,), extras=None, meta=None) -> Trace:
    N, n = q.shape
    t = np.arange(N) * DT
    collision = np.zeros(N, bool)
    collided = np.zeros((N, n), bool)
    if detect_at is not None:
        collision[detect_at:] = True
        collided[detect_at:, list(crossed)] = True
    f = np.zeros((N, 3))
    f[:, 0] = force
    zeros = np.zeros((N, n))
    return Trace(
        t=t, q=q, dq=dq, q_meas=q, q_d=q, dq_d=dq, tau=zeros, tau_m=zeros, residual=zeros,
        collision=collision, collided=collided, mode=np.full(N, "compliant"), fault=np.full(N, ""),
        wrench=np.zeros((N, 6)), f_ext_ee=f, tau_ext=tau_ext, extras=extras or {}, meta=meta or {"name": "hand"},
    )  # fmt: skip


# ------------------------------------------------------------------------------------------ the hand-made run
# 2 s at 1 kHz, q2 = 0 (arm stretched). Joint 1 turns at W = 0.4 rad/s until detection at t = 1.0 s (tick
# 1000), then its speed decays as W exp(-(t - 1)/TAU). The wrist is pushed from t = 0.8 s: |f| = 3 + 100 (t
# - 0.8) N until detection (23 N at it), rising to 25 N at 1.1 s, down to 0 at 1.3 s, 0 until 1.6 s, then a
# second strike: a 30 N triangle peaking at 1.65 s, 0 from 1.7 s. tau_ext on joint 1 is half the force.
N, I_DET, W, TAU = 2000, 1000, 0.4, 0.1


def force_profile(t: np.ndarray) -> np.ndarray:
    return np.select(
        [t < 0.8, t <= 1.0, t <= 1.1, t <= 1.3, t <= 1.6, t <= 1.65, t <= 1.7],
        [0.0, 3 + 100 * (t - 0.8), 23 + 20 * (t - 1.0), 25 * (1.3 - t) / 0.2, 0.0, 30 * (t - 1.6) / 0.05,
         30 * (1.7 - t) / 0.05],
        0.0,
    )  # fmt: skip


def swing_motion(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = np.clip(t - 1.0, 0.0, None)
    dq1 = np.where(t < 1.0, W, W * np.exp(-s / TAU))
    q1 = np.where(t < 1.0, W * t, W + W * TAU * (1 - np.exp(-s / TAU)))
    q = np.column_stack([q1, np.zeros_like(t)])
    return q, np.column_stack([dq1, np.zeros_like(t)])


@pytest.fixture(scope="module")
def ee_run(arm):
    t = np.arange(N) * DT
    q, dq = swing_motion(t)
    f = force_profile(t)
    tau = np.column_stack([0.5 * f, np.zeros(N)])
    tip = np.column_stack([t, 2 * t, 3 * t])
    return t, collision_outcome(make_trace(q, dq, f, tau, I_DET, extras={"stick_tip": tip}), arm)


def test_contact_is_the_first_tick_of_force_or_torque(ee_run):
    _, o = ee_run
    # tau_ext = 1.5 Nm > CONTACT_TORQUE_NM (1 Nm) at t = 0.8 s already; the force alone (> 5 N) would give 0.821
    assert o.contact_s == pytest.approx(0.8, abs=TOL)
    assert o.detected_s == pytest.approx(1.0, abs=TOL)
    assert o.delay_s == pytest.approx(0.2, abs=TOL)
    assert o.contact_class == "end_effector" and o.contact_link == "ee"
    assert o.joints_crossed == (1,)
    assert o.run == "hand"


def test_forces_at_and_after_detection(ee_run):
    _, o = ee_run
    assert o.force_at_detection_N == pytest.approx(23.0, abs=1e-9)  # 3 + 100 * 0.2
    assert o.peak_force_after_detection_N == pytest.approx(30.0, abs=1e-9)  # the second strike's peak
    assert o.peak_force_N == pytest.approx(30.0, abs=1e-9)
    assert o.external_torque_at_detection_Nm == pytest.approx(11.5, abs=1e-9)
    assert o.peak_external_torque_after_detection_Nm == pytest.approx(15.0, abs=1e-9)


def test_kinetic_energy_against_the_hand_mass_matrix(ee_run):
    _, o = ee_run
    m11 = mass_matrix(0.0)[0, 0]  # 2.77 kg m^2 stretched
    assert m11 == pytest.approx(0.01 + 0.5 + 0.01 + 2.25, abs=TOL)
    assert o.kinetic_energy_at_detection_J == pytest.approx(0.5 * m11 * W**2, abs=TOL)
    ke_after = 0.5 * m11 * (W * math.exp(-KE_WINDOW_S / TAU)) ** 2
    assert o.kinetic_energy_after_J == pytest.approx(ke_after, rel=1e-9)
    assert o.kinetic_energy_ratio == pytest.approx(math.exp(-2 * KE_WINDOW_S / TAU), rel=1e-9)
    # T falls as exp(-2 s / TAU): below 1 % at s > TAU ln(100) / 2 = 0.2303 s, the first tick is 0.231 s
    first = math.ceil(TAU * math.log(1 / KE_RESIDUAL_SHARE) / 2 / DT) * DT
    assert o.stopped_after_s == pytest.approx(first, abs=TOL)
    assert o.peak_kinetic_energy_after_detection_J < o.kinetic_energy_at_detection_J


def test_motion_after_detection(ee_run):
    _, o = ee_run
    # joint 1 travels W TAU (1 - exp(-(2 - 0.001 - 1)/TAU)) after detection; the end effector, 2 m out,
    # moves on a circle: its largest distance from where it was is the chord 2 * 2 sin(travel / 2)
    travel = W * TAU * (1 - math.exp(-(N - 1 - I_DET) * DT / TAU))
    assert o.joint_travel_after_detection_rad == pytest.approx(travel, abs=TOL)
    assert o.joint_travel_joint == 1
    assert o.moved_after_detection_m == pytest.approx(4 * math.sin(travel / 2), abs=TOL)
    # an end-effector contact: the end effector's distance at the run's end (the travel only grows: the largest)
    assert o.away_at_end_m == pytest.approx(4 * math.sin(travel / 2), abs=TOL)
    assert o.peak_speed_ratio == pytest.approx(W / V_LIMIT[0], abs=TOL)
    assert o.peak_speed_joint == 1 and o.peak_speed_rad_s == pytest.approx(W, abs=TOL)


def test_recontact_after_a_release(ee_run):
    _, o = ee_run
    # the force drops below 5 N at 1.26 s, is 0 from 1.3 to 1.6 s, rises above 5 N at 1.6 + 5/600 s
    assert o.recontact
    assert o.recontact_s == pytest.approx(1.609, abs=TOL)
    assert o.peak_after_recontact == pytest.approx(30.0, abs=1e-9)


def test_contact_point_is_the_scenes_recorded_tip(ee_run):
    _, o = ee_run
    assert o.contact_point == pytest.approx((1.0, 2.0, 3.0), abs=TOL)
    assert o.contact_point_source == "stick_tip"


# ------------------------------------------------------------------------------------------ a link collision
def link_run(arm, gap_ticks: int, meta=None, gap_level: float = 0.0):
    """Joint 2 turns at 0.5 rad/s (link 1 still); a torque on joint 2 only (a push on link 2): 4 Nm from
    t = 0.5 s, detection at 0.7 s, then it falls to ``gap_level`` for ``gap_ticks`` ticks at 1.0 s and
    comes back."""
    t = np.arange(1500) * DT
    q = np.column_stack([np.zeros_like(t), 0.5 * t])
    dq = np.column_stack([np.zeros_like(t), np.full_like(t, 0.5)])
    tau2 = np.where(t >= 0.5, 4.0, 0.0)
    tau2[1000 : 1000 + gap_ticks] = gap_level
    tau = np.column_stack([np.zeros_like(t), tau2])
    return collision_outcome(make_trace(q, dq, np.zeros_like(t), tau, 700, crossed=(1,), meta=meta), arm)


def test_away_at_end_follows_the_recorded_contact_point_on_its_link(arm):
    """The stick tip recorded at detection, 0.5 m out along link 2: fixed on b2, it turns with joint 2 (0.5 rad/s
    from detection at 0.7 s to the last sample at 1.499 s) on a circle of 0.5 m about joint 2's axis, while b2's
    origin, on that axis, stays put."""
    t = np.arange(1500) * DT
    q2_det = 0.5 * 0.7
    tip = np.tile([L1 + 0.5 * math.cos(q2_det), 0.5 * math.sin(q2_det), 0.0], (t.size, 1))
    q = np.column_stack([np.zeros_like(t), 0.5 * t])
    dq = np.column_stack([np.zeros_like(t), np.full_like(t, 0.5)])
    tau = np.column_stack([np.zeros_like(t), np.where(t >= 0.5, 4.0, 0.0)])
    o = collision_outcome(make_trace(q, dq, np.zeros_like(t), tau, 700, crossed=(1,), extras={"stick_tip": tip}), arm)
    assert o.contact_class == "link" and o.contact_link == "b2"
    assert o.moved_after_detection_m == pytest.approx(0.0, abs=TOL)
    turned = 0.5 * (1499 - 700) * DT
    assert o.away_at_end_m == pytest.approx(2 * 0.5 * math.sin(turned / 2), abs=TOL)


def test_link_collision_class_link_and_its_origin(arm):
    o = link_run(arm, gap_ticks=0)
    assert o.contact_class == "link"
    assert o.contact_s == pytest.approx(0.5, abs=TOL)
    assert o.joints_crossed == (2,)
    # the most distal joint with external torque is joint 2: its link b2, whose origin sits on joint 2's
    # axis and does not move when only joint 2 turns (its end effector would move 2 sin(0.4) m)
    assert o.contact_link == "b2"
    assert o.moved_after_detection_m == pytest.approx(0.0, abs=TOL)
    assert o.force_at_detection_N is None and o.peak_force_after_detection_N is None
    assert o.external_torque_at_detection_Nm == pytest.approx(4.0)
    # constant speed: T stays at 1/2 M22 0.5^2
    ke = 0.5 * mass_matrix(0.35)[1, 1] * 0.25
    assert o.kinetic_energy_at_detection_J == pytest.approx(ke, abs=TOL)
    assert o.kinetic_energy_ratio == pytest.approx(1.0, abs=TOL)
    assert o.stopped_after_s is None
    assert o.peak_speed_ratio == pytest.approx(0.5 / V_LIMIT[1], abs=TOL) and o.peak_speed_joint == 2
    assert not o.recontact and o.contact_point is None


def test_the_scenes_pushed_body_names_the_contact_link(arm):
    o = link_run(arm, gap_ticks=0, meta={"pushed_body": "b1"})
    assert o.contact_link == "b1"
    o = link_run(arm, gap_ticks=0, meta={"placement": {"body": "b1"}})
    assert o.contact_link == "b1"


@pytest.mark.parametrize(
    ("gap_ticks", "expected"),
    [(int(RELEASE_MIN_S / DT) - 10, False), (int(RELEASE_MIN_S / DT), True), (300, True)],
)
def test_recontact_needs_a_release_of_RELEASE_MIN_S(arm, gap_ticks, expected):
    o = link_run(arm, gap_ticks)
    assert o.recontact is expected
    if expected:
        assert o.recontact_s == pytest.approx(1.0 + gap_ticks * DT, abs=TOL)
        assert o.peak_after_recontact == pytest.approx(4.0)


@pytest.mark.parametrize("share", [0.9, 1.0, RELEASE_SHARE + 0.01])
def test_a_resting_contact_at_its_level_is_no_recontact(arm, share):
    """The torque sits at (or just under) the 1 Nm contact level for 300 ms: not a release, so the rise
    back to 4 Nm is the same contact (the Atlas demo's Coll.Det rests on the block at 4.6-5.2 N)."""
    assert not link_run(arm, 300, gap_level=share * 1.0).recontact


def test_undetected_and_contact_free_runs(arm):
    t = np.arange(600) * DT
    q = np.zeros((600, 2))
    o = collision_outcome(make_trace(q, q, np.zeros(600), q, None), arm)
    assert o.contact_class == "none" and o.contact_s is None and o.detected_s is None
    assert o.kinetic_energy_at_detection_J is None and not o.recontact
    f = np.where(t > 0.3, 10.0, 0.0)
    o = collision_outcome(make_trace(q, q, f, q, None), arm)
    assert o.contact_class == "end_effector" and o.contact_s == pytest.approx(0.301, abs=TOL)
    assert o.delay_s is None and o.force_at_detection_N is None
    # detected, but the run ends before +0.5 s: no energy there
    o = collision_outcome(make_trace(q, q, f, q, 400), arm)
    assert o.kinetic_energy_at_detection_J == 0.0 and o.kinetic_energy_after_J is None


def test_bad_input_is_named(arm):
    q = np.zeros((10, 3))
    with pytest.raises(DataError, match="the trace has 3 joints; robot 'planar2' has 2"):
        collision_outcome(make_trace(q, q, np.zeros(10), q, None), arm)
    with pytest.raises(DataError, match="needs a Trace; got dict"):
        collision_outcome({}, arm)  # type: ignore[arg-type]


def test_write_outcomes_json_and_csv(ee_run, tmp_path: Path):
    _, o = ee_run
    rows = [o, {"arm": "x", **o.as_dict()}]
    doc = json.loads(write_outcomes(rows, tmp_path / "o.json").read_text())
    assert doc[0]["joints_crossed"] == [1] and doc[1]["arm"] == "x"
    assert CollisionOutcome(**{**doc[0], "joints_crossed": (1,), "contact_point": tuple(doc[0]["contact_point"])}) == o
    text = write_outcomes(rows, tmp_path / "o.csv").read_text().splitlines()
    assert text[0].startswith("run,contact_class,") and "arm" in text[0]
    assert len(text) == 3
    with pytest.raises(ConfigError, match=r"unknown outcome file type '.txt' for .*; use .json or .csv"):
        write_outcomes(rows, tmp_path / "o.txt")


# ------------------------------------------------------------------------------------------ the obstacle's advance
def _stick_tip(n: int, appear: int, push: int, speed_per_tick: float) -> np.ndarray:
    """A stick tip parked 50 m below until tick ``appear``, then advancing along +x by ``speed_per_tick`` [m] a tick
    for ``push`` ticks, back the same way, then parked again (as ElbowStick records it)."""
    tip = np.tile([0.0, 0.0, -50.0], (n, 1))
    for k in range(appear, n):
        s = k - appear
        if s <= push:
            x = speed_per_tick * s
        elif s <= 2 * push:
            x = speed_per_tick * (2 * push - s)
        else:
            break
        tip[k] = [x, 0.3, 0.5]
    return tip


@pytest.mark.parametrize(
    "detect_at, expected",
    [
        (700, (900 - 700) * 1e-4),  # 200 ticks of the push left at 0.1 mm a tick: 2 cm further
        (880, (900 - 880) * 1e-4),  # late: 2 mm further, not the 4 cm back to where it appeared
        (1050, 0.0),  # on its way back: no further
    ],
)
def test_the_obstacle_s_advance_after_detection(arm, detect_at, expected):
    t = np.arange(1500) * DT
    q = np.column_stack([np.zeros_like(t), 0.5 * t])
    dq = np.column_stack([np.zeros_like(t), np.full_like(t, 0.5)])
    tau = np.column_stack([np.zeros_like(t), np.where(t >= 0.5, 4.0, 0.0)])
    tip = _stick_tip(t.size, appear=500, push=400, speed_per_tick=1e-4)
    trace = make_trace(q, dq, np.zeros_like(t), tau, detect_at, crossed=(1,), extras={"stick_tip": tip})
    o = collision_outcome(trace, arm)
    assert o.obstacle_advance_after_detection_m == pytest.approx(expected, abs=TOL)


def test_an_obstacle_that_stands_still_or_is_not_recorded(arm):
    t = np.arange(1500) * DT
    q = np.column_stack([np.zeros_like(t), 0.5 * t])
    dq = np.column_stack([np.zeros_like(t), np.full_like(t, 0.5)])
    tau = np.column_stack([np.zeros_like(t), np.where(t >= 0.5, 4.0, 0.0)])
    held = np.tile([0.2, 0.3, 0.5], (t.size, 1))
    held[:400] = [0.0, 0.0, -50.0]
    o = collision_outcome(make_trace(q, dq, np.zeros_like(t), tau, 700, crossed=(1,), extras={"stick_tip": held}), arm)
    assert o.obstacle_advance_after_detection_m == 0.0
    o = collision_outcome(make_trace(q, dq, np.zeros_like(t), tau, 700, crossed=(1,)), arm)
    assert o.obstacle_advance_after_detection_m is None
    assert o.as_dict()["obstacle_advance_after_detection_m"] is None
