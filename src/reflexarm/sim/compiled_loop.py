"""run_compiled: the closed loop of :func:`~reflexarm.sim.run_closed_loop` as one C++ call per run.

The plant stays the Python :class:`~reflexarm.sim.Plant` (its compiled MuJoCo model and data are handed
to C++ by address, so the run continues from its state and leaves it there); the sensor noise is drawn in
Python from the plant's own generator, in the same blocks as :meth:`Plant.measure` draws it; the reference
is sampled in Python at the tick times MuJoCo's clock will show; the controller is the C++ core
(``reflexarm._core``) configured like the given :class:`~reflexarm.control.Controller`; every tick is
recorded by C++ into preallocated numpy arrays, returned as the same :class:`Trace`. Scenes act through
data (see :mod:`reflexarm.sim._playback`); at the few ticks where a scene must look at the state (a force
switched on, a stick started) the loop stops, runs the scene's Python ``update`` and goes on.

:func:`compiled_reason` says why a run cannot be compiled (None when it can); :func:`run_fast` uses the
compiled loop when it can and :func:`run_closed_loop` otherwise. The Python ``controller`` object itself is
not stepped by the compiled loop (its state after the run is its state before it).

Run observers (:mod:`reflexarm.sim.run_observers`): stills stay compiled. C++ keeps MuJoCo's integration
state at the first tick and at the tick of the largest true external joint torque (the criterion of
:class:`~reflexarm.sim.video.StillCapture`, ``reflexarm::StillStates``) and :func:`run_fast` hands both to the
observers after the run. A video needs a frame rendered during the run, so any observer that cannot take
the recorded states (``accepts_compiled`` false, e.g. the CLI's ``--video``) sends the run to the Python loop.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from types import ModuleType
from typing import Any

import mujoco
import numpy as np

from reflexarm.errors import ConfigError, SimulationError
from reflexarm.signals import Command
from reflexarm.sim._compiled_inputs import _core_params, _draw_noise, _forces, _sample_reference, _tick_times
from reflexarm.sim._playback import ScenePlay, event_ticks, hand_push_back, hand_push_to, playback
from reflexarm.sim._run_memory import check_memory
from reflexarm.sim.plant import MAX_SPEED, Plant
from reflexarm.sim.recording import _Recorder
from reflexarm.sim.run_observers import (
    CompiledStill,
    accepts_compiled,
    make_observers,
    observers_active,
    using_observers,
)
from reflexarm.sim.runner import ControllerLike, TrajectoryLike, _check, run_closed_loop
from reflexarm.sim.trace import Trace

__all__ = ["compiled_reason", "run_compiled", "run_fast"]

#: The MuJoCo state a still keeps (as StillCapture keeps it from the Python loop).
_STILL_SPEC = int(mujoco.mjtState.mjSTATE_INTEGRATION)
#: Mode names in the order of the C++ enum reflexarm::Mode (as reflexarm.control.controller.MODES).
_MODES = np.array([
    "compliant", "precise_stiff", "precise_ee_compliant", "gravity_compensation", "fault", "braking", "retracting",
    "holding",
])  # fmt: skip


def _modules() -> tuple[ModuleType, ModuleType] | str:
    try:
        core = importlib.import_module("reflexarm._core")  # registers ControllerParams for _closed_loop
        loop = importlib.import_module("reflexarm._closed_loop")
    except ImportError as e:
        return f"the compiled loop is not built ({e}); run make install"
    return core, loop


def compiled_reason(plant: Plant, controller: Any, *, reset_controller: bool = True) -> str | None:
    """Why this run cannot use the compiled loop (a sentence), or None if it can."""
    mods = _modules()
    if isinstance(mods, str):
        return mods
    from reflexarm.control import Controller

    if type(controller) is not Controller:
        return f"the controller is a {type(controller).__name__}, not a reflexarm Controller (its step is Python)"
    if not reset_controller:
        return "reset_controller=False: the compiled loop starts its controller from a reset"
    if getattr(controller, "torque_rate_limit", None) is not None:
        # a reset keeps the last command and the rate limit goes on from it; the compiled loop's controller
        # is configured afresh, without one
        return "the controller has a torque_rate_limit, which continues from its last command across a reset"
    if plant._extra is not None:
        return "the plant has a Python extra_joint_torque (called every substep); use smooth_friction for that law"
    if plant._failed is not None:
        return f"the plant failed earlier ({plant._failed})"
    for s in plant.scenes:
        p = playback(s, plant)
        if isinstance(p, str):
            return p
    return None


def run_fast(
    plant: Plant, controller: ControllerLike, trajectory: TrajectoryLike, duration: float, **kwargs: Any
) -> Trace:
    """:func:`run_compiled` when :func:`compiled_reason` finds nothing against it, else :func:`run_closed_loop`
    (same arguments; ``progress`` and ``callback`` always take the Python loop). Active run observers that
    accept the compiled loop's recorded states (stills) get them after a compiled run; any other observer (a
    video, which renders frames during the run) takes the Python loop. ``trace.meta["loop"]`` says which."""
    N, _ = _check(plant, controller, trajectory, duration)
    check_memory(N, plant.n, "run_fast")  # both loops keep every tick in memory
    reset = bool(kwargs.get("reset_controller", True))
    if (
        kwargs.get("callback") is None
        and not kwargs.get("progress")
        and compiled_reason(plant, controller, reset_controller=reset) is None
    ):
        if not observers_active():
            return run_compiled(plant, controller, trajectory, duration)
        observers = make_observers(plant)  # once per run, whichever loop runs it
        if all(accepts_compiled(o) for o in observers):

            def hand_over(record: CompiledStill) -> None:
                for o in observers:
                    o.take_compiled(plant, record)

            return _run(plant, controller, trajectory, duration, reset_controller=True, still=hand_over)
        with using_observers(plant, observers):  # a video: frames rendered every tick in Python
            trace = run_closed_loop(plant, controller, trajectory, duration, **kwargs)
    else:
        trace = run_closed_loop(plant, controller, trajectory, duration, **kwargs)
    trace.meta["loop"] = "python"
    return trace


def run_compiled(
    plant: Plant,
    controller: ControllerLike,
    trajectory: TrajectoryLike,
    duration: float,
    *,
    reset_controller: bool = True,
) -> Trace:
    """:func:`~reflexarm.sim.run_closed_loop` (same arguments and :class:`Trace`, tick for tick) as compiled code.

    Raises:
        ConfigError: this run cannot be compiled (the message says why; :func:`run_fast` falls back instead).
        SimulationError: the plant diverged (as in the Python loop; the trace so far is attached as ``.trace``).
    """
    return _run(plant, controller, trajectory, duration, reset_controller=reset_controller, still=None)


def _run(
    plant: Plant,
    controller: ControllerLike,
    trajectory: TrajectoryLike,
    duration: float,
    *,
    reset_controller: bool,
    still: Callable[[CompiledStill], None] | None,
) -> Trace:
    """:func:`run_compiled`; with ``still``, the states of a still are kept in C++ and handed to ``still``
    after the run (also when the run fails: the Python loop's observers have seen its ticks then too)."""
    N, meta = _check(plant, controller, trajectory, duration)
    check_memory(N, plant.n, "run_compiled")
    reason = compiled_reason(plant, controller, reset_controller=reset_controller)
    if reason is not None:
        raise ConfigError(f"this run cannot use the compiled loop: {reason}")
    with plant.in_use("a compiled run"):  # C++ steps the plant's MuJoCo data through raw pointers
        return _run_held(plant, controller, trajectory, N, meta, still)


def _run_held(
    plant: Plant,
    controller: ControllerLike,
    trajectory: TrajectoryLike,
    N: int,
    meta: dict[str, Any],
    still: Callable[[CompiledStill], None] | None,
) -> Trace:
    """:func:`_run` on the plant it holds."""
    mods = _modules()
    assert not isinstance(mods, str)
    core, cl = mods
    ctrl: Any = controller  # a reflexarm Controller (compiled_reason checked it)
    ctrl.reset()  # the switches to configure from are those after a reset
    n = plant.n
    loop = _make_loop(plant, ctrl, core, cl)
    if still is not None:
        loop.keep_still(_STILL_SPEC)
    times = _tick_times(plant, N)
    rec = _Recorder(N, n)
    ddq_d = np.zeros((N, n))
    _sample_reference(trajectory, times, rec.q_d, rec.dq_d, ddq_d)
    mode, fault_code, fault_info = np.zeros(N, np.int32), np.zeros(N, np.int32), np.zeros((N, 5))
    collision, collided = rec.collision.view(np.uint8), rec.collided.view(np.uint8)
    noise = _draw_noise(plant, N)  # a local: the loop reads it through a raw pointer until the run ends
    loop.set_buffers(
        noise, rec.q_d, rec.dq_d, ddq_d, rec.t, rec.q, rec.dq, rec.q_meas, rec.tau, rec.tau_m,
        rec.residual, rec.wrench, rec.tau_ext, rec.f_ext_ee, collision, collided, mode, fault_code, fault_info,
    )  # fmt: skip
    plays, plans, consts = _scene_data(plant, loop, rec, N)
    loop.set_forces(_forces(plant))
    loop.set_applied_torque(np.array(plant._tau))

    run = _EventRun(plant, loop, rec, times, plays, plans, consts, int(cl.STEP_DIVERGED))
    try:
        run.run()
    except BaseException as e:
        run.sync()
        _texts(rec, mode, fault_code, fault_info, core)
        try:
            e.trace = rec.trace(meta | {"loop": "compiled", "error": f"{type(e).__name__}: {e}"})  # type: ignore[attr-defined]
            if still is not None:
                _hand_over_still(loop, rec, fault_code, still)
        except Exception:  # pragma: no cover - never mask the original error
            pass
        raise
    run.sync()
    _texts(rec, mode, fault_code, fault_info, core)
    if still is not None:
        _hand_over_still(loop, rec, fault_code, still)
    _check_clock(rec, times)
    return rec.trace(meta | {"loop": "compiled", "collision_event": _event(loop.event, ctrl)})


class _EventRun:
    """A compiled run played in C++ from scene event to scene event: at an event tick the loop stops, the scene's
    Python ``update`` runs (and a HandPush is handed to C++), and the loop goes on."""

    def __init__(
        self,
        plant: Plant,
        loop: Any,
        rec: _Recorder,
        times: np.ndarray,
        plays: list[ScenePlay],
        plans: dict[int, Any],
        consts: list[Any],
        diverged: int,
    ) -> None:
        self.plant, self.loop, self.rec, self.times = plant, loop, rec, times
        self.plans, self.consts, self.diverged = plans, consts, diverged
        self.events = event_ticks(plays, times)
        self.pushes: list[ScenePlay] = []  # HandPush scenes handed to C++ (in the order of their index there)
        self.owned: set[int] = set()  # handles of plant._forces that a C++ push evaluates now
        self.keep: list[np.ndarray] = []  # arrays the loop reads through raw pointers
        self.tick0 = plant._tick
        self.done = self.acted = 0  # rows recorded, physics periods stepped

    def hold_constants(self, k_from: int) -> None:
        """Values of the scenes' observe() from row k_from on."""
        N = self.times.size
        for p in self.consts:
            if p in self.pushes:
                continue  # recorded by C++
            for key, value in p.scene.observe(self.plant).items():
                v = np.asarray(value)
                arr = self.rec.extras.setdefault(key, np.zeros((N, *v.shape), dtype=v.dtype))
                arr[k_from:] = v

    def fail(self, status: int) -> None:
        """The plant's SimulationError of the Python loop, with the plant in the same state."""
        self.sync()
        self.plant._fail(float(np.sum(self.plant.data.qvel**2)) if status == self.diverged else np.inf)

    def sync(self) -> None:
        """The plant's own bookkeeping, as Plant.step keeps it."""
        plant = self.plant
        plant._tau[:] = self.loop.applied_torque
        plant._tick = self.tick0 + self.acted
        for i, p in enumerate(self.pushes):
            hand_push_back(plant, p.scene, self.loop.push_state(i), self.owned)

    def run(self) -> None:
        plant, loop, rec, times, events = self.plant, self.loop, self.rec, self.times, self.events
        N = times.size
        self.hold_constants(0)
        for k_event in [*sorted(events), N]:
            status = _advance(loop, self.done, k_event, rec)
            self.done = self.acted = rec.done
            if status:
                self.fail(status)
            if k_event == N:
                break
            loop.sense(k_event)
            rec.done = self.done = k_event + 1
            for p in events[k_event]:
                p.scene.update(plant)
                p.plan_after_update(plant, k_event, times, self.plans.get(id(p)))
            self.hold_constants(k_event + 1)
            loop.set_forces(_forces(plant))
            status = loop.act(k_event)
            self.acted = k_event + 1
            if status:
                self.fail(status)
            for p in events[k_event]:
                if p.push and p not in self.pushes:
                    self.keep.extend(hand_push_to(loop, plant, p.scene, k_event, times, rec, self.owned))
                    self.pushes.append(p)
            loop.set_forces(_forces(plant, self.owned))


def _check_clock(rec: _Recorder, times: np.ndarray) -> None:
    if not np.array_equal(rec.t[: rec.done], times[: rec.done]):
        raise SimulationError("the compiled loop's clock differs from the sampled reference times; not returning it")


def _scene_data(plant: Plant, loop: Any, rec: _Recorder, N: int) -> tuple[list[ScenePlay], dict[int, Any], list[Any]]:
    """The scenes' data handed to the loop (mocap plans, recorded qpos and mocap slices in ``rec.extras``):
    (the scenes' plays, their mocap plans by play id, the plays with constant observed values)."""
    plays = [p for p in (playback(s, plant) for s in plant.scenes) if isinstance(p, ScenePlay)]
    plans: dict[int, np.ndarray] = {}
    qrec, mrec, consts = [], [], []
    for p in plays:
        if p.mocap_id is not None:
            plans[id(p)] = np.full((N, 3), np.nan)
        for key, (adr, size) in p.qpos_keys.items():
            rec.extras[key] = np.zeros((N, size))
            qrec.append((adr, size, rec.extras[key]))
        for key, mid in p.mocap_keys.items():
            rec.extras[key] = np.zeros((N, 3))
            mrec.append((mid, rec.extras[key]))
        if p.constant_keys:
            consts.append(p)
    loop.set_scene_data([(p.mocap_id, plans[id(p)]) for p in plays if p.mocap_id is not None], qrec, mrec)
    return plays, plans, consts


def _make_loop(plant: Plant, ctrl: Any, core: ModuleType, cl: ModuleType) -> Any:
    """The C++ ClosedLoop on ``plant``'s MuJoCo model and data with the (reset) controller's configuration."""
    m = plant.model
    loop = cl.ClosedLoop(
        m._address,
        plant.data._address,
        ctrl.robot.pin_model.saveToString(),
        _core_params(ctrl, core),
        np.asarray(plant._qadr_arr, dtype=np.int64),
        np.asarray(plant._arm_dofs, dtype=np.int64),
        np.asarray(plant._load_bodies, dtype=np.int64),
        np.asarray(plant._arm_bodies, dtype=np.int64),
        plant._force_adr,
        plant._torque_adr,
        plant._com_ref_body,
        plant._sensor_site,
        plant._physical_sensor,
        plant.substeps,
        MAX_SPEED,
        tuple(float(g) for g in plant._gravity),
    )
    if getattr(ctrl, "contact_geometry", None) is not None:  # isolation in the tick, as the Python controller's
        from reflexarm.control.collision.classify import contact_geometry_args

        loop.set_contact_geometry(*contact_geometry_args(ctrl.contact_geometry, ctrl.isolation_share))
    # MuJoCo's profiling timers read the clock dozens of times per step through the mujoco package's time
    # callback (5-8 % of a step); unless someone installed a callback to read them, they read 0 in the loop
    # (no effect on the state; reflexarm::QuietTimers)
    loop.quiet_timers = mujoco.get_mjcb_time() is None
    return loop


def _event(record: dict[str, Any], ctrl: Any) -> dict[str, Any] | None:
    """The compiled controller's collision event record, JSON-ready (None: no detection)."""
    from reflexarm.control.collision.event import CollisionEvent

    event = CollisionEvent.from_core(record, geometry=ctrl.contact_geometry, robot=ctrl.robot)
    return None if event is None else event.to_dict()


def _command(rec: _Recorder, fault_code: np.ndarray, k: int) -> Command:
    """The Command of recorded row k (``saturated`` is not recorded: empty)."""
    return Command(
        tau=rec.tau[k].copy(),
        residual=rec.residual[k].copy(),
        collision=bool(rec.collision[k]),
        collided_joints=tuple(int(j) for j in np.flatnonzero(rec.collided[k])),
        mode=str(rec.mode[k]),
        fault=str(rec.fault[k]),
        fault_code=int(fault_code[k]),
    )


def _hand_over_still(loop: Any, rec: _Recorder, fault_code: np.ndarray, still: Callable[[CompiledStill], None]) -> None:
    """The states C++ kept (``loop.still_states()``) as a :class:`CompiledStill`, given to ``still`` (nothing
    when no tick was sensed)."""
    spec, k0, start, kp, peak, peak2 = loop.still_states()
    if k0 < 0:
        return
    has_peak = kp >= 0
    still(
        CompiledStill(
            spec=int(spec),
            start_tick=int(k0),
            start_state=start,
            start_time=float(rec.t[k0]),
            start_command=_command(rec, fault_code, k0),
            peak_tick=int(kp) if has_peak else None,
            peak_state=peak if has_peak else None,
            peak_time=float(rec.t[kp]) if has_peak else None,
            peak_command=_command(rec, fault_code, kp) if has_peak else None,
            peak2=float(peak2),
        )
    )


def _advance(loop: Any, k0: int, k1: int, rec: _Recorder) -> int:
    """Ticks [k0, k1) in C++; ``rec.done`` is updated; returns the step status (0: fine)."""
    if k1 <= k0:
        return 0
    ran, status = loop.run(k0, k1)
    rec.done = k0 + ran
    return int(status)


def _texts(rec: _Recorder, mode: np.ndarray, code: np.ndarray, info: np.ndarray, core: ModuleType) -> None:
    """Mode names and fault texts of the recorded rows (the C++ core's own texts)."""
    d = rec.done
    rec.mode[:] = _MODES[mode[:d]].tolist()
    faults = [""] * d
    for k in np.flatnonzero(code[:d]):
        s, i, v, lo, hi = info[k]
        faults[k] = core.describe_fault(int(code[k]), int(s), int(i), float(v), float(lo), float(hi))
    rec.fault[:] = faults
