"""Collision detection, eq. (12): a constant per-joint threshold zeta on the observed disturbance."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from reflexarm._validation import as_vector

__all__ = ["CollisionDetector"]


class CollisionDetector:
    """CollDet = 1 if |tau_eps_hat_i| > zeta_i for any joint i, eq. (12) (taken on the magnitude).

    The detection latches: after the first crossing :attr:`detected` stays True until :meth:`reset`.
    :attr:`first_time` and :attr:`first_joints` record when and where it first happened.

    Args:
        n: number of joints.
        threshold: zeta per joint [Nm], positive; scalar or (n,).
    """

    def __init__(self, n: int, threshold: npt.ArrayLike) -> None:
        self.n = int(n)
        self.threshold = as_vector(threshold, self.n, "threshold", positive=True)
        self.detected = False
        self.first_time: float | None = None
        self.first_joints: tuple[int, ...] = ()
        self._threshold_list = self.threshold.tolist()

    def reset(self) -> None:
        self.detected = False
        self.first_time = None
        self.first_joints = ()

    def update(self, residual: np.ndarray, t: float) -> tuple[int, ...]:
        """Check one sample; returns the joints whose |residual| exceeds the threshold now."""
        # plain floats: for a handful of joints this is cheaper than three numpy calls
        joints = tuple(
            i for i, (r, z) in enumerate(zip(residual.tolist(), self._threshold_list, strict=True)) if r > z or -r > z
        )
        if joints:
            self.record(joints, t)
        return joints

    def record(self, joints: tuple[int, ...], t: float) -> None:
        """Register a threshold crossing of ``joints`` at time ``t`` (latches the detection)."""
        if not self.detected:
            self.detected = True
            self.first_time = float(t)
            self.first_joints = joints
