"""MuJoCo's profiling timers in the compiled loop (reflexarm::QuietTimers): unless someone installed a time
callback, they read a clock of 0 while the loop steps. The timers feed nothing in the dynamics, so the run is
the same to the bit; the mujoco package's own clock is back after the run; a user's callback is kept."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import mujoco
import numpy as np
import pytest

from reflexarm import load_robot
from reflexarm.control import Controller
from reflexarm.experiments import collision as C
from reflexarm.sim import PAPER_NOISE, Cinderblock, Plant
from reflexarm.sim.compiled_loop import run_compiled
from reflexarm.sim.trace import Trace
from reflexarm.sim.trajectory import JointTrajectory

cl = pytest.importorskip("reflexarm._closed_loop", reason="compiled loop not built: run make install")

STEP = int(mujoco.mjtTimer.mjTIMER_STEP)
#: Past the first contact of the hand with the block (~3.7 s): the contact code runs under the quiet clock too.
DURATION = 4.5
FIELDS = ("t", "q", "dq", "q_meas", "tau", "tau_m", "residual", "wrench", "tau_ext", "f_ext_ee", "collision")


@pytest.fixture(scope="module")
def demo() -> tuple[Plant, Controller, JointTrajectory, np.ndarray]:
    return _fresh_demo()


@pytest.fixture
def user_clock() -> Iterator[list[int]]:
    """A time callback installed by the user (it counts its calls and returns the count)."""
    calls = [0]

    def clock() -> float:
        calls[0] += 1
        return float(calls[0])

    mujoco.set_mjcb_time(clock)
    try:
        yield calls
    finally:
        mujoco.set_mjcb_time(None)


def _run(plant: Plant, ctrl: Controller, traj: JointTrajectory, q0: np.ndarray) -> tuple[Trace, np.ndarray, int, float]:
    plant.reset(q0)
    for t in plant.data.timer:
        t.number, t.duration = 0, 0.0
    tr = run_compiled(plant, ctrl, traj, DURATION)
    timer = plant.data.timer[STEP]
    return tr, plant.data.qpos.copy(), int(timer.number), float(timer.duration)


def test_quiet_timers_leave_the_run_bit_for_bit(
    demo: tuple[Plant, Controller, JointTrajectory, np.ndarray], request: pytest.FixtureRequest
) -> None:
    plant, ctrl, traj, q0 = demo
    quiet, q_quiet, n_quiet, dur_quiet = _run(plant, ctrl, traj, q0)
    assert bool(quiet.collision.any())  # the run reaches the contact and its detection
    # every physics step counted, none timed
    assert n_quiet == len(quiet.t) * plant.substeps
    assert dur_quiet == 0.0
    # the mujoco package's clock is back: a step from Python is timed again
    mujoco.mj_step(plant.model, plant.data)
    assert plant.data.timer[STEP].duration > 0.0

    calls = request.getfixturevalue("user_clock")
    timed, q_timed, n_timed, dur_timed = _run(plant, ctrl, traj, q0)
    # the user's callback was kept: it timed every step (two calls per step at least: start and end)
    assert n_timed == n_quiet
    assert dur_timed > 0.0
    assert calls[0] >= 2 * n_timed
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(timed, f), getattr(quiet, f), err_msg=f)
    np.testing.assert_array_equal(q_timed, q_quiet)


def test_replay_with_quiet_timers_is_the_same_motion(
    demo: tuple[Plant, Controller, JointTrajectory, np.ndarray],
) -> None:
    plant, ctrl, traj, q0 = demo
    plant.reset(q0)
    tau = np.ascontiguousarray(run_compiled(plant, ctrl, traj, DURATION).tau)
    finals = []
    for quiet in (False, True):
        plant.reset(q0)
        for t in plant.data.timer:
            t.number, t.duration = 0, 0.0
        cl.replay_torques(plant.model._address, plant.data._address, tau, plant._arm_dofs, plant.substeps, quiet)
        assert (plant.data.timer[STEP].duration == 0.0) is quiet
        assert plant.data.timer[STEP].number == len(tau) * plant.substeps
        finals.append(np.concatenate([plant.data.qpos, plant.data.qvel]))
    np.testing.assert_array_equal(finals[1], finals[0])


def test_runs_in_threads_at_once_give_the_clock_back() -> None:
    """Two compiled runs at once in threads (as Dask workers in one process run them): the time callback
    is global, and before the count under a lock a check-then-write race left the clock of 0 installed
    for good (seen after tests/test_sweeps_paper.py's in-process cluster)."""

    def plant_timed() -> bool:
        plant, _, _, q0 = _fresh_demo()
        plant.reset(q0)
        plant.data.timer[STEP].duration = 0.0
        mujoco.mj_step(plant.model, plant.data)
        return plant.data.timer[STEP].duration > 0.0

    assert plant_timed(), "no clock to begin with: the test proves nothing"
    errors: list[BaseException] = []

    def work() -> None:
        try:
            plant, ctrl, traj, q0 = _fresh_demo()
            for _ in range(2):
                plant.reset(q0)
                run_compiled(plant, ctrl, traj, 2.0)
        except BaseException as e:  # noqa: BLE001 - reported below
            errors.append(e)

    threads = [threading.Thread(target=work) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    assert plant_timed(), "the clock of 0 stayed installed after the threads' runs"


def _fresh_demo() -> tuple[Plant, Controller, JointTrajectory, np.ndarray]:
    """The demo's plant, controller, path and start (each call its own: one per thread)."""
    robot = load_robot(C.ROBOT)
    model, _ = C.controller_model(robot, None, 0, None)
    traj = C.ee_collision_trajectory()
    plant = Plant(robot, scene=Cinderblock(**C.EE_BLOCK), noise=PAPER_NOISE, seed=0)  # type: ignore[arg-type]
    return plant, C.EE_SETTINGS[2].controller(model), traj, traj.sample(0.0).q_d
