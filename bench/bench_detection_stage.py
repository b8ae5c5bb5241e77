"""The detection residual's second stage (``detection_filter_gain``, issue 15's faster detection) in the tick: its
cost against the same tick without it, inside C++ and from Python, ratios in one run.

Four bound controllers over the same states inside C++ (``reflexarm._core.time_ticks_in_cpp``, round after round):
with the stage, without, a copy of each; the per-tick ratio with / without (same tick and round), its median over
the ticks, beside the noise floor (copy / original of each, the same statistic). All run a detection observer
(exact, 200 1/s) with the detection observer's own friction model (band 0.1 rad/s), levels high enough that the
smooth motion with sensor-like noise (``bench_cpp_core.make_states``) never crosses them: the stage is the only
difference. From Python: the median of ``Controller._core.update`` with / without.

    python bench/bench_detection_stage.py [--rounds 31]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench_cpp_core import make_states
from reflexarm import load_robot
from reflexarm.control import Controller
from reflexarm.control._setup import load_core

ARMS = ("atlas_v5_left_arm", "panda", "iiwa14")


def _controller(robot, stage: bool) -> Controller:
    return Controller(robot, detection_observer_gain=200.0, observer_discretization="exact", detection_kappa_f=1,
                      detection_friction_velocity_band=0.1, threshold=1e4, reaction="brake",
                      detection_filter_gain=200.0 if stage else None, torque_limit=None)  # fmt: skip


def in_cpp(robot, states: list[tuple], rounds: int) -> dict[str, float]:
    """Median per-tick ratio with / without the stage inside C++, and the noise floor."""
    core = load_core()
    ctrls = [_controller(robot, s) for s in (True, False, True, False)]
    cols = list(zip(*states, strict=True))
    arrays = [np.ascontiguousarray(np.array(c, dtype=float)) for c in cols[1:]]
    times, faults = core.time_ticks_in_cpp([c._core for c in ctrls], np.array(cols[0], dtype=float), *arrays,
                                           rounds, False)  # fmt: skip
    assert faults == 0, f"{faults} ticks faulted: the timing would not be of the tick"
    T = np.asarray(times)[:, :, 10:]  # (rounds, controllers, ticks), the first ticks (start-up) left out
    ratio = float(np.median(np.median(T[:, 0] / T[:, 1], axis=0)))
    floor = max(abs(float(np.median(np.median(T[:, 2] / T[:, 0], axis=0))) - 1.0),
                abs(float(np.median(np.median(T[:, 3] / T[:, 1], axis=0))) - 1.0))  # fmt: skip
    return {"stage_over_plain": ratio, "noise_floor": floor, "plain_tick_us": float(np.median(T[:, 1])) * 1e6}


def in_python(robot, states: list[tuple], rounds: int) -> dict[str, float]:
    """Median of Controller._core.update with / without the stage, alternating rounds."""
    ctrls = [_controller(robot, s) for s in (True, False)]
    best = {0: [], 1: []}
    clock = time.perf_counter
    for r in range(rounds):
        for i in (r % 2, 1 - r % 2):
            c = ctrls[i]
            c.reset()
            update = c._core.update
            ts = np.empty(len(states))
            for k, a in enumerate(states):
                t0 = clock()
                update(*a)
                ts[k] = clock() - t0
            best[i].append(float(np.median(ts[10:])))
    stage, plain = float(np.median(best[0])), float(np.median(best[1]))
    return {"stage_over_plain": stage / plain, "plain_update_us": plain * 1e6}


def main(rounds: int = 31) -> dict[str, dict[str, float]]:
    out = {}
    print(f"{'arm':>18} {'C++ stage/plain':>16} {'noise floor':>12} {'plain [us]':>11} {'Python stage/plain':>19}")
    for name in ARMS:
        robot = load_robot(name)
        states = make_states(robot)
        c, p = in_cpp(robot, states, rounds), in_python(robot, states, rounds)
        out[name] = {"cpp": c, "python": p}
        print(f"{name:>18} {c['stage_over_plain']:16.3f} {c['noise_floor']:12.3f} {c['plain_tick_us']:11.2f} "
              f"{p['stage_over_plain']:19.3f}")  # fmt: skip
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=31)
    main(ap.parse_args().rounds)
