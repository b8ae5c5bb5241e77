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
"""

from __future__ import annotations

import importlib
from dataclasses import fields
from types import ModuleType
from typing import Any

import numpy as np

from reflexarm.errors import ConfigError, SimulationError
from reflexarm.sim._plant_forces import _AppliedForce
from reflexarm.sim._plant_sensors import _NOISE_BLOCK
from reflexarm.sim._playback import TIME_SLACK, ScenePlay, event_ticks, playback
from reflexarm.sim.plant import MAX_SPEED, Plant
from reflexarm.sim.recording import _Recorder
from reflexarm.sim.run_observers import observers_active
from reflexarm.sim.runner import ControllerLike, TrajectoryLike, _check, run_closed_loop
from reflexarm.sim.trace import Trace
from reflexarm.sim.trajectory import JointTrajectory

__all__ = ["compiled_reason", "run_compiled", "run_fast"]

#: Mode names in the order of the C++ enum reflexarm::Mode (as reflexarm.control.controller.MODES).
_MODES = np.array(["compliant", "precise_stiff", "precise_ee_compliant", "gravity_compensation", "fault"])


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
    (same arguments; ``progress``, ``callback`` and active run observers always take the Python loop).
    ``trace.meta["loop"]`` says which."""
    reset = bool(kwargs.get("reset_controller", True))
    if (
        kwargs.get("callback") is None
        and not observers_active()  # stills and videos (reflexarm.sim.run_observers) watch every tick in Python
        and not kwargs.get("progress")
        and compiled_reason(plant, controller, reset_controller=reset) is None
    ):
        return run_compiled(plant, controller, trajectory, duration)
    trace = run_closed_loop(plant, controller, trajectory, duration, **kwargs)
    trace.meta["loop"] = "python"
    return trace


def _core_params(controller: Any, core: ModuleType) -> Any:
    """The core's ControllerParams of a (reset) Python Controller: those the Controller configures its own core
    with (``control._setup.core_params``) when it has that function, with the switches it has now."""
    setup = importlib.import_module("reflexarm.control._setup")
    if hasattr(setup, "core_params"):
        p = setup.core_params(controller, core)
        p.kappa_f, p.kappa_eps, p.kappa_ext = (
            int(controller.kappa_f),
            int(controller.kappa_eps),
            int(controller.kappa_ext),
        )
        return p
    p = core.ControllerParams()
    robot, imp = controller.robot, controller.impedance
    gains = getattr(imp, "gains", imp)
    p.stiffness = np.array(gains.stiffness, dtype=float)
    p.damping_ratio = np.array(gains.damping_ratio, dtype=float)
    p.observer_gain = np.array(controller.observer.observer_gain, dtype=float)
    det = controller.detection_observer
    p.detection_observer_gain = np.zeros(0) if det is None else np.array(det.observer_gain, dtype=float)
    p.threshold = np.zeros(0) if controller.detector is None else np.array(controller.detector.threshold, dtype=float)
    p.reaction = controller.reaction
    p.kappa_f, p.kappa_eps, p.kappa_ext = int(controller.kappa_f), int(controller.kappa_eps), int(controller.kappa_ext)
    p.residual_limit, p.switch_time, p.dt = controller.residual_limit, controller.switch_time, controller.dt
    p.damping_update_period = int(imp.damping_update_period)
    fr = robot.friction
    p.friction_coulomb, p.friction_viscous = fr.coulomb.copy(), fr.viscous.copy()
    p.friction_velocity_band = fr.velocity_band
    if robot.has_springs:
        p.spring_stiffness = np.array(robot.spring_stiffness, dtype=float)
        p.spring_reference = np.array(robot.spring_reference, dtype=float)
    p.sensor_frame_id = robot.sensor_frame_id
    limit = controller.torque_limit
    p.torque_limit = np.full(robot.n, np.inf) if limit is None else np.array(limit, dtype=float)
    rate = controller.torque_rate_limit
    p.torque_rate_limit = np.zeros(0) if rate is None else np.array(rate, dtype=float)
    bounds = core.InputBounds()
    for f in fields(controller.input_bounds):
        setattr(bounds, f.name, float(getattr(controller.input_bounds, f.name)))
    p.input_bounds = bounds
    p.period_band_low, p.period_band_high = (float(x) for x in controller.period_band)
    return p


def _tick_times(plant: Plant, N: int) -> np.ndarray:
    """MuJoCo's clock at each of the next N ticks (it adds ``opt.timestep`` once per physics step)."""
    h = float(plant.model.opt.timestep)
    steps = np.full(N * plant.substeps + 1, h)
    steps[0] = float(plant.data.time)
    # add.accumulate adds left to right, one step at a time: the very sums MuJoCo's clock makes
    return np.add.accumulate(steps)[: N * plant.substeps : plant.substeps].copy()


def _sample_reference(
    trajectory: TrajectoryLike, times: np.ndarray, q_d: np.ndarray, dq_d: np.ndarray, ddq_d: np.ndarray
) -> None:
    """``trajectory.sample`` at every tick time into the (N, n) arrays.

    Two shapes are evaluated as whole arrays (the per-call cost of ``sample`` is ~5 us, a quarter of a
    tick's physics): a :class:`JointTrajectory`, with the operations of its sampling kernel in the same
    order (so the same numbers to the bit), and a trajectory whose ``sample`` returns one and the same
    Reference object at the first and last tick (a hold). Anything else is sampled tick by tick.
    """
    if type(trajectory) is JointTrajectory:
        tr: Any = trajectory
        starts, lengths, t_end = tr._starts_arr, tr._lengths_arr, float(tr._t_end)
        i = np.clip(np.searchsorted(starts, times, side="right") - 1, 0, starts.size - 1)
        T = lengths[i]
        x = (times - starts[i]) / T
        x2 = x * x
        s = x2 * x * (10.0 - 15.0 * x + 6.0 * x2)
        ds = 30.0 * x2 * (1.0 - 2.0 * x + x2) / T
        dds = 60.0 * x * (1.0 - 3.0 * x + 2.0 * x2) / (T * T)
        before, after = times <= starts[0], times >= t_end
        i[before], s[before], ds[before], dds[before] = 0, 0.0, 0.0, 0.0
        i[after], s[after], ds[after], dds[after] = starts.size - 1, 1.0, 0.0, 0.0
        d = tr._deltas[i]
        q_d[:] = tr._origins[i] + s[:, None] * d
        dq_d[:] = ds[:, None] * d
        ddq_d[:] = dds[:, None] * d
        return
    first = trajectory.sample(float(times[0]))
    if trajectory.sample(float(times[-1])) is first:
        q_d[:], dq_d[:], ddq_d[:] = first.q_d, first.dq_d, first.ddq_d
        return
    sample = trajectory.sample
    for k in range(times.size):
        r = sample(float(times[k]))
        q_d[k], dq_d[k], ddq_d[k] = r.q_d, r.dq_d, r.ddq_d


def _draw_noise(plant: Plant, N: int) -> np.ndarray | None:
    """The noise rows of the next N measurements, drawn as N calls of ``Plant.measure`` would draw them."""
    if not plant._noisy:
        return None
    out = np.empty((N, plant._dim))
    k = 0
    while k < N:
        if plant._noise_i >= plant._noise_rows.shape[0]:
            plant._noise_rows = plant._rng.uniform(-1.0, 1.0, (_NOISE_BLOCK, plant._dim)) * plant._levels
            plant._noise_i = 0
        take = min(N - k, plant._noise_rows.shape[0] - plant._noise_i)
        out[k : k + take] = plant._noise_rows[plant._noise_i : plant._noise_i + take]
        plant._noise_i += take
        k += take
    return out


def _forces(plant: Plant, skip: set[int] | None = None) -> np.ndarray:
    """The plant's applied forces as rows (body, force, point in the body frame), without the ``skip`` handles."""
    rows = [[f.body, *f.force, *f.point_local] for h, f in plant._forces.items() if not skip or h not in skip]
    return np.array(rows, dtype=float).reshape(-1, 7)


def _push_to(
    loop: Any, plant: Plant, scene: Any, k: int, times: np.ndarray, rec: _Recorder, owned: set[int]
) -> list[np.ndarray]:
    """Hand a HandPush, just updated in Python at tick k, to C++ for the ticks after k; returns its arrays."""
    N = times.size
    rest, rest_v = np.full(N, np.nan), np.zeros(N)
    for j in range(k + 1, N):
        t = float(times[j]) + TIME_SLACK  # as HandPush.update: plant.time + 1e-9
        if not (t < scene.t_start or t >= scene.t_release):
            rest[j], rest_v[j] = scene._rest(t)
    handle = scene._handle
    local = plant._forces[handle].point_local if handle is not None else np.zeros(3)
    if handle is not None:
        owned.add(handle)
    u = scene._u if scene._u is not None else np.zeros(3)
    last = scene._last_x
    loop.set_push(
        plant._ee_body, plant._ee_site, tuple(u), tuple(scene._p0), scene.stiffness, scene.damping,
        plant.control_period, rest, rest_v, rec.extras["hand_force"], rec.extras["hand_target"],
        0.0 if last is None else last, last is not None, handle is not None,
        tuple(scene._force), tuple(scene._target), tuple(local),
    )  # fmt: skip
    return [rest, rest_v]


def _push_back(plant: Plant, scene: Any, state: tuple, owned: set[int]) -> None:
    """The HandPush's Python state (and its force in the plant) as the Python loop would have left them."""
    last_x, has_last, applied, force, target, local = state
    scene._last_x = last_x if has_last else None
    scene._force, scene._target = np.array(force), np.array(target)
    if scene._handle is not None and scene._handle in owned:
        plant._forces.pop(scene._handle, None)
        owned.discard(scene._handle)
    scene._handle = None
    if applied:
        handle = plant._next_force
        plant._next_force += 1
        plant._forces[handle] = _AppliedForce(plant._ee_body, np.array(force), np.array(local))
        scene._handle = handle
        owned.add(handle)


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
    N, meta = _check(plant, controller, trajectory, duration)
    reason = compiled_reason(plant, controller, reset_controller=reset_controller)
    if reason is not None:
        raise ConfigError(f"this run cannot use the compiled loop: {reason}")
    mods = _modules()
    assert not isinstance(mods, str)
    core, cl = mods
    ctrl: Any = controller  # a reflexarm Controller (compiled_reason checked it)
    ctrl.reset()  # the switches to configure from are those after a reset
    m, n = plant.model, plant.n
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
    loop.set_forces(_forces(plant))
    loop.set_applied_torque(np.array(plant._tau))

    pushes: list[ScenePlay] = []  # HandPush scenes handed to C++ (in the order of their index there)
    owned: set[int] = set()  # handles of plant._forces that a C++ push evaluates now
    keep: list[np.ndarray] = []  # arrays the loop reads through raw pointers

    def hold_constants(k_from: int) -> None:  # values of observe() from row k_from on
        for p in consts:
            if p in pushes:
                continue  # recorded by C++
            for key, value in p.scene.observe(plant).items():
                v = np.asarray(value)
                arr = rec.extras.setdefault(key, np.zeros((N, *v.shape), dtype=v.dtype))
                arr[k_from:] = v

    events = event_ticks(plays, times)
    tick0 = plant._tick
    done = acted = 0  # rows recorded, physics periods stepped

    def fail(status: int) -> None:
        """The plant's SimulationError of the Python loop, with the plant in the same state."""
        sync(acted)
        plant._fail(float(np.sum(plant.data.qvel**2)) if status == cl.STEP_DIVERGED else np.inf)

    def sync(periods: int) -> None:  # the plant's own bookkeeping, as Plant.step keeps it
        plant._tau[:] = loop.applied_torque
        plant._tick = tick0 + periods
        for i, p in enumerate(pushes):
            _push_back(plant, p.scene, loop.push_state(i), owned)

    try:
        hold_constants(0)
        for k_event in [*sorted(events), N]:
            status = _advance(loop, done, k_event, rec)
            done = acted = rec.done
            if status:
                fail(status)
            if k_event == N:
                break
            loop.sense(k_event)
            rec.done = done = k_event + 1
            for p in events[k_event]:
                p.scene.update(plant)
                p.plan_after_update(plant, k_event, times, plans.get(id(p)))
            hold_constants(k_event + 1)
            loop.set_forces(_forces(plant))
            status = loop.act(k_event)
            acted = k_event + 1
            if status:
                fail(status)
            for p in events[k_event]:
                if p.push and p not in pushes:
                    keep.extend(_push_to(loop, plant, p.scene, k_event, times, rec, owned))
                    pushes.append(p)
            loop.set_forces(_forces(plant, owned))
    except BaseException as e:
        sync(acted)
        _texts(rec, mode, fault_code, fault_info, core)
        try:
            e.trace = rec.trace(meta | {"loop": "compiled", "error": f"{type(e).__name__}: {e}"})  # type: ignore[attr-defined]
        except Exception:  # pragma: no cover - never mask the original error
            pass
        raise
    sync(acted)
    _texts(rec, mode, fault_code, fault_info, core)
    if not np.array_equal(rec.t[: rec.done], times[: rec.done]):
        raise SimulationError("the compiled loop's clock differs from the sampled reference times; not returning it")
    return rec.trace(meta | {"loop": "compiled"})


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
