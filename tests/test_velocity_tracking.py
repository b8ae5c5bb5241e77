"""Fig. 5: the constant-velocity single-joint experiment, PD position control against impedance control (2)."""

from __future__ import annotations

import numpy as np
import pytest

from reflexarm.errors import ConfigError
from reflexarm.experiments.velocity_tracking import (
    JointPDController,
    TrapezoidalJointMotion,
    VelocityTrackingSetup,
    plot_velocity_tracking,
    run_velocity_tracking,
)
from reflexarm.robots import load_robot
from reflexarm.signals import Measurement, Reference


def test_trapezoidal_motion_is_consistent():
    m = TrapezoidalJointMotion(np.zeros(7), joint=3, speed=0.3, travel=0.9, ramp=0.2, hold=0.5)
    t = np.arange(0.0, m.duration + 0.2, 1e-3)
    refs = [m.sample(ti) for ti in t]
    q = np.array([r.q_d[3] for r in refs])
    dq = np.array([r.dq_d[3] for r in refs])
    ddq = np.array([r.ddq_d[3] for r in refs])
    # position is the integral of velocity, velocity of acceleration (trapezoid rule on a 1 ms grid:
    # exact for the linear ramps, O(dt) = 1e-3 relative at the ramp corners)
    np.testing.assert_allclose(q[1:] - q[0], np.cumsum(0.5 * (dq[1:] + dq[:-1])) * 1e-3, atol=1e-4)
    np.testing.assert_allclose(dq[1:] - dq[0], np.cumsum(0.5 * (ddq[1:] + ddq[:-1])) * 1e-3, atol=2e-3)
    assert q.max() == pytest.approx(0.9) and q[-1] == pytest.approx(0.0, abs=1e-12)
    assert dq.max() == pytest.approx(0.3) and dq.min() == pytest.approx(-0.3)
    window = m.constant_speed(t, margin=0.0)
    np.testing.assert_allclose(np.abs(dq[window]), 0.3, atol=1e-12)
    # the other joints hold
    assert all(np.count_nonzero(r.dq_d) <= 1 and np.all(r.q_d[:3] == 0.0) for r in refs)


def test_trapezoidal_motion_arguments():
    with pytest.raises(ConfigError, match=r"travel must exceed speed \* ramp = 0.2 rad .*; got 0.1"):
        TrapezoidalJointMotion(np.zeros(7), 3, speed=1.0, travel=0.1, ramp=0.2)
    with pytest.raises(ConfigError, match="speed must be a positive number; got -1"):
        TrapezoidalJointMotion(np.zeros(7), 3, speed=-1.0, travel=0.5)
    with pytest.raises(ConfigError, match="joint must be in 0..6; got 7"):
        TrapezoidalJointMotion(np.zeros(7), 7, speed=0.3, travel=0.5)


def test_pd_controller_law():
    robot = load_robot("atlas_v5_left_arm")
    pd = JointPDController(robot, kp=1000.0, kd=30.0)
    q = np.array([0.0, -1.3, 1.57, 1.0, 0.0, 0.0, 0.0])
    dq = np.zeros(7)
    dq[3] = 0.1
    m = Measurement(0.0, q, dq, np.zeros(7), np.zeros(6), np.array([0.0, 0.0, -9.81]))
    q_d = q.copy()
    q_d[3] += 0.001
    cmd = pd.step(m, Reference(q_d, np.zeros(7), np.zeros(7)))
    expected = robot.compute_gravity(q)
    expected[3] += 1000.0 * 0.001 - 30.0 * 0.1
    np.testing.assert_allclose(cmd.tau, expected, atol=1e-12)
    assert cmd.mode == "pd_position" and not cmd.collision
    with pytest.raises(ConfigError, match="kp must be positive"):
        JointPDController(robot, kp=0.0, kd=1.0)


@pytest.fixture(scope="module")
def result():
    return run_velocity_tracking(VelocityTrackingSetup(), seed=0)


@pytest.mark.slow
def test_impedance_tracks_constant_speed_better_pd_breaks_away_sooner(result):
    # What this plant shows with the stated gains (see the module docstring of velocity_tracking):
    # at constant speed the impedance controller's velocity error is smaller (its damping, 2 * 0.7 *
    # sqrt(300 * 0.32) = 14 Nms/rad, passes less velocity noise than the PD's 30 Nms/rad) ...
    rms = result.rms_velocity_error
    assert rms["impedance"] < 0.8 * rms["PD"]
    # ... while the stiffer PD (1000 vs 300 Nm/rad) builds the breakaway torque against elx's 6.1 Nm of
    # stiction sooner, so over the whole run (ramps included) PD has the smaller error
    assert result.rms_velocity_error_all["PD"] < result.rms_velocity_error_all["impedance"]
    # both follow the commanded speed: error at constant speed below 5 % of 0.3 rad/s
    assert max(rms.values()) < 0.05 * result.setup.speed
    assert result.model_info == {"source": "perturbed", "level": 0.1, "seed": 0}


@pytest.mark.slow
def test_velocity_tracking_plot_shows_both_controllers(result, monkeypatch, tmp_path):
    from matplotlib.figure import Figure

    saved = []
    original = Figure.savefig

    def savefig(self, *args, **kwargs):
        saved.append(self)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", savefig)
    assert plot_velocity_tracking(result, tmp_path / "fig5.png").is_file()
    (fig,) = saved
    top, bottom = fig.axes
    labels = [ln.get_label() for ln in top.get_lines()]
    assert labels[0] == "dq_d,4"
    assert labels[1].startswith("PD (RMS error ") and labels[2].startswith("impedance (RMS error ")
    for ln, name in zip(top.get_lines()[1:], ("PD", "impedance"), strict=True):
        np.testing.assert_array_equal(ln.get_ydata(), result.traces[name].dq[:, 3])
    assert [ln.get_label() for ln in bottom.get_lines()] == ["PD", "impedance"]
    assert top.get_ylabel() == "dq_4 [rad/s]" and bottom.get_xlabel() == "t [s]"
