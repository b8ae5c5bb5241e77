"""A Plant is run by one closed loop at a time (issue 20 item 10): two threads running compiled loops on one
plant segfaulted (7 of 8 runs), and ``plant.reset()`` from another thread during a run in 3 of 6. Now the plant in
use refuses a second run (compiled or Python, any thread) and ``reset()`` / ``step()`` from another thread, with
an error naming who holds it; the run that holds it is not disturbed (its trace equals an undisturbed run's)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from reflexarm import load_robot
from reflexarm.control import Controller
from reflexarm.errors import SimulationError
from reflexarm.experiments import collision as C
from reflexarm.sim import Plant, run_closed_loop, run_compiled, run_fast, stream_fast

pytest.importorskip("reflexarm._closed_loop", reason="compiled loop not built: run make install")

DURATION = 6.0  # [s] simulated: long enough (~0.3-1 s of wall time) for the main thread to act during it


@pytest.fixture(scope="module")
def atlas():
    return load_robot(C.ROBOT)


def _controller(atlas):
    return Controller(atlas, stiffness=300.0, threshold=11.0, reaction="none", contact_geometry=None)


def _plant(atlas, traj):
    plant = Plant(atlas, seed=2)
    plant.reset(traj.sample(0.0).q_d)
    return plant


def _wait_held(plant, thread, timeout=30.0):
    t0 = time.monotonic()
    while plant._user is None:
        assert thread.is_alive() and time.monotonic() - t0 < timeout, "the run never held the plant"
        time.sleep(0.001)


@pytest.mark.parametrize("runner", [run_compiled, stream_fast, run_closed_loop])
def test_a_plant_in_use_refuses_a_second_run_reset_and_step(atlas, runner):
    traj = C.free_motion_trajectory(DURATION, "demo", atlas)
    plant = _plant(atlas, traj)
    out: dict[str, object] = {}

    def first() -> None:
        try:
            out["result"] = runner(plant, _controller(atlas), traj, DURATION)
        except BaseException as e:  # pragma: no cover - reported below
            out["error"] = e

    th = threading.Thread(target=first, name="runner-A")
    th.start()
    _wait_held(plant, th)
    held_by = r"a (compiled |compiled streamed |streamed )?(closed-loop )?run in thread 'runner-A'"
    with pytest.raises(SimulationError, match=rf"this Plant is in use by {held_by}; a compiled run cannot run on it"):
        run_compiled(plant, _controller(atlas), traj, 0.01)
    with pytest.raises(SimulationError, match=rf"this Plant is in use by {held_by}; a closed-loop run cannot run"):
        run_closed_loop(plant, _controller(atlas), traj, 0.01)
    with pytest.raises(SimulationError, match=rf"reset\(\) from thread 'MainThread' while this Plant is in use by "
                       rf"{held_by}; wait for that run to end"):  # fmt: skip
        plant.reset()
    with pytest.raises(SimulationError, match=r"step\(\) from thread 'MainThread' while this Plant is in use"):
        plant.step(np.zeros(atlas.n))
    assert th.is_alive() or plant._user is None
    th.join()
    assert "error" not in out, out.get("error")
    assert plant._user is None  # released: the plant is usable again
    # the run was not disturbed by the refused calls
    ref = runner(_plant(atlas, traj), _controller(atlas), traj, DURATION)
    if runner is stream_fast:
        np.testing.assert_array_equal(out["result"].max_abs_residual, ref.max_abs_residual)
        assert out["result"].ticks == ref.ticks
    else:
        np.testing.assert_array_equal(out["result"].q, ref.q)
    plant.reset()
    run_fast(plant, _controller(atlas), traj, 0.05)


def test_threads_racing_for_one_plant_end_in_a_run_or_a_clear_error(atlas):
    """Eight threads start compiled runs on one plant at once: each ends in a finished run or the in-use error,
    never a crash; runs never overlap (each finished one is whole)."""
    traj = C.free_motion_trajectory(1.0, "demo", atlas)
    plant = _plant(atlas, traj)
    barrier = threading.Barrier(8)
    results: list[object] = []

    def go() -> None:
        barrier.wait()
        try:
            results.append(run_fast(plant, _controller(atlas), traj, 1.0))
        except BaseException as e:
            results.append(e)

    threads = [threading.Thread(target=go, name=f"racer-{i}") for i in range(8)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    errors = [r for r in results if isinstance(r, BaseException)]
    traces = [r for r in results if not isinstance(r, BaseException)]
    assert len(results) == 8 and len(traces) >= 1
    for e in errors:
        assert isinstance(e, SimulationError) and "this Plant is in use by a compiled run in thread 'racer-" in str(e)
    for tr in traces:
        assert len(tr.t) == 1000 and np.all(np.diff(tr.t) > 0)
