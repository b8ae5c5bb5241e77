"""The tick with the collision pipeline inside it (issue 15): isolation and identification in update().

A static arm with a seeded contact on a distal link appearing at tick 100 (tau_m = g - J_c^T f), the Controller
with a detection observer (exact, 200 1/s), threshold 11 Nm and the retract reaction; the core's bare ``update``
timed per call from Python, with the links' geometry (isolation in the tick) and without, interleaved round by
round. Printed as ratios in the same run: the median tick with geometry / without (the ticks without an
isolation), and the isolating tick (20 ms after detection) / the median plain tick.

    python bench/bench_collision_tick.py [--rounds 5]
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

N_TICKS = 300
ONSET = 100


def _states(robot, contact) -> list[tuple]:
    g = robot.compute_gravity(contact.q)
    zeros, gravity = np.zeros(robot.n), np.array([0.0, 0.0, -9.81])
    out = []
    for k in range(N_TICKS):
        tau_m = g - (contact.torque if k >= ONSET else 0.0)
        out.append(((k + 1) * 1e-3, contact.q, zeros, tau_m, np.zeros(6), gravity, contact.q, zeros, zeros))
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


def _controller(robot, geometry: object) -> Controller:
    return Controller(robot, threshold=11.0, reaction="retract", detection_observer_gain=200.0,
                      observer_discretization="exact", reaction_settings=ReactionSettings(),
                      contact_geometry=geometry)  # fmt: skip


def bench_arm(name: str, rounds: int) -> dict[str, float]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        robot = load_robot(name)
    truth = link_collision_geometry(robot, spacing=0.01, seed=3)
    contact = next(c for c in draw_contacts(robot, truth, 1000, seed=1)
                   if c.link >= robot.n - 3 and np.abs(c.torque).max() > 25)  # fmt: skip
    states = _states(robot, contact)
    with_geo, without = _controller(robot, "auto"), _controller(robot, None)
    a, b = [], []
    for _ in range(rounds):
        a.append(_run(with_geo, states))
        b.append(_run(without, states))
    ev = with_geo.event
    assert ev is not None and ev.estimate is not None, "the contact was not detected and isolated"
    k_iso = int(round(ev.t_estimate / 1e-3)) - 1  # the tick that isolated
    ta, tb = np.median(np.array(a), axis=0), np.median(np.array(b), axis=0)
    plain = np.ones(N_TICKS, bool)
    plain[k_iso] = False
    out = {
        "plain_tick_us": float(np.median(tb) * 1e6),
        "tick_with_geometry_over_without": float(np.median(ta[plain]) / np.median(tb[plain])),
        "isolating_tick_us": float(ta[k_iso] * 1e6),
        "isolating_tick_over_plain": float(ta[k_iso] / np.median(tb)),
        "candidate_points": int(with_geo.contact_geometry.point_counts().sum()),  # type: ignore[union-attr]
    }
    print(f"{name:18s} plain tick {out['plain_tick_us']:6.1f} us; with geometry / without (other ticks) "
          f"{out['tick_with_geometry_over_without']:.2f}; isolating tick {out['isolating_tick_us']:7.1f} us = "
          f"{out['isolating_tick_over_plain']:5.1f} x a plain tick ({out['candidate_points']} candidate points, "
          f"estimate: {ev.estimate.link_name}, {ev.estimate.determined.value})")  # fmt: skip
    return out


def main(rounds: int = 5) -> dict[str, dict[str, float]]:
    return {name: bench_arm(name, rounds) for name in ("atlas_v5_left_arm", "panda", "iiwa14")}


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=5)
    main(p.parse_args().rounds)
