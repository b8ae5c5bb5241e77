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

Not playable: any scene type not listed here that overrides ``update`` or ``observe``: those runs use the
Python loop.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from reflexarm.sim.cinderblock import Cinderblock
from reflexarm.sim.elbow_stick import PARKED, ElbowStick
from reflexarm.sim.end_effector_force import EndEffectorForce
from reflexarm.sim.hand_push import HandPush
from reflexarm.sim.link_force import LinkForce
from reflexarm.sim.scene import Scene

if TYPE_CHECKING:
    from reflexarm.sim.plant import Plant

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
