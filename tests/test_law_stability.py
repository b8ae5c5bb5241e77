"""The impedance law sampled at the control rate (reflexarm.control.law_stability): its stability limit checked
against a plain zero-order-hold simulation and against the MuJoCo plant, the Controller's refusal of an unstable
law, and the experiments' stiffness on an arm too light for the paper's 300 Nm/rad."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from ident_arms import write_six_dof_urdf
from reflexarm import load_robot
from reflexarm.control import Controller
from reflexarm.control.impedance import JointImpedanceController
from reflexarm.control.law_stability import (
    RATE_SHARE,
    UnstableLawWarning,
    check_law_stability,
    experiment_stiffness,
    law_modes,
    limit_omega_dt,
    rate_limited_stiffness,
    unstable_law_message,
)
from reflexarm.errors import ConfigError, SimulationError
from reflexarm.robots.friction import CoulombViscousFriction
from reflexarm.signals import Measurement, Reference
from reflexarm.sim import Plant

DT = 1e-3
#: The six-DoF test arm's last joint: its wrist (0.19 kg, 2e-4 kg m^2 about its axis) carries the highest mode.
WRIST = 5


def _zoh_growth(omega_dt: float, ratio: float, substeps: int = 0, ticks: int = 4000) -> float:
    """|state| after ``ticks`` over |state| at the start: a unit mass with the PD torque -k z - d z' computed from
    the state at each tick and held over the period, integrated exactly (``substeps`` 0: z'' constant within it)
    or in that many semi-implicit Euler steps (velocity first, then position, as MuJoCo's Euler). Written from the
    mechanics, not from the module's map."""
    dt = DT
    omega = omega_dt / dt
    k, d = omega**2, 2.0 * ratio * omega
    z, v = 1e-3, 0.0
    for _ in range(ticks):
        a = -k * z - d * v
        if substeps == 0:
            z, v = z + v * dt + 0.5 * a * dt * dt, v + a * dt
        else:
            h = dt / substeps
            for _ in range(substeps):
                v += a * h
                z += v * h
    return float(np.hypot(z, v * dt) / 1e-3)


@pytest.mark.parametrize("ratio", [0.7, 0.2, 1.0])
@pytest.mark.parametrize("substeps", [0, 2, 4])
def test_the_limit_separates_decay_from_growth_of_a_held_pd_loop(ratio, substeps):
    gain = 0.5 if substeps == 0 else (substeps + 1) / (2 * substeps)  # the position's share of a dt^2
    limit = limit_omega_dt(ratio, gain)
    # 3 % either side: at 4000 ticks the growth factor per tick (1 + ~1e-2 or more) is unmistakable
    assert _zoh_growth(0.97 * limit, ratio, substeps) < 1.0
    assert _zoh_growth(1.03 * limit, ratio, substeps) > 1e3


def test_the_limit_is_the_damping_bound_or_the_lag_bound():
    assert limit_omega_dt(0.7) == pytest.approx(1.0 / 0.7)  # the -1 crossing
    assert limit_omega_dt(0.2) == pytest.approx(0.8)  # the pair leaves the unit circle (4 d_xi)
    assert limit_omega_dt(0.0) == float("inf")  # undamped: not checked


@pytest.fixture(scope="module")
def light_wrist(tmp_path_factory):
    path = write_six_dof_urdf(tmp_path_factory.mktemp("six"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_robot(path, ee_frame="tool")


def _wrist_limit_stiffness(robot, position_gain: float = 0.5) -> float:
    """The wrist stiffness at which the law's highest mode reaches its limit (others 300 Nm/rad), by bisection."""
    lo, hi = 1.0, 1e5
    for _ in range(60):
        mid = np.sqrt(lo * hi)
        k = np.full(robot.n, 300.0)
        k[WRIST] = mid
        share = max(m.share for m in law_modes(robot, k, np.full(robot.n, 0.7), DT, position_gain))
        lo, hi = (mid, hi) if share < 1.0 else (lo, mid)
    return float(lo)


@pytest.mark.parametrize("factor, grows", [(0.85, False), (1.15, True)])
def test_the_mujoco_plant_follows_the_predicted_limit(light_wrist, factor, grows):
    """The law alone (JointImpedanceController, no Controller check) on the MuJoCo plant (no joint friction),
    holding the home posture from a 0.01 rad/s wrist velocity, at the limit predicted for the plant's integration
    (its substeps of semi-implicit Euler): below it the wrist settles, above it its velocity grows by orders of
    magnitude (sign-flipping every tick) until the plant reports the divergence."""
    robot = light_wrist
    plant = Plant(robot, true_friction=CoulombViscousFriction.zeros(robot.n))
    gain = (plant.substeps + 1) / (2 * plant.substeps)
    k = np.full(robot.n, 300.0)
    k[WRIST] = factor * _wrist_limit_stiffness(robot, gain)
    law = JointImpedanceController(robot, stiffness=k, damping_ratio=0.7, damping_update_period=1)
    dq0 = np.zeros(robot.n)
    dq0[WRIST] = 0.01
    plant.reset(robot.home, dq0)
    ref = Reference(robot.home, np.zeros(robot.n), np.zeros(robot.n))
    speeds = []
    try:
        for _ in range(300):
            plant.step(law.compute_torque(plant.q, plant.dq, ref))
            speeds.append(abs(plant.dq[WRIST]))
    except SimulationError as e:
        assert grows, str(e)
        assert "diverged" in str(e)
        return
    late = max(speeds[-20:])
    if grows:
        assert late > 100 * 0.01
    else:
        assert late < 0.01


def test_the_controller_warns_of_an_unstable_law_and_names_the_joint(light_wrist):
    robot = light_wrist
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnstableLawWarning)
        Controller(robot, stiffness=300.0)  # the wrist's mode at 0.86 of its limit: no warning
        k = np.full(robot.n, 300.0)
        k[WRIST] = 1.1 * _wrist_limit_stiffness(robot)
        Controller(robot, stiffness=k, dt=5e-4)  # a faster rate makes the same stiffness stable
    with pytest.warns(UnstableLawWarning, match=r"unstable at dt = 0.001 s.*joint 6 \(wrist_3_joint\).*wrist_3_j"):
        Controller(robot, stiffness=k)
    with pytest.raises(ConfigError, match=r"unstable at dt = 0.001 s.*joint 6 \(wrist_3_joint\)"):
        check_law_stability(robot, k, np.full(robot.n, 0.7), DT)  # what a controller that drives calls (ROS)


def test_the_suggested_stiffness_is_stable_and_lowers_only_the_light_joint(light_wrist):
    robot = light_wrist
    k = np.full(robot.n, 300.0)
    k[WRIST] = 2.0 * _wrist_limit_stiffness(robot)
    capped, lowered = rate_limited_stiffness(robot, k, np.full(robot.n, 0.7), DT)
    assert lowered == [WRIST]
    np.testing.assert_array_equal(capped[:WRIST], k[:WRIST])
    assert max(m.share for m in law_modes(robot, capped, np.full(robot.n, 0.7), DT)) <= RATE_SHARE * (1 + 1e-9)
    Controller(robot, stiffness=capped)
    assert unstable_law_message(robot, capped, np.full(robot.n, 0.7), DT) is None


def test_experiments_keep_a_stable_stiffness_and_say_when_they_lower_one(light_wrist, recwarn):
    robot = light_wrist
    np.testing.assert_array_equal(experiment_stiffness(robot, 300.0), np.full(robot.n, 300.0))
    assert not [w for w in recwarn if "stiffness lowered" in str(w.message)]
    k = np.full(robot.n, 300.0)
    k[WRIST] = 1.5 * _wrist_limit_stiffness(robot)
    with pytest.warns(UserWarning, match=r"stiffness lowered \[Nm/rad\]: wrist_3_joint"):
        out = experiment_stiffness(robot, k)
    assert out[WRIST] < k[WRIST]
    Controller(robot, stiffness=out)


@pytest.mark.parametrize("name", ["atlas_v5_left_arm", "panda", "iiwa14"])
def test_the_built_in_arms_keep_the_papers_stiffness(name):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        robot = load_robot(name)
    k, d = np.full(robot.n, 300.0), np.full(robot.n, 0.7)
    assert max(m.share for m in law_modes(robot, k, d, DT)) < RATE_SHARE  # 0.19-0.52 of the limit
    assert unstable_law_message(robot, k, d, DT) is None


def test_a_faulted_run_is_reported_with_its_first_fault():
    from types import SimpleNamespace

    from reflexarm._cli.run_outputs import fault_line, fault_record

    t = np.arange(5) * DT
    clean = SimpleNamespace(t=t, fault=np.array([""] * 5))
    assert fault_record(clean) is None  # type: ignore[arg-type]
    texts = np.array(["", "", "measurement dq[5] = 100.8 rad/s outside the plausible", "later", ""])
    rec = fault_record(SimpleNamespace(t=t, fault=texts))  # type: ignore[arg-type]
    assert rec == {"first_s": 0.002, "ticks": 2, "text": "measurement dq[5] = 100.8 rad/s outside the plausible"}
    line = fault_line("link collision", rec)
    assert line.startswith("[link collision] the controller FAULTED at t = 0.002 s (2 ticks in fault): measurement")


def test_the_ros_node_refuses_an_unstable_law_in_control_mode_only(light_wrist, tmp_path):
    from reflexarm.ros.config import MonitorConfig
    from reflexarm.ros.controller_setup import build_controller

    robot = light_wrist
    # 450 Nm/rad on every joint: the wrist's mode at 0.86 sqrt(1.5) = 1.06 of its limit at the node's 1 kHz
    values = {"robot": str(robot.source), "stiffness": 450.0, "threshold": "11"}
    with pytest.raises(ConfigError, match=r"unstable at dt = 0.001 s.*\(wrist_3_joint\)"):
        build_controller(MonitorConfig.from_values("control", values), robot)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnstableLawWarning)  # a monitor never applies the law: not even a warning
        build_controller(MonitorConfig.from_values("monitor", values), robot)


def test_the_robots_command_prints_the_law_s_margin(light_wrist, tmp_path, capsys):
    from reflexarm.cli import main

    assert main(["robots", "atlas_v5_left_arm"]) == 0
    line = capsys.readouterr().out.splitlines()[-1]
    assert line.startswith("law (2) at 300 Nm/rad, 1 kHz: highest mode omega dt = 0.744, 0.52 of its stability limit")
    # the six-DoF arm with its wrist's inertia scaled down 4x (2e-4 -> 5e-5 kg m^2): omega dt doubles, unstable
    text = open(light_wrist.source).read().replace('iyy="0.0002"', 'iyy="5e-05"', 1)
    assert text.count('iyy="5e-05"') == 1
    lighter = tmp_path / "lighter.urdf"
    lighter.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["robots", str(lighter), "--ee-frame", "tool"]) == 0
    line = capsys.readouterr().out.splitlines()[-1]
    assert "of its stability limit (joint 6 wrist_3_joint): UNSTABLE; the experiments lower the stiffness" in line


@pytest.mark.parametrize("wrist_factor", [0.9, 1.1])
def test_the_cores_share_at_the_posture_equals_the_modules(light_wrist, wrist_factor):
    """The C++ core's lawModeShare (its Cholesky and Jacobi rotations of the damping in use) against law_modes
    (scipy's generalized eigen-solver) at the same posture: two implementations of the same number."""
    robot = light_wrist
    k = np.full(robot.n, 300.0)
    k[WRIST] = wrist_factor * _wrist_limit_stiffness(robot)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnstableLawWarning)
        ctrl = Controller(robot, stiffness=k, threshold=None)
    assert np.isnan(ctrl._core.law_mode_share)  # no damping yet
    q = np.clip(np.asarray(robot.home, dtype=float), robot.lower_limit, robot.upper_limit)
    ctrl.step(Measurement(0.0, q, np.zeros(robot.n), robot.compute_gravity(q), np.zeros(6), robot.gravity),
              Reference.hold(q))  # fmt: skip
    share = max(m.share for m in law_modes(robot, k, np.full(robot.n, 0.7), DT) if m.posture == "home")
    # eigenvalues of two solvers agree to ~1e-12 relative; the share is their square root
    assert ctrl._core.law_mode_share == pytest.approx(share, rel=1e-9)
    assert (ctrl._core.law_mode_share >= 1.0) == (wrist_factor > 1.0)

