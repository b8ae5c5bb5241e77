"""Link collision geometry for the controller: sampled surface points with outward normals per joint.

Collision isolation and identification (``reflexarm.control.collision.isolate``/``identify``) score
candidate contact points on the surface of each link. This module gives them: for each joint i (0-based),
the surface of the link(s) it moves -- every body rigidly attached after joint i up to the next joint,
fixed child bodies included (Atlas's ``l_tool`` belongs to ``l_arm_wry2``) -- as points spaced about
``spacing`` apart with outward unit normals, expressed in the Pinocchio joint frame of joint i.

How: the robot file is compiled by MuJoCo exactly as the plant does it (URDF rewritten by
``robots/_urdf.py``, MJCF through ``robots/_mjcf.py``, the joints off a cut chain frozen by
``robots/_cut.py``); MuJoCo and Pinocchio are put at the same configuration, and each geom's world pose is
expressed in the matching Pinocchio joint frame. Only geoms that take part in contacts count
(``contype`` or ``conaffinity`` nonzero). Primitives (sphere, capsule, cylinder, box, ellipsoid) are sampled
on rings and grids; a mesh by the faces of its convex hull (what MuJoCo's collision uses), or by its
bounding box with a :class:`~reflexarm.robots.RobotFileWarning` when no hull can be built. Points of one
geom that lie inside another geom of the same link are dropped (they cannot be touched). A link without
collision geometry has zero points (:attr:`LinkSurface.has_geometry` is False).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

from reflexarm.errors import ConfigError, ModelError
from reflexarm.robots._cut import freeze_joints
from reflexarm.robots._mjcf import load_mjcf_spec
from reflexarm.robots._notes import warn_note
from reflexarm.robots._urdf import mujoco_urdf_spec, read_urdf
from reflexarm.robots.robot_model import RobotModel

__all__ = ["CollisionGeometry", "LinkSurface", "compile_collision_model", "link_collision_geometry"]

#: Points closer than this inside another geom of the same link are dropped [m].
INSIDE_MARGIN = 1e-6


@dataclass(frozen=True)
class LinkSurface:
    """The sampled collision surface of the link moved by one joint.

    Attributes:
        joint: 0-based joint index (Pinocchio joint ``joint + 1``).
        joint_name: the joint's name.
        link_name: the body the joint moves (MuJoCo body name), or the joint name if MuJoCo has none.
        bodies: every body rigidly carried by the joint (fixed children included).
        geoms: names of the contact geoms sampled (MuJoCo names, ``"BODY#id"`` for unnamed ones).
        points: (m, 3) surface points in the Pinocchio joint frame [m].
        normals: (m, 3) outward unit normals in the joint frame.
        geom_index: (m,) index into ``geoms`` of each point.
        geom_points: (m, 3) the same points in their geom's own frame [m].
    """

    joint: int
    joint_name: str
    link_name: str
    bodies: tuple[str, ...]
    geoms: tuple[str, ...]
    points: np.ndarray
    normals: np.ndarray
    geom_index: np.ndarray
    geom_points: np.ndarray

    @property
    def has_geometry(self) -> bool:
        """Whether the link has any collision surface point."""
        return self.points.shape[0] > 0

    @property
    def size(self) -> int:
        """Number of surface points."""
        return int(self.points.shape[0])


@dataclass(frozen=True)
class CollisionGeometry:
    """Collision surfaces of every link of an arm, in joint order (``links[i]`` is moved by joint i)."""

    robot_name: str
    spacing: float
    links: tuple[LinkSurface, ...]
    notes: tuple[str, ...] = ()

    @property
    def n(self) -> int:
        return len(self.links)

    def __getitem__(self, joint: int) -> LinkSurface:
        return self.links[joint]

    def point_counts(self) -> np.ndarray:
        """Number of surface points per link (n,)."""
        return np.array([s.size for s in self.links], dtype=int)

    def links_without_geometry(self) -> tuple[int, ...]:
        """0-based joints whose link has no collision geometry."""
        return tuple(s.joint for s in self.links if not s.has_geometry)


# ---------------------------------------------------------------------- MuJoCo side
def compile_collision_model(robot: RobotModel) -> tuple[mujoco.MjModel, np.ndarray]:
    """The robot file compiled by MuJoCo as the plant compiles it (same rewrite, same frozen joints).

    Returns the model and the qpos address of each arm joint (n,), in the robot's joint order.

    Raises:
        ModelError: no source file, unparsable file, an arm joint MuJoCo does not know.
    """
    if robot.source is None:
        raise ModelError(f"robot {robot.name!r} has no source file; collision geometry comes from the robot file")
    path = Path(robot.source)
    if not path.is_file():
        raise ModelError(f"robot file {str(path)!r} does not exist")
    if path.suffix.lower() == ".urdf":
        spec, _ = mujoco_urdf_spec(read_urdf(path))
    else:
        spec, _ = load_mjcf_spec(path)
    if robot.cut is not None:
        freeze_joints(spec, robot.cut.locked, path)
    try:
        mj = spec.compile()
    except Exception as e:
        raise ModelError(f"MuJoCo cannot compile robot file {str(path)!r}: {e}") from e
    adr = []
    for name in robot.joint_names:
        jid = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, name)
        if jid < 0:
            names = [mj.joint(j).name for j in range(mj.njnt)]
            raise ModelError(f"robot file {str(path)!r}: MuJoCo has no joint {name!r}; its joints are {names}")
        adr.append(int(mj.jnt_qposadr[jid]))
    return mj, np.array(adr, dtype=int)


def _owning_joint(mj: mujoco.MjModel, body: int, joint_of: dict[str, int]) -> int:
    """The arm joint (0-based) that moves ``body`` rigidly: the first joint found walking up; -1 for none."""
    b = body
    while b > 0:
        if mj.body_jntnum[b] > 0:
            return joint_of.get(mj.joint(int(mj.body_jntadr[b])).name, -1)
        b = int(mj.body_parentid[b])
    return -1


# ---------------------------------------------------------------------- sampling (geom frame)
def _count(length: float, spacing: float) -> int:
    return max(1, math.ceil(length / spacing - 1e-9))


def _cells(n: int, rng: np.random.Generator | None) -> np.ndarray:
    """Positions in [0, 1) of n cells: centres, or one uniform draw per cell with ``rng``."""
    u = np.full(n, 0.5) if rng is None else rng.uniform(0.0, 1.0, n)
    return (np.arange(n) + u) / n


def _sphere_cap(
    r: float, theta0: float, theta1: float, spacing: float, rng: np.random.Generator | None
) -> tuple[np.ndarray, np.ndarray]:
    """Rings of a sphere between polar angles theta0..theta1 (about +z); returns unit directions."""
    dirs = []
    for theta in theta0 + (theta1 - theta0) * _cells(_count(r * (theta1 - theta0), spacing), rng):
        phi = 2.0 * np.pi * _cells(_count(2.0 * np.pi * r * math.sin(theta), spacing), rng)
        s = math.sin(theta)
        dirs.append(np.stack([s * np.cos(phi), s * np.sin(phi), np.full(phi.size, math.cos(theta))], axis=1))
    u = np.concatenate(dirs)
    return u * r, u


def _tube(r: float, h: float, spacing: float, rng: np.random.Generator | None) -> tuple[np.ndarray, np.ndarray]:
    """Side of a cylinder of radius r, z in [-h, h]."""
    pts, nrm = [], []
    for z in -h + 2.0 * h * _cells(_count(2.0 * h, spacing), rng):
        phi = 2.0 * np.pi * _cells(_count(2.0 * np.pi * r, spacing), rng)
        n = np.stack([np.cos(phi), np.sin(phi), np.zeros(phi.size)], axis=1)
        pts.append(np.column_stack([r * n[:, :2], np.full(phi.size, z)]))
        nrm.append(n)
    return np.concatenate(pts), np.concatenate(nrm)


def _disk(
    r: float, z: float, sign: float, spacing: float, rng: np.random.Generator | None
) -> tuple[np.ndarray, np.ndarray]:
    pts = []
    for rho in r * _cells(_count(r, spacing), rng):
        phi = 2.0 * np.pi * _cells(_count(2.0 * np.pi * rho, spacing), rng)
        pts.append(np.stack([rho * np.cos(phi), rho * np.sin(phi), np.full(phi.size, z)], axis=1))
    p = np.concatenate(pts)
    return p, np.tile([0.0, 0.0, sign], (p.shape[0], 1))


def _box(half: np.ndarray, spacing: float, rng: np.random.Generator | None) -> tuple[np.ndarray, np.ndarray]:
    pts, nrm = [], []
    for axis in range(3):
        a, b = [k for k in range(3) if k != axis]
        ua = -half[a] + 2.0 * half[a] * _cells(_count(2.0 * half[a], spacing), rng)
        ub = -half[b] + 2.0 * half[b] * _cells(_count(2.0 * half[b], spacing), rng)
        A, B = np.meshgrid(ua, ub, indexing="ij")
        for sign in (-1.0, 1.0):
            p = np.zeros((A.size, 3))
            p[:, a], p[:, b], p[:, axis] = A.ravel(), B.ravel(), sign * half[axis]
            n = np.zeros_like(p)
            n[:, axis] = sign
            pts.append(p)
            nrm.append(n)
    return np.concatenate(pts), np.concatenate(nrm)


def _triangles(
    vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray, spacing: float, rng: np.random.Generator | None
) -> tuple[np.ndarray, np.ndarray]:
    """About area / spacing^2 points per face: an R2 low-discrepancy sequence folded into the triangle
    (deterministic), or uniform draws with ``rng``."""
    pts, nrm = [], []
    for face, n in zip(faces, normals, strict=True):
        a, b, c = vertices[face]
        area = 0.5 * float(np.linalg.norm(np.cross(b - a, c - a)))
        count = max(1, round(area / spacing**2))
        if rng is None:
            k = np.arange(1, count + 1)[:, None]
            st = np.mod(0.5 + k * np.array([1.0 / _PLASTIC, 1.0 / _PLASTIC**2]), 1.0)
        else:
            st = rng.uniform(size=(count, 2))
        flip = st.sum(axis=1) > 1.0
        st[flip] = 1.0 - st[flip]
        pts.append(a + st[:, :1] * (b - a) + st[:, 1:] * (c - a))
        nrm.append(np.tile(n, (count, 1)))
    return np.concatenate(pts), np.concatenate(nrm)


#: The plastic number, generator of the R2 sequence (Roberts 2018).
_PLASTIC = 1.324717957244746


def _mesh_hull(mj: mujoco.MjModel, geom: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Vertices, faces and outward face normals of a mesh geom's convex hull (mesh frame = geom frame)."""
    from scipy.spatial import ConvexHull, QhullError

    mesh = int(mj.geom_dataid[geom])
    start, count = int(mj.mesh_vertadr[mesh]), int(mj.mesh_vertnum[mesh])
    vertices = np.array(mj.mesh_vert[start : start + count], dtype=float)
    try:
        hull = ConvexHull(vertices)
    except (QhullError, ValueError):
        return None
    return vertices, np.asarray(hull.simplices), np.asarray(hull.equations[:, :3])


def _sample_geom(
    mj: mujoco.MjModel, geom: int, spacing: float, rng: np.random.Generator | None, notes: list[str]
) -> tuple[np.ndarray, np.ndarray, tuple[str, np.ndarray] | None]:
    """Points and normals in the geom frame, and the geom's shape for the inside test."""
    kind = int(mj.geom_type[geom])
    size = np.array(mj.geom_size[geom], dtype=float)
    gt = mujoco.mjtGeom
    if kind == gt.mjGEOM_SPHERE:
        p, n = _sphere_cap(size[0], 0.0, np.pi, spacing, rng)
        return p, n, ("sphere", size)
    if kind == gt.mjGEOM_CAPSULE:
        r, h = size[0], size[1]
        side = _tube(r, h, spacing, rng)
        top = _sphere_cap(r, 0.0, np.pi / 2, spacing, rng)
        bottom = _sphere_cap(r, np.pi / 2, np.pi, spacing, rng)
        p = np.concatenate([side[0], top[0] + [0.0, 0.0, h], bottom[0] - [0.0, 0.0, h]])
        return p, np.concatenate([side[1], top[1], bottom[1]]), ("capsule", size)
    if kind == gt.mjGEOM_CYLINDER:
        r, h = size[0], size[1]
        parts = [_tube(r, h, spacing, rng), _disk(r, h, 1.0, spacing, rng), _disk(r, -h, -1.0, spacing, rng)]
        return np.concatenate([a for a, _ in parts]), np.concatenate([b for _, b in parts]), ("cylinder", size)
    if kind == gt.mjGEOM_BOX:
        p, n = _box(size, spacing, rng)
        return p, n, ("box", size)
    if kind == gt.mjGEOM_ELLIPSOID:
        u, _ = _sphere_cap(1.0, 0.0, np.pi, spacing / float(size.max()), rng)
        n = u / size
        return u * size, n / np.linalg.norm(n, axis=1, keepdims=True), ("ellipsoid", size)
    if kind == gt.mjGEOM_MESH:
        hull = _mesh_hull(mj, geom)
        if hull is not None:
            vertices, faces, normals = hull
            p, n = _triangles(vertices, faces, normals, spacing, rng)
            return p, n, ("hull", np.column_stack([normals, -np.einsum("fk,fk->f", normals, vertices[faces[:, 0]])]))
        centre, half = np.array(mj.geom_aabb[geom][:3]), np.array(mj.geom_aabb[geom][3:])
        notes.append(
            f"collision geometry: mesh geom {_geom_name(mj, geom)!r} has no convex hull (flat or degenerate); "
            f"its bounding box (half sides {np.round(half, 4).tolist()} m) stands in for it"
        )
        p, n = _box(half, spacing, rng)
        return p + centre, n, ("box_at", np.concatenate([centre, half]))
    notes.append(
        f"collision geometry: geom {_geom_name(mj, geom)!r} of type {mujoco.mjtGeom(kind).name} is not sampled "
        "(only sphere, capsule, cylinder, box, ellipsoid and mesh)"
    )
    return np.zeros((0, 3)), np.zeros((0, 3)), None


def _inside(shape: tuple[str, np.ndarray], p: np.ndarray) -> np.ndarray:
    """Whether points (geom frame) lie strictly inside a shape, by more than INSIDE_MARGIN."""
    kind, s = shape
    eps = INSIDE_MARGIN
    if kind == "sphere":
        return np.linalg.norm(p, axis=1) < s[0] - eps
    if kind == "capsule":
        z = np.clip(p[:, 2], -s[1], s[1])
        return np.linalg.norm(p - np.column_stack([np.zeros((p.shape[0], 2)), z]), axis=1) < s[0] - eps
    if kind == "cylinder":
        return (np.linalg.norm(p[:, :2], axis=1) < s[0] - eps) & (np.abs(p[:, 2]) < s[1] - eps)
    if kind == "box":
        return np.all(np.abs(p) < s[:3] - eps, axis=1)
    if kind == "box_at":
        return np.all(np.abs(p - s[:3]) < s[3:] - eps, axis=1)
    if kind == "ellipsoid":
        return np.linalg.norm(p / s[:3], axis=1) < 1.0 - eps / float(s.max())
    # hull: every face plane n.p + d < -eps
    return np.all(p @ s[:, :3].T + s[:, 3] < -eps, axis=1)


def _geom_name(mj: mujoco.MjModel, geom: int) -> str:
    return mj.geom(geom).name or f"{mj.body(int(mj.geom_bodyid[geom])).name}#{geom}"


def _reference_q(robot: RobotModel) -> np.ndarray:
    lo, hi = robot.lower_limit, robot.upper_limit
    return np.clip(np.zeros(robot.n), np.where(np.isfinite(lo), lo, -np.pi), np.where(np.isfinite(hi), hi, np.pi))


def link_collision_geometry(robot: RobotModel, *, spacing: float = 0.01, seed: int | None = None) -> CollisionGeometry:
    """Sampled collision surfaces of every link of ``robot`` (see the module docstring).

    Args:
        robot: the arm (its :attr:`~RobotModel.source` file is read; a cut arm is cut the same way).
        spacing: approximate distance between neighbouring points [m], > 0.
        seed: ``None`` for the deterministic sampling (cell centres; the controller's candidate points);
            an integer draws one uniform point per cell instead (a random surface sample, e.g. true contact
            points of a study that differ from the candidates).

    Raises:
        ConfigError: spacing not a positive finite number.
        ModelError: the file cannot be compiled by MuJoCo, or MuJoCo lacks an arm joint.
    """
    if not (isinstance(spacing, (int, float)) and math.isfinite(spacing) and spacing > 0.0):
        raise ConfigError(f"spacing must be a positive number of metres; got {spacing!r}")
    rng = None if seed is None else np.random.default_rng(seed)
    mj, qadr = compile_collision_model(robot)
    q = _reference_q(robot)
    data = mujoco.MjData(mj)
    data.qpos[:] = mj.qpos0
    data.qpos[qadr] = q
    mujoco.mj_kinematics(mj, data)
    model = robot.pin_model
    pdata = model.createData()
    pin.forwardKinematics(model, pdata, q)
    joint_of = {name: i for i, name in enumerate(robot.joint_names)}
    notes: list[str] = []
    per_joint: list[list[int]] = [[] for _ in range(robot.n)]
    bodies: list[list[str]] = [[] for _ in range(robot.n)]
    for b in range(1, mj.nbody):
        j = _owning_joint(mj, b, joint_of)
        if j >= 0:
            bodies[j].append(mj.body(b).name)
    for g in range(mj.ngeom):
        if mj.geom_contype[g] == 0 and mj.geom_conaffinity[g] == 0:
            continue
        j = _owning_joint(mj, int(mj.geom_bodyid[g]), joint_of)
        if j >= 0:
            per_joint[j].append(g)
    links = []
    for j in range(robot.n):
        oMi_inv = pdata.oMi[j + 1].inverse()
        sampled = []
        for g in per_joint[j]:
            p, n, shape = _sample_geom(mj, g, spacing, rng, notes)
            T = oMi_inv * pin.SE3(np.array(data.geom_xmat[g]).reshape(3, 3), np.array(data.geom_xpos[g]))
            sampled.append((g, p, n, shape, np.asarray(T.rotation), np.asarray(T.translation)))
        kept = []
        for k, (_, p, n, _, R, t) in enumerate(sampled):
            keep = np.ones(p.shape[0], dtype=bool)
            in_joint = p @ R.T + t
            for m, (_, _, _, other, R2, t2) in enumerate(sampled):
                if m != k and other is not None and p.shape[0]:
                    keep &= ~_inside(other, (in_joint - t2) @ R2)
            kept.append((k, p[keep], in_joint[keep], n[keep] @ R.T))
        name = bodies[j][0] if bodies[j] else robot.joint_names[j]
        links.append(
            LinkSurface(
                joint=j,
                joint_name=robot.joint_names[j],
                link_name=name,
                bodies=tuple(bodies[j]),
                geoms=tuple(_geom_name(mj, s[0]) for s in sampled),
                points=_stack([c for _, _, c, _ in kept]),
                normals=_stack([d for _, _, _, d in kept]),
                geom_index=np.concatenate(
                    [np.full(c.shape[0], k, dtype=int) for k, _, c, _ in kept] or [np.zeros(0, int)]
                ),
                geom_points=_stack([b for _, b, _, _ in kept]),
            )
        )
    for note in notes:
        warn_note(note)
    return CollisionGeometry(robot.name, float(spacing), tuple(links), tuple(notes))


def _stack(parts: list[np.ndarray]) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros((0, 3))
