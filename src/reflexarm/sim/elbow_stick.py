"""ElbowStick: a cardboard stick pushed into the elbow against the arm's motion (Sec. III-B, Fig. 9)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import mujoco
import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError, SimulationError
from reflexarm.robots.robot_model import RobotModel
from reflexarm.sim.scene import CONTACT_ARM, Scene, quat_from_x_axis

if TYPE_CHECKING:
    from reflexarm.sim.plant import Plant

__all__ = ["ElbowStick"]

#: Cardboard contact: 30 ms time constant, critically damped (softer than MuJoCo's 20 ms default) ...
STICK_SOLREF = (0.03, 1.0)
#: ... and an impedance rising from 0.5 at first touch to 0.9 at 1.5 cm of indentation: the cardboard
#: tip crumples before it transmits the full push.
STICK_SOLIMP = (0.5, 0.9, 0.015, 0.5, 2.0)
#: Where the stick waits when it is not in use (it only collides with the arm, so anywhere away works).
PARKED = (0.0, 0.0, -50.0)


class ElbowStick(Scene):
    """A kinematic (mocap) stick that is pushed into an arm link during a time window.

    At ``t_start`` the stick appears with its tip ``standoff`` (plus its radius) away from the target
    point, on the side the point is moving towards, pointing along ``direction`` (default: against the
    point's velocity at ``t_start``, as in the paper where the elbow was "pushed ... against the moving
    direction"). It then moves along ``direction`` at ``speed`` for ``duration`` seconds, retracts at
    the same speed to where it started, and is parked away. Contact with the arm is soft (cardboard,
    see ``STICK_SOLREF``/``STICK_SOLIMP``); the stick is kinematic, so it pushes with whatever force its
    motion requires.

    Args:
        body: the arm body pushed (default ``"l_larm"``: link 4 of Atlas, after the elbow joint elx).
        t_start: when the stick appears and starts moving [s].
        speed: stick speed [m/s] (the paper's elbow moved at ~50 mm/s).
        duration: length of the pushing phase [s].
        direction: (3,) world direction of the stick's motion; None: against the target's velocity at
            ``t_start`` (the run fails with a SimulationError if the target is then at rest).
        point: target point in the body frame [m]; None: the centre of the body's first collision geom.
        standoff: distance from the target point to the stick's tip at ``t_start`` [m] (the gap to the
            link's surface is ``standoff`` minus the link's radius: 5 cm on Atlas' forearm by default,
            closed in ~0.5 s when arm and stick both move at 50 mm/s).
        radius: stick radius [m].
        length: stick length [m].
        name: mocap body name (unique per plant); the tip position is recorded as ``{name}_tip``.
        tip: world position of the tip's centre [m] (needs ``direction``): the stick appears there at
            ``t_start`` instead of ahead of the target point (a held stick placed on the link's path).
    """

    def __init__(
        self,
        body: str = "l_larm",
        t_start: float = 5.0,
        speed: float = 0.05,
        duration: float = 1.5,
        *,
        direction: npt.ArrayLike | None = None,
        point: npt.ArrayLike | None = None,
        standoff: float = 0.10,
        radius: float = 0.015,
        length: float = 0.6,
        name: str = "elbow_stick",
        tip: npt.ArrayLike | None = None,
    ) -> None:
        self.body = str(body)
        self.t_start = _nonneg(t_start, "t_start")
        self.speed = _nonneg(speed, "speed")
        self.duration = _nonneg(duration, "duration")
        if direction is None:
            self.direction: np.ndarray | None = None
        else:
            d = np.asarray(direction, dtype=float).reshape(-1)
            if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) < 1e-12:
                raise ConfigError(f"direction must be a non-zero finite 3-vector; got {direction!r}")
            self.direction = d / np.linalg.norm(d)
        if point is None:
            self.point: np.ndarray | None = None
        else:
            p = np.asarray(point, dtype=float).reshape(-1)
            if p.shape != (3,) or not np.all(np.isfinite(p)):
                raise ConfigError(f"point must be a finite 3-vector in the body frame [m]; got {point!r}")
            self.point = p
        if tip is None:
            self.tip: np.ndarray | None = None
        else:
            t = np.asarray(tip, dtype=float).reshape(-1)
            if t.shape != (3,) or not np.all(np.isfinite(t)):
                raise ConfigError(f"tip must be a finite world 3-vector [m]; got {tip!r}")
            if self.direction is None:
                raise ConfigError("ElbowStick: tip= needs direction= (the stick's axis)")
            self.tip = t
        self.standoff = _nonneg(standoff, "standoff")
        self.radius = _positive(radius, "radius")
        self.length = _positive(length, "length")
        self.name = str(name)
        self._id_cache: tuple[mujoco.MjModel, int, int] | None = None
        self._reset_run()

    def _reset_run(self) -> None:
        self._start: np.ndarray | None = None  # tip position at t_start
        self._dir: np.ndarray | None = None

    # ------------------------------------------------------------------ Scene hooks
    def build(self, spec: mujoco.MjSpec, robot: RobotModel) -> None:
        if spec.body(self.body) is None:
            names = [b.name for b in spec.bodies if b.name]
            raise ConfigError(f"ElbowStick: unknown arm body {self.body!r}; bodies are: {', '.join(names)}")
        if spec.body(self.name) is not None:
            raise ConfigError(f"a body named {self.name!r} already exists; give the ElbowStick another name=")
        stick = spec.worldbody.add_body(name=self.name, pos=list(PARKED), mocap=True)
        stick.add_geom(
            name=f"{self.name}_geom",
            type=mujoco.mjtGeom.mjGEOM_CAPSULE,
            fromto=[-self.length, 0.0, 0.0, 0.0, 0.0, 0.0],
            size=[self.radius, 0.0, 0.0],
            contype=CONTACT_ARM,
            conaffinity=0,
            solref=list(STICK_SOLREF),
            solimp=list(STICK_SOLIMP),
            rgba=[0.75, 0.6, 0.4, 1.0],
        )

    def reset(self, plant: Plant) -> None:
        self._reset_run()
        self._set(plant, np.array(PARKED), np.array([1.0, 0.0, 0.0, 0.0]))

    def _ids(self, plant: Plant) -> tuple[int, int]:
        m = plant.model
        cached = self._id_cache
        if cached is not None and cached[0] is m:
            return cached[1], cached[2]
        bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, self.name)
        target = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, self.body)
        if bid < 0 or target < 0:
            raise ConfigError(f"this plant has no ElbowStick named {self.name!r} (or no body {self.body!r})")
        self._id_cache = (m, int(m.body_mocapid[bid]), int(target))
        return self._id_cache[1], self._id_cache[2]

    def _set(self, plant: Plant, pos: np.ndarray, quat: np.ndarray | None = None) -> None:
        mocap, _ = self._ids(plant)
        plant.data.mocap_pos[mocap] = pos
        if quat is not None:
            plant.data.mocap_quat[mocap] = quat

    def target_point(self, plant: Plant) -> np.ndarray:
        """World position of the target point on the arm body (last physics evaluation)."""
        m, d = plant.model, plant.data
        _, bid = self._ids(plant)
        if self.point is not None:
            return np.array(d.xpos[bid] + d.xmat[bid].reshape(3, 3) @ self.point)
        geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] == bid and (m.geom_contype[g] or m.geom_conaffinity[g])]
        if not geoms:
            return np.array(d.xipos[bid])
        return np.array(d.geom_xpos[geoms[0]])

    def _start_run(self, plant: Plant) -> None:
        m, d = plant.model, plant.data
        _, bid = self._ids(plant)
        if self.tip is not None and self.direction is not None:
            self._dir = self.direction
            self._start = self.tip.copy()
            self._set(plant, self._start, quat_from_x_axis(self.direction))
            return
        p = self.target_point(plant)
        if self.direction is None:
            jacp = np.zeros((3, m.nv))
            mujoco.mj_jac(m, d, jacp, None, p, bid)
            v = jacp @ d.qvel
            speed = float(np.linalg.norm(v))
            if speed < 1e-3:
                raise SimulationError(
                    f"ElbowStick: the target point on {self.body!r} moves at {speed:.2g} m/s at t_start = "
                    f"{self.t_start} s; give direction= explicitly"
                )
            direction = -v / speed
        else:
            direction = self.direction
        self._dir = direction
        self._start = p - direction * (self.standoff + self.radius)
        self._set(plant, self._start, quat_from_x_axis(direction))

    def tip_position(self, t: float) -> np.ndarray | None:
        """Centre of the stick's tip at time t (None while parked or before the run started)."""
        if self._start is None or self._dir is None:
            return None
        s = t - self.t_start
        if s < 0.0:
            return None
        travel = self.speed * self.duration
        if s <= self.duration:
            x = self.speed * s
        elif s <= 2.0 * self.duration:
            x = travel - self.speed * (s - self.duration)
        else:
            return None
        return np.asarray(self._start + self._dir * x)

    def update(self, plant: Plant) -> None:
        t = plant.time
        if t + 1e-9 < self.t_start:
            return
        if self._start is None:
            self._start_run(plant)
        tip = self.tip_position(t)
        self._set(plant, np.array(PARKED) if tip is None else tip)

    def observe(self, plant: Plant) -> dict[str, np.ndarray]:
        mocap, _ = self._ids(plant)
        return {f"{self.name}_tip": plant.data.mocap_pos[mocap].copy()}

    def describe(self) -> dict[str, object]:
        return {
            "type": "ElbowStick",
            "name": self.name,
            "body": self.body,
            "t_start": self.t_start,
            "speed": self.speed,
            "duration": self.duration,
            "direction": None if self.direction is None else self.direction.tolist(),
            "standoff": self.standoff,
            "radius": self.radius,
        }


def _nonneg(value: float, name: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{name} must be a non-negative number; got {value!r}") from e
    if not math.isfinite(x) or x < 0.0:
        raise ConfigError(f"{name} must be a non-negative number; got {value!r}")
    return x


def _positive(value: float, name: str) -> float:
    x = _nonneg(value, name)
    if x == 0.0:
        raise ConfigError(f"{name} must be a positive number; got {value!r}")
    return x
