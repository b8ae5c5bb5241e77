"""Compiled (numba) inner loop of :meth:`reflexarm.control.Controller.step`.

One fused pass over the joints replaces some twenty small numpy calls whose dispatch overhead would
otherwise dominate a 1 kHz control tick. The math is exactly that of :class:`MomentumObserver`
(eqs. (4)-(6)), eq. (2) and eq. (12); ``tests/test_control.py`` checks the two against each other.

The tick first checks every input against the controller's contract (shapes, time stamp, finiteness,
plausibility bounds, model terms, the damping factorization) and returns a negative fault code *before*
writing any state; only an accepted tick updates the observers, the damping matrix and the clock.

All parameters and state live in one flat float64 ``work`` array (a header of scalars, then ``N_ROWS``
rows of n values, then three n x n matrices) so that the call unboxes as few arguments as possible. The
kernels are compiled for float64 arrays only (explicit signatures): an argument of another dtype raises
``TypeError`` at the call instead of compiling a new specialization inside the control loop (the
controller converts such inputs before the call, see ``Controller.step``).
"""

from __future__ import annotations

import numpy as np
from numba import njit, types

from reflexarm.control._damping import modal_damping_into

# ---- header entries of ``work`` (scalars)
(
    N_JOINTS,
    DT,  # nominal control period [s]
    PERIOD_LO,  # band of the integrated period [s]
    PERIOD_HI,
    INV_BAND,  # 1 / friction velocity band
    KAPPA_F,
    KAPPA_EXT,
    EPS_WEIGHT,  # ramped kappa_eps actually applied
    LIMIT,  # residual cut-off for compensation [Nm]
    USE_DET,  # a second (detection) observer runs
    GRAVITY_MODE,  # reaction (13) active
    UPDATE_DAMPING,  # recompute D from the M block this tick
    STARTED,  # observers initialised (p(0) taken)
    HAS_T,  # a time stamp was accepted since reset
    LAST_T,  # last accepted time stamp [s]
    HAS_LAST_Q,  # LAST_Q row holds an accepted position
    OBS_INVALID,  # latched: the observer state became non-finite
    HAS_PREV_TAU,  # TAU row holds the previous command
    G_NORM,  # |gravity| of the model [m/s^2]
    G_TOL,  # accepted deviation of |gravity| from G_NORM [m/s^2]
    FORCE_MAX,  # |wrist force component| bound [N]
    MOMENT_MAX,  # |wrist moment component| bound [Nm]
    T_COUNT,  # timing statistics: measured periods, their sum, min, max, number clipped
    T_SUM,
    T_MIN,
    T_MAX,
    T_CLIPPED,
    F_SIGNAL,  # fault details: signal id, component, value, bound(s)
    F_INDEX,
    F_VALUE,
    F_LO,
    F_HI,
    N_SAT,  # joints saturated this tick
) = range(33)
N_HEADER = 33

# ---- rows of n values
(
    K_ROW,
    KO_ROW,
    KO_DET_ROW,
    THRESHOLD_ROW,
    COULOMB_ROW,
    VISCOUS_ROW,
    DAMPING_RATIO_ROW,
    Q_LO_ROW,  # plausibility bounds of q and q_d [rad]
    Q_HI_ROW,
    DQ_MAX_ROW,  # of |dq| and |dq_d| [rad/s]
    DDQ_MAX_ROW,  # of |ddq_d| [rad/s^2]
    TAU_M_MAX_ROW,  # of |tau_m| [Nm]
    TAU_MAX_ROW,  # saturation of the command [Nm]
    TAU_STEP_ROW,  # largest change of the command per tick [Nm]
    INT_ROW,  # observer state: integral, p(0), residual (compensation observer) ...
    P0_ROW,
    R_ROW,
    INT_DET_ROW,  # ... and the same for the detection observer
    P0_DET_ROW,
    R_DET_ROW,
    LAST_Q_ROW,  # last accepted measured position
    TAU_ROW,  # the last command sent
    OVER_ROW,  # 1 where |residual| > threshold this tick
    SAT_ROW,  # 1 where the command was saturated / rate limited this tick
    TAU_NEW_ROW,  # this tick's command while it is computed
) = range(25)
N_ROWS = 25
# ---- n x n matrices after the rows
D_MAT, M_MAT, D_NEW_MAT = range(3)
N_MATS = 3

# ---- signal ids (F_SIGNAL)
SIG_T, SIG_Q, SIG_DQ, SIG_TAU_M, SIG_WRENCH, SIG_GRAVITY, SIG_Q_D, SIG_DQ_D, SIG_DDQ_D, SIG_MODEL = range(10)

# ---- fault codes (negative return values; 0..: accepted, see ``controller_tick``)
BAD_SHAPE = -1  # F_SIGNAL has F_VALUE elements, F_HI expected
NON_FINITE = -2  # F_SIGNAL[F_INDEX] = F_VALUE is NaN/inf
OUT_OF_BOUNDS = -3  # F_SIGNAL[F_INDEX] = F_VALUE outside [F_LO, F_HI]
TIME_NOT_INCREASING = -4  # t = F_VALUE <= last accepted t = F_LO
MODEL_NON_FINITE = -5  # a Pinocchio term is NaN/inf
MASS_NOT_POSITIVE_DEFINITE = -6  # the damping update's Cholesky factorization failed
OBSERVER_INVALID = -7  # latched until reset
OUTPUT_NON_FINITE = -8  # the control law gave NaN/inf (never expected with accepted inputs); latches as -7

SAT_SHIFT = 8  # accepted return value: n_over + (n_saturated << SAT_SHIFT)

# inputs are read-only views of any layout (read-only and strided float64 arrays need no copy); ``work`` is
# the one array written
_IN1 = types.Array(types.float64, 1, "A", readonly=True)
_IN2 = types.Array(types.float64, 2, "A", readonly=True)
TICK_SIGNATURE = types.int64(
    types.float64, *[_IN1] * 8, _IN1, _IN2, _IN1, _IN1, _IN2, types.Array(types.float64, 1, "C")
)


def layout_size(n: int) -> int:
    """Length of the ``work`` array for n joints."""
    return N_HEADER + N_ROWS * n + N_MATS * n * n


@njit(cache=True)
def _rows(work, n):  # pragma: no cover - compiled
    return work[N_HEADER : N_HEADER + N_ROWS * n].reshape((N_ROWS, n))


@njit(cache=True)
def _mats(work, n):  # pragma: no cover - compiled
    return work[N_HEADER + N_ROWS * n : N_HEADER + N_ROWS * n + N_MATS * n * n].reshape((N_MATS, n, n))


@njit(cache=True)
def _fault(work, code, signal, index, value, lo, hi):  # pragma: no cover - compiled
    work[F_SIGNAL] = signal
    work[F_INDEX] = index
    work[F_VALUE] = value
    work[F_LO] = lo
    work[F_HI] = hi
    return code


@njit(cache=True)
def _check_box(x, lo, hi, work, signal):  # pragma: no cover - compiled
    """0 if every x[i] is finite and within [lo[i], hi[i]], else the fault code (details in ``work``)."""
    for i in range(x.shape[0]):
        v = x[i]
        if not np.isfinite(v):
            return _fault(work, NON_FINITE, signal, i, v, lo[i], hi[i])
        if v < lo[i] or v > hi[i]:
            return _fault(work, OUT_OF_BOUNDS, signal, i, v, lo[i], hi[i])
    return 0


@njit(cache=True)
def _check_abs(x, bound, work, signal):  # pragma: no cover - compiled
    """0 if every |x[i]| <= bound[i] (and finite), else the fault code."""
    for i in range(x.shape[0]):
        v = x[i]
        if not np.isfinite(v):
            return _fault(work, NON_FINITE, signal, i, v, -bound[i], bound[i])
        if v > bound[i] or -v > bound[i]:
            return _fault(work, OUT_OF_BOUNDS, signal, i, v, -bound[i], bound[i])
    return 0


@njit(TICK_SIGNATURE, cache=True)
def controller_tick(t, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d, g, C, p, ff, J, work):  # noqa: D103
    # Returns a fault code < 0 (nothing written but the fault details), or n_over + (n_sat << SAT_SHIFT).
    n = int(work[N_JOINTS])
    rows = _rows(work, n)
    mats = _mats(work, n)
    # ---------------------------------------------------------------- 1. shapes
    for sig, length, want in (
        (SIG_Q, q.shape[0], n),
        (SIG_DQ, dq.shape[0], n),
        (SIG_TAU_M, tau_m.shape[0], n),
        (SIG_WRENCH, wrench.shape[0], 6),
        (SIG_GRAVITY, gravity.shape[0], 3),
        (SIG_Q_D, q_d.shape[0], n),
        (SIG_DQ_D, dq_d.shape[0], n),
        (SIG_DDQ_D, ddq_d.shape[0], n),
    ):
        if length != want:
            return _fault(work, BAD_SHAPE, sig, -1, length, want, want)
    # ---------------------------------------------------------------- 2. time
    if not np.isfinite(t):
        return _fault(work, NON_FINITE, SIG_T, -1, t, -np.inf, np.inf)
    if work[HAS_T] != 0.0 and not t > work[LAST_T]:
        return _fault(work, TIME_NOT_INCREASING, SIG_T, -1, t, work[LAST_T], np.inf)
    # ---------------------------------------------------------------- 3. values against the bounds
    code = _check_box(q, rows[Q_LO_ROW], rows[Q_HI_ROW], work, SIG_Q)
    if code == 0:
        code = _check_abs(dq, rows[DQ_MAX_ROW], work, SIG_DQ)
    if code == 0:
        code = _check_abs(tau_m, rows[TAU_M_MAX_ROW], work, SIG_TAU_M)
    if code == 0:
        fm, mm = work[FORCE_MAX], work[MOMENT_MAX]
        for k in range(6):
            b = fm if k < 3 else mm
            v = wrench[k]
            if not np.isfinite(v):
                return _fault(work, NON_FINITE, SIG_WRENCH, k, v, -b, b)
            if v > b or -v > b:
                return _fault(work, OUT_OF_BOUNDS, SIG_WRENCH, k, v, -b, b)
        gn = 0.0
        for k in range(3):
            if not np.isfinite(gravity[k]):
                return _fault(work, NON_FINITE, SIG_GRAVITY, k, gravity[k], -np.inf, np.inf)
            gn += gravity[k] * gravity[k]
        gn = np.sqrt(gn)
        lo = max(work[G_NORM] - work[G_TOL], 0.0)
        hi = work[G_NORM] + work[G_TOL]
        if gn < lo or gn > hi:
            return _fault(work, OUT_OF_BOUNDS, SIG_GRAVITY, -1, gn, lo, hi)
        code = _check_box(q_d, rows[Q_LO_ROW], rows[Q_HI_ROW], work, SIG_Q_D)
    if code == 0:
        code = _check_abs(dq_d, rows[DQ_MAX_ROW], work, SIG_DQ_D)
    if code == 0:
        code = _check_abs(ddq_d, rows[DDQ_MAX_ROW], work, SIG_DDQ_D)
    if code != 0:
        return code
    # ---------------------------------------------------------------- 4. model terms
    kappa_ext = work[KAPPA_EXT]
    acc = 0.0
    for i in range(n):
        acc += g[i] + p[i] + ff[i]
        for j in range(n):
            acc += C[i, j]
        if kappa_ext != 0.0:
            for k in range(6):
                acc += J[k, i]
    if not np.isfinite(acc):
        return _fault(work, MODEL_NON_FINITE, SIG_MODEL, -1, acc, 0.0, 0.0)
    gravity_mode = work[GRAVITY_MODE] != 0.0
    update_damping = work[UPDATE_DAMPING] != 0.0 and not gravity_mode
    if update_damping:
        if not modal_damping_into(mats[M_MAT], rows[K_ROW], rows[DAMPING_RATIO_ROW], mats[D_NEW_MAT]):
            return _fault(work, MASS_NOT_POSITIVE_DEFINITE, SIG_MODEL, -1, 0.0, 0.0, 0.0)
    # ---------------------------------------------------------------- accepted: commit from here on
    for i in range(n):
        rows[LAST_Q_ROW, i] = q[i]
    work[HAS_LAST_Q] = 1.0
    if update_damping:
        D = mats[D_MAT]
        Dn = mats[D_NEW_MAT]
        for i in range(n):
            for j in range(n):
                D[i, j] = Dn[i, j]
    work[UPDATE_DAMPING] = 0.0
    # clock: the observer integrates the measured period clipped to [PERIOD_LO, PERIOD_HI]
    period = work[DT]
    if work[HAS_T] != 0.0:
        measured = t - work[LAST_T]
        period = min(max(measured, work[PERIOD_LO]), work[PERIOD_HI])
        if work[T_COUNT] == 0.0:
            work[T_MIN] = measured
            work[T_MAX] = measured
        else:
            work[T_MIN] = min(work[T_MIN], measured)
            work[T_MAX] = max(work[T_MAX], measured)
        work[T_COUNT] += 1.0
        work[T_SUM] += measured
        if period != measured:
            work[T_CLIPPED] += 1.0
    work[HAS_T] = 1.0
    work[LAST_T] = t
    if work[OBS_INVALID] != 0.0:
        return OBSERVER_INVALID
    use_det = work[USE_DET] != 0.0
    integrate = work[STARTED] != 0.0
    if not integrate:  # p(0): the integral of (4) starts here, nothing to integrate yet
        for i in range(n):
            rows[INT_ROW, i] = 0.0
            rows[R_ROW, i] = 0.0
            rows[P0_ROW, i] = p[i]
            rows[INT_DET_ROW, i] = 0.0
            rows[R_DET_ROW, i] = 0.0
            rows[P0_DET_ROW, i] = p[i]
        work[STARTED] = 1.0
    inv_band = work[INV_BAND]
    kappa_f = work[KAPPA_F]
    eps_w = work[EPS_WEIGHT]
    limit = work[LIMIT]
    D = mats[D_MAT]
    n_over = 0
    n_sat = 0
    obs_acc = 0.0
    has_prev = work[HAS_PREV_TAU] != 0.0
    for i in range(n):
        # gamma = g - C^T dq  (5);  C dq for (2)
        ct_dq = 0.0
        c_dq = 0.0
        for j in range(n):
            ct_dq += C[j, i] * dq[j]
            c_dq += C[i, j] * dq[j]
        # alpha = kappa_f tau_f - kappa_ext J^T F  (6)
        s = dq[i] * inv_band
        if s > 1.0:
            s = 1.0
        elif s < -1.0:
            s = -1.0
        tau_f = rows[COULOMB_ROW, i] * s + rows[VISCOUS_ROW, i] * dq[i]
        alpha = kappa_f * tau_f
        if kappa_ext != 0.0:
            jt_f = 0.0
            for k in range(6):
                jt_f += J[k, i] * wrench[k]
            alpha -= jt_f
        base = tau_m[i] - (g[i] - ct_dq) - alpha
        # momentum observer (4), explicit Euler over the measured period
        if integrate:
            rows[INT_ROW, i] += period * (base + rows[R_ROW, i])
            rows[R_ROW, i] = rows[KO_ROW, i] * (p[i] - rows[P0_ROW, i] - rows[INT_ROW, i])
            if use_det:
                rows[INT_DET_ROW, i] += period * (base + rows[R_DET_ROW, i])
                rows[R_DET_ROW, i] = rows[KO_DET_ROW, i] * (p[i] - rows[P0_DET_ROW, i] - rows[INT_DET_ROW, i])
        obs_acc += rows[INT_ROW, i] + rows[R_ROW, i] + rows[INT_DET_ROW, i] + rows[R_DET_ROW, i]
        r_det = rows[R_DET_ROW, i] if use_det else rows[R_ROW, i]
        # detection (12)
        if r_det > rows[THRESHOLD_ROW, i] or -r_det > rows[THRESHOLD_ROW, i]:
            rows[OVER_ROW, i] = 1.0
            n_over += 1
        else:
            rows[OVER_ROW, i] = 0.0
        # control law (2) or gravity compensation (13)
        if gravity_mode:
            tau = g[i]
        else:
            d_e = 0.0
            for j in range(n):
                d_e += D[i, j] * (dq_d[j] - dq[j])
            tau = rows[K_ROW, i] * (q_d[i] - q[i]) + d_e + g[i] + c_dq + ff[i] + kappa_f * tau_f
            if eps_w != 0.0:
                r = rows[R_ROW, i]
                if r > limit:
                    r = limit
                elif r < -limit:
                    r = -limit
                tau -= eps_w * r
        if not np.isfinite(tau):  # the observers are part-way updated: they latch as invalid either way
            work[OBS_INVALID] = 1.0
            if not np.isfinite(obs_acc):
                return OBSERVER_INVALID
            return _fault(work, OUTPUT_NON_FINITE, SIG_MODEL, i, tau, 0.0, 0.0)
        # bounded torque: per-tick rate limit, then saturation
        sat = 0.0
        if has_prev:
            step = rows[TAU_STEP_ROW, i]
            prev = rows[TAU_ROW, i]
            if tau > prev + step:
                tau = prev + step
                sat = 1.0
            elif tau < prev - step:
                tau = prev - step
                sat = 1.0
        tmax = rows[TAU_MAX_ROW, i]
        if tau > tmax:
            tau = tmax
            sat = 1.0
        elif tau < -tmax:
            tau = -tmax
            sat = 1.0
        rows[SAT_ROW, i] = sat
        if sat != 0.0:
            n_sat += 1
        rows[TAU_NEW_ROW, i] = tau
    if not np.isfinite(obs_acc):
        work[OBS_INVALID] = 1.0
        return OBSERVER_INVALID
    for i in range(n):
        rows[TAU_ROW, i] = rows[TAU_NEW_ROW, i]
    work[HAS_PREV_TAU] = 1.0
    work[N_SAT] = n_sat
    return n_over + (n_sat << SAT_SHIFT)


_warm = False


def warm_up() -> None:
    """Resolve the tick's dispatch for writable and for read-only float64 inputs once per process (the first
    call with a new kind of array otherwise costs a few hundred microseconds, no compilation)."""
    global _warm
    if _warm:
        return
    work = np.zeros(layout_size(0))  # n = 0: every array is the wrong length, the call returns at once
    for readonly in (False, True):
        vecs = [np.zeros(1) for _ in range(11)]
        mats = [np.zeros((1, 1)) for _ in range(2)]
        for a in vecs + mats:
            a.flags.writeable = not readonly
        controller_tick(0.0, *vecs[:8], vecs[8], mats[0], vecs[9], vecs[10], mats[1], work)  # type: ignore[call-arg]
    _warm = True
