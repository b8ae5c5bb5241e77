"""ISO/TS 15066 contacts in the plant against the two-mass model of Annex A.3, and the reactions on a clamped
region.

1. The scene and the effective mass: the arm released at the contact posture with the swing's velocity and
   only its gravity compensated (a free mass, as the standard's model assumes) hits the region's spring; the
   peak force is v sqrt(mu k) with mu from m_R(q, u).
2. The closed loop with detection off: the same swing under the study's impedance controller. The controller
   keeps driving the arm into the body during the impact, so the simulation lies above the free-mass
   prediction by its drive force; how far depends on how long the contact lasts (hand: ~8 ms, a few %;
   chest and abdomen: 20-40 ms, up to ~50 % on Atlas, see the README's pfl section); with the share of the
   measured drive force that a linearly rising force adds at the peak, within 15 %.
3. Clamping: a wall behind the spring; retract and compliant bring the force below F_QS within 0.5 s.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from reflexarm.errors import ConfigError
from reflexarm.experiments.pfl import run_region_contact
from reflexarm.experiments.pfl_placement import place_region, swing_at_speed
from reflexarm.robots import CoulombViscousFriction, load_robot
from reflexarm.safety import body_region, effective_mass, point_jacobian
from reflexarm.sim import Plant, SensorNoise
from reflexarm.sim.human_contact import HumanContact

ARMS = ("panda", "atlas_v5_left_arm")
SPEEDS = (0.25, 0.5, 0.75)  # [m/s]

#: Free arm against v sqrt(mu k): the spring force is held over each 1 ms tick, so a contact of n ticks peaks a
#: little high (measured +0.5 % hand transient (7 ticks) to +3.5 % chest (21 ticks); the posture moves by < 1 cm
#: during the contact). Stiff contacts with few ticks (skull 7-9, hand clamped 12) overshoot up to 11 %.
FREE_ARM_RTOL = 0.05
FREE_ARM_STIFF_RTOL = 0.12
#: The issue's target for the closed loop with detection off, met where the contact is short (hand).
CLOSED_LOOP_RTOL = 0.15


def _robot(name):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_robot(name)


def _free_arm_peak(robot, region, mode, speed):
    traj, _ = swing_at_speed(robot, speed)
    pl = place_region(robot, traj)
    dq = traj.sample(pl.contact_time).dq_d
    J, p = point_jacobian(robot, pl.q_contact, robot.ee_frame)
    u = pl.normal
    scene = HumanContact(region, p + 0.001 * u, u, mode=mode)
    plant = Plant(robot, scene=scene, noise=SensorNoise.none(), true_friction=CoulombViscousFriction.zeros(robot.n))
    plant.reset(pl.q_contact, dq)
    peak = 0.0
    for _ in range(150):
        plant.step(robot.compute_gravity(plant.q))
        peak = max(peak, plant.scenes[0].observe(plant)["human_force"][0])
    r = body_region(region)
    m_h = r.human_mass if mode == "transient" else math.inf
    mu = 1.0 / (1.0 / m_h + 1.0 / effective_mass(robot, pl.q_contact, robot.ee_frame, (0, 0, 0), u))
    return peak, float(u @ J @ dq) * math.sqrt(mu * r.spring_constant_si)


@pytest.mark.parametrize("arm", ARMS)
@pytest.mark.parametrize(
    ("region", "mode", "rtol"),
    [
        ("hand", "transient", FREE_ARM_RTOL),
        ("chest", "transient", FREE_ARM_RTOL),
        ("abdomen", "transient", FREE_ARM_RTOL),
        ("chest", "clamped", FREE_ARM_RTOL),
        ("skull", "transient", FREE_ARM_STIFF_RTOL),
        ("hand", "clamped", FREE_ARM_STIFF_RTOL),
    ],
)
def test_free_arm_peak_is_v_sqrt_mu_k(arm, region, mode, rtol):
    peak, analytic = _free_arm_peak(_robot(arm), region, mode, 0.5)
    assert peak >= analytic * 0.99  # the hold only overshoots
    np.testing.assert_allclose(peak, analytic, rtol=rtol, err_msg=f"{arm} {region} {mode}")


def _closed_loop(arm, region, speed):
    result, _ = run_region_contact(
        _robot(arm), region, speed, detection=False, model_error=0.0, noise=SensorNoise.none(), plant_friction="file"
    )
    return result


@pytest.mark.parametrize("arm", ARMS)
@pytest.mark.parametrize("speed", SPEEDS)
def test_closed_loop_hand_within_15_percent(arm, speed):
    r = _closed_loop(arm, "hand", speed)
    assert r.approach_speed_m_s == pytest.approx(speed, rel=0.1)
    np.testing.assert_allclose(r.peak_force_N, r.analytic_force_N, rtol=CLOSED_LOOP_RTOL)


@pytest.mark.parametrize("arm", ARMS)
@pytest.mark.parametrize("region", ["chest", "abdomen"])
def test_closed_loop_soft_regions_lie_above_by_the_controllers_push(arm, region):
    """Measured, not the issue's 15 %: on chest and abdomen the contact lasts 20-40 ms and the controller drives
    the arm on (positive drive force along u at the peak), so the simulated peak lies 14-52 % above the free-mass
    prediction at every speed. That drive force, rising from first contact to the peak, adds (1 - 2/pi) of its
    value at the peak to an undamped spring's peak: with it the simulation is within 15 %. (The drive force is
    read from the run's commanded torques: this checks the explanation, it is no independent prediction.)"""
    for speed in SPEEDS:
        r = _closed_loop(arm, region, speed)
        assert r.controller_force_at_peak_N is not None and r.controller_force_at_peak_N > 0.0
        assert r.simulated_over_analytic is not None and r.simulated_over_analytic > 1.0 + CLOSED_LOOP_RTOL / 2
        np.testing.assert_allclose(r.peak_force_N, r.controller_corrected_force_N, rtol=CLOSED_LOOP_RTOL)


@pytest.mark.parametrize("arm", ARMS)
@pytest.mark.parametrize("reaction", ["retract", "compliant"])
def test_clamped_force_falls_below_quasi_static_limit_within_half_a_second(arm, reaction):
    from dataclasses import replace

    from reflexarm.experiments.pfl import PFL_SETTING

    setting = replace(PFL_SETTING, stiffness=300.0)
    r, trace = run_region_contact(_robot(arm), "chest", 0.25, mode="clamped", reaction=reaction, setting=setting)
    assert r.detection_delay_s is not None and r.detection_delay_s > 0.0
    assert r.below_qs_after_detection_s is not None and r.below_qs_after_detection_s <= 0.5
    assert (
        r.max_force_after_window_N is not None and r.max_force_after_window_N < body_region("chest").quasi_static_force
    )
    # without a reaction the same arm presses on: the clamped force exceeds what it is after the reaction
    none, _ = run_region_contact(_robot(arm), "chest", 0.25, mode="clamped", reaction="none", setting=setting)
    assert none.max_force_after_window_N > r.max_force_after_window_N + 50.0


def test_a_speed_the_arm_cannot_reach_says_so():
    with pytest.raises(ConfigError, match=r"panda: the end-effector swing \(joint 3, 1.00 rad\) reaches at most 0.79"):
        swing_at_speed(_robot("panda"), 2.0)


def test_a_region_another_link_would_hit_first_is_refused():
    robot = _robot("panda")
    traj, _ = swing_at_speed(robot, 0.5)
    # this straight joint-space move brings joint 5's frame (the forearm) through the region's patch 0.14 s before
    # the end effector reaches the region where it is fastest
    from reflexarm.sim import JointTrajectory

    q1 = np.clip(robot.home + np.array([-1.0, -0.4, -0.2, 1.1, 0.1, -0.6, -0.6]), robot.lower_limit, robot.upper_limit)
    back = JointTrajectory(np.array([robot.home, q1]), np.array([1.0]))
    with pytest.raises(ConfigError, match=r"frame 'panda_joint5' crosses the region's surface .* cannot be placed"):
        place_region(robot, back, samples=100)
    assert place_region(robot, traj).reference_speed == pytest.approx(0.5, rel=0.01)


def test_unknown_region_and_reaction_are_named():
    robot = _robot("panda")
    with pytest.raises(ConfigError, match="unknown body region 'knee'"):
        run_region_contact(robot, "knee", 0.25)
    with pytest.raises(ConfigError, match="unknown reaction 'stop'; choose one of: none, gravity"):
        run_region_contact(robot, "hand", 0.25, reaction="stop")


def test_cli_checks_a_trajectory_file_sample_by_sample(tmp_path, capsys):
    import json

    from reflexarm.cli import main

    robot = _robot("panda")
    t = np.linspace(0.0, 1.0, 101)
    q = robot.home + np.outer(np.sin(np.pi * t), [1.2, 0, 0, 0, 0, 0, 0])  # joint 1 swings out at up to ~3.8 rad/s
    path = tmp_path / "motion.csv"
    np.savetxt(
        path, np.column_stack([t, q]), delimiter=",", header="t," + ",".join(f"q{i}" for i in range(1, 8)), comments=""
    )
    assert (
        main(
            ["pfl", "--arms", "panda", "--regions", "skull,chest", "--trajectory", str(path), "--check-only"]
            + ["--out", str(tmp_path)]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "skull:" in out and "samples over the limit" in out and "m/s" in out
    report = json.loads((tmp_path / "pfl_trajectory.json").read_text())
    skull = report["regions"]["skull"]
    assert skull["samples_over_limit"] == len(skull["violations"]) > 0
    first = skull["violations"][0]
    assert first["speed_m_s"] > first["permissible_speed_m_s"] and set(first) >= {"t_s", "point", "effective_mass_kg"}
    # a file without the arm's seven joints is refused, naming what it found
    bad = tmp_path / "bad.csv"
    bad.write_text("t,a,b\n0,0,0\n1,0,0\n")
    assert main(["pfl", "--arms", "panda", "--trajectory", str(bad), "--out", str(tmp_path)]) == 2
    assert "needs columns t and 7 joint positions [rad]" in (err := capsys.readouterr().err)
    assert "found ['t', 'a', 'b']" in err


def test_scene_refuses_bad_input():
    with pytest.raises(ConfigError, match="unknown contact mode 'pinned'; choose one of: transient, clamped"):
        HumanContact("hand", (0, 0, 0), (1, 0, 0), mode="pinned")
    with pytest.raises(ConfigError, match="normal must be a non-zero direction"):
        HumanContact("hand", (0, 0, 0), (0, 0, 0))
    with pytest.raises(ConfigError, match="surface must be a finite 3-vector"):
        HumanContact("hand", (0, np.nan, 0), (1, 0, 0))


def test_study_outputs_carry_units_and_name_failed_runs(tmp_path):
    from reflexarm.experiments.pfl_report import speed_table, write_pfl_outputs
    from reflexarm.experiments.pfl_study import run_pfl_study

    study = run_pfl_study([("panda", _robot("panda"))], ["hand"], [0.25, 5.0], ["retract"])
    failed = [r for r in study.rows if r["error"]]
    assert failed and all("reaches at most 0.79 m/s" in r["error"] for r in failed)  # 5 m/s: said, not dropped
    table = speed_table(study)
    assert table[0]["v_posture_m_s"] > table[0]["v_standard_m_s"] > 0.0  # m_R(q, u) < M/2 on this swing
    paths = write_pfl_outputs(study, tmp_path)
    header = paths["table_csv"].read_text().splitlines()[0]
    assert "v_standard_m_s" in header and "F_T_N" in header and "effective_mass_kg" in header
    page = paths["html"].read_text()
    assert "Speeds [m/s], forces [N], masses [kg]" in page and "reaches at most 0.79 m/s" in page
    assert paths["pfl_hand"].stat().st_size > 10_000


#: A contact in the middle of the forearm (link 4 of the Panda, 0.1 m along its x axis): the free arm's peak
#: against v sqrt(mu k) with m_R(q, u) of that point; same hold error as at the end effector.
@pytest.mark.parametrize("region", ["chest", "upper_arm"])
def test_free_arm_peak_at_a_link_point(region):
    robot = _robot("panda")
    link, local = "panda_link4", np.array([0.1, 0.0, 0.0])
    q = robot.home
    dq = np.zeros(robot.n)
    dq[0] = 1.5  # [rad/s]: the first joint swings the forearm sideways
    J, p = point_jacobian(robot, q, link, local)
    v = J @ dq
    u = v / np.linalg.norm(v)
    scene = HumanContact(region, p + 0.001 * u, u, arm_body=link, arm_point=local)
    plant = Plant(robot, scene=scene, noise=SensorNoise.none(), true_friction=CoulombViscousFriction.zeros(robot.n))
    plant.reset(q, dq)
    peak = 0.0
    for _ in range(150):
        plant.step(robot.compute_gravity(plant.q))
        peak = max(peak, scene.observe(plant)["human_force"][0])
    r = body_region(region)
    mu = 1.0 / (1.0 / r.human_mass + 1.0 / effective_mass(robot, q, link, local, u))
    np.testing.assert_allclose(peak, float(u @ v) * math.sqrt(mu * r.spring_constant_si), rtol=FREE_ARM_RTOL)
    with pytest.raises(ConfigError, match="unknown body 'forearm'; bodies are: world, panda_link0"):
        bad = Plant(robot, scene=HumanContact(region, p, u, arm_body="forearm"), noise=SensorNoise.none())
        bad.step(np.zeros(robot.n))
