"""The tick against its four bare Pinocchio calls, from Python and inside C++, ratios in one run (issue 10).

Timed in the same process on the same states, interleaved round by round so that the load of the machine hits
them alike:

- from Python: ``Controller.step`` (the whole tick: one call into the C++ core, the Command built), the four
  (five with the wrist-wrench term, EFC) Pinocchio calls of a tick made from Python and nothing else, and the
  core's bare ``update`` (no Command);
- inside C++ (``reflexarm._core.time_tick_in_cpp``): ``reflexarm::Controller::update`` and the same Pinocchio
  calls made from C++, alternating which goes first.

Goals: Controller.step / calls from Python <= 1.0; update / calls inside C++ <= 1.5.

    python bench/bench_cpp_core.py [--rounds 7]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
import pinocchio as pin
import reflexarm._core as core

from _pinocchio_floor import floor_data
from reflexarm import Measurement, Reference, load_robot
from reflexarm.control import Controller
from reflexarm.control.controller import core_params

N_STATES = 1000


def make_states(robot, seed: int = 0) -> list[tuple]:
    """(t, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d) along a smooth motion with sensor-like noise."""
    rng = np.random.default_rng(seed)
    n = robot.n
    out = []
    for k in range(N_STATES):
        t = (k + 1) * 1e-3
        s = np.pi * t
        q_d = robot.home + 0.3 * np.sin(s)
        dq_d = 0.3 * np.pi * np.cos(s) * np.ones(n)
        ddq_d = -0.3 * np.pi**2 * np.sin(s) * np.ones(n)
        q = q_d + rng.uniform(-3.4e-4, 3.4e-4, n)
        dq = dq_d + rng.uniform(-5.5e-2, 5.5e-2, n)
        tau = robot.compute_gravity(q) + rng.uniform(-1, 1, n)
        out.append((t, q, dq, tau, rng.uniform(-2.3, 2.3, 6), np.array([0.0, 0.0, -9.81]), q_d, dq_d, ddq_d))
    return out


def per_call(fn: Callable[..., object], args: list[tuple], reset: Callable[[], None]) -> float:
    """Median wall time of one call ``fn(*a)`` over a pass of the argument tuples [s]."""
    reset()
    clock = time.perf_counter
    ts = np.empty(len(args))
    for i, a in enumerate(args):
        t0 = clock()
        fn(*a)
        ts[i] = clock() - t0
    return float(np.median(ts))


def make_controller(robot, efc: bool) -> Controller:
    return Controller(robot, kappa_f=1, kappa_eps=1, kappa_ext=int(efc), reaction="none")


def make_floor(robot, efc: bool) -> Callable[..., None]:
    """The Pinocchio calls of one tick, made from Python, and nothing else."""
    f = floor_data(robot)
    model, model0, d_g, d_c, d_j, d_p, d_ff, zeros, fid = (
        f.model, f.model0, f.d_g, f.d_c, f.d_j, f.d_p, f.d_ff, f.zeros, f.fid
    )

    def floor(t, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d) -> None:  # type: ignore[no-untyped-def]
        pin.computeGeneralizedGravity(model, d_g, q)
        pin.computeCoriolisMatrix(model, d_c, q, dq)
        pin.rnea(model0, d_p, q, zeros, dq)
        pin.rnea(model0, d_ff, q_d, zeros, ddq_d)
        if efc:
            pin.computeFrameJacobian(model, d_j, q, fid, pin.LOCAL)

    return floor


def in_cpp(robot, efc: bool, states: list[tuple], rounds: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-call times [s] of the tick and of its Pinocchio calls, both inside C++."""
    ctrl = make_controller(robot, efc)
    cols = list(zip(*states, strict=True))
    t = np.array(cols[0])
    arrays = [np.ascontiguousarray(np.array(c)) for c in cols[1:]]
    tick, calls, faults = core.time_tick_in_cpp(robot.pin_model.saveToString(), core_params(ctrl, core), t,
                                                *arrays, rounds)  # fmt: skip
    assert faults == 0, f"{faults} ticks faulted: the timing would not be of the tick"
    return np.asarray(tick), np.asarray(calls)


def main(rounds: int = 7) -> dict[str, float]:
    robot = load_robot("atlas_v5_left_arm")
    states = make_states(robot)
    print(f"{robot.name}, n={robot.n}, {N_STATES} states x {rounds} rounds (medians of per-round medians)")
    print(f"{'':14}{'---------------- from Python ----------------':>47}{'------- inside C++ -------':>32}")
    head = ("configuration", "step", "update", "calls", "step/calls", "update", "calls", "update/calls")
    print(f"{head[0]:<14}{head[1]:>10}{head[2]:>10}{head[3]:>10}{head[4]:>12}{head[5]:>10}{head[6]:>10}{head[7]:>14}")
    results: dict[str, float] = {}
    for efc in (False, True):
        step_ctrl, core_ctrl = make_controller(robot, efc), make_controller(robot, efc)
        # the caller's Measurement and Reference exist before the tick, as in a control loop
        prepared = [(Measurement(*s[:6]), Reference(*s[6:])) for s in states]
        runs = {
            "step": (step_ctrl.step, step_ctrl.reset, prepared),
            "update": (core_ctrl._core.update, core_ctrl.reset, states),
            "calls": (make_floor(robot, efc), lambda: None, states),
        }
        for fn, reset, seq in runs.values():  # warm-up pass
            per_call(fn, seq[:100], reset)
        med: dict[str, list[float]] = {k: [] for k in runs}
        cpp_tick: list[float] = []
        cpp_calls: list[float] = []
        for _ in range(rounds):
            for key, (fn, reset, seq) in runs.items():
                med[key].append(per_call(fn, seq, reset))
            tick, calls = in_cpp(robot, efc, states, 1)
            cpp_tick.append(float(np.median(tick)))
            cpp_calls.append(float(np.median(calls)))
        st, up, ca = (float(np.median(med[k])) * 1e6 for k in ("step", "update", "calls"))
        ct, cc = float(np.median(cpp_tick)) * 1e6, float(np.median(cpp_calls)) * 1e6
        name = "DC+EFC" if efc else "DC"
        py = f"{st:>7.2f} us{up:>7.2f} us{ca:>7.2f} us{st / ca:>12.2f}"
        print(f"{name:<14}{py}{ct:>7.2f} us{cc:>7.2f} us{ct / cc:>14.2f}")
        key = "efc" if efc else "dc"
        results.update({f"step_us_{key}": st, f"update_us_{key}": up, f"py_calls_us_{key}": ca,
                        f"step_over_calls_{key}": st / ca, f"cpp_update_us_{key}": ct, f"cpp_calls_us_{key}": cc,
                        f"cpp_update_over_calls_{key}": ct / cc})  # fmt: skip
    return results


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    main(parser.parse_args().rounds)
