"""Whether the wrist wrench enters the regression: it does when the data say it explains the torque.

Eq. (14) explains the measured torque plus the external torque of the wrist wrench, ``tau_m + J^T F``.
A wrench topic that carries only sensor noise (no contact during the excitation) adds nothing but its
noise, ``J(q)^T n_F``: 2.3 N of force noise on a ~1 m arm is ~2 Nm on the shoulder, 30 times the paper's
torque noise. So the regression first asks the data: with ``tau_m = Phi_b beta - alpha J^T F`` and alpha
a free unknown (one more column, ``-J^T F``, in the weighted least squares), alpha comes out ~1 when the
wrench measures real external forces and ~0 when it is noise (its errors are uncorrelated with the
torque; errors in a regressor pull alpha towards 0 in proportion to its noise share). Then:

* alpha within :data:`SIGNIFICANCE` standard deviations of 0: the wrench is **left out** (it explains
  nothing; including it would only add its noise), and the result says so with the numbers;
* otherwise it is **included** as eq. (14) says (alpha = 1); its noise then enters each joint's residual
  variance, hence its weight in Sigma of (18) (the two-step weighting).

alpha itself is not a calibration of the sensor: a constant force at the hand acts like a point mass
there and is partly absorbed by the inertial parameters (measured: 0.80 for a constant 20 N + 10 N
contact on the Panda), so only its distance from 0 is used.

The standard deviation of alpha is that of the weighted least squares, scaled by the row correlation of
filtered data (:func:`~reflexarm.ident.estimation.inertia_determinacy.filtered_rows_factor`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: alpha within this many standard deviations of 0 (of 1) counts as 0 (as 1): 3 sigma, a 0.3 % chance
#: of calling a real wrench noise under Gaussian errors.
SIGNIFICANCE = 3.0

__all__ = ["SIGNIFICANCE", "WristWrenchDecision", "decide_wrist_wrench", "validation_reference"]


class WristWrenchDecision(NamedTuple):
    """alpha (its estimate and standard deviation), whether the wrench is used, and why (a sentence)."""

    alpha: float
    alpha_std: float
    included: bool
    reason: str


def decide_wrist_wrench(alpha: float, alpha_std: float) -> WristWrenchDecision:
    """The decision of the module docstring for an estimated alpha +- alpha_std."""
    std = max(alpha_std, 1e-300)
    est = f"alpha = {alpha:.3g} +- {alpha_std:.2g} in tau_m = Phi_b beta_b - alpha J^T F"
    if abs(alpha) < SIGNIFICANCE * std:
        return WristWrenchDecision(
            alpha, alpha_std, False,
            f"wrist wrench left out: it does not explain the measured torque ({est}, within {SIGNIFICANCE:g} sigma "
            "of 0): it carries only sensor noise, which would enter the regression through J^T F",
        )  # fmt: skip
    return WristWrenchDecision(
        alpha, alpha_std, True,
        f"wrist wrench included as eq. (14) says (J^T F added to the measured torque; it explains the torque: {est}, "
        f"beyond {SIGNIFICANCE:g} sigma of 0); its noise enters each joint's residual variance, hence its weight "
        "in Sigma",
    )  # fmt: skip


def validation_reference(
    wrench_torque: np.ndarray, measured: np.ndarray, predicted: np.ndarray
) -> tuple[np.ndarray, WristWrenchDecision]:
    """The torque a model's prediction is scored against on a log with a wrist wrench: ``measured + J^T F``
    when the wrench explains the prediction's error (alpha of ``predicted - measured = alpha J^T F`` beyond
    :data:`SIGNIFICANCE` sigma of 0), else ``measured`` alone (a wrench of only noise would add its noise to
    the reference). ``wrench_torque`` is J^T F per sample (N, n) [Nm]."""
    w = wrench_torque.reshape(-1)
    e = (predicted - measured).reshape(-1)
    ww = float(w @ w)
    alpha = float(w @ e) / max(ww, 1e-300)
    r = e - alpha * w
    alpha_std = float(np.sqrt(float(r @ r) / max(e.size - 1, 1) / max(ww, 1e-300)))
    decision = decide_wrist_wrench(alpha, alpha_std)
    return (measured + wrench_torque if decision.included else measured), decision
