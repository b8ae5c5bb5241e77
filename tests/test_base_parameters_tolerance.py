"""Base parameters count what data can determine: nearly aligned axes (a rounded pi) are not new ones."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.linalg

from gen3_like import GEN3_TIP, write_gen3_like_urdf
from reflexarm.ident import compute_base_parameters
from reflexarm.ident.estimation.base_parameters import (
    DEFAULT_RANK_TOLERANCE,
    ROUND_OFF_TOLERANCE,
    NearlyDependentWarning,
)
from reflexarm.ident.estimation.regressor import BatchRegressor
from reflexarm.robots import load_robot


@pytest.fixture(scope="module")
def gen3(tmp_path_factory):
    folder = tmp_path_factory.mktemp("gen3")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        exact = load_robot(write_gen3_like_urdf(folder, rounded_pi=False), tip=GEN3_TIP)
        rounded = load_robot(write_gen3_like_urdf(folder, rounded_pi=True), tip=GEN3_TIP)
    return exact, rounded


def test_rounded_pi_gives_the_base_parameters_of_exact_pi_and_names_the_joint(gen3):
    """``rpy="3.1416 0 0"`` on joint 1 tilts its axis 7.3e-6 rad off the vertical: two combinations of
    link 1 (its first moments under gravity) add torques 3e-6 of the largest, far below any torque
    measurement. Today's unit-normalised QR counts them: 45 instead of 43."""
    exact, rounded = gen3
    with warnings.catch_warnings():
        warnings.simplefilter("error", NearlyDependentWarning)
        bp_exact = compute_base_parameters(exact)  # exact pi: nothing nearly dependent, no warning
    assert bp_exact.n_base == 43 and bp_exact.note == ""
    named = r"joint 1 \(joint_1\) axis is 7\.3e-06 rad from parallel to gravity"
    with pytest.warns(NearlyDependentWarning, match=named) as rec:
        bp = compute_base_parameters(rounded)
    assert bp.n_base == 43
    w = rec[0].message
    assert isinstance(w, NearlyDependentWarning) and w.n_near == 2 and w.joints == (0,)
    # the two are well inside the band between round-off and the tolerance (measured 3.1e-6, 3.0e-6)
    assert all(ROUND_OFF_TOLERANCE < r < DEFAULT_RANK_TOLERANCE for r in w.relative)
    assert "nearly dependent" in bp.explain() and "joint_1" in bp.explain()
    # the same identifiable combinations as with exact pi: the row spaces of the maps beta_b = A pi
    # agree up to the tilt (largest principal angle measured 5.2e-6 rad for a 7.3e-6 rad tilt; bound 1e-4)
    angles = scipy.linalg.subspace_angles(bp.matrix().T, bp_exact.matrix().T)
    assert np.max(angles) < 1e-4, np.max(angles)


def test_rounded_pi_base_map_reproduces_torques_to_the_dropped_size(gen3):
    """beta_b reproduces the torques of the rounded arm up to what was dropped: the near-dependent
    combinations' torques, 3e-6 of the largest. Bound: 1e-4 (the tolerance) of the torque scale."""
    _, rounded = gen3
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NearlyDependentWarning)
        bp = compute_base_parameters(rounded)
    rng = np.random.default_rng(7)
    q = rng.uniform(-2.0, 2.0, (40, 7))
    dq, ddq = rng.normal(0, 1, (40, 7)), rng.normal(0, 3, (40, 7))
    Y = BatchRegressor(rounded).compute_regressor(q, dq, ddq)
    pi = rounded.inertial_parameters()
    full = Y @ pi
    np.testing.assert_allclose(
        bp.select(Y) @ bp.base_from_standard(pi), full, atol=DEFAULT_RANK_TOLERANCE * np.abs(full).max()
    )


def test_a_large_projection_change_is_explained(gen3):
    """``identify dynamics`` prints |delta beta_b| / |beta_b| of the consistency projection; a large one comes
    with the combinations that moved and by how many standard deviations (never a bare number)."""
    from dataclasses import replace

    from reflexarm.ident import identify_dynamics
    from reflexarm.ident.estimation.identify import PROJECTION_EXPLAIN, explain_projection
    from reflexarm.ident.excitation.fourier_trajectory import FourierTrajectory
    from reflexarm.logs.robot_log import RobotLog

    exact, _ = gen3
    rng = np.random.default_rng(0)
    a, b = 0.1 * rng.normal(size=(7, 4)), 0.1 * rng.normal(size=(7, 4))
    a[:, 0] = -a[:, 1:].sum(axis=1)
    b[:, 0] = -(b[:, 1:] * np.arange(2, 5)).sum(axis=1)
    tr = FourierTrajectory(2 * np.pi * 0.1, a, b, np.zeros(7))
    t = np.arange(1000) / 100.0
    q, dq, ddq = tr.evaluate(t)
    tau = np.array([exact.compute_motor_torque(q[k], dq[k], ddq[k]) for k in range(t.size)])
    tau += rng.normal(0.0, 0.05, tau.shape)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify_dynamics(exact, RobotLog(t=t, q=q, dq=dq, tau=tau, ddq=ddq, source="gen"), method="combined")
    assert explain_projection(res, res) == ""
    moved = res.beta_b.copy()
    moved[3] += 2.0 * np.linalg.norm(res.beta_b)  # a change far beyond PROJECTION_EXPLAIN
    text = explain_projection(res, replace(res, beta_b=moved))
    assert text.startswith("|delta beta_b| / |beta_b| = 2: the largest changes [")
    assert "sigma)" in text and res.base.base_names(max_terms=1)[3] in text
    assert PROJECTION_EXPLAIN < 2.0
