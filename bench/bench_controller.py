"""Controller.step against its floor (the bare Pinocchio calls it needs) and against a naive step.

All three are timed in the same process on the same sequence of states, so the printed ratios do not
depend on how fast this machine is. Run with ``make bench`` (or ``python bench/bench_controller.py``).

``python bench/bench_controller.py --baseline DIR`` times Controller.step of this checkout against the
one of another checkout ``DIR`` (e.g. ``git worktree add /tmp/base <commit>``): two subprocesses, one
per checkout, time one pass of the same states in turn, ``--rounds`` times per configuration; it prints
each side's median pass time and the median of the paired ratios (this checkout / DIR). A pass's time is the
mean per call without the calls above the pass's 99th percentile (the median would jump between the ticks
with and without a part of the modal damping computation, 50 % each). Each subprocess imports reflexarm
from its checkout's ``src/`` and the C++ core built in its ``build/<wheel tag>/`` (bench/_checkout.py),
not from the editable install; DIR therefore needs its own build, made once with
``python -m pip wheel --no-build-isolation --no-deps -w DIR/build/wheel DIR`` (this checkout has one after
``make install``). The files each side loaded are printed, and a build older than its C++ sources is flagged.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pinocchio as pin
import scipy.linalg

from _checkout import CheckoutError, check_loaded, compiled_modules, loaded_files, stale_sources
from _pinocchio_floor import floor_data
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


def time_per_call(fn: Callable[[Measurement, Reference], object], seq, reset: Callable[[], None] | None = None):
    """Per-call wall times [s] over REPEATS passes of the sequence (``reset`` before each pass: the time
    stamps start again, which a controller that checks them would refuse without a reset)."""
    ts = np.empty(len(seq) * REPEATS)
    k = 0
    clock = time.perf_counter
    for _ in range(REPEATS):
        if reset is not None:
            reset()
        for m, r in seq:
            t0 = clock()
            fn(m, r)
            ts[k] = clock() - t0
            k += 1
    return ts


def make_floor(robot, efc: bool):
    """The Pinocchio calls Controller.step makes, and nothing else."""
    f = floor_data(robot)
    model, model0, d_g, d_c, d_j, d_p, d_ff, zeros, fid = (
        f.model, f.model0, f.d_g, f.d_c, f.d_j, f.d_p, f.d_ff, f.zeros, f.fid
    )  # fmt: skip

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


def damping_ticks(ctrl: Controller, seq) -> np.ndarray:
    """Which calls of :func:`time_per_call`'s passes ran a part of the modal damping computation (the core
    spreads one over several ticks of each ``damping_update_period``): one pass after a reset, repeated."""
    ctrl.reset()
    parts = np.empty(len(seq), dtype=bool)
    for i, (m, r) in enumerate(seq):
        ctrl.step(m, r)
        parts[i] = ctrl._core.damping_parts_run != 0
    return np.tile(parts, REPEATS)


def main() -> dict[str, float]:
    robot = load_robot("atlas_v5_left_arm")
    seq = states(robot)
    results: dict[str, float] = {}
    print("Controller.step on atlas_v5_left_arm (7 joints), median per call over", N_STATES * REPEATS, "calls")
    print("(plain: ticks without a part of the modal damping computation; damping: ticks with one, their share)")
    print(
        f"{'configuration':34s} {'step [us]':>10s} {'plain':>7s} {'damping':>13s} {'mean':>7s} {'p99':>7s} "
        f"{'floor':>7s} {'naive':>7s} {'step/floor':>10s} {'plain/floor':>11s} {'naive/step':>10s}"
    )
    for label, kw, efc in (
        ("detection (kappa_eps=0)", dict(kappa_eps=0, kappa_ext=0, reaction="none"), False),
        ("DC + EFC (kappa_eps=kappa_ext=1)", dict(kappa_eps=1, kappa_ext=1, reaction="none"), True),
    ):
        ctrl = Controller(robot, stiffness=300, observer_gain=5, threshold=11, **kw)
        floor = make_floor(robot, efc)
        naive = make_naive(robot, efc)
        damping = np.tile(damping_ticks(ctrl, seq), 3)
        # warm up, then interleave the three so drifts in machine load hit all of them alike
        for fn in (ctrl.step, floor, naive):
            time_per_call(fn, seq[:200], ctrl.reset if fn == ctrl.step else None)
        t_step, t_floor, t_naive = [], [], []
        for _ in range(3):
            t_step.append(time_per_call(ctrl.step, seq, ctrl.reset))
            t_floor.append(time_per_call(floor, seq))
            t_naive.append(time_per_call(naive, seq))
        s, f, nv = (np.concatenate(x) * 1e6 for x in (t_step, t_floor, t_naive))
        ms, mf, mn = np.median(s), np.median(f), np.median(nv)
        mp, md = np.median(s[~damping]), np.median(s[damping])
        print(
            f"{label:34s} {ms:10.1f} {mp:7.1f} {md:7.1f} ({damping.mean():3.0%}) {s.mean():7.1f} "
            f"{np.percentile(s, 99):7.1f} {mf:7.1f} {mn:7.1f} {ms / mf:10.2f} {mp / mf:11.2f} {mn / ms:10.2f}"
        )
        key = "efc" if efc else "det"
        results.update(
            {f"step_us_{key}": ms, f"floor_us_{key}": mf, f"naive_us_{key}": mn, f"step_mean_us_{key}": float(s.mean()),
             f"step_plain_us_{key}": mp, f"step_damping_us_{key}": md}
        )  # fmt: skip
    return results


CONFIGS = (
    ("detection (kappa_eps=0)", dict(kappa_eps=0, kappa_ext=0, reaction="none")),
    ("DC + EFC (kappa_eps=kappa_ext=1)", dict(kappa_eps=1, kappa_ext=1, reaction="none")),
)


def trimmed_mean(ts: np.ndarray) -> float:
    """Mean of the times up to their 99th percentile (a preempted call does not weigh in)."""
    return float(np.mean(ts[ts <= np.percentile(ts, 99)]))


def serve() -> None:
    """Subprocess mode of ``--baseline``: for each config index read on stdin, time one pass of the states
    (after a reset) and print its trimmed mean step time [us]."""
    robot = load_robot("atlas_v5_left_arm")
    seq = states(robot)
    ctrls = [Controller(robot, stiffness=300, observer_gain=5, threshold=11, **kw) for _, kw in CONFIGS]
    for c in ctrls:
        time_per_call(c.step, seq[:500], c.reset)
    package, core = loaded_files()
    print(f"ready\t{package}\t{core}", flush=True)
    for line in sys.stdin:
        c = ctrls[int(line)]
        print(trimmed_mean(time_per_call(c.step, seq, c.reset)) * 1e6, flush=True)


def compare(baseline: Path, rounds: int) -> dict[str, float]:
    """This checkout's step times against ``baseline``'s: two subprocesses time one pass each in turn
    (order alternating), so drifts in machine load hit both alike; the ratio is the median of the paired
    per-pass ratios."""
    here = Path(__file__).resolve().parents[1]
    checkouts = {"baseline": baseline.resolve(), "this": here}
    for name, checkout in checkouts.items():
        stale = stale_sources(checkout, compiled_modules(checkout))  # CheckoutError if it has no build
        if stale:
            print(f"WARNING: the {name} build of reflexarm._core is older than {len(stale)} of its C++ sources "
                  f"(e.g. {stale[-1]}): rebuild it for a meaningful comparison")  # fmt: skip
    launcher = Path(__file__).with_name("_checkout.py")
    procs = {}
    for name, checkout in checkouts.items():
        procs[name] = subprocess.Popen(
            [sys.executable, str(launcher), str(checkout), Path(__file__).stem, "--serve"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
    for name, proc in procs.items():
        assert proc.stdout is not None
        line = proc.stdout.readline().rstrip("\n").split("\t")
        if line[0] != "ready":
            raise SystemExit(f"the {name} subprocess ({checkouts[name]}) did not start; see its error above")
        package, core = Path(line[1]), None if line[2] == "None" else Path(line[2])
        check_loaded(checkouts[name], package, core)
        print(f"{name:8s} = {checkouts[name]}: reflexarm from {package}, _core {core}")
    times: dict[str, dict[int, list[float]]] = {name: {i: [] for i in range(len(CONFIGS))} for name in procs}
    order = list(procs)
    for k in range(rounds):
        for i in range(len(CONFIGS)):
            for name in order if k % 2 == 0 else order[::-1]:
                proc = procs[name]
                assert proc.stdin is not None and proc.stdout is not None
                proc.stdin.write(f"{i}\n")
                proc.stdin.flush()
                times[name][i].append(float(proc.stdout.readline()))
    for proc in procs.values():
        assert proc.stdin is not None
        proc.stdin.close()
        proc.wait()
    print(
        f"Controller.step [us]: trimmed mean per call (calls above the pass's 99th percentile left out) of a pass "
        f"of {N_STATES * REPEATS} calls, median over {rounds} paired passes"
    )
    print(f"{'configuration':34s} {'baseline':>9s} {'this':>9s} {'this/baseline':>14s} {'(quartiles)':>14s}")
    ratios = {}
    for i, (label, _) in enumerate(CONFIGS):
        b, t = np.array(times["baseline"][i]), np.array(times["this"][i])
        r = t / b
        ratios[label] = float(np.median(r))
        q1, q3 = np.percentile(r, [25, 75])
        print(f"{label:34s} {np.median(b):9.2f} {np.median(t):9.2f} {np.median(r):14.3f} {q1:6.3f}-{q3:.3f}")
    return ratios


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, help="another checkout to compare Controller.step against")
    parser.add_argument("--rounds", type=int, default=20, help="paired passes per configuration")
    parser.add_argument("--serve", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        serve()
    elif args.baseline is not None:
        try:
            compare(args.baseline, args.rounds)
        except CheckoutError as e:
            raise SystemExit(f"bench_controller.py --baseline: {e}") from e
    else:
        main()
