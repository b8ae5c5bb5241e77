"""``reflexarm pfl`` on a user's motion: a trajectory file (plain or the excitation export) read, the region placed
where a point of the arm (the end effector or a link) moves fastest, the contact simulated, the speed swept by
time-scaling the motion; estimated safe speeds beyond the tested ones simulated where the joints allow.

The references are the test's own: the motion is a known function of time (a cosine swing of joint 1), the
points' speeds come from MuJoCo's Jacobians, the arm's effective mass from MuJoCo's mass matrix (not from
reflexarm.safety), the peak from the standard's two-mass formula F = v sqrt(mu k).
"""

from __future__ import annotations

import json
import math
import re
import warnings

import mujoco
import numpy as np
import pytest

from reflexarm.errors import ConfigError
from reflexarm.experiments.pfl import run_motion_contact
from reflexarm.experiments.pfl_motion import SpeedLimitError, read_motion_csv
from reflexarm.experiments.pfl_placement import place_region_on_motion
from reflexarm.experiments.pfl_study import transient_series
from reflexarm.ident.excitation.export import SampledExcitation, write_excitation_csv
from reflexarm.robots import CoulombViscousFriction, load_robot
from reflexarm.safety import body_region
from reflexarm.sim import Plant, SensorNoise
from reflexarm.sim.human_contact import HumanContact

#: Free arm against v sqrt(mu k): the spring force is held over each 1 ms tick; a contact of ~7 (hand) to ~21
#: (chest) ticks peaks up to ~3.5 % high (measured in tests/test_pfl.py, same scene).
FREE_ARM_RTOL = 0.05
#: The spline through 10 ms samples of the cosine swing against its exact derivative [-] (a cubic spline's
#: derivative error ~ h^3 |q''''| / 24 relative to the swing's own speed: < 1e-4 here).
SPLINE_RTOL = 1e-3
#: Joint 1's swing [rad] and the file's duration [s]: dq1 peaks at pi A / (2 T) = 0.94 rad/s (< 2.175 rad/s).
AMPLITUDE, DURATION = 1.2, 2.0


def _robot():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_robot("panda")


def _swing(robot, t, amplitude=AMPLITUDE, duration=DURATION):
    """q, dq of the cosine swing of joint 1 from the home posture (exact)."""
    a = np.zeros(robot.n)
    a[0] = amplitude
    s = 0.5 * (1.0 - np.cos(np.pi * np.asarray(t) / duration))
    ds = 0.5 * np.pi / duration * np.sin(np.pi * np.asarray(t) / duration)
    return robot.home + np.multiply.outer(s, a), np.multiply.outer(ds, a)


def _write(robot, path, fmt, amplitude=AMPLITUDE, duration=DURATION):
    t = np.arange(0.0, duration + 1e-9, 0.01)
    q, dq = _swing(robot, t, amplitude, duration)
    if fmt == "plain":
        header = "t," + ",".join(f"q{i}" for i in range(1, robot.n + 1))
        np.savetxt(path, np.column_stack([t, q]), delimiter=",", header=header, comments="")
    else:  # the excitation export's own writer
        names = tuple(robot.joint_names)
        write_excitation_csv(SampledExcitation(t, q, dq, np.zeros_like(q), names, 100.0, {}, {}), path)
    return path


def _mujoco_point(plant, q, dq, body, local):
    """(world point [m], its velocity [m/s], m_R along the velocity [kg]) from MuJoCo's model of the plant."""
    m, d = plant.model, plant.data
    d.qpos[plant._qadr_arr] = q
    mujoco.mj_forward(m, d)
    bid = m.body(body).id if body is not None else None
    if bid is None:
        site = plant._ee_site
        p = d.site_xpos[site].copy()
        jacp = np.zeros((3, m.nv))
        mujoco.mj_jacSite(m, d, jacp, None, site)
    else:
        p = d.xpos[bid] + d.xmat[bid].reshape(3, 3) @ np.asarray(local)
        jacp = np.zeros((3, m.nv))
        mujoco.mj_jac(m, d, jacp, None, p, bid)
    dofs = np.asarray(plant._arm_dofs)
    J = jacp[:, dofs]
    v = J @ dq
    u = v / np.linalg.norm(v)
    minv = np.zeros((m.nv, m.nv))
    mujoco.mj_solveM(m, d, minv, np.eye(m.nv))
    return p, v, 1.0 / float(u @ J @ minv[np.ix_(dofs, dofs)] @ J.T @ u)


def _free_arm_peak(robot, scene, q, dq):
    plant = Plant(robot, scene=scene, noise=SensorNoise.none(), true_friction=CoulombViscousFriction.zeros(robot.n))
    plant.reset(q, dq)
    peak = 0.0
    for _ in range(150):
        plant.step(robot.compute_gravity(plant.q))
        peak = max(peak, scene.observe(plant)["human_force"][0])
    return peak, plant


@pytest.mark.parametrize("fmt", ["plain", "excitation"])
@pytest.mark.parametrize(("point", "region"), [("ee", "hand"), ("ee", "chest"), ("link4", "chest")])
def test_file_motion_free_arm_peak_is_v_sqrt_mu_k(tmp_path, fmt, point, region):
    robot = _robot()
    motion = read_motion_csv(_write(robot, tmp_path / "motion.csv", fmt), robot)
    pl = place_region_on_motion(robot, motion, point)
    q, dq = _swing(robot, pl.contact_time)  # the exact motion at the placement's contact time
    # the motion read back is the written one (spline against the exact cosine)
    q_read, dq_read, _ = motion.at_file_time(pl.contact_time)
    np.testing.assert_allclose(dq_read, dq, atol=SPLINE_RTOL * np.max(np.abs(dq)), err_msg="velocity read back")
    # 1 mm ahead, as in tests/test_pfl.py: the spring starts from zero indentation within the first tick
    scene = HumanContact(
        region, pl.surface + 0.001 * pl.normal, pl.normal, arm_body=pl.arm_body, arm_point=pl.point.point
    )
    peak, plant = _free_arm_peak(robot, scene, q, dq)
    p, v, m_r = _mujoco_point(plant, q, dq, pl.arm_body, pl.point.point)
    # the region faces the point's direction of travel, at the point's position
    np.testing.assert_allclose(pl.normal, v / np.linalg.norm(v), atol=1e-3, err_msg="normal = direction of travel")
    np.testing.assert_allclose(pl.surface, p, atol=1e-3, err_msg="surface at the point [m]")
    r = body_region(region)
    mu = 1.0 / (1.0 / r.human_mass + 1.0 / m_r)
    analytic = float(np.linalg.norm(v)) * math.sqrt(mu * r.spring_constant_si)
    np.testing.assert_allclose(peak, analytic, rtol=FREE_ARM_RTOL, err_msg=f"{fmt} {point} {region}")


def test_the_link_point_is_the_fastest_point_of_the_link(tmp_path):
    robot = _robot()
    motion = read_motion_csv(_write(robot, tmp_path / "motion.csv", "plain"), robot)
    pl = place_region_on_motion(robot, motion, "link4")
    assert pl.arm_body == "panda_link4" and pl.point.link == "panda_link4"
    # joint 1 swings: the fastest point of link 4 is the one farthest from joint 1's (vertical) axis, its far end
    # at the next joint (link 5's origin): compare with the world positions of link 4's and link 5's origins
    q, dq = _swing(robot, pl.contact_time)
    plant = Plant(robot, noise=SensorNoise.none())
    p, v, _ = _mujoco_point(plant, q, dq, pl.arm_body, pl.point.point)
    radius = np.linalg.norm(p[:2])  # the Panda's joint 1 axis is the world z axis through the origin
    for other in ("panda_link4", "panda_link5"):
        o, _, _ = _mujoco_point(plant, q, dq, other, (0.0, 0.0, 0.0))
        assert radius >= np.linalg.norm(o[:2]) - 1e-9, other
    assert np.linalg.norm(v) == pytest.approx(radius * abs(dq[0]), rel=1e-9)  # v = r omega about the z axis


def test_time_scaled_closed_loop_at_a_link_reaches_the_asked_speed(tmp_path):
    robot = _robot()
    motion = read_motion_csv(_write(robot, tmp_path / "motion.csv", "plain"), robot)
    result, trace = run_motion_contact(
        robot, motion, "upper_arm", 0.4, point="link4", detection=False, model_error=0.0, noise=SensorNoise.none()
    )
    assert result.contact_point == "link4" and trace.meta["placement"]["arm_body"] == "panda_link4"
    # the time scale is the asked speed over the file's: v = r |dq1| with r from MuJoCo at the peak of dq1 (t = 1 s)
    q, dq = _swing(robot, DURATION / 2)
    _, v, _ = _mujoco_point(Plant(robot, noise=SensorNoise.none()), q, dq, "panda_link4", trace_point(trace))
    assert result.time_scale == pytest.approx(0.4 / np.linalg.norm(v), rel=1e-3)
    assert result.approach_speed_m_s == pytest.approx(0.4, rel=0.1)  # the arm lags its reference a little
    assert result.peak_force_N is not None and result.peak_force_N > 0.0


def trace_point(trace):
    return np.asarray(trace.meta["placement"]["contact_point"].split("@")[1].strip("()").split(","), dtype=float)


def test_a_motion_faster_than_every_limit_is_reported_per_sample_never_clipped(tmp_path, capsys):
    from reflexarm.cli import main

    robot = _robot()
    # 2.4 rad in 0.9 s: dq1 up to 4.2 rad/s, twice the joint's 2.175 rad/s, the end effector at ~1.3 m/s: beyond
    # the skull's permissible speed (~0.25 m/s at this arm's effective mass) most of the time, the chest's at the peak
    path = _write(robot, tmp_path / "fast.csv", "plain", amplitude=2.4, duration=0.9)
    args = ["pfl", "--arms", "panda", "--regions", "skull,chest", "--trajectory", str(path), "--check-only"]
    assert main([*args, "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "pfl_trajectory.json").read_text())
    t = np.arange(0.0, 0.9 + 1e-9, 0.01)
    q, dq = _swing(robot, t, 2.4, 0.9)
    plant = Plant(robot, noise=SensorNoise.none())
    ee = np.array(
        [
            np.linalg.norm(_mujoco_point(plant, qk, dk, None, None)[1]) if dk[0] else 0.0
            for qk, dk in zip(q, dq, strict=True)
        ]
    )
    for region, share in (("skull", 0.5), ("chest", 0.0)):
        viol = report["regions"][region]["violations"]
        assert len(viol) == report["regions"][region]["samples_over_limit"] > share * t.size
        for v in viol:  # each sample over the limit, its speed as it is (>= the ee's own speed: never clipped)
            assert v["speed_m_s"] > v["permissible_speed_m_s"]
            assert v["speed_m_s"] >= ee[v["sample"]] * (1.0 - SPLINE_RTOL)
        assert max(v["speed_m_s"] for v in viol) >= ee.max() * (1.0 - SPLINE_RTOL)
    assert "m/s" in capsys.readouterr().out
    # simulated at a speed the joints cannot reach: refused naming the joint, the limit and the reachable speed
    motion = read_motion_csv(path, robot)
    with pytest.raises(SpeedLimitError, match=r"needs joint 1 at .* its velocity limit 2.17 rad/s") as e:
        run_motion_contact(robot, motion, "hand", 3.0, detection=False)
    assert e.value.joint == 0 and e.value.reachable_speed < 3.0


HEADER = "t," + ",".join(f"q{i}" for i in range(7))


def test_malformed_files_say_why(tmp_path):
    robot = _robot()
    cases = {
        "t,a,b\n0,0,0\n1,0,0\n": "needs columns t and 7 joint positions [rad]",
        HEADER + "\n0" + ",0" * 7 + "\n0" + ",1" * 7 + "\n": "time must increase strictly",
        HEADER + "\n0" + ",0" * 7 + "\n1,x" + ",0" * 6 + "\n": "column 'q0' is not a number in data row 2",
    }
    for text, message in cases.items():
        path = tmp_path / "bad.csv"
        path.write_text(text)
        with pytest.raises(ConfigError, match=re.escape(message)):
            read_motion_csv(path, robot)
    with pytest.raises(ConfigError, match="cannot read --trajectory"):
        read_motion_csv(tmp_path / "missing.csv", robot)
    with pytest.raises(ConfigError, match="unknown contact point 'elbow'; choose from: ee, link1"):
        place_region_on_motion(robot, read_motion_csv(_write(robot, tmp_path / "m.csv", "plain"), robot), "elbow")


#: A fake contact: the peak proportional to the speed (F = 100 N per m/s), reachable up to REACH m/s.
SLOPE, REACH = 100.0, 1.6


def _fake(speed, reaction, detection):
    row = {"reaction": reaction, "detection": detection, "reference_speed_m_s": speed, "F_T_N": 140.0}
    if speed is not None and speed > REACH:
        return {**row, "error": "beyond the joints", "reachable_speed_m_s": REACH}
    return {**row, "error": None, "approach_speed_m_s": speed, "peak_force_N": SLOPE * speed}


def test_estimated_safe_speeds_beyond_the_tested_ones_are_simulated_where_reachable():
    from reflexarm.experiments.pfl_study import safe_speeds

    rows = transient_series(_fake, [0.25, 0.5], ["retract"])
    off = [r for r in rows if not r["detection"]]
    # F_T / slope = 1.4 m/s: beyond the tested 0.5 m/s, reachable: simulated there, no longer extrapolated
    assert [r["reference_speed_m_s"] for r in off] == pytest.approx([0.25, 0.5, 1.4])
    assert safe_speeds(off)["extrapolated"] is False
    # a limit of 200 N: 2 m/s, beyond the reach of 1.6 m/s: refused, simulated at the reach, still flagged
    high = transient_series(lambda v, r, d: {**_fake(v, r, d), "F_T_N": 200.0}, [0.25, 0.5], [])
    assert [r["error"] for r in high[2:]] == ["beyond the joints", None]
    assert high[3]["reference_speed_m_s"] == pytest.approx(0.999 * REACH)
    est = safe_speeds(high)
    assert est["simulated_safe_speed_m_s"] == pytest.approx(2.0) and est["extrapolated"] is True


@pytest.mark.slow  # ~5 s alone, ~45 s on a loaded machine (16-20 closed-loop runs)
def test_cli_simulates_a_trajectory_file_per_contact_point(tmp_path, capsys):
    import csv

    from reflexarm.cli import main

    robot = _robot()
    path = _write(robot, tmp_path / "motion.csv", "excitation")
    args = ["pfl", "--arms", "panda", "--regions", "skull", "--reactions", "retract", "--speeds", "0.3"]
    assert main([*args, "--points", "ee,link4", "--trajectory", str(path), "--out", str(tmp_path)]) == 0
    out = capsys.readouterr()
    assert "time-scaled" in out.err
    lines = [x for x in out.out.splitlines() if "v_max standard" in x]
    assert len(lines) == 2 and " ee " in lines[0] and " link4 " in lines[1] and all("m/s" in x for x in lines)
    with (tmp_path / "pfl_table.csv").open() as f:
        table = list(csv.DictReader(f))
    assert [r["contact_point"] for r in table] == ["ee", "link4"]
    assert all(float(r["own_timing_peak_N"]) > 0.0 and float(r["v_sim_detection_off_m_s"]) > 0.0 for r in table)
    runs = json.loads((tmp_path / "pfl.json").read_text())["runs"]
    own = [r for r in runs if r.get("requested_speed_m_s") is None and r["error"] is None]
    assert own and all(r["time_scale"] == 1.0 for r in own)  # the file's own timing, as written
    # a contact point the arm has not: named, with the choices
    assert main([*args, "--points", "link9", "--trajectory", str(path), "--out", str(tmp_path)]) == 2
    assert "--points: panda has no contact point 'link9'; choose from: ee, link1" in capsys.readouterr().err
