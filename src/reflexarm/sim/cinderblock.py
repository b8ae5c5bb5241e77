"""Cinderblock: the styrofoam-padded cinderblock of the end-effector collision experiment (Sec. III-A, Fig. 7)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import mujoco
import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError
from reflexarm.robots.robot_model import RobotModel
from reflexarm.sim.scene import CONTACT_ARM, CONTACT_WORLD, Scene, add_floor

if TYPE_CHECKING:
    from reflexarm.sim.plant import Plant

__all__ = ["Cinderblock"]

#: Contact softness of the styrofoam padding (MuJoCo solref = (time constant [s], damping ratio)).
#: 25 ms (MuJoCo's default is 20 ms) with critical damping. MuJoCo's contact stiffness scales with the
#: effective mass at the contact; pressing Atlas' hand down with 100 N indents the padding by 3.1 mm
#: (~3e4 N/m, measured): millimetres at the ~70 N of Fig. 8, and no bounce, as foam behaves.
PADDING_SOLREF = (0.025, 1.0)
#: solimp = (d0, dwidth, width [m], midpoint, power): the impedance rises from 0.7 at first touch to 0.95
#: once the foam is compressed by ``width``: soft at first, firmer as the foam is crushed.
PADDING_SOLIMP = (0.7, 0.95, 0.02, 0.5, 2.0)
#: Hard contact between the block's concrete core and the table/floor: 4 ms time constant, so that the
#: 15 kg block sinks only micrometres into its support (2 um measured) and the displacement since reset
#: is the block's own motion, not contact settling.
HARD_SOLREF = (0.004, 1.0)
#: Coulomb friction of concrete on the table (sliding, torsional, rolling). The sliding coefficient is the
#: ``friction`` argument of :class:`Cinderblock`; 0.6 is concrete on wood. A higher one (0.9, e.g. a
#: rough or rubber-topped table) holds the block's base while the arm pushes high on its side, so it
#: tips instead of sliding (Fig. 7 b).
BLOCK_FRICTION = (0.6, 0.005, 0.0001)


class Cinderblock(Scene):
    """A heavy free box with a soft padding, standing on a static table (or the floor).

    The block is a free body (15 kg default) with a hard core of the cinderblock's size that rests on
    the table, and a padding box ``padding`` thicker on the four sides and the top that only the arm
    touches (styrofoam: softer contact, see ``PADDING_SOLREF``/``PADDING_SOLIMP``). A stiff controller
    that keeps pushing can slide or tip it (Fig. 7 b).

    The table is a solid box from the floor to ``table_height`` centred under the block; the arm
    collides with it too (a real collision), but never with the floor plane at z = 0.

    Args:
        position: (x, y) of the block's centre in the world [m], or (x, y, z) where z is the height of
            the block's bottom above the table top (0: standing on it; > 0 drops it from there).
        size: full edge lengths (x, y, z) of the cinderblock [m] (0.39 x 0.19 x 0.19 is a standard one).
        mass: [kg].
        padding: styrofoam thickness on the sides and top [m].
        table_height: height of the table top [m]; 0 puts the block on the floor without a table.
        friction: sliding friction coefficient between the block and its support (table or floor) [-];
            MuJoCo takes the larger of the two geoms' coefficients, so it is set on both.
        table_size: (x, y) extent of the table top [m].
        yaw: rotation of the block about the vertical axis [rad].
        name: body name (unique per plant); extras are recorded as ``{name}_pos`` and ``{name}_quat``.
    """

    def __init__(
        self,
        position: npt.ArrayLike,
        size: npt.ArrayLike = (0.39, 0.19, 0.19),
        mass: float = 15.0,
        padding: float = 0.03,
        table_height: float = 0.75,
        friction: float = BLOCK_FRICTION[0],
        *,
        table_size: npt.ArrayLike = (0.8, 0.8),
        yaw: float = 0.0,
        name: str = "cinderblock",
    ) -> None:
        pos = _finite(position, "position")
        if pos.shape not in ((2,), (3,)):
            raise ConfigError(f"position must be (x, y) or (x, y, z) [m]; got shape {pos.shape}")
        lift = float(pos[2]) if pos.size == 3 else 0.0
        if lift < 0.0:
            raise ConfigError(f"position z (height of the block above its support) must be >= 0; got {lift}")
        self.position = pos[:2].copy()
        self.lift = lift
        self.size = _finite(size, "size")
        if self.size.shape != (3,) or np.any(self.size <= 0.0):
            raise ConfigError(f"size must be three positive edge lengths [m]; got {np.asarray(size).tolist()}")
        self.mass = _positive(mass, "mass")
        self.padding = float(padding)
        if not math.isfinite(self.padding) or self.padding < 0.0:
            raise ConfigError(f"padding must be a non-negative thickness [m]; got {padding!r}")
        self.table_height = float(table_height)
        if not math.isfinite(self.table_height) or self.table_height < 0.0:
            raise ConfigError(f"table_height must be >= 0 [m]; got {table_height!r}")
        self.friction = float(friction)
        if not math.isfinite(self.friction) or self.friction <= 0.0:
            raise ConfigError(f"friction must be a positive coefficient [-]; got {friction!r}")
        self.table_size = _finite(table_size, "table_size")
        if self.table_size.shape != (2,) or np.any(self.table_size <= 0.0):
            raise ConfigError(f"table_size must be two positive lengths [m]; got {np.asarray(table_size).tolist()}")
        self.yaw = float(yaw)
        self.name = str(name)
        self._adr_cache: tuple[mujoco.MjModel, int] | None = None

    # ------------------------------------------------------------------ Scene hooks
    def build(self, spec: mujoco.MjSpec, robot: RobotModel) -> None:
        if spec.body(self.name) is not None:
            raise ConfigError(f"a body named {self.name!r} already exists; give the Cinderblock another name=")
        add_floor(spec)
        sx, sy, sz = self.size
        if self.table_height > 0.0:
            tx, ty = self.table_size / 2.0
            h = self.table_height / 2.0
            spec.worldbody.add_geom(
                name=f"{self.name}_table",
                type=mujoco.mjtGeom.mjGEOM_BOX,
                size=[tx, ty, h],
                pos=[self.position[0], self.position[1], h],
                contype=CONTACT_WORLD | CONTACT_ARM,
                conaffinity=CONTACT_WORLD,
                solref=list(HARD_SOLREF),
                friction=[self.friction, *BLOCK_FRICTION[1:]],
                rgba=[0.55, 0.4, 0.25, 1.0],
            )
        z = self.table_height + self.lift + sz / 2.0
        half = self.yaw / 2.0
        body = spec.worldbody.add_body(
            name=self.name,
            pos=[self.position[0], self.position[1], z],
            quat=[math.cos(half), 0.0, 0.0, math.sin(half)],
        )
        body.add_freejoint(name=f"{self.name}_free")
        body.explicitinertial = True
        body.mass = self.mass
        body.ipos = [0.0, 0.0, 0.0]
        body.inertia = [
            self.mass / 12.0 * (sy * sy + sz * sz),
            self.mass / 12.0 * (sx * sx + sz * sz),
            self.mass / 12.0 * (sx * sx + sy * sy),
        ]
        body.add_geom(
            name=f"{self.name}_core",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[sx / 2.0, sy / 2.0, sz / 2.0],
            contype=CONTACT_WORLD,
            conaffinity=CONTACT_WORLD,
            solref=list(HARD_SOLREF),
            friction=[self.friction, *BLOCK_FRICTION[1:]],
            mass=self.mass,
            rgba=[0.5, 0.5, 0.5, 1.0],
        )
        if self.padding > 0.0:
            p = self.padding
            body.add_geom(
                name=f"{self.name}_padding",
                type=mujoco.mjtGeom.mjGEOM_BOX,
                size=[sx / 2.0 + p, sy / 2.0 + p, sz / 2.0 + p / 2.0],
                pos=[0.0, 0.0, p / 2.0],
                contype=CONTACT_ARM,
                conaffinity=0,
                solref=list(PADDING_SOLREF),
                solimp=list(PADDING_SOLIMP),
                mass=0.0,
                rgba=[0.95, 0.95, 0.9, 0.4],
            )

    def observe(self, plant: Plant) -> dict[str, np.ndarray]:
        adr = self._qpos_adr(plant)
        qpos = plant.data.qpos
        return {f"{self.name}_pos": qpos[adr : adr + 3].copy(), f"{self.name}_quat": qpos[adr + 3 : adr + 7].copy()}

    def describe(self) -> dict[str, object]:
        return {
            "type": "Cinderblock",
            "name": self.name,
            "position": [*self.position.tolist(), self.lift],
            "size": self.size.tolist(),
            "mass": self.mass,
            "padding": self.padding,
            "table_height": self.table_height,
            "friction": self.friction,
            "yaw": self.yaw,
        }

    # ------------------------------------------------------------------ queries
    def _qpos_adr(self, plant: Plant) -> int:
        m = plant.model
        if self._adr_cache is not None and self._adr_cache[0] is m:
            return self._adr_cache[1]
        jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"{self.name}_free")
        if jid < 0:
            raise ConfigError(f"this plant has no cinderblock named {self.name!r}")
        self._adr_cache = (m, int(m.jnt_qposadr[jid]))
        return self._adr_cache[1]

    def pose(self, plant: Plant) -> tuple[np.ndarray, np.ndarray]:
        """(position (3,), quaternion (w, x, y, z)) of the block's centre now."""
        adr = self._qpos_adr(plant)
        q = plant.data.qpos
        return q[adr : adr + 3].copy(), q[adr + 3 : adr + 7].copy()

    def displacement(self, plant: Plant) -> np.ndarray:
        """Change of the block's centre position since the plant's reset (3,) [m] (world frame)."""
        adr = self._qpos_adr(plant)
        return np.array(plant.data.qpos[adr : adr + 3] - plant.model.qpos0[adr : adr + 3])

    def tilt(self, plant: Plant) -> float:
        """Angle between the block's up axis and the world vertical [rad]."""
        _, quat = self.pose(plant)
        w, x, y, _z = quat / np.linalg.norm(quat)
        up_z = 1.0 - 2.0 * (x * x + y * y)  # R[2, 2]
        return float(math.acos(max(-1.0, min(1.0, up_z))))

    def tipped(self, plant: Plant) -> bool:
        """True if the block's up axis is tilted more than 45 degrees (it fell over)."""
        return self.tilt(plant) > math.pi / 4.0


def _finite(value: npt.ArrayLike, name: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{name} must be numeric; got {value!r}") from e
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} must be finite; got {arr.tolist()}")
    return arr


def _positive(value: float, name: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{name} must be a positive number; got {value!r}") from e
    if not math.isfinite(x) or x <= 0.0:
        raise ConfigError(f"{name} must be a positive number; got {value!r}")
    return x
