"""HumanContact: a human body region in the arm's way, as ISO/TS 15066 A.3 models it: the region's spring
(effective spring constant k) in front of its effective mass m_H, free to recoil (transient contact) or
backed by a rigid wall (quasi-static contact, clamping).

Why the spring is a force law of the scene, not a MuJoCo contact: MuJoCo's soft contacts are specified
as a time constant and damping ratio (solref), or as a stiffness per unit of the contact's effective mass;
either way the force per metre of indentation scales with the effective mass of the bodies in contact,
which changes with the arm's posture, and a stiffness of 150 N/mm on a light pad would need a time
constant far below the 2 x timestep MuJoCo accepts. So the region is a plane with a one-sided linear
spring, F = k max(0, x) (x the indentation of the arm's contact point into the region's surface, which
moves with the region's mass), applied to the arm at its contact point and, opposite, to the region's
mass, a MuJoCo body on a slide joint along the contact normal (gravity compensated along the slide).
The indentation is evaluated once per control tick, predicted to mid-tick from the relative velocity,
and the force held over the tick: exact k [N/m] at any posture, a zero-order hold of 1 ms (see the
tests for the error it leaves). The region's own surface has no MuJoCo collision: only this spring acts.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import mujoco
import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError
from reflexarm.robots.robot_model import RobotModel
from reflexarm.safety.body_regions import BodyRegion, body_region
from reflexarm.sim.scene import Scene, quat_from_x_axis

if TYPE_CHECKING:
    from reflexarm.sim.plant import Plant

__all__ = ["CONTACT_MODES", "HumanContact"]

#: "transient": the region's mass is free to recoil along the normal; "clamped": a rigid wall behind it.
CONTACT_MODES = ("transient", "clamped")
#: Half-size of the region's drawn patch [m] (drawing only; the spring acts along the whole plane).
PATCH_HALF_SIZE = 0.08


class HumanContact(Scene):
    """A body region's spring on the arm's path (ISO/TS 15066 A.3).

    Args:
        region: a key of :data:`~reflexarm.safety.BODY_REGIONS` or a :class:`~reflexarm.safety.BodyRegion`
            (its k and m_H are used).
        surface: a world point of the region's undeformed surface [m].
        normal: world direction into the region (the arm's direction of travel at contact) (3,).
        mode: "transient" (free mass m_H) or "clamped" (rigid wall behind the spring), see
            :data:`CONTACT_MODES`.
        damping: a viscous term c [Ns/m] in parallel with the spring (default 0: the standard's model is
            undamped); it only pushes, like the spring.
        arm_body: the arm's body (MuJoCo name) that carries the contact point; None: the end-effector site.
        arm_point: the contact point in ``arm_body``'s frame [m] (ignored without ``arm_body``).
        name: body name (unique per plant).

    Recorded extras: ``{name}_force`` (1,) the spring's
    force [N], ``{name}_indentation`` (1,) [m], ``{name}_recoil`` (1,) the region's displacement [m].
    """

    def __init__(
        self,
        region: str | BodyRegion,
        surface: npt.ArrayLike,
        normal: npt.ArrayLike,
        *,
        mode: str = "transient",
        damping: float = 0.0,
        arm_body: str | None = None,
        arm_point: npt.ArrayLike = (0.0, 0.0, 0.0),
        name: str = "human",
    ) -> None:
        self.region = body_region(region)
        self.surface = _vector(surface, "surface")
        n = _vector(normal, "normal")
        norm = float(np.linalg.norm(n))
        if norm < 1e-9:
            raise ConfigError(f"normal must be a non-zero direction; got {n.tolist()}")
        self.normal = n / norm
        if mode not in CONTACT_MODES:
            raise ConfigError(f"unknown contact mode {mode!r}; choose one of: {', '.join(CONTACT_MODES)}")
        self.mode = mode
        if not (math.isfinite(damping) and damping >= 0.0):
            raise ConfigError(f"damping must be a non-negative coefficient [Ns/m]; got {damping!r}")
        self.damping = float(damping)
        self.arm_body = None if arm_body is None else str(arm_body)
        self.arm_point = _vector(arm_point, "arm_point")
        self.name = str(name)
        self._reset_run()

    @property
    def stiffness(self) -> float:
        """k [N/m]."""
        return self.region.spring_constant_si

    def _reset_run(self) -> None:
        self._handles: list[int] = []
        self._force = 0.0
        self._indent = 0.0
        self._recoil = 0.0
        self._last: tuple[float, float] | None = None

    # ------------------------------------------------------------------ Scene hooks
    def build(self, spec: mujoco.MjSpec, robot: RobotModel) -> None:
        if spec.body(self.name) is not None:
            raise ConfigError(f"a body named {self.name!r} already exists; give the HumanContact another name=")
        quat = quat_from_x_axis(self.normal)
        body = spec.worldbody.add_body(name=self.name, pos=self.surface.tolist(), quat=quat.tolist())
        if self.mode == "transient":
            # every property given: the robot file's joint defaults (limits, damping, armature) must not apply
            body.add_joint(
                name=f"{self.name}_slide",
                type=mujoco.mjtJoint.mjJNT_SLIDE,
                axis=[1.0, 0.0, 0.0],
                limited=mujoco.mjtLimited.mjLIMITED_FALSE,
                range=[-1.0, 1.0],
                damping=0.0,
                frictionloss=0.0,
                armature=0.0,
                stiffness=0.0,
            )
            body.gravcomp = 1.0
        body.explicitinertial = True
        body.mass = self.region.human_mass
        body.ipos = [0.0, 0.0, 0.0]
        body.inertia = [self.region.human_mass * 0.01] * 3
        h = PATCH_HALF_SIZE
        body.add_geom(
            name=f"{self.name}_patch",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[0.01, h, h],
            pos=[0.01, 0.0, 0.0],
            contype=0,
            conaffinity=0,
            mass=0.0,
            rgba=[0.95, 0.7, 0.6, 0.6] if self.mode == "transient" else [0.7, 0.5, 0.45, 0.8],
        )

    def reset(self, plant: Plant) -> None:
        self._reset_run()

    def _recoil_state(self, plant: Plant) -> tuple[float, float]:
        if self.mode == "clamped":
            return 0.0, 0.0
        jid = mujoco.mj_name2id(plant.model, mujoco.mjtObj.mjOBJ_JOINT, f"{self.name}_slide")
        return float(plant.data.qpos[plant.model.jnt_qposadr[jid]]), float(plant.data.qvel[plant.model.jnt_dofadr[jid]])

    def update(self, plant: Plant) -> None:
        for h in self._handles:
            plant.clear_external_force(h)
        self._handles = []
        if self.arm_body is None:
            p = plant.ee_position()
        else:
            bid = plant._body_id(self.arm_body)  # ConfigError naming the bodies if unknown
            d = plant.data
            p = d.xpos[bid] + d.xmat[bid].reshape(3, 3) @ self.arm_point
        y, ydot = self._recoil_state(plant)
        u = self.normal
        x = float(u @ (p - self.surface)) - y  # indentation [m]
        xdot = 0.0 if self._last is None else (x - self._last[0]) / plant.control_period
        self._last = (x, xdot)
        x_mid = x + 0.5 * plant.control_period * xdot  # the hold's mid-tick indentation
        f = 0.0
        if x_mid > 0.0:
            f = max(0.0, self.stiffness * x_mid + self.damping * xdot)
        self._force, self._indent, self._recoil = f, x, y
        if f > 0.0:
            self._handles.append(plant.apply_external_force(-f * u, p, body=self.arm_body))
            if self.mode == "transient":
                self._handles.append(plant.apply_external_force(f * u, None, body=self.name))

    def observe(self, plant: Plant) -> dict[str, np.ndarray]:
        return {
            f"{self.name}_force": np.array([self._force]),
            f"{self.name}_indentation": np.array([self._indent]),
            f"{self.name}_recoil": np.array([self._recoil]),
        }

    def describe(self) -> dict[str, object]:
        return {
            "type": "HumanContact",
            "name": self.name,
            "region": self.region.name,
            "mode": self.mode,
            "k_N_per_mm": self.region.spring_constant,
            "m_H_kg": self.region.human_mass if self.mode == "transient" else None,
            "damping_Ns_per_m": self.damping,
            "arm_body": self.arm_body,
            "arm_point_m": self.arm_point.tolist(),
            "surface_m": self.surface.tolist(),
            "normal": self.normal.tolist(),
        }


def _vector(value: npt.ArrayLike, name: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{name} must be a 3-vector [m]; got {value!r}") from e
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ConfigError(f"{name} must be a finite 3-vector; got {np.asarray(value).tolist()!r}")
    return v
