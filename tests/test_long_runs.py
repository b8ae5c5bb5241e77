"""Long runs in the compiled loop (reflexarm.sim.stream_fast): the statistics folded in C++ and the trace written in
blocks against the Python loop's stream_closed_loop on the same plant, noise and controller (issue 19 item 1), and
the size of an in-memory run checked before anything is allocated (issue 20 item 13).

The reference is the Python loop: its statistics are numpy reductions of the recorded blocks
(RunStatistics.update), its trace file is written from the rows the Python Controller returned. The compiled loop
runs the same C++ tick on the same MuJoCo data, so both agree to the bit (as tests/test_compiled_loop.py shows for
in-memory runs); the statistics are compared exactly.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from reflexarm import load_robot
from reflexarm.control import Controller, InputBounds
from reflexarm.errors import ConfigError
from reflexarm.experiments import collision as C
from reflexarm.sim import PAPER_NOISE, Plant, Trace, run_fast, stream_closed_loop, stream_fast
from reflexarm.sim.compiled_stream import stream_compiled, stream_reason

pytest.importorskip("reflexarm._closed_loop", reason="compiled loop not built: run make install")

STAT_FIELDS = ("max_abs_residual", "t_max_abs_residual", "max_abs_tau", "collided_ticks", "residual_counts")
SCALARS = ("ticks", "t_first", "t_last", "collision_ticks", "collision_events", "first_collision_t", "fault_ticks")
TRACE_FIELDS = ("t", "q", "dq", "q_meas", "q_d", "dq_d", "tau", "tau_m", "residual", "collision", "collided", "mode",
                "fault", "wrench", "tau_ext", "f_ext_ee")  # fmt: skip


@pytest.fixture(scope="module")
def atlas():
    return load_robot(C.ROBOT)


@pytest.fixture(scope="module")
def model(atlas):
    return C.controller_model(atlas, 0.1, 0, None)[0]  # the free-motion run's +-10 % model


def _setup(atlas, model, traj, *, threshold=1.5, torque_factor=3.0, seed=1):
    plant = Plant(atlas, noise=PAPER_NOISE, seed=seed)
    plant.reset(traj.sample(0.0).q_d)
    bounds = InputBounds(torque_factor=torque_factor)
    ctrl = Controller(model, stiffness=300.0, observer_gain=5.0, threshold=threshold, reaction="none",
                      input_bounds=bounds)  # fmt: skip
    return plant, ctrl


def _assert_same_statistics(a, b):
    for f in SCALARS:
        assert getattr(b, f) == getattr(a, f), f
    for f in STAT_FIELDS:
        np.testing.assert_array_equal(getattr(b, f), getattr(a, f), err_msg=f)
    assert b.modes == a.modes and b.faults == a.faults


@pytest.mark.parametrize("torque_factor", [3.0, 0.09])  # 0.09: some ticks' measured torque is a fault
def test_compiled_stream_is_the_python_stream(atlas, model, tmp_path, torque_factor):
    """Free motion (the demo swing) with alarms (a low threshold): same statistics, same trace file, same plant."""
    traj = C.free_motion_trajectory(2.5, "demo", atlas)
    plant_a, ctrl_a = _setup(atlas, model, traj, torque_factor=torque_factor)
    a = stream_closed_loop(plant_a, ctrl_a, traj, 2.5, path=tmp_path / "a.parquet", block_size=777)
    plant_b, ctrl_b = _setup(atlas, model, traj, torque_factor=torque_factor)
    b = stream_fast(plant_b, ctrl_b, traj, 2.5, path=tmp_path / "b.parquet", block_size=777)
    assert (a.loop, b.loop) == ("python", "compiled")
    assert a.ticks == 2500
    if torque_factor < 1.0:  # the faults hold the arm: no alarm, but fault texts to count
        assert a.fault_ticks > 0 and len(a.faults) >= 1
    else:
        assert a.collision_events > 0 and a.fault_ticks == 0
    _assert_same_statistics(a, b)
    ta, tb = Trace.load(tmp_path / "a.parquet"), Trace.load(tmp_path / "b.parquet")
    for f in TRACE_FIELDS:
        np.testing.assert_array_equal(getattr(tb, f), getattr(ta, f), err_msg=f)
    # the plant is left in the same state, its clock, tick and noise sequence continue at the same place
    np.testing.assert_array_equal(plant_b.q, plant_a.q)
    np.testing.assert_array_equal(plant_b.dq, plant_a.dq)
    assert plant_b._tick == plant_a._tick and plant_b.time == plant_a.time
    np.testing.assert_array_equal(plant_b.measure().q, plant_a.measure().q)


def test_statistics_only_and_a_decimated_trace(atlas, model, tmp_path):
    """trace_every=k writes the ticks whose index is a multiple of k, whatever the block size, in both loops;
    no file: statistics only, the same."""
    traj = C.free_motion_trajectory(1.5, "demo", atlas)
    plant, ctrl = _setup(atlas, model, traj)
    full = stream_closed_loop(plant, ctrl, traj, 1.5, path=tmp_path / "full.parquet", block_size=500)
    ref = Trace.load(tmp_path / "full.parquet")
    for loop, block in (("compiled", 333), ("python", 333), ("compiled", 1500)):
        plant, ctrl = _setup(atlas, model, traj)
        run = stream_fast if loop == "compiled" else stream_closed_loop
        out = tmp_path / f"{loop}{block}.parquet"
        stats = run(plant, ctrl, traj, 1.5, path=out, block_size=block, trace_every=7)
        dec = Trace.load(out)
        assert len(dec) == 215  # ticks 0, 7, ..., 1498
        for f in ("t", "residual", "tau", "mode", "collision"):
            np.testing.assert_array_equal(getattr(dec, f), getattr(ref, f)[::7], err_msg=f"{loop} {f}")
        _assert_same_statistics(full, stats)
    plant, ctrl = _setup(atlas, model, traj)
    none = stream_fast(plant, ctrl, traj, 1.5, block_size=400)
    _assert_same_statistics(full, none)
    assert none.path is None


def test_what_the_compiled_stream_cannot_run_goes_to_python(atlas, model):
    traj = C.free_motion_trajectory(0.3, "demo", atlas)
    plant, ctrl = _setup(atlas, model, traj)
    seen = []
    stats = stream_fast(plant, ctrl, traj, 0.3, callback=lambda k, *_: seen.append(k))
    assert stats.loop == "python" and len(seen) == 300
    assert stream_reason(plant, ctrl, callback=print) == "a callback is called after every tick (Python loop)"
    rate_limited = Controller(model, threshold=1.5, reaction="none", torque_rate_limit=1e4)
    with pytest.raises(ConfigError, match="cannot use the compiled loop: the controller has a torque_rate_limit"):
        stream_compiled(plant, rate_limited, traj, 0.3)
    assert stream_fast(plant, rate_limited, traj, 0.3).loop == "python"
    with pytest.raises(ConfigError, match=r"trace_every must be a positive number of ticks; got 0"):
        stream_fast(plant, ctrl, traj, 0.3, trace_every=0)
    with pytest.raises(ConfigError, match=r"block_size must be a positive number of ticks; got -1"):
        stream_compiled(plant, ctrl, traj, 0.3, block_size=-1)


def _peak(atlas, model, duration):
    traj = C.free_motion_trajectory(duration, "demo", atlas)
    plant, ctrl = _setup(atlas, model, traj)
    tracemalloc.start()
    try:
        stream_fast(plant, ctrl, traj, duration, block_size=500)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_compiled_stream_memory_does_not_grow_with_the_duration(atlas, model):
    """Issue 20 item 18: a soak's memory is one block's buffers (C++ folds the statistics), not the run's."""
    _peak(atlas, model, 0.6)  # first-use allocations out of the way
    # from 2 s on every buffer (blocks of 500 ticks, the plant's noise drawn 1024 rows at a time) is in use
    short, long = _peak(atlas, model, 2.0), _peak(atlas, model, 5.0)
    # 3000 more ticks kept would be >= 3000 x 73 x 8 B ~ 1.8 MB; streamed, only the longer trajectory's
    # description in meta grows (~1 kB per second): 100 kB is 18 x below it
    assert long - short < 100e3, (short, long)


def test_run_fast_refuses_a_run_that_cannot_fit_in_memory(atlas, model):
    """Issue 20 item 13: run_fast(duration=1e9) raised a raw MemoryError after allocating; now it is refused
    before, naming the size and the streamed alternative."""
    traj = C.free_motion_trajectory(1.0, "demo", atlas)
    plant, ctrl = _setup(atlas, model, traj)
    with pytest.raises(ConfigError, match=r"run_fast: 1,000,000,000,000 ticks keep ~.* GB in memory; .* GB are "
                       r"available\. For a run this long use reflexarm\.sim\.stream_fast"):  # fmt: skip
        run_fast(plant, ctrl, traj, 1e9)
    assert plant._tick == 0 and plant._user is None  # nothing ran, the plant is free
    run_fast(plant, ctrl, traj, 0.05)  # and usable


def test_recorded_measurements_are_the_python_loops(atlas, model):
    """record_measurements (what tune-thresholds' simulated logs hold): the compiled loop keeps the measured q, dq,
    tau_m and wrench of every tick, as a callback on the Python loop records them from Plant.measure."""
    from reflexarm.sim.measurement_log import _record_in_python, record_measurements

    traj = C.free_motion_trajectory(1.2, "demo", atlas)
    plant_a, ctrl_a = _setup(atlas, model, traj)
    stats_a, a = _record_in_python(plant_a, ctrl_a, traj, 1.2, 1200, 500, False)
    plant_b, ctrl_b = _setup(atlas, model, traj)
    stats_b, b = record_measurements(plant_b, ctrl_b, traj, 1.2, block_size=500)
    assert (stats_a.loop, stats_b.loop) == ("python", "compiled")
    for k in ("t", "q", "dq", "tau_m", "wrench"):
        assert b[k].shape[0] == 1200
        np.testing.assert_array_equal(b[k], a[k], err_msg=k)
    _assert_same_statistics(stats_a, stats_b)
    assert np.abs(b["dq"] - b["dq"].mean(axis=0)).max() > 0  # measured, i.e. noisy, not the true velocities


def test_the_still_of_a_compiled_stream_is_the_python_streams(atlas, model):
    """The CLI's stills (StillCapture through observing_runs) keep the compiled stream: the start and the tick of
    the largest true external torque (a push applied before the run) are the Python stream's, across blocks."""
    from reflexarm.sim.run_observers import observing_runs
    from reflexarm.sim.video import StillCapture

    traj = C.free_motion_trajectory(1.5, "demo", atlas)
    caps = []
    for run in (stream_closed_loop, stream_fast):
        plant, ctrl = _setup(atlas, model, traj, threshold=11.0)
        plant.apply_external_force([0.0, 0.0, -15.0])  # on the end effector, constant: tau_ext moves with the pose
        cap = StillCapture()
        with observing_runs(lambda _plant, c=cap: c):
            stats = run(plant, ctrl, traj, 1.5, block_size=400)
        caps.append((stats, cap))
    (sa, a), (sb, b) = caps
    assert (sa.loop, sb.loop) == ("python", "compiled")
    assert a.peak_time is not None and a.peak_time > 0.4  # in a later block than the first
    assert b.peak_time == a.peak_time and b.peak_torque == a.peak_torque
    np.testing.assert_array_equal(b._start, a._start)
    np.testing.assert_array_equal(b._peak, a._peak)
    np.testing.assert_array_equal(b._peak_cmd.tau, a._peak_cmd.tau)
    assert b._peak_cmd.mode == a._peak_cmd.mode and b._start_cmd.mode == a._start_cmd.mode


def test_tuning_refuses_a_decimated_trace(atlas, model, tmp_path):
    """A long run's default trace keeps every 100th tick: tune-thresholds (recorded residual or a replay of the
    trace) needs every tick and says so instead of fitting the tail of a 10 Hz residual."""
    from reflexarm.errors import DataError
    from reflexarm.tuning.replay import load_free_motion_log, recorded_residual

    traj = C.free_motion_trajectory(0.5, "demo", atlas)
    for run in (stream_fast, stream_closed_loop):
        plant, ctrl = _setup(atlas, model, traj)
        path = tmp_path / f"{run.__name__}.parquet"
        run(plant, ctrl, traj, 0.5, path=path, trace_every=100)
        with pytest.raises(DataError, match=r"is a decimated trace \(every 100th tick, --trace-every\): the residual's "
                           r"tail needs every tick; write the run's trace with --trace-every 1"):  # fmt: skip
            recorded_residual(path, atlas.n)
        with pytest.raises(DataError, match="is a decimated trace"):
            load_free_motion_log(path, atlas)
    plant, ctrl = _setup(atlas, model, traj)
    stream_fast(plant, ctrl, traj, 0.5, path=tmp_path / "full.parquet")
    assert recorded_residual(tmp_path / "full.parquet", atlas.n).t.size == 500


def test_trace_files_keep_no_dictionary_of_float_columns(atlas, model, tmp_path):
    """A streamed trace (and Trace.save) writes the float columns without a dictionary (a noisy signal's values
    are all distinct: Arrow's default dictionary held every one of them and cost three quarters of the writing
    time) and the repeating text columns (mode, fault) with one; the file reads back the same rows."""
    import pyarrow.parquet as pq

    traj = C.free_motion_trajectory(1.0, "demo", atlas)
    plant, ctrl = _setup(atlas, model, traj)
    stream_fast(plant, ctrl, traj, 1.0, path=tmp_path / "s.parquet", block_size=400)
    streamed = Trace.load(tmp_path / "s.parquet")
    streamed.save(tmp_path / "saved.parquet")
    for name in ("s.parquet", "saved.parquet"):
        meta = pq.ParquetFile(tmp_path / name).metadata
        for g in range(meta.num_row_groups):
            for c in range(meta.num_columns):
                col = meta.row_group(g).column(c)
                dictionary = any("DICTIONARY" in e for e in col.encodings)
                if col.physical_type in ("DOUBLE", "BYTE_ARRAY"):  # (flags: bit-packed booleans either way)
                    expected = col.physical_type == "BYTE_ARRAY"
                    assert dictionary == expected, (name, col.path_in_schema, col.encodings)
    saved = Trace.load(tmp_path / "saved.parquet")
    for f in TRACE_FIELDS:
        np.testing.assert_array_equal(getattr(saved, f), getattr(streamed, f), err_msg=f)
