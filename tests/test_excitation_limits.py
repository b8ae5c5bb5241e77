"""Excitations stay within torque, joint and workspace limits, checked by an independent inverse-dynamics
pass (Pinocchio's RNEA on a model built here from the URDF) and the URDF's own collision cylinders."""

from __future__ import annotations

import csv
import warnings

import numpy as np
import pinocchio as pin
import pytest

from gen3_like import GEN3_LINKS, GEN3_TIP, GEN3_VELOCITY, write_gen3_like_urdf
from reflexarm.ident.excitation.design import excitation_limits, optimize_excitation
from reflexarm.ident.excitation.export import ExcitationLimitError, sample_excitation, write_excitation_csv
from reflexarm.ident.excitation.fourier_trajectory import FourierTrajectory
from reflexarm.robots import load_robot

#: The test file's joint friction (``<dynamics damping="0.1" friction="0.3"/>`` on every joint).
VISCOUS, COULOMB = 0.1, 0.3
#: Round-off allowance of the independent checks: the CSV holds 10 significant digits.
ROUND_OFF = 1e-6
TORQUE_FRACTION = 0.5


@pytest.fixture(scope="module")
def gen3(tmp_path_factory):
    folder = tmp_path_factory.mktemp("gen3")
    path = write_gen3_like_urdf(folder, rounded_pi=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return path, load_robot(path, tip=GEN3_TIP)


@pytest.fixture(scope="module")
def exported(gen3, tmp_path_factory):
    """A briefly optimized excitation (3 harmonics, 3 iterations: a short run, any result must be within)
    with half the effort limits, exported at 200 Hz and read back from the CSV."""
    _, robot = gen3
    design = optimize_excitation(
        robot, n_harmonics=3, maxiter=3, n_samples=40, n_grid=100, n_grid_dynamics=30, seed=1,
        torque_fraction=TORQUE_FRACTION,
    )  # fmt: skip
    sampled = sample_excitation(design.trajectory.with_periods(1), robot, rate=200.0, limits=design.limits)
    path = write_excitation_csv(sampled, tmp_path_factory.mktemp("csv") / "traj.csv")
    with path.open() as fh:
        rows = list(csv.reader(fh))
    data = np.array(rows[1:], dtype=float)
    n = robot.n
    return design, data[:, 1 : 1 + n], data[:, 1 + n : 1 + 2 * n], data[:, 1 + 2 * n :]


def _independent_torque(urdf, q, dq, ddq):
    """RNEA of Pinocchio's own URDF parser (not reflexarm's loader) plus the file's friction law."""
    model = pin.buildModelFromUrdf(str(urdf))
    data = model.createData()
    tau = np.array([pin.rnea(model, data, q[k], dq[k], ddq[k]) for k in range(q.shape[0])])
    return tau + VISCOUS * dq + COULOMB * np.sign(dq)


def _lowest_point(urdf, q):
    """Lowest point over the samples of the URDF's collision cylinders (axis along each link's z)."""
    model = pin.buildModelFromUrdf(str(urdf))
    data = model.createData()
    low = np.inf
    for k in range(q.shape[0]):
        pin.forwardKinematics(model, data, q[k])
        for j, link in enumerate(GEN3_LINKS):
            com, (radius, length) = np.array(link[8]), link[10]
            M = data.oMi[j + 1]
            centre = M.act(com)
            axis = M.rotation[:, 2]
            reach = 0.5 * length * abs(axis[2]) + radius * np.sqrt(max(1.0 - axis[2] ** 2, 0.0))
            low = min(low, centre[2] - reach)
    return low


@pytest.mark.slow  # a short optimization with the nonlinear limits (~1 min)
def test_exported_excitation_is_within_every_limit_by_an_independent_check(gen3, exported):
    urdf, robot = gen3
    design, q, dq, ddq = exported
    effort = np.array([link[5] for link in GEN3_LINKS], dtype=float)
    tau = _independent_torque(urdf, q, dq, ddq)
    use = np.abs(tau) / (TORQUE_FRACTION * effort)
    assert use.max() <= 1.0 + ROUND_OFF, (use.max(), np.unravel_index(np.argmax(use), use.shape))
    lo, hi = robot.lower_limit, robot.upper_limit
    assert np.all(q >= lo - ROUND_OFF) and np.all(q <= hi + ROUND_OFF)
    assert np.abs(dq).max() <= GEN3_VELOCITY + ROUND_OFF
    assert np.abs(ddq).max() <= max(design.limits.max_acceleration) + ROUND_OFF
    # workspace: the arm stands on its base, so the default floor is the base plane (2 cm clearance)
    assert design.limits.floor == 0.0
    assert _lowest_point(urdf, q) >= 0.0, _lowest_point(urdf, q)
    # the design's own report agrees with the independent torque within the CSV's rounding
    assert design.limits_optimized["torque"] <= 1.0
    assert design.limit_report["torque"]["use"] == pytest.approx(use.max(), abs=0.02)


def test_a_csv_beyond_the_torque_limit_is_refused(gen3):
    """A trajectory that asks more torque than the bound is refused, naming joint, value and limit."""
    _, robot = gen3
    limits, _ = excitation_limits(robot, torque_fraction=0.05, floor=None, self_collision=False)
    rng = np.random.default_rng(0)
    a = 0.1 * rng.normal(size=(7, 3))
    a[:, 0] = -a[:, 1:].sum(axis=1)
    b = np.zeros((7, 3))
    q0 = np.array([0.0, 0.5, 0.0, 0.5, 0.0, 0.5, 0.0])
    tr = FourierTrajectory(2 * np.pi * 0.2, a, b, q0)
    with pytest.raises(ExcitationLimitError, match=r"joint \d \(joint_\d\) torque -?[\d.]+ Nm at t = .* beyond its "
                       r"(upper|lower) limit") as err:  # fmt: skip
        sample_excitation(tr, robot, rate=100.0, limits=limits)
    assert err.value.quantity == "torque" and err.value.excess > 0


def test_a_csv_below_the_floor_is_refused(gen3):
    """Shoulder and elbow folding forward by up to 1.7 rad bring the hand below the base plane: refused,
    naming the link and the depth."""
    _, robot = gen3
    limits, _ = excitation_limits(robot, torque_fraction=None, floor=0.0, self_collision=False)
    a = np.zeros((7, 2))
    a[1] = a[3] = [0.4, -0.4]
    tr = FourierTrajectory(2 * np.pi * 0.05, a, np.zeros((7, 2)), np.zeros(7))
    with pytest.raises(ExcitationLimitError, match=r"the link of joint \d \(joint_\d\) goes [\d.]+ m below the floor "
                       r"z = 0 m at t = [\d.]+ s \(workspace\)") as err:  # fmt: skip
        sample_excitation(tr, robot, rate=100.0, limits=limits)
    assert err.value.quantity == "workspace" and err.value.excess > 0


def test_a_recorded_run_that_leaves_the_trajectory_is_reported(gen3):
    """``excite --record`` compares the log with the trajectory: a joint 0.2 rad off, a torque at its limit
    in a tenth of the samples and the hand below the base plane are each reported with a WARNING."""
    from reflexarm.experiments.identification import DEVIATION_WARN, describe_tracking
    from reflexarm.logs.robot_log import RobotLog

    _, robot = gen3
    a = np.zeros((7, 2))
    a[1] = a[3] = [0.4, -0.4]  # folds forward to below the base plane (see the test above)
    tr = FourierTrajectory(2 * np.pi * 0.05, a, np.zeros((7, 2)), np.zeros(7))
    t = np.arange(0.0, tr.period, 0.01)
    q, dq, _ = tr.evaluate(t)
    q[:, 2] += 0.2  # joint 3 off by 0.2 rad > DEVIATION_WARN
    tau = np.zeros_like(q)
    tau[: t.size // 10, 1] = 0.98 * robot.effort_limit[1]
    lines = describe_tracking(robot, tr, RobotLog(t=t, q=q, dq=dq, tau=tau, source="rec"))
    assert 0.2 > DEVIATION_WARN
    assert lines[0].startswith("WARNING: recorded run vs the trajectory: largest deviation 0.2 rad on joint 3")
    assert lines[1].startswith("WARNING: measured torque at >= 97 % of the effort limit: 10 % of the samples on")
    assert lines[2].startswith("WARNING: lowest point of the arm in the run:") and "below the base plane" in lines[2]


def _one_joint_swing(robot, peak_velocity):
    """Joint 1 swings as dq = s (cos(2 w t) - cos(w t)) (at rest at t = 0), the other joints stay at 0: its
    speed peaks once, at t = T / 2 (|dq| = 2 s there), scaled to ``peak_velocity``; returns (par, x)."""
    from reflexarm.ident.excitation.cost import Parametrisation

    par = Parametrisation(robot.n, 2, 2 * np.pi * 0.1)  # a 10 s period
    a = np.zeros((robot.n, 2))
    a[0, 1] = 0.5 * peak_velocity
    return par, par.pack(a, np.zeros((robot.n, 2)), np.zeros(robot.n))


def test_the_constraint_grid_adds_the_time_of_a_peak_between_its_points(gen3):
    """A velocity peak between the grid's points passes the grid; refining the grid at 1 kHz adds the
    peak's sample time, and the refined grid no longer passes it. Within the limit at 1 kHz: no refinement."""
    from reflexarm.ident.excitation.constraints import CHECK_STEP, ConstraintGrid
    from reflexarm.ident.excitation.limits import LimitEvaluator

    _, robot = gen3
    limits, _ = excitation_limits(robot, torque_fraction=None, floor=None, self_collision=False)
    evaluator = LimitEvaluator(robot, limits, None)
    vmax = limits.max_velocity[0]
    # 8 points at (k + 1/2) T / 8: the nearest to the peak (t = 5 s) see cos(2 phi) - cos(phi) = 0.815 of it
    par, x = _one_joint_swing(robot, 1.05 * vmax)
    grid = ConstraintGrid(par, limits, evaluator, (np.arange(8) + 0.5) * 10.0 / 8, np.zeros(0))
    assert grid.feasible(x)
    refined = grid.refined(x)
    assert refined is not None
    added = np.setdiff1d(refined.t_linear, grid.t_linear)
    np.testing.assert_allclose(added, [5.0], atol=0.5 * CHECK_STEP)  # the peak, to the sampling's resolution
    assert not refined.feasible(x)
    # 1 % within the limit at 1 kHz: nothing to add
    assert grid.refined(_one_joint_swing(robot, 0.99 * vmax)[1]) is None


def test_dense_margins_match_the_optimizers_margins(gen3):
    """LimitEvaluator.margin_samples (vectorised, for the 1 kHz check) gives the values of .margins (per
    sample, with derivatives, what the optimizer sees) for the torque, floor and self-collision bounds."""
    from reflexarm.ident.excitation.cost import Parametrisation
    from reflexarm.ident.excitation.limits import LimitEvaluator, arm_geometry

    _, robot = gen3
    limits, _ = excitation_limits(robot, floor=0.0)
    geometry = arm_geometry(robot, np.zeros(robot.n))
    evaluator = LimitEvaluator(robot, limits, geometry)
    assert evaluator.torque_joints.size and evaluator.use_floor and evaluator.pairs
    par = Parametrisation(robot.n, 3, 2 * np.pi * 0.1)
    rng = np.random.default_rng(4)
    x = 0.3 * rng.normal(size=par.size)
    t = np.linspace(0.0, 10.0, 7)
    q, dq, ddq = par.trajectory(x).evaluate(t)
    values, _ = evaluator.margins(q, dq, ddq, *par.linear_maps(t))
    dense = evaluator.margin_samples(q, dq, ddq)
    # the same quantities along two code paths (loops vs vectorised): agreement to round-off of O(1) margins
    np.testing.assert_allclose(dense, values.reshape(t.size, -1), rtol=0, atol=1e-12)


def test_a_peak_between_grid_points_is_restored_without_shrinking(gen3):
    """restored() moves a trajectory whose joint 1 speed peaks 5 % over the limit between grid points onto
    the limit at 1 kHz (nothing left for the final check to shrink) and leaves joint 2, well within its
    limits, as it was, where a uniform shrink would scale both joints by 1/1.05."""
    from reflexarm.ident.excitation.constraints import ConstraintGrid, check_at_1khz
    from reflexarm.ident.excitation.limits import LimitEvaluator

    _, robot = gen3
    limits, _ = excitation_limits(robot, torque_fraction=None, floor=None, self_collision=False)
    evaluator = LimitEvaluator(robot, limits, None)
    vmax = limits.max_velocity[0]
    par, x = _one_joint_swing(robot, 1.05 * vmax)
    a, b, q0 = par.unpack(x)
    a[1] = 0.5 * a[0] / 1.05 * 0.5  # joint 2: the same swing at half the speed limit
    x = par.pack(a, b, q0)
    grid = ConstraintGrid(par, limits, evaluator, (np.arange(8) + 0.5) * 10.0 / 8, np.zeros(0))
    y = grid.restored(x)
    assert grid.refined(y) is None  # within every limit at 1 kHz
    checked, _ = check_at_1khz(par, y, limits, evaluator)
    np.testing.assert_allclose(checked, y, rtol=1e-12, atol=0)  # the final check leaves it as it is (round-off)
    uses = par.trajectory(y).check_limits(limits.lower, limits.upper, limits.max_velocity, limits.max_acceleration)
    # on the limit (SLSQP's constraint tolerance, FEASIBILITY_TOLERANCE = 1e-6 of vmax), not below it
    assert uses["velocity"] == pytest.approx(1.0, abs=1e-6)
    # joint 2's coefficients kept (no constraint of joint 2 is active: the nearest point does not move them;
    # 1e-8 rad/s allows SLSQP's round-off), and the move is no larger than the uniform shrink's (the shrunk
    # trajectory is one of the points the projection could have chosen)
    np.testing.assert_allclose(par.unpack(y)[0][1], par.unpack(x)[0][1], atol=1e-8)
    np.testing.assert_allclose(par.unpack(y)[1][1], par.unpack(x)[1][1], atol=1e-8)
    assert np.linalg.norm(y - x) <= np.linalg.norm(par.scaled(x, 1 / 1.05) - x) * (1 + 1e-9)
