"""Measured joint torque from motor currents: ``tau_j = k_j i_j`` with a gain ``k_j`` [Nm/A] per joint.

Many arms log motor currents, not joint torques. The gain of a joint is its motor's torque constant
times its gear ratio (and the gear's efficiency, if the vendor folds it in); a vendor usually publishes
it per joint. A negative gain flips the sign (a motor mounted the other way round). The reader takes
the currents (mapping key ``current``, columns ``current_1..n`` / ``current_<joint>``, a JointState's
effort field in a bag) when asked to (``torque_from="current"``; on the command line ``--torque-from
current --gains 0.1,0.1,...``) and turns them into the log's measured torque here, saying so in a note.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError

__all__ = ["check_gains", "torque_from_current"]


def check_gains(gains: npt.ArrayLike | None, n: int | None, where: str) -> np.ndarray:
    """The gains [Nm/A] as an (n,) array: one finite, non-zero number per joint.

    Raises:
        ConfigError: no gains, a count other than ``n`` (``n`` None: any count), a zero or non-finite gain;
            the message names the log (``where``), the count or the joint.
    """
    if gains is None:
        raise ConfigError(
            f"{where}: the torque from motor currents needs the gain of every joint [Nm/A] (motor torque constant x "
            "gear ratio), e.g. --gains 0.1,0.1,0.1,0.1,0.1,0.1"
        )
    try:
        k = np.asarray(gains, dtype=float).reshape(-1)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{where}: gains must be numbers [Nm/A]; got {gains!r}") from e
    if n is not None and k.size != n:
        raise ConfigError(
            f"{where}: {k.size} gain(s) given for {n} joints: give one gain per joint [Nm/A] in the model's joint "
            f"order ({', '.join(['G'] * n)})"
        )
    bad = np.flatnonzero(~np.isfinite(k) | (k == 0.0))
    if bad.size:
        j = int(bad[0])
        raise ConfigError(
            f"{where}: the gain of joint {j + 1} is {float(k[j])!r}; gains must be finite and non-zero [Nm/A]"
        )
    return k


def torque_from_current(
    current: np.ndarray, gains: npt.ArrayLike | None, where: str, columns: Sequence[str] = ()
) -> tuple[np.ndarray, str]:
    """(``current * gains`` (N, n) [Nm], a note saying so) for motor currents ``current`` (N, n) [A]."""
    k = check_gains(gains, current.shape[1], where)
    source = f" (columns {', '.join(columns)})" if columns else ""
    note = (
        f"{where}: measured torque = gain x motor current{source}, gains {', '.join(f'{g:g}' for g in k)} Nm/A "
        f"(|current| up to {float(np.max(np.abs(current))):.4g} A -> |torque| up to "
        f"{float(np.max(np.abs(current * k))):.4g} Nm)"
    )
    return current * k, note
