"""The C++ tick (``reflexarm._core``) called from Python against the bare Pinocchio calls it makes, from Python.

Three things are timed in the same process on the same states, interleaved round by round so that the load
of the machine hits them alike: ``core.update`` (the whole tick in C++, one call), the four (five with the
wrist-wrench term) Pinocchio calls of a tick made from Python and nothing else, and today's
``Controller.step``. Printed: medians per call and the ratios (issue 10 asks tick/floor <= 1.0).

    python bench/bench_cpp_core.py [--rounds 7]
"""

from __future__ import annotations

import argparse
import importlib
import time
from collections.abc import Callable

import numpy as np
import pinocchio as pin

from reflexarm import Measurement, Reference, load_robot
from reflexarm.control import Controller

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


def per_call(fn: Callable[[tuple], object], states: list[tuple], reset: Callable[[], None]) -> float:
    """Median wall time of one call over a pass of the states [s]."""
    reset()
    clock = time.perf_counter
    ts = np.empty(len(states))
    for i, s in enumerate(states):
        t0 = clock()
        fn(s)
        ts[i] = clock() - t0
    return float(np.median(ts))


def make_core(robot, efc: bool):
    core = importlib.import_module("reflexarm._core")  # built by make install (scikit-build-core)

    p = core.ControllerParams()
    p.kappa_f = p.kappa_eps = 1
    p.kappa_ext = int(efc)
    p.friction_coulomb, p.friction_viscous = robot.friction.coulomb.copy(), robot.friction.viscous.copy()
    p.friction_velocity_band = robot.friction.velocity_band
    p.sensor_frame_id = robot.sensor_frame_id
    ctrl = core.Controller(robot.pin_model.saveToString(), p)
    update = ctrl.update

    def tick(s: tuple) -> None:
        update(*s)

    return tick, ctrl.reset


def make_floor(robot, efc: bool):
    """The Pinocchio calls of one tick, made from Python, and nothing else."""
    model = robot.pin_model.copy()
    d_g, d_c, d_j = model.createData(), model.createData(), model.createData()
    model0 = model.copy()
    model0.gravity.linear = np.zeros(3)
    d_p, d_ff = model0.createData(), model0.createData()
    zeros = np.zeros(robot.n)
    fid = robot.sensor_frame_id

    def floor(s: tuple) -> None:
        q, dq, q_d, ddq_d = s[1], s[2], s[6], s[8]
        pin.computeGeneralizedGravity(model, d_g, q)
        pin.computeCoriolisMatrix(model, d_c, q, dq)
        pin.rnea(model0, d_p, q, zeros, dq)
        pin.rnea(model0, d_ff, q_d, zeros, ddq_d)
        if efc:
            pin.computeFrameJacobian(model, d_j, q, fid, pin.LOCAL)

    return floor, lambda: None


def make_python(robot, efc: bool):
    ctrl = Controller(robot, kappa_f=1, kappa_eps=1, kappa_ext=int(efc))

    def step(s: tuple) -> None:
        ctrl.step(Measurement(*s[:6]), Reference(*s[6:]))

    return step, ctrl.reset


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args()
    robot = load_robot("atlas_v5_left_arm")
    states = make_states(robot)
    print(f"{robot.name}, n={robot.n}, {N_STATES} states x {args.rounds} rounds (medians of per-round medians)")
    head = ("configuration", "core.update", "pin floor", "Controller", "core/floor", "core/Ctrl")
    print(f"{head[0]:<14}{head[1]:>13}{head[2]:>12}{head[3]:>13}{head[4]:>12}{head[5]:>11}")
    for efc in (False, True):
        runs = {"core": make_core(robot, efc), "floor": make_floor(robot, efc), "py": make_python(robot, efc)}
        for fn, reset in runs.values():  # warm-up pass
            per_call(fn, states[:100], reset)
        med: dict[str, list[float]] = {k: [] for k in runs}
        for _ in range(args.rounds):
            for key, (fn, reset) in runs.items():
                med[key].append(per_call(fn, states, reset))
        c, f, p = (float(np.median(med[k])) * 1e6 for k in ("core", "floor", "py"))
        name = "DC+EFC" if efc else "DC"
        print(f"{name:<14}{c:>10.2f} us{f:>9.2f} us{p:>10.2f} us{c / f:>12.2f}{c / p:>11.2f}")


if __name__ == "__main__":
    main()
