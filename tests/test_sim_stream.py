"""stream_closed_loop: long runs in bounded memory (issue 8, finding 15). The streamed file and the
running statistics equal what the in-memory run records; the memory does not grow with the duration."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from reflexarm.errors import ConfigError
from reflexarm.robots import load_robot
from reflexarm.signals import Command
from reflexarm.sim import JointTrajectory, Plant, RunStatistics, Trace, run_closed_loop, stream_closed_loop
from reflexarm.sim.recording import RESIDUAL_BIN_NM
from test_sim_runner import PDGravity


class ResidualPD(PDGravity):
    """PD + gravity whose 'residual' is the tracking error scaled to Nm, with a 'collision' whenever it
    exceeds 2 Nm on any joint: gives the statistics something to count (seeded plant noise)."""

    def step(self, m, r) -> Command:
        cmd = super().step(m, r)
        res = self.kp * (r.q_d - m.q)
        hit = tuple(int(j) for j in np.flatnonzero(np.abs(res) > 2.0))
        return Command(cmd.tau, res, bool(hit), hit, "pd", "slow" if hit else "")


@pytest.fixture(scope="module")
def robot():
    return load_robot("atlas_v5_left_arm")


def _traj(robot, moves):
    q0 = robot.home
    q1 = q0 + np.array([0.3, 0.2, -0.2, 0.3, 0.5, 0.2, 0.3])
    return JointTrajectory([q0, q1] * moves + [q0], [0.5] * (2 * moves))


def test_streamed_trace_and_statistics_equal_the_in_memory_run(robot, tmp_path):
    traj = _traj(robot, 1)
    plant = Plant(robot, seed=3)
    plant.reset(robot.home)
    full = run_closed_loop(plant, ResidualPD(robot), traj, traj.duration)
    plant = Plant(robot, seed=3)
    plant.reset(robot.home)
    # 333-row blocks: several full blocks and a partial last one
    stats = stream_closed_loop(plant, ResidualPD(robot), traj, traj.duration, path=tmp_path / "t.parquet",
                               block_size=333)  # fmt: skip
    streamed = Trace.load(tmp_path / "t.parquet")
    assert len(streamed) == len(full) == stats.ticks == 1000
    for name in ("t", "q", "dq", "tau", "residual", "collision", "collided", "mode", "fault", "tau_ext"):
        np.testing.assert_array_equal(getattr(streamed, name), getattr(full, name), err_msg=name)
    assert [len(b) for b in Trace.iter_blocks(tmp_path / "t.parquet")] == [333, 333, 333, 1]
    # the statistics are exact reductions of the full trace
    r = np.abs(full.residual)
    np.testing.assert_array_equal(stats.max_abs_residual, r.max(axis=0))
    np.testing.assert_array_equal(stats.t_max_abs_residual, full.t[r.argmax(axis=0)])
    assert stats.collision_ticks == int(full.collision.sum()) > 0
    edges = np.flatnonzero(np.diff(np.r_[0, full.collision.astype(int)]) == 1)
    assert stats.collision_events == edges.size and stats.first_collision_t == full.t[edges[0]]
    np.testing.assert_array_equal(stats.collided_ticks, full.collided.sum(axis=0))
    assert stats.fault_ticks == stats.faults["slow"] == int((full.fault == "slow").sum())
    assert stats.modes == {"pd": 1000}
    assert stats.residual_counts.sum(axis=1).tolist() == [1000] * robot.n
    # ticks_above counts whole 0.1 Nm bins: exact at a bin edge
    np.testing.assert_array_equal(stats.ticks_above(2.0), (r >= 2.0 - 1e-12).sum(axis=0))
    assert stats.ticks_above(RESIDUAL_BIN_NM * 10).shape == (robot.n,)


def _peak_bytes(robot, duration: float, stream: bool) -> int:
    traj = _traj(robot, int(np.ceil(duration)))
    plant = Plant(robot, seed=0)
    plant.reset(robot.home)
    tracemalloc.start()
    try:
        if stream:
            stream_closed_loop(plant, PDGravity(robot), traj, duration, block_size=500)
        else:
            run_closed_loop(plant, PDGravity(robot), traj, duration)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_long_run_memory_is_bounded_by_one_block(robot):
    """`simulate free-motion --duration 3600` needed 4.7 GB: every tick was kept in RAM."""
    _peak_bytes(robot, 0.5, True)  # first-use allocations (lazy imports, caches) out of the way
    short, long = _peak_bytes(robot, 2.0, True), _peak_bytes(robot, 8.0, True)
    in_memory = _peak_bytes(robot, 8.0, False)
    # 6000 more ticks kept in memory cost 6000 x (9 x 7 + 10) x 8 B ~ 3.5 MB (twice while the trace is
    # copied out); streamed in 500-row blocks the peak may grow only with the run's description (the
    # longer trajectory's waypoints in meta, ~1 kB per second here): 100 kB is 35 x below one increment
    assert long - short < 100e3, (short, long)
    assert in_memory - long > 3e6, (in_memory, long)


def test_stream_arguments_and_failures(robot, tmp_path):
    traj = _traj(robot, 1)
    plant = Plant(robot, seed=0)
    with pytest.raises(ConfigError, match=r"block_size must be a positive number of ticks; got 0"):
        stream_closed_loop(plant, PDGravity(robot), traj, 1.0, block_size=0)

    class Failing(PDGravity):
        def step(self, m, r):
            if m.t > 0.2495:  # the tick at t = 0.25 s raises
                raise RuntimeError("boom")
            return super().step(m, r)

    plant.reset(robot.home)
    with pytest.raises(RuntimeError, match="boom") as info:
        stream_closed_loop(plant, Failing(robot), traj, 1.0, path=tmp_path / "f.parquet", block_size=100)
    stats = info.value.statistics
    assert isinstance(stats, RunStatistics) and stats.error == "RuntimeError: boom"
    assert stats.ticks == len(Trace.load(tmp_path / "f.parquet")) == 250  # ticks t = 0 .. 0.249 s
