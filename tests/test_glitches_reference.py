"""find_glitches (vectorised: joint by joint, the spike tests only where a sample is beyond OUTLIER_FACTOR) against a
slow obvious reading of its definitions, sample by sample and joint by joint in plain Python, on a noisy log with
velocity spikes, torque spikes at stops and in motion, two-joint torque bumps (a contact), steps and spikes at the
ends, at 1 kHz and at 100 Hz (where the stop condition applies)."""

from __future__ import annotations

import statistics

import numpy as np
import pytest

from reflexarm.detect import glitches as G
from reflexarm.detect.defaults import SHORTEST_IMPACT_S
from reflexarm.logs.robot_log import RobotLog


def _reference(t: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> list[tuple[int, int, str, float, float]]:
    N, n = dq.shape
    period = statistics.median((t[1:] - t[:-1]).tolist())

    def inconsistency(x: np.ndarray) -> tuple[list[list[float]], list[float]]:
        d = [[float(x[k, j] - 0.5 * (x[k - 1, j] + x[k + 1, j])) for k in range(1, N - 1)] for j in range(n)]
        sigma = []
        for j in range(n):
            med = statistics.median(d[j])
            sigma.append(1.4826 * statistics.median([abs(v - med) for v in d[j]]))
        return d, sigma

    def beside(a: list[float], i: int) -> float:
        return max(a[i - 1] if i > 0 else 0.0, a[i + 1] if i + 1 < len(a) else 0.0)

    found = []
    for kind, x, floor in (("velocity", dq, 1e-4), ("torque", tau, 1e-3)):
        d, sigma = inconsistency(x)
        a = [[abs(v) for v in row] for row in d]
        for i in range(N - 2):
            biggest = max(a[j][i] for j in range(n))
            for j in range(n):
                s = max(sigma[j], floor)
                if not (a[j][i] > G.OUTLIER_FACTOR * s and a[j][i] > G.SPIKE_RATIO * beside(a[j], i)):
                    continue
                if kind == "torque":
                    stirred = [
                        a[m][i] > G.CALM_FACTOR * max(sigma[m], floor)
                        and a[m][i] > G.CALM_SHARE * biggest
                        and a[m][i] >= beside(a[m], i)
                        for m in range(n)
                    ]
                    if sum(stirred) != 1:
                        continue
                    if period >= 0.5 * SHORTEST_IMPACT_S:
                        fastest = max(abs(float(v)) for v in dq[:, j])
                        near = [float(dq[i + r, j]) for r in range(3)]
                        reverses = near[0] * near[2] < 0
                        slow = all(abs(v) <= G.STOP_SHARE * fastest for v in near)
                        if not (reverses or slow):
                            continue
                found.append((i + 1, j, kind, float(x[i + 1, j]), 0.5 * float(x[i, j] + x[i + 2, j])))
    return sorted(found, key=lambda g: (g[0], g[2] != "velocity", g[1]))


@pytest.mark.parametrize("period", [1e-3, 1e-2])
def test_find_glitches_is_the_slow_reading_of_its_definitions(period):
    rng = np.random.default_rng(7)
    N, n = 3000, 4
    t = np.arange(N) * period
    phase = np.linspace(0, 6 * np.pi, N)[:, None] * (1 + np.arange(n)) / n
    dq = 0.8 * np.sin(phase) + 2e-3 * rng.standard_normal((N, n))
    dq[:, 3] = 1e-3 * rng.standard_normal(N)  # a joint at rest: at a stop everywhere
    tau = 5 * np.cos(phase) + 0.05 * rng.standard_normal((N, n))
    k = rng.choice(np.arange(3, N - 3), 60, replace=False)
    j = rng.integers(0, n, 60)
    dq[k[:15], j[:15]] += rng.choice([-1, 1], 15) * rng.uniform(0.03, 1.0, 15)  # velocity spikes
    tau[k[15:40], j[15:40]] += rng.choice([-1, 1], 25) * rng.uniform(1, 50, 25)  # torque spikes, some at stops
    tau[k[40:50], j[40:50]] += 30.0  # a contact: two joints at once
    tau[k[40:50], (j[40:50] + 1) % n] -= 20.0
    for kk, jj in zip(k[50:], j[50:], strict=True):  # steps
        tau[kk:, jj] += 10.0
    tau[1, 2] += 40.0  # spikes next to the ends
    dq[N - 2, 0] += 2.0
    log = RobotLog(t=t, q=np.cumsum(dq, axis=0) * period, dq=dq, tau=tau, source="synthetic")
    expected = _reference(t, log.dq, log.measured_torque)
    assert len(expected) >= 20  # the log does exercise the tests (both kinds)
    assert {e[2] for e in expected} == {"velocity", "torque"}
    got = [(g.sample, g.joint, g.kind, g.logged, g.repaired) for g in G.find_glitches(log)]
    assert got == expected
