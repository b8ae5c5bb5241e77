"""JointTrajectory: minimum-jerk segments (boundary conditions, derivatives by finite differences)."""

from __future__ import annotations

import numpy as np
import pytest

from reflexarm.errors import ConfigError
from reflexarm.sim import JointTrajectory

W = np.array([[0.0, 1.0, -0.5], [1.0, 0.5, 0.5], [-0.5, 0.5, 2.0]])


def test_passes_through_waypoints_at_rest():
    traj = JointTrajectory(W, [1.0, 2.0], t0=0.5, holds=[0.25, 0.5, 0.0])
    assert traj.duration == pytest.approx(3.75) and traj.t_end == pytest.approx(4.25)
    for t, q in [(0.5, W[0]), (0.75, W[0]), (1.75, W[1]), (2.25, W[1]), (4.25, W[2])]:
        r = traj.sample(t)
        np.testing.assert_allclose(r.q_d, q, atol=1e-15, err_msg=f"t={t}")
        np.testing.assert_allclose(r.dq_d, 0.0, atol=1e-15)
        np.testing.assert_allclose(r.ddq_d, 0.0, atol=1e-15)
    # before t0 and after the end: hold the first/last waypoint
    np.testing.assert_array_equal(traj.sample(-3.0).q_d, W[0])
    np.testing.assert_array_equal(traj.sample(100.0).q_d, W[2])
    # half-way through a rest-to-rest quintic: the midpoint, at the peak speed 15/8 * delta / T
    r = traj.sample(0.75 + 0.5)
    np.testing.assert_allclose(r.q_d, (W[0] + W[1]) / 2, atol=1e-15)
    np.testing.assert_allclose(r.dq_d, 15.0 / 8.0 * (W[1] - W[0]) / 1.0, atol=1e-14)
    np.testing.assert_allclose(r.ddq_d, 0.0, atol=1e-14)


def test_derivatives_match_central_differences():
    """Central differences with h = 1e-5: truncation error ~h^2 q''' ~ 1e-9, round-off ~1e-16 / h = 1e-11;
    1e-7 (rad/s, rad/s^2) is far above both and far below any wrong coefficient (order 1)."""
    traj = JointTrajectory(W, [1.0, 2.0])
    h = 1e-5
    for t in np.linspace(0.01, 2.99, 37):
        r = traj.sample(t)
        a, b = traj.sample(t - h), traj.sample(t + h)
        np.testing.assert_allclose(r.dq_d, (b.q_d - a.q_d) / (2 * h), atol=1e-7)
        np.testing.assert_allclose(r.ddq_d, (b.dq_d - a.dq_d) / (2 * h), atol=1e-7)


def test_hold_and_sample_many():
    q = np.array([0.1, 0.2])
    traj = JointTrajectory.hold(q, 2.0)
    assert traj.duration == 2.0
    qs, dqs, ddqs = traj.sample_many([0.0, 1.0, 5.0])
    np.testing.assert_array_equal(qs, np.tile(q, (3, 1)))
    assert not dqs.any() and not ddqs.any()
    r = traj.sample(0.5)
    r.q_d[0] = 99.0  # fresh arrays: mutating a sample never changes the trajectory
    assert traj.sample(0.5).q_d[0] == 0.1


@pytest.mark.parametrize(
    ("waypoints", "durations", "kwargs", "message"),
    [
        (W[:1], [], {}, r"waypoints must have shape \(k, n\) with k >= 2 waypoints; got shape \(1, 3\)"),
        (W, [1.0], {}, r"durations must have shape \(2,\) \(one per segment of 3 waypoints\); got \(1,\)"),
        (W, [1.0, 0.0], {}, r"durations must be positive and finite \[s\]; got \[1.0, 0.0\]"),
        (W, [1.0, 1.0], {"holds": [0.0, -1.0, 0.0]}, r"holds must be 3 non-negative finite times"),
        (np.full((2, 3), np.nan), [1.0], {}, r"waypoints must be finite"),
    ],
)
def test_bad_arguments(waypoints, durations, kwargs, message):
    with pytest.raises(ConfigError, match=message):
        JointTrajectory(waypoints, durations, **kwargs)
