"""run_closed_loop: a PD + gravity controller defined here tracks a JointTrajectory; failures keep the
recorded ticks; the trace records what the plant and controller did."""

from __future__ import annotations

import numpy as np
import pytest

from reflexarm.errors import ConfigError, SimulationError
from reflexarm.robots import load_robot
from reflexarm.signals import Command, Measurement, Reference
from reflexarm.sim import Cinderblock, JointTrajectory, Plant, SensorNoise, Trace, run_closed_loop

#: PD gains: stiff on the hydraulic joints, softer on the light wrist (k_p dt^2 / M_ii << 1 at 1 kHz).
KP = np.array([300.0, 300.0, 300.0, 300.0, 30.0, 30.0, 30.0])
DAMPING_RATIO = 0.7


class PDGravity:
    """tau = K_p (q_d - q) + K_d (dq_d - dq) + g(q), with K_d = 2 zeta sqrt(K_p M_ii(home))."""

    def __init__(self, robot, kp=KP):
        self.robot = robot
        self.kp = np.asarray(kp, dtype=float)
        self.kd = 2.0 * DAMPING_RATIO * np.sqrt(self.kp * np.diag(robot.compute_mass_matrix(robot.home)))
        self.resets = 0

    def reset(self) -> None:
        self.resets += 1

    def step(self, m: Measurement, r: Reference) -> Command:
        tau = self.kp * (r.q_d - m.q) + self.kd * (r.dq_d - m.dq) + self.robot.compute_gravity(m.q)
        return Command(tau, np.zeros(self.robot.n), False, (), "pd", "")

    def describe(self) -> dict:
        return {"kp": self.kp, "kd": self.kd}


@pytest.fixture(scope="module")
def robot():
    return load_robot("atlas_v5_left_arm")


@pytest.fixture(scope="module")
def traj(robot):
    q0 = robot.home
    q1 = q0 + np.array([0.3, 0.2, -0.2, 0.3, 0.5, 0.2, 0.3])
    return JointTrajectory([q0, q1, q0], [1.0, 1.0], holds=[0.2, 0.3, 0.3])


def test_pd_gravity_tracks_a_trajectory(robot, traj):
    """Quasi-static bound of PD + gravity: the tracking error of joint i stays below
    (mu_C,i + d_v,i |dq_d,i| + |M ddq_d + C dq_d|_i) / k_p,i -- what the P term must supply against
    friction and the uncompensated dynamics -- plus the velocity noise's share k_d 5.5e-2 / k_p; the
    factor 1.5 covers the lag of the damped second-order closed loop."""
    plant = Plant(robot, seed=1)  # the paper's noise
    ctrl = PDGravity(robot)
    trace = run_closed_loop(plant, ctrl, traj, traj.duration)
    assert ctrl.resets == 1
    assert len(trace) == round(traj.duration / 1e-3)
    np.testing.assert_allclose(np.diff(trace.t), 1e-3, atol=1e-12)
    fr = plant.true_friction
    bound = np.zeros(7)
    for t in trace.t[::10]:
        r = traj.sample(t)
        dyn = robot.compute_inverse_dynamics(r.q_d, r.dq_d, r.ddq_d) - robot.compute_gravity(r.q_d)
        bound = np.maximum(bound, fr.coulomb + fr.viscous * np.abs(r.dq_d) + np.abs(dyn))
    bound = 1.5 * (bound + ctrl.kd * 5.5e-2) / ctrl.kp
    err = np.abs(trace.q - trace.q_d).max(axis=0)
    assert np.all(err < bound), f"tracking error {err} exceeds the bound {bound}"
    # at the end the arm is back at the start, within the friction dead band mu_C / k_p
    np.testing.assert_array_less(np.abs(trace.q[-1] - traj.waypoints[0]), 1.5 * (fr.coulomb + 2.0) / ctrl.kp)
    # what was recorded is what happened
    np.testing.assert_array_equal(trace.q_d, np.array([traj.sample(t).q_d for t in trace.t]))
    assert np.abs(trace.q_meas - trace.q).max() <= 3.4e-4
    # tau_m at tick k is the torque the motors applied over the previous period: the command of tick k - 1
    assert np.abs(trace.tau_m[1:] - trace.tau[:-1]).max() <= 7.3e-2
    assert np.abs(trace.tau_m[0]).max() <= 7.3e-2
    assert set(trace.mode) == {"pd"} and not trace.collision.any() and (trace.fault == "").all()
    assert trace.meta["controller"]["type"] == "PDGravity" and len(trace.meta["controller"]["kp"]) == 7
    assert trace.meta["robot"] == "atlas_v5_left_arm" and trace.meta["seed"] == 1
    np.testing.assert_allclose(trace.tau_ext, 0.0, atol=0.0)  # free motion


class FailingController(PDGravity):
    def __init__(self, robot, fail_at, how):
        super().__init__(robot)
        self.k, self.fail_at, self.how = 0, fail_at, how

    def step(self, m, r):
        cmd = super().step(m, r)
        self.k += 1
        if self.k - 1 == self.fail_at:
            if self.how == "nan":
                tau = cmd.tau.copy()
                tau[3] = np.nan
                return cmd._replace(tau=tau)
            raise RuntimeError("controller bug")
        return cmd


def test_partial_trace_is_kept_when_the_plant_refuses(robot, traj):
    plant = Plant(robot, noise=SensorNoise.none())
    with pytest.raises(SimulationError, match=r"non-finite motor torque on joint\(s\) \['l_arm_elx'\]") as info:
        run_closed_loop(plant, FailingController(robot, 50, "nan"), traj, 1.0)
    trace = info.value.trace
    assert isinstance(trace, Trace) and len(trace) == 51  # ticks 0..50, the failing command included
    assert np.isnan(trace.tau[-1, 3]) and np.isfinite(trace.tau[:-1]).all()
    assert "SimulationError" in trace.meta["error"]


def test_partial_trace_is_kept_when_the_controller_raises(robot, traj):
    plant = Plant(robot, noise=SensorNoise.none())
    with pytest.raises(RuntimeError, match="controller bug") as info:
        run_closed_loop(plant, FailingController(robot, 30, "raise"), traj, 1.0)
    assert len(info.value.trace) == 30


def test_callback_can_stop_the_run_and_extras_are_recorded(robot, traj):
    block = Cinderblock(position=(0.6, -0.5), table_height=0.6)
    plant = Plant(robot, scene=block, noise=SensorNoise.none())
    seen = []

    def callback(k, plant, m, cmd):
        seen.append(k)
        return k == 99

    trace = run_closed_loop(plant, PDGravity(robot), traj, 1.0, callback=callback, progress=True)
    assert len(trace) == 100 and seen == list(range(100))
    assert trace.extras["cinderblock_pos"].shape == (100, 3)
    np.testing.assert_allclose(trace.extras["cinderblock_pos"][0], [0.6, -0.5, 0.695], atol=1e-12)
    assert trace.meta["scene"][0]["type"] == "Cinderblock"


def test_runner_arguments(robot, traj):
    plant = Plant(robot)
    with pytest.raises(ConfigError, match=r"duration must be a positive number of seconds; got -1"):
        run_closed_loop(plant, PDGravity(robot), traj, -1)
    with pytest.raises(ConfigError, match=r"controller must have a step\(measurement, reference\) method; got int"):
        run_closed_loop(plant, 3, traj, 1.0)  # type: ignore[arg-type]
