"""Compiled per-tick kernels of the plant (private).

MuJoCo's com-based spatial algebra (``cinert``, ``cvel``, ``cacc``, ``cfrc_*``: 6-vectors (angular;
linear) expressed in world orientation about ``subtree_com`` of the body's root) is reproduced here so
that the load compensation of the wrist sensor costs one call per tick.
"""

from __future__ import annotations

import numba
import numpy as np

# the layout of the packed integer index array of :func:`measurement` (then qadr (n), vadr (n), load (nload)): one
# definition, in the numba-free module the plant imports
from reflexarm.sim._kernel_layout import (
    IDX_COM_BODY,
    IDX_FORCE,
    IDX_HEADER,
    IDX_N,
    IDX_NLOAD,
    IDX_PHYSICAL,
    IDX_SITE,
    IDX_TORQUE,
)


@numba.njit(cache=True, inline="always")
def _mul_inert(i: np.ndarray, v: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """MuJoCo's mju_mulInertVec: com-based inertia (10,) times spatial motion vector (6,)."""
    out[0] = i[0] * v[0] + i[3] * v[1] + i[4] * v[2] - i[8] * v[4] + i[7] * v[5]
    out[1] = i[3] * v[0] + i[1] * v[1] + i[5] * v[2] + i[8] * v[3] - i[6] * v[5]
    out[2] = i[4] * v[0] + i[5] * v[1] + i[2] * v[2] - i[7] * v[3] + i[6] * v[4]
    out[3] = i[8] * v[1] - i[7] * v[2] + i[9] * v[3]
    out[4] = i[6] * v[2] - i[8] * v[0] + i[9] * v[4]
    out[5] = i[7] * v[0] - i[6] * v[1] + i[9] * v[5]


@numba.njit(cache=True)
def load_compensated_wrench(
    cinert: np.ndarray,
    cvel: np.ndarray,
    cacc: np.ndarray,
    cfrc: np.ndarray,
    sensordata: np.ndarray,
    load_bodies: np.ndarray,
    com_ref: np.ndarray,
    site_pos: np.ndarray,
    site_mat: np.ndarray,
    force_adr: int,
    torque_adr: int,
    physical: bool,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """External wrench on the sensor's load, in the sensor frame, about its origin, written to ``out[:6]``.

    ``physical``: the sensor body is welded to its parent, so the MuJoCo force/torque sensors report the
    wrench the parent exerts on the load subtree (``cfrc_int`` of the sensor body, in the site frame). The
    external wrench is then load inertia x acceleration (gravity included: MuJoCo's ``cacc`` carries
    -g) plus the velocity product, minus that reading: what a load-compensated sensor gives.
    Otherwise (``cfrc`` = ``cfrc_ext``) the external wrenches of the subtree are summed directly (an
    ideal sensor; used when the sensor frame sits on a moving link).
    """
    w = np.zeros(6)
    tmp = np.empty(6)
    tmp2 = np.empty(6)
    for b in load_bodies:
        if physical:
            _mul_inert(cinert[b], cacc[b], tmp)
            w += tmp
            _mul_inert(cinert[b], cvel[b], tmp)
            v = cvel[b]
            # mju_crossForce(v, f): (w x f_rot + u x f_lin ; w x f_lin)
            tmp2[0] = -v[2] * tmp[1] + v[1] * tmp[2] - v[5] * tmp[4] + v[4] * tmp[5]
            tmp2[1] = v[2] * tmp[0] - v[0] * tmp[2] + v[5] * tmp[3] - v[3] * tmp[5]
            tmp2[2] = -v[1] * tmp[0] + v[0] * tmp[1] - v[4] * tmp[3] + v[3] * tmp[4]
            tmp2[3] = -v[2] * tmp[4] + v[1] * tmp[5]
            tmp2[4] = v[2] * tmp[3] - v[0] * tmp[5]
            tmp2[5] = -v[1] * tmp[3] + v[0] * tmp[4]
            w += tmp2
        else:
            w += cfrc[b]
    # move the reference point from com_ref to the site: m_s = m_c - (s - c) x f
    dx = site_pos[0] - com_ref[0]
    dy = site_pos[1] - com_ref[1]
    dz = site_pos[2] - com_ref[2]
    mx = w[0] - (dy * w[5] - dz * w[4])
    my = w[1] - (dz * w[3] - dx * w[5])
    mz = w[2] - (dx * w[4] - dy * w[3])
    # rotate into the site frame: R^T x (site_mat is R row-major)
    for k in range(3):
        out[k] = site_mat[k] * w[3] + site_mat[3 + k] * w[4] + site_mat[6 + k] * w[5]
        out[3 + k] = site_mat[k] * mx + site_mat[3 + k] * my + site_mat[6 + k] * mz
    if physical:
        for k in range(3):
            out[k] -= sensordata[force_adr + k]
            out[3 + k] -= sensordata[torque_adr + k]


@numba.njit(cache=True)
def measurement(
    qpos: np.ndarray,
    qvel: np.ndarray,
    tau: np.ndarray,
    gravity: np.ndarray,
    cinert: np.ndarray,
    cvel: np.ndarray,
    cacc: np.ndarray,
    cfrc: np.ndarray,
    sensordata: np.ndarray,
    subtree_com: np.ndarray,
    site_xpos: np.ndarray,
    site_xmat: np.ndarray,
    idx: np.ndarray,
    noise: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """The measurement vector (q, dq, tau_m, wrench (6), gravity (3)) plus ``noise`` into ``out``.

    ``idx`` packs the integer layout (see ``IDX_*``) so that one call with few arguments does it all
    (numba's dispatch cost grows with the number of arguments).
    """
    n = idx[IDX_N]
    nload = idx[IDX_NLOAD]
    h = IDX_HEADER
    for i in range(n):
        out[i] = qpos[idx[h + i]] + noise[i]
        out[n + i] = qvel[idx[h + n + i]] + noise[n + i]
        out[2 * n + i] = tau[i] + noise[2 * n + i]
    site = idx[IDX_SITE]
    w = out[3 * n : 3 * n + 6]
    load_compensated_wrench(
        cinert,
        cvel,
        cacc,
        cfrc,
        sensordata,
        idx[h + 2 * n : h + 2 * n + nload],
        subtree_com[idx[IDX_COM_BODY]],
        site_xpos[site],
        site_xmat[site],
        idx[IDX_FORCE],
        idx[IDX_TORQUE],
        idx[IDX_PHYSICAL] != 0,
        w,
    )
    for k in range(6):
        w[k] += noise[3 * n + k]
    for k in range(3):
        out[3 * n + 6 + k] = gravity[k] + noise[3 * n + 6 + k]


@numba.njit(cache=True)
def set_torque(tau: np.ndarray, vadr: np.ndarray, stored: np.ndarray, qfrc: np.ndarray) -> float:  # pragma: no cover
    """Return sum(tau^2) (NaN/inf if any entry is); only if finite, copy ``tau`` to ``stored`` and ``qfrc[vadr]``."""
    s = 0.0
    for i in range(tau.size):
        s += tau[i] * tau[i]
    if s < np.inf:
        for i in range(tau.size):
            stored[i] = tau[i]
            qfrc[vadr[i]] = tau[i]
    return s


@numba.njit(cache=True)
def sum_squares(x: np.ndarray) -> float:  # pragma: no cover - compiled
    """sum(x^2) (NaN/inf if any entry is)."""
    s = 0.0
    for i in range(x.size):
        s += x[i] * x[i]
    return s


@numba.njit(cache=True)
def external_joint_torque(
    cfrc_ext: np.ndarray,
    cdof: np.ndarray,
    arm_bodies: np.ndarray,
    parent: np.ndarray,
    dof_body: np.ndarray,
    arm_dofs: np.ndarray,
    acc: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """tau_ext_j = cdof_j . (sum of ``cfrc_ext`` over the subtree of dof j's body), for the arm's dofs.

    Both ``cdof`` and ``cfrc_ext`` are com-based about the same point (the arm's root ``subtree_com``),
    so this is sum_b J_b^T F_b exactly. ``arm_bodies`` is sorted (parents before children); ``acc`` is a
    (nbody, 6) work array.
    """
    for k in range(arm_bodies.size):
        b = arm_bodies[k]
        for c in range(6):
            acc[b, c] = cfrc_ext[b, c]
    for k in range(arm_bodies.size - 1, 0, -1):
        b = arm_bodies[k]
        p = parent[b]
        for c in range(6):
            acc[p, c] += acc[b, c]
    for i in range(arm_dofs.size):
        j = arm_dofs[i]
        b = dof_body[j]
        s = 0.0
        for c in range(6):
            s += cdof[j, c] * acc[b, c]
        out[i] = s


@numba.njit(cache=True)
def sum_force(cfrc_ext: np.ndarray, bodies: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """out = sum over ``bodies`` of the force part of ``cfrc_ext``."""
    out[:] = 0.0
    for b in bodies:
        for c in range(3):
            out[c] += cfrc_ext[b, 3 + c]


@numba.njit(cache=True)
def quintic_sample(
    starts: np.ndarray, lengths: np.ndarray, origins: np.ndarray, deltas: np.ndarray, t_end: float, t: float
) -> np.ndarray:  # pragma: no cover - compiled
    """Rows (q, dq, ddq) of a chain of rest-to-rest minimum-jerk segments at time ``t`` (see JointTrajectory)."""
    nseg = starts.size
    if t <= starts[0]:
        i, s, ds, dds = 0, 0.0, 0.0, 0.0
    elif t >= t_end:
        i, s, ds, dds = nseg - 1, 1.0, 0.0, 0.0
    else:
        i = int(np.searchsorted(starts, t, side="right")) - 1
        T = lengths[i]
        x = (t - starts[i]) / T
        x2 = x * x
        s = x2 * x * (10.0 - 15.0 * x + 6.0 * x2)
        ds = 30.0 * x2 * (1.0 - 2.0 * x + x2) / T
        dds = 60.0 * x * (1.0 - 3.0 * x + 2.0 * x2) / (T * T)
    n = origins.shape[1]
    out = np.empty((3, n))
    for j in range(n):
        d = deltas[i, j]
        out[0, j] = origins[i, j] + s * d
        out[1, j] = ds * d
        out[2, j] = dds * d
    return out
