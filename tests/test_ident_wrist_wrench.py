"""The wrist wrench enters the regression when it explains the torque, not when it is only noise
(issue 18 item 6), on generated logs: Panda torques by inverse dynamics plus friction, the paper's noise."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from reflexarm.ident import identify_dynamics, validate_model
from reflexarm.ident.excitation.fourier_trajectory import FourierTrajectory
from reflexarm.logs.robot_log import RobotLog
from reflexarm.robots import load_robot
from reflexarm.sim import PAPER_NOISE

RATE = 100.0  # [Hz]


@pytest.fixture(scope="module")
def panda():
    return load_robot("panda")


def _log(robot, seed, *, contact=None, wrench=True):
    """One 10 s period of a random Fourier motion about the range centre, torques from the model plus the
    paper's torque noise; the wrench: the contact (if any) plus the paper's force/torque sensor noise."""
    rng = np.random.default_rng(seed)
    n, L = robot.n, 4
    a, b = 0.1 * rng.normal(size=(n, L)), 0.1 * rng.normal(size=(n, L))
    a[:, 0] = -a[:, 1:].sum(axis=1)
    b[:, 0] = -(b[:, 1:] * np.arange(2, L + 1)).sum(axis=1)
    tr = FourierTrajectory(2 * np.pi * 0.1, a, b, 0.5 * (robot.lower_limit + robot.upper_limit))
    t = np.arange(int(tr.duration * RATE)) / RATE
    q, dq, ddq = tr.evaluate(t)
    tau = np.array([robot.compute_motor_torque(q[k], dq[k], ddq[k]) for k in range(t.size)])
    F = np.zeros((t.size, 6))
    if contact is not None:  # tau_m + J^T F = model torque (eq. 14)
        F[:] = contact
        tau -= np.array([robot.compute_frame_jacobian(q[k]).T @ F[k] for k in range(t.size)])
    tau += rng.normal(0.0, PAPER_NOISE.tau_m, tau.shape)
    noise = np.column_stack(
        [rng.normal(0.0, PAPER_NOISE.force, (t.size, 3)), rng.normal(0.0, PAPER_NOISE.torque, (t.size, 3))]
    )
    return RobotLog(t=t, q=q, dq=dq, tau=tau, ddq=ddq, wrench=F + noise if wrench else None, source=f"gen{seed}")


def test_a_wrench_of_only_noise_is_left_out_and_says_why(panda):
    log = _log(panda, 1)
    val = _log(panda, 2, wrench=False)
    auto = identify_dynamics(panda, log, method="combined")
    without = identify_dynamics(panda, replace(log, wrench=None), method="combined")
    today = identify_dynamics(panda, log, method="combined", wrench="include")  # what the regression did before
    (note,) = [x for x in auto.notes if "wrench" in x]
    assert note.startswith("wrist wrench left out: it does not explain the measured torque (alpha = ")
    assert "it carries only sensor noise" in note
    # left out, the estimate is the one without the wrench (same rows; round-off of the extra column only)
    np.testing.assert_allclose(auto.beta_b, without.beta_b, rtol=1e-6, atol=1e-9)
    # and better than including its noise: measured 0.159 vs 0.182 Nm pooled RMSE on a held-out log
    rmse_auto = validate_model(auto, panda, val).pooled_rmse
    rmse_today = validate_model(today, panda, val).pooled_rmse
    assert rmse_auto < 0.95 * rmse_today, (rmse_auto, rmse_today)


def test_a_wrench_that_measures_a_contact_is_included(panda):
    """A constant 20 N / -10 N contact at the hand: the wrench explains the torque and is used; leaving
    it out would leave the contact torque in the torque rows (measured 0.150 vs 4.0 Nm pooled RMSE)."""
    contact = np.array([20.0, 0.0, -10.0, 0.0, 0.0, 0.0])
    log = _log(panda, 3, contact=contact)
    val = _log(panda, 4, wrench=False)
    auto = identify_dynamics(panda, log, method="combined")
    (note,) = [x for x in auto.notes if "wrench" in x]
    assert note.startswith("wrist wrench included as eq. (14) says")
    excluded = identify_dynamics(panda, log, method="combined", wrench="exclude")
    rmse_auto = validate_model(auto, panda, val).pooled_rmse
    rmse_excluded = validate_model(excluded, panda, val).pooled_rmse
    assert rmse_auto < 0.2 * rmse_excluded, (rmse_auto, rmse_excluded)


def test_validation_scores_against_the_wrench_only_when_it_explains_the_error(panda):
    """A held-out log whose wrench is only noise is scored against its measured torque alone (J^T F of the
    noise would add ~0.2 Nm RMS to the reference); one with a contact against tau_m + J^T F."""
    model = identify_dynamics(panda, _log(panda, 1, wrench=False), method="combined")
    noisy = _log(panda, 2)
    v_noise = validate_model(model, panda, noisy)
    v_clean = validate_model(model, panda, replace(noisy, wrench=None))
    np.testing.assert_array_equal(v_noise.measured, v_clean.measured)
    assert "wrist wrench left out" in v_noise.friction_model
    contact = _log(panda, 4, contact=np.array([20.0, 0.0, -10.0, 0.0, 0.0, 0.0]))
    v_contact = validate_model(model, panda, contact)
    assert "wrist wrench included" in v_contact.friction_model
    # (its force noise stays in the reference: J^T n_F, ~1 Nm RMS here; without the wrench the contact's
    # torque would stay in the error instead)
    v_without = validate_model(model, panda, replace(contact, wrench=None))
    assert v_contact.pooled_rmse < 0.5 * v_without.pooled_rmse, (v_contact.pooled_rmse, v_without.pooled_rmse)
