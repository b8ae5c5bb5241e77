"""Controller.step against its floor (the bare Pinocchio calls it needs) and against a naive step.

All three are timed in the same process on the same sequence of states, so the printed ratios do not
depend on how fast this machine is. Run with ``make bench`` (or ``python bench/bench_controller.py``).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import pinocchio as pin
import scipy.linalg

from reflexarm import Measurement, Reference, load_robot
from reflexarm.control import Controller

N_STATES = 2000
REPEATS = 5


def states(robot, n=N_STATES, seed=0):
    """Measurements and references along a smooth joint motion (with sensor-like noise)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    w = 2 * np.pi * 0.5
    amp = 0.3
    out = []
    for ti in t:
        q_d = robot.home + amp * np.sin(w * ti)
        dq_d = amp * w * np.cos(w * ti) * np.ones(robot.n)
        ddq_d = -amp * w * w * np.sin(w * ti) * np.ones(robot.n)
        q = q_d + rng.uniform(-3.4e-4, 3.4e-4, robot.n)
        dq = dq_d + rng.uniform(-5.5e-2, 5.5e-2, robot.n)
        tau = robot.compute_gravity(q) + rng.uniform(-1, 1, robot.n)
        m = Measurement(float(ti), q, dq, tau, rng.uniform(-2.3, 2.3, 6), np.array([0.0, 0.0, -9.81]))
        out.append((m, Reference(q_d, dq_d, ddq_d)))
    return out


def time_per_call(fn: Callable[[Measurement, Reference], object], seq) -> np.ndarray:
    """Per-call wall times [s] over REPEATS passes of the sequence."""
    ts = np.empty(len(seq) * REPEATS)
    k = 0
    clock = time.perf_counter
    for _ in range(REPEATS):
        for m, r in seq:
            t0 = clock()
            fn(m, r)
            ts[k] = clock() - t0
            k += 1
    return ts


def make_floor(robot, efc: bool):
    """The Pinocchio calls Controller.step makes, and nothing else."""
    model = robot.pin_model.copy()
    d_g, d_c, d_j = model.createData(), model.createData(), model.createData()
    model0 = model.copy()
    model0.gravity.linear = np.zeros(3)
    d_p, d_ff = model0.createData(), model0.createData()
    zeros = np.zeros(robot.n)
    fid = robot.sensor_frame_id

    def floor(m: Measurement, r: Reference) -> None:
        pin.computeGeneralizedGravity(model, d_g, m.q)
        pin.computeCoriolisMatrix(model, d_c, m.q, m.dq)
        pin.rnea(model0, d_p, m.q, zeros, m.dq)
        pin.rnea(model0, d_ff, r.q_d, zeros, r.ddq_d)
        if efc:
            pin.computeFrameJacobian(model, d_j, m.q, fid, pin.LOCAL)

    return floor


def make_naive(robot, efc: bool, k=300.0, xi=0.7, k_o=5.0, dt=1e-3):
    """The same law written the obvious way: every term recomputed separately, allocations everywhere."""
    r = robot.copy()
    state = {"I": None, "p0": None, "res": np.zeros(robot.n)}
    K = np.diag(np.full(robot.n, k))

    def naive(m: Measurement, ref: Reference) -> np.ndarray:
        M = r.compute_mass_matrix(m.q)
        C = r.compute_coriolis_matrix(m.q, m.dq)
        g = r.compute_gravity(m.q)
        Md = r.compute_mass_matrix(ref.q_d)
        lam, V = scipy.linalg.eigh(K, M)
        Vinv = np.linalg.inv(V)
        D = Vinv.T @ np.diag(2 * xi * np.sqrt(lam)) @ Vinv
        p = M @ m.dq
        alpha = np.zeros(robot.n)
        if efc:
            alpha = alpha - r.compute_frame_jacobian(m.q).T @ m.wrench
        if state["I"] is None:
            state["I"] = np.zeros(robot.n)
            state["p0"] = p
        state["I"] = state["I"] + dt * (m.tau_m - (g - C.T @ m.dq) + state["res"] - alpha)
        state["res"] = k_o * (p - state["p0"] - state["I"])
        tau = K @ (ref.q_d - m.q) + D @ (ref.dq_d - m.dq) + g + C @ m.dq + Md @ ref.ddq_d
        if efc:
            tau = tau - np.clip(state["res"], -30, 30)
        if np.any(np.abs(state["res"]) > 11):
            pass
        return tau

    return naive


def main() -> dict[str, float]:
    robot = load_robot("atlas_v5_left_arm")
    seq = states(robot)
    results: dict[str, float] = {}
    print("Controller.step on atlas_v5_left_arm (7 joints), median per call over", N_STATES * REPEATS, "calls")
    print(
        f"{'configuration':34s} {'step [us]':>10s} {'mean':>8s} {'p99':>8s} {'floor':>8s} {'naive':>8s} "
        f"{'step/floor':>10s} {'naive/step':>10s}"
    )
    for label, kw, efc in (
        ("detection (kappa_eps=0)", dict(kappa_eps=0, kappa_ext=0, reaction="none"), False),
        ("DC + EFC (kappa_eps=kappa_ext=1)", dict(kappa_eps=1, kappa_ext=1, reaction="none"), True),
    ):
        ctrl = Controller(robot, stiffness=300, observer_gain=5, threshold=11, **kw)
        floor = make_floor(robot, efc)
        naive = make_naive(robot, efc)
        # warm up, then interleave the three so drifts in machine load hit all of them alike
        for fn in (ctrl.step, floor, naive):
            time_per_call(fn, seq[:200])
        t_step, t_floor, t_naive = [], [], []
        for _ in range(3):
            t_step.append(time_per_call(ctrl.step, seq))
            t_floor.append(time_per_call(floor, seq))
            t_naive.append(time_per_call(naive, seq))
        s, f, nv = (np.concatenate(x) * 1e6 for x in (t_step, t_floor, t_naive))
        ms, mf, mn = np.median(s), np.median(f), np.median(nv)
        print(
            f"{label:34s} {ms:10.1f} {s.mean():8.1f} {np.percentile(s, 99):8.1f} {mf:8.1f} {mn:8.1f} "
            f"{ms / mf:10.2f} {mn / ms:10.2f}"
        )
        key = "efc" if efc else "det"
        results.update(
            {f"step_us_{key}": ms, f"floor_us_{key}": mf, f"naive_us_{key}": mn, f"step_mean_us_{key}": float(s.mean())}
        )
    return results


if __name__ == "__main__":
    main()
