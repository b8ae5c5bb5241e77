"""The tick with the collision pipeline inside it (issue 15): isolation and identification in update().

A static arm with a seeded contact on a distal link appearing at tick 100 (tau_m = g - J_c^T f), the Controller
with a detection observer (exact, 200 1/s), threshold 11 Nm and the retract reaction; the core's bare ``update``
timed per call from Python, with the links' geometry (isolation in the ticks) and without, interleaved round by
round. The isolation begins 20 ms after detection and fits ``isolation_points_per_tick`` candidate points per
following tick (ReactionSettings; each point twice: pass 1 and pass 2). Printed as ratios in the same run: the
median tick with geometry / without (the ticks outside the isolation), the largest tick of the isolation (begin to
finish, the finishing tick plans the retract) / the median plain tick, the ticks it takes (latency at 1 kHz), and
the same with the whole isolation in one tick (a budget of 10^8 points) for comparison.

    python bench/bench_collision_tick.py [--rounds 5] [--points-per-tick 8 16 24 32 64]
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from reflexarm import load_robot
from reflexarm.control import Controller, ReactionSettings
from reflexarm.experiments.isolation_study import draw_contacts
from reflexarm.robots import link_collision_geometry

ONSET = 100
DT = 1e-3
#: A budget that fits the whole isolation in the tick after it began (the one-shot isolation, for comparison).
ONE_SHOT = 10**8


def _states(robot, contact, n_ticks: int) -> list[tuple]:
    g = robot.compute_gravity(contact.q)
    zeros, gravity = np.zeros(robot.n), np.array([0.0, 0.0, -9.81])
    out = []
    for k in range(n_ticks):
        tau_m = g - (contact.torque if k >= ONSET else 0.0)
        out.append(((k + 1) * DT, contact.q, zeros, tau_m, np.zeros(6), gravity, contact.q, zeros, zeros))
    return out


def _run(ctrl: Controller, states: list[tuple]) -> np.ndarray:
    ctrl.reset()
    update, clock = ctrl._core.update, time.perf_counter
    ts = np.empty(len(states))
    for i, a in enumerate(states):
        t0 = clock()
        update(*a)
        ts[i] = clock() - t0
    return ts


def _controller(robot, geometry: object, points_per_tick: int = 24) -> Controller:
    return Controller(robot, threshold=11.0, reaction="retract", detection_observer_gain=200.0,
                      observer_discretization="exact",
                      reaction_settings=ReactionSettings(isolation_points_per_tick=points_per_tick),
                      contact_geometry=geometry)  # fmt: skip


def bench_arm(name: str, rounds: int, budgets: list[int]) -> dict[str, dict[str, float]]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        robot = load_robot(name)
    truth = link_collision_geometry(robot, spacing=0.01, seed=3)
    contact = next(c for c in draw_contacts(robot, truth, 1000, seed=1)
                   if c.link >= robot.n - 3 and np.abs(c.torque).max() > 25)  # fmt: skip
    without = _controller(robot, None)
    results: dict[str, dict[str, float]] = {}
    for budget in [*budgets, ONE_SHOT]:
        with_geo = _controller(robot, "auto", budget)
        n_ticks = ONSET + 100 + 4000 // budget + 200  # room for the isolation (a few thousand units at most)
        states = _states(robot, contact, n_ticks)
        a, b = [], []
        for _ in range(rounds):
            a.append(_run(with_geo, states))
            b.append(_run(without, states))
        ev = with_geo.event
        assert ev is not None and ev.estimate is not None, "the contact was not isolated"
        k_begin = int(round(ev.t_estimate / DT)) - 1  # the tick the isolation began
        k_end = int(round(ev.t_estimated / DT)) - 1  # the tick its estimate came in
        ta, tb = np.median(np.array(a), axis=0), np.median(np.array(b), axis=0)
        plain = np.ones(len(states), bool)
        plain[k_begin : k_end + 1] = False
        base = float(np.median(tb))
        out = {
            "plain_tick_us": base * 1e6,
            "tick_with_geometry_over_without": float(np.median(ta[plain]) / np.median(tb[plain])),
            "largest_isolation_tick_us": float(ta[k_begin : k_end + 1].max() * 1e6),
            "largest_isolation_tick_over_plain": float(ta[k_begin : k_end + 1].max() / base),
            "median_isolation_tick_over_plain": float(np.median(ta[k_begin + 1 : k_end + 1]) / base),
            "finishing_tick_over_plain": float(ta[k_end] / base),
            "isolation_ticks": float(k_end - k_begin),
            "isolation_latency_ms": (k_end - k_begin) * DT * 1e3,
        }
        results[str(budget)] = out
        label = "one tick" if budget == ONE_SHOT else f"{budget:4d} points/tick"
        print(f"{name:18s} {label:16s} plain {out['plain_tick_us']:5.1f} us, others with/without geometry "
              f"{out['tick_with_geometry_over_without']:.2f}; isolation: largest tick "
              f"{out['largest_isolation_tick_over_plain']:6.2f} x plain (median "
              f"{out['median_isolation_tick_over_plain']:.2f}, finishing {out['finishing_tick_over_plain']:.2f}), "
              f"{k_end - k_begin:4d} ticks = {out['isolation_latency_ms']:5.0f} ms after it began "
              f"({ev.estimate.link_name}, {ev.estimate.determined.value})")  # fmt: skip
    return results


def main(rounds: int = 5, budgets: list[int] | None = None) -> dict[str, dict[str, dict[str, float]]]:
    budgets = [ReactionSettings().isolation_points_per_tick] if budgets is None else budgets
    return {name: bench_arm(name, rounds, budgets) for name in ("atlas_v5_left_arm", "panda", "iiwa14")}


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--points-per-tick", type=int, nargs="+", default=None)
    args = p.parse_args()
    main(args.rounds, args.points_per_tick)
