"""Batch regressor against Pinocchio, base parameters of the built-in arms, friction regressor (15)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from reflexarm.ident import BatchRegressor, compute_base_parameters, compute_friction_regressor
from reflexarm.ident.estimation.base_parameters import random_samples
from reflexarm.robots import CoulombViscousFriction, RobotModel, load_robot
from rpr_arm import rpr_urdf

ROBOTS = ["atlas_v5_left_arm", "panda"]

# Both implementations evaluate the same Newton-Euler recursion in double precision; regressor entries
# are O(1..100) (accelerations up to ~10 rad/s^2 times lever arms), so 1e-10 absolute leaves four orders
# of magnitude over round-off and is far below any modelling difference (a wrong frame gives O(1) errors).
REGRESSOR_ATOL = 1e-10


@pytest.fixture(scope="module", params=ROBOTS)
def robot(request):
    return load_robot(request.param)


def _samples(robot, n, seed):
    return random_samples(robot, n, np.random.default_rng(seed))


def test_batch_regressor_equals_pinocchio_sample_by_sample(robot):
    q, dq, ddq = _samples(robot, 60, seed=1)
    Y = BatchRegressor(robot).compute_regressor(q, dq, ddq)
    assert Y.shape == (60, robot.n, 10 * robot.n)
    for k in range(60):
        np.testing.assert_allclose(
            Y[k], robot.compute_regressor(q[k], dq[k], ddq[k]), atol=REGRESSOR_ATOL, err_msg=f"sample {k}"
        )


def test_regressor_times_parameters_is_rnea(robot):
    q, dq, ddq = _samples(robot, 40, seed=2)
    tau = BatchRegressor(robot).compute_regressor(q, dq, ddq) @ robot.inertial_parameters()
    rnea = np.array([robot.compute_inverse_dynamics(q[k], dq[k], ddq[k]) for k in range(40)])
    # torques are O(10..100) Nm; the two routes differ by round-off only
    np.testing.assert_allclose(tau, rnea, atol=1e-9)


URDF_PRISMATIC = rpr_urdf()


def test_batch_regressor_handles_prismatic_and_unaligned_axes(tmp_path):
    path = tmp_path / "rpr.urdf"
    path.write_text(URDF_PRISMATIC)
    robot = RobotModel(pin.buildModelFromUrdf(str(path)), ee_frame="l3")
    q, dq, ddq = _samples(robot, 30, seed=3)
    Y = BatchRegressor(robot).compute_regressor(q, dq, ddq)
    for k in range(30):
        np.testing.assert_allclose(Y[k], robot.compute_regressor(q[k], dq[k], ddq[k]), atol=REGRESSOR_ATOL)


def test_friction_regressor_is_eq15_and_matches_the_friction_model():
    dq = np.array([[0.5, -0.2, 0.0], [-1.0, 2.0, 0.3]])
    F = compute_friction_regressor(dq)
    fr = CoulombViscousFriction(np.zeros(3), np.zeros(3))
    for k in range(2):
        np.testing.assert_array_equal(F[k], fr.compute_regressor(dq[k]))
    Fo = compute_friction_regressor(dq, offset=True)
    np.testing.assert_array_equal(Fo[:, :, 6:], np.broadcast_to(np.eye(3), (2, 3, 3)))


def test_atlas_has_43_base_parameters_upright_and_45_with_tilted_gravity(atlas):
    """The paper's 45 (of 70) for the Atlas arm: our arm hangs from an upright torso, so the shoulder
    joint shz is vertical and gravity does no work on it; of link 1 only the inertia about shz moves a
    joint (9 parameters have no effect at all). Tilt gravity away from the shz axis (a torso that is
    not upright, as on the standing robot) and two more combinations become identifiable: 45."""
    bp = compute_base_parameters(atlas)
    assert bp.n_base == 43
    text = bp.explain()
    assert "link 1:  0 base (-); 1 lumped (Izz); 9 no effect (m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz)" in text
    tilted = atlas.copy()
    tilted.gravity = [0.5, 0.0, -9.8]
    assert compute_base_parameters(tilted).n_base == 45


def test_panda_has_43_base_parameters():
    assert compute_base_parameters(load_robot("panda")).n_base == 43


def test_base_parameters_reproduce_torques_on_new_samples(robot):
    bp = compute_base_parameters(robot, seed=0)
    q, dq, ddq = _samples(robot, 50, seed=99)  # not the samples the reduction saw
    Y = BatchRegressor(robot).compute_regressor(q, dq, ddq)
    pi = robot.inertial_parameters()
    np.testing.assert_allclose(bp.select(Y) @ bp.base_from_standard(pi), Y @ pi, atol=1e-9)
    # the QR diagonal shows a clean gap: the rank is not a matter of the tolerance
    assert bp.diagonal[bp.n_base - 1] > 1e-4 and bp.diagonal[bp.n_base] < 1e-12


def test_standard_from_base_is_consistent_and_nearest_to_nominal(robot):
    bp = compute_base_parameters(robot)
    pi0 = robot.inertial_parameters()
    beta = bp.base_from_standard(pi0) * 1.05
    pi = bp.standard_from_base(beta, pi0)
    np.testing.assert_allclose(bp.base_from_standard(pi), beta, rtol=1e-10, atol=1e-12)
    # nearest: the change lies in the row space of the base map (orthogonal to its null space)
    A = bp.matrix()
    null = np.linalg.svd(A)[2][bp.n_base :]
    np.testing.assert_allclose(null @ (pi - pi0), 0.0, atol=1e-10)
    # and the model built from it has the torques of beta
    model = robot.with_inertial_parameters(pi)
    q, dq, ddq = _samples(robot, 5, seed=4)
    Yb = bp.select(BatchRegressor(robot).compute_regressor(q, dq, ddq))
    for k in range(5):
        np.testing.assert_allclose(model.compute_inverse_dynamics(q[k], dq[k], ddq[k]), Yb[k] @ beta, atol=1e-9)


def test_base_parameter_map_roundtrips_through_dict(atlas):
    from reflexarm.ident import BaseParameters

    bp = compute_base_parameters(atlas)
    again = BaseParameters.from_dict(bp.to_dict())
    pi = atlas.inertial_parameters()
    np.testing.assert_array_equal(again.base_from_standard(pi), bp.base_from_standard(pi))
    assert len(bp.base_names()) == bp.n_base
