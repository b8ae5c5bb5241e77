"""The cinderblock placed on the end effector's path of any arm, from the arm's own kinematics and collision
geometry (the end-effector collision of Sec. III-A on arms other than Atlas; see
:mod:`reflexarm.experiments.any_arm` for the motion)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from reflexarm.errors import ConfigError
from reflexarm.experiments.any_arm import geometry_plant, horizontal, up_direction
from reflexarm.robots import RobotModel
from reflexarm.sim import JointTrajectory

__all__ = ["CLEARANCE_M", "OUTSIDE_SHARE", "SPHERES_PER_GEOM", "place_cinderblock"]

#: Vertical clearance kept between the block's top and the links before the wrist (they pass above
#: it), and between the table and every link [m].
CLEARANCE_M = 0.02
#: Pieces (spheres or slabs) per collision geom in the swept check of :func:`place_cinderblock` [-].
SPHERES_PER_GEOM = 7
#: Share of the block's length that lies beyond the end effector's path, away from the arm's base [-].
OUTSIDE_SHARE = 0.75


def _geom_pieces(m: Any, geoms: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each geom cut along the longest axis of its local bounding box into :data:`SPHERES_PER_GEOM` pieces:
    spheres for a sphere or capsule (a swept sphere: exact), slabs of the oriented bounding box otherwise
    (boxes exactly; meshes and cylinders by their box, never lower than they reach). Returns the pieces'
    owner (index into ``geoms``), centres and half extents in the geom frame, and which are spheres."""
    import mujoco

    swept = (int(mujoco.mjtGeom.mjGEOM_SPHERE), int(mujoco.mjtGeom.mjGEOM_CAPSULE))
    owner, centres, halves, spheres = [], [], [], []
    for i, g in enumerate(geoms):
        c, h = np.array(m.geom_aabb[g, :3]), np.array(m.geom_aabb[g, 3:])
        a = int(np.argmax(h))
        sphere = int(m.geom_type[g]) in swept
        r = float(np.delete(h, a).max())
        reach = max(0.0, float(h[a]) - r) if sphere else float(h[a]) * (1.0 - 1.0 / SPHERES_PER_GEOM)
        piece = np.full(3, r) if sphere else np.where(np.arange(3) == a, h[a] / SPHERES_PER_GEOM, h)
        for x in np.linspace(-reach, reach, SPHERES_PER_GEOM):
            owner.append(i)
            centres.append(c + x * np.eye(3)[a])
            halves.append(piece)
            spheres.append(sphere)
    return np.array(owner), np.array(centres), np.array(halves), np.array(spheres)


def _arm_geoms_along(robot: RobotModel, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The arm's collision geoms at each posture of ``qs`` in pieces (see :func:`_geom_pieces`): (centres
    (k, s, 3), half extents along the world axes (k, s, 3), masks (s,): on a body beyond the wrist sensor;
    on the wrist, i.e. the last two links or beyond the sensor). A link is a long body: its geom's
    world-aligned box would overstate how low it reaches, spheres around its axis understate it for a box
    or mesh (by up to 4 cm on the arms tested, more than :data:`CLEARANCE_M`)."""
    import mujoco

    plant = geometry_plant(robot)
    m, d = plant.model, plant.data
    arm = set(int(b) for b in plant._arm_bodies)
    distal = set(int(b) for b in plant._load_bodies)
    geoms = [g for g in range(m.ngeom) if int(m.geom_bodyid[g]) in arm and (m.geom_contype[g] or m.geom_conaffinity[g])]
    own, pts, local_h, spheres = _geom_pieces(m, geoms)
    centres = np.empty((len(qs), len(pts), 3))
    halves = np.empty_like(centres)
    for k, q in enumerate(qs):
        d.qpos[plant._qadr_arr] = q
        mujoco.mj_kinematics(m, d)
        R = np.array(d.geom_xmat[geoms]).reshape(-1, 3, 3)[own]
        centres[k] = d.geom_xpos[geoms][own] + np.einsum("gij,gj->gi", R, pts)
        boxed = np.einsum("gij,gj->gi", np.abs(R), local_h)  # a slab's world-aligned half extents
        halves[k] = np.where(spheres[:, None], local_h, boxed)
    wrist_root = int(m.jnt_bodyid[m.joint(robot.joint_names[max(0, robot.n - 2)]).id])
    bodies = [int(m.geom_bodyid[geoms[i]]) for i in own]
    beyond = np.array([b in distal for b in bodies], dtype=bool)
    wrist = np.array([_descends(m, b, wrist_root) for b in bodies], dtype=bool) | beyond
    return centres, halves, beyond, wrist


def _descends(m: Any, body: int, root: int) -> bool:
    while body > 0:
        if body == root:
            return True
        body = int(m.body_parentid[body])
    return root == 0


def place_cinderblock(
    robot: RobotModel,
    trajectory: JointTrajectory,
    *,
    depth: float = 0.12,
    size: tuple[float, float, float] = (0.39, 0.19, 0.19),
    padding: float = 0.03,
    samples: int = 400,
) -> dict[str, Any]:
    """Keyword arguments of :class:`~reflexarm.sim.Cinderblock` that put the block on the end effector's path.

    The path is the forward kinematics of ``trajectory`` (the end-effector frame). The block's padded
    face is put across the path at the point from which the rest of the path is ``depth`` long [m] (so
    the unobstructed end effector would run ``depth`` into the block), facing the path's horizontal
    direction there with its long side, :data:`OUTSIDE_SHARE` of which lies beyond the path, away from
    the base.

    Heights come from the arm's collision geometry swept along the path, as the plant has it (each geom
    in :data:`SPHERES_PER_GEOM` spheres or slabs of its oriented box, never higher than it reaches): the
    end effector meets the face at half the block's height unless the links before the wrist sensor pass
    lower over the block; then the block's top stays
    :data:`CLEARANCE_M` below them, so that the bodies beyond the sensor meet the block first, as the
    hand does on Atlas (if that leaves no room, the last two links may touch it too). The table (the
    block's support, a square of side ``size[0] + 0.1`` m) stays :data:`CLEARANCE_M` below every link
    over it; below 5 cm the block stands on the floor and is as tall as the top requires (its core's
    height then differs from ``size``). The block's core is ``size`` otherwise.

    Raises:
        ConfigError: a non-positive ``depth``; the path is shorter than ``depth`` or does not move
            horizontally; the arm passes above the block.
    """
    if not (math.isfinite(depth) and depth > 0.0):
        raise ConfigError(f"depth must be a positive distance [m]; got {depth!r}")
    t, qs, P, i = _path_point(robot, trajectory, depth, samples)
    up = up_direction(robot)
    u = horizontal(P[i + 1] - P[i - 1], up)
    nu = float(np.linalg.norm(u))
    if nu < 1e-9:
        raise ConfigError("the end effector's path does not move horizontally where the block would stand")
    u /= nu
    sx, sy, sz = size
    # the long side (x of the block) faces the path: the block's y axis is the path's direction; the
    # block reaches OUTSIDE_SHARE of its length away from the base beyond the path point (the links
    # nearer the base do not stand over it)
    w = np.cross(up, u)
    outward = 1.0 if float(w @ horizontal(P[i], up)) >= 0.0 else -1.0
    centre = P[i] + u * (padding + sy / 2.0) + w * outward * (OUTSIDE_SHARE - 0.5) * sx
    # the table: a square of side sx + 0.1 m, world-aligned, centred under the block
    table_half = (sx + 0.1) / 2.0
    height = float(P[i] @ up)
    table, sz = _block_heights(robot, qs, centre, (u, w, up), height, size, padding, table_half)
    yaw = math.atan2(u[1], u[0]) - math.pi / 2.0
    return {
        "position": (float(centre[0]), float(centre[1])),
        "size": (sx, sy, sz),
        "padding": padding,
        "table_height": table,
        "table_size": (2.0 * table_half, 2.0 * table_half),
        "yaw": yaw,
        "contact_time_s": float(t[i]),
        "depth": depth,
        "ee_height_m": height,
    }


def _path_point(
    robot: RobotModel, trajectory: JointTrajectory, depth: float, samples: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The end effector's path at ``samples`` times (times, postures, positions) and the index of the point
    from which the rest of the path is ``depth`` long (ConfigError if the path is not longer)."""
    t = np.linspace(0.0, trajectory.duration, samples)
    qs = np.array([trajectory.sample(float(ti)).q_d for ti in t])
    P = np.array([robot.compute_frame_pose(q)[1] for q in qs])
    seg = np.linalg.norm(np.diff(P, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= depth:
        raise ConfigError(f"the end effector's path is {s[-1]:.3f} m long; the block needs more than depth {depth} m")
    i = int(np.searchsorted(s, s[-1] - depth))
    return t, qs, P, min(max(i, 1), samples - 2)


def _block_heights(
    robot: RobotModel,
    qs: np.ndarray,
    centre: np.ndarray,
    axes: tuple[np.ndarray, np.ndarray, np.ndarray],
    height: float,
    size: tuple[float, float, float],
    padding: float,
    table_half: float,
) -> tuple[float, float]:
    """The table's height and the block core's height [m] under the arm's geoms swept along ``qs`` (``axes``:
    the path's horizontal direction u, the block's long side w, up; ``height``: the end effector's at the face);
    ConfigError if the arm passes above the block."""
    u, w, up = axes
    sx, sy, sz = size
    # the arm's geoms (bounding boxes) over the block's padded footprint along the path
    centres, halves, beyond, wrist = _arm_geoms_along(robot, qs)
    rel = centres - centre
    over = (np.abs(rel @ u) < sy / 2 + padding + np.abs(halves) @ np.abs(u)) & (
        np.abs(rel @ w) < sx / 2 + padding + np.abs(halves) @ np.abs(w)
    )
    bottoms = (centres @ up) - np.abs(halves) @ np.abs(up)
    over_table = (np.abs(rel[..., 0]) < table_half + halves[..., 0]) & (
        np.abs(rel[..., 1]) < table_half + halves[..., 1]
    )
    lowest = float(bottoms[over_table].min()) if over_table.any() else math.inf
    # first the bodies beyond the wrist sensor must meet the block first (as Atlas' hand); if the links
    # before them hang too low for that, the last two links may as well
    for distal in (beyond, wrist):
        prox = over & ~distal[None, :]
        lowest_proximal = float(bottoms[prox].min()) if prox.any() else math.inf
        top = min(height + sz / 2.0 + padding, lowest_proximal - CLEARANCE_M)
        bottom = min(top - padding - sz, lowest - CLEARANCE_M)
        table = bottom if bottom >= 0.05 else 0.0
        core = top - padding if table == 0.0 else sz
        block_top = table + core + padding
        lowest_distal = float(bottoms[over & distal[None, :]].min(initial=math.inf))
        if core >= 0.05 and block_top > lowest_distal:
            break
    else:
        raise ConfigError(
            f"the arm passes above the block (its top at {block_top:.3f} m, the wrist no lower than "
            f"{lowest_distal:.3f} m); choose another start posture"
        )
    return table, core
