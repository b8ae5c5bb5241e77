"""What the compiled loop needs from a scene: the ticks where its Python ``update`` must run, and what it
does in between as data (a mocap path sampled per tick, forces fixed on bodies), plus where its recorded
signals come from (private; used by :mod:`reflexarm.sim.compiled_loop`).

Scenes stay defined in Python. A scene is *playable* when, between a few event ticks, what it does each
tick is a function of time alone or nothing:

* a scene that overrides neither ``update`` nor ``observe`` (static scenery);
* :class:`~reflexarm.sim.Cinderblock`: no per-tick action; its pose is recorded from ``qpos``;
* :class:`~reflexarm.sim.EndEffectorForce`, :class:`~reflexarm.sim.LinkForce`: act at switch-on (the
  direction is resolved from the state then) and switch-off; the force in between is fixed on the body
  and refreshed from the body's pose every tick in C++, as ``Plant`` does;
* :class:`~reflexarm.sim.ElbowStick`: acts at ``t_start`` (its direction comes from the arm's velocity
  then); afterwards the tip path is a function of time, sampled for every later tick.
* :class:`~reflexarm.sim.HandPush`: acts at ``t_start`` in Python (its direction and start point come from
  the state then); afterwards its spring-damper on the end-effector position is evaluated in C++ every
  tick (``reflexarm::SpringPush``) from its rest travel, sampled per tick.

:func:`hand_push_to` and :func:`hand_push_back` move a HandPush's state from Python to C++ and back.

Not playable: any scene type not listed here that overrides ``update`` or ``observe``: those runs use the
Python loop.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

from reflexarm.sim._plant_forces import _AppliedForce
from reflexarm.sim.cinderblock import Cinderblock
from reflexarm.sim.elbow_stick import PARKED, ElbowStick
from reflexarm.sim.end_effector_force import EndEffectorForce
from reflexarm.sim.hand_push import HandPush
from reflexarm.sim.link_force import LinkForce
from reflexarm.sim.scene import Scene

if TYPE_CHECKING:
    from reflexarm.sim.plant import Plant
    from reflexarm.sim.recording import _Recorder

#: Scenes updated by ``Plant.step`` compare times with this slack [s] (``plant.time + 1e-9``).
TIME_SLACK = 1e-9


@dataclass
class ScenePlay:
    """How one scene runs in the compiled loop.

    Attributes:
        scene: the scene.
        events: times [s] at which its ``update`` runs in Python (at the first tick whose time + 1e-9
            reaches them).
        constant_keys: recorded signals that change only in ``update`` (read with ``observe`` after each
            Python update and held).
        qpos_keys: recorded signals read from ``qpos`` every tick: key -> (address, size).
        mocap_keys: recorded signals read from a mocap position every tick: key -> mocap id.
        mocap_id: the mocap body whose path is played after an event (ElbowStick), else None.
        push: the scene is a HandPush, evaluated in C++ after its event.
    """

    scene: Scene
    events: list[float] = field(default_factory=list)
    constant_keys: list[str] = field(default_factory=list)
    qpos_keys: dict[str, tuple[int, int]] = field(default_factory=dict)
    mocap_keys: dict[str, int] = field(default_factory=dict)
    mocap_id: int | None = None
    push: bool = False

    def plan_after_update(self, plant: Plant, k: int, times: np.ndarray, plan: np.ndarray | None) -> None:
        """After the Python update at tick ``k``: write the mocap path of ticks k+1.. into ``plan`` (N, 3)."""
        s = self.scene
        if plan is None or not isinstance(s, ElbowStick):
            return
        for j in range(k + 1, times.size):
            tip = s.tip_position(float(times[j]))
            plan[j] = PARKED if tip is None else tip


def playback(scene: Scene, plant: Plant) -> ScenePlay | str:
    """The scene's :class:`ScenePlay`, or why it cannot be played (a sentence)."""
    m = plant.model
    kind = type(scene)
    if kind.update is Scene.update and kind.observe is Scene.observe:
        return ScenePlay(scene)
    if isinstance(scene, Cinderblock) and kind.update is Scene.update:
        adr = scene._qpos_adr(plant)
        return ScenePlay(scene, qpos_keys={f"{scene.name}_pos": (adr, 3), f"{scene.name}_quat": (adr + 3, 4)})
    if isinstance(scene, (EndEffectorForce, LinkForce)) and kind in (EndEffectorForce, LinkForce):
        return ScenePlay(scene, events=[scene.t_on, scene.t_off], constant_keys=list(scene.observe(plant)))
    if kind is ElbowStick:
        assert isinstance(scene, ElbowStick)
        mocap, _ = scene._ids(plant)
        bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, scene.name)
        assert int(m.body_mocapid[bid]) == mocap
        return ScenePlay(scene, events=[scene.t_start], mocap_keys={f"{scene.name}_tip": mocap}, mocap_id=mocap)
    if kind is HandPush:
        assert isinstance(scene, HandPush)
        return ScenePlay(scene, events=[scene.t_start], constant_keys=list(scene.observe(plant)), push=True)
    return (
        f"scene {kind.__name__} acts every tick from the state (update/observe in Python) and has no playback; "
        "playable: static scenes, Cinderblock, EndEffectorForce, LinkForce, ElbowStick, HandPush"
    )


def event_ticks(plays: list[ScenePlay], times: np.ndarray) -> dict[int, list[ScenePlay]]:
    """Tick -> the scenes whose Python update runs at it (first tick with time + 1e-9 >= the event time)."""
    out: dict[int, list[ScenePlay]] = {}
    for p in plays:
        for te in p.events:
            if not np.isfinite(te):
                continue
            k = int(np.searchsorted(times + TIME_SLACK, te, side="left"))
            if k < times.size:
                out.setdefault(k, []).append(p)
    return out


def hand_push_to(
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


def hand_push_back(plant: Plant, scene: Any, state: tuple, owned: set[int]) -> None:
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
