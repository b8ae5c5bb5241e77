"""Reading URDF files for both models (private): dangling joints, ``package://`` meshes, MuJoCo's copy.

- A joint whose child link is not in the file (e.g. ``neck_ry -> head`` of drcsim's ``atlas_v5.urdf``,
  whose head comes from another xacro) is dropped with a note; Pinocchio and MuJoCo then read the same
  tree. A joint whose *parent* link is missing is refused (its child would be a second root).
- Mesh URIs: ``package://PKG/rest`` is looked up in the folders of ``ROS_PACKAGE_PATH``, then in the robot
  file's folder and its parents (``DIR/PKG/rest``, or ``DIR/rest`` when ``DIR`` is named ``PKG``);
  ``file://`` and relative paths are taken from the file's folder. MuJoCo gets absolute paths; meshes
  that cannot be found are dropped with their geoms and a note (meshes only shape contact and visuals;
  the dynamics come from ``<inertial>``). Pinocchio does not read meshes for the dynamics at all.
- Mesh formats: MuJoCo decodes STL, OBJ and MSH. COLLADA (``.dae``, what most ROS description packages
  ship) is read by ``_collada.py`` and given to MuJoCo as the vertices of its convex hull, which is what
  MuJoCo collides with for any mesh; other formats and unreadable files are dropped with a note, as
  missing ones are. Never fatal.
- A link with a mass and no collision geometry (none in the file, e.g. a hand that comes from another
  file, or its meshes dropped) gets, in the plant only, a box with its mass and inertia (no larger than
  the link's reach; so scenes still touch the arm), with a note.
"""

from __future__ import annotations

import copy
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from reflexarm.errors import ModelError
from reflexarm.robots._collada import collada_vertices

__all__ = ["MujocoUrdf", "UrdfFile", "mujoco_urdf", "mujoco_urdf_spec", "read_urdf", "resolve_mesh_uri"]

#: How many folders above the robot file are searched for a ``package://`` package.
PACKAGE_SEARCH_DEPTH = 4
#: Half sides [m] of a stand-in contact box: at least MIN_HALF_SIDE (a thin or point-like inertia still
#: touches), at most the link's reach (farthest of its origin and its children's origins from the COM)
#: plus REACH_MARGIN (published inertias are not always those of a compact solid: the Menagerie Panda's
#: link1 inertia is that of a 1.3 m box).
MIN_HALF_SIDE = 0.01
REACH_MARGIN = 0.03


@dataclass
class UrdfFile:
    """A parsed URDF with its dangling joints removed, and notes saying what was changed."""

    path: Path
    root: ET.Element
    notes: list[str] = field(default_factory=list)

    @property
    def text(self) -> str:
        return ET.tostring(self.root, encoding="unicode")


def read_urdf(path: Path) -> UrdfFile:
    """Parse a URDF file and drop the joints whose child link is missing (with a note).

    Raises:
        ModelError: unreadable or malformed file, root element not ``<robot>``, a joint without a parent
            link in the file.
    """
    try:
        root = ET.fromstring(path.read_text())
    except (OSError, UnicodeDecodeError, ET.ParseError) as e:
        raise ModelError(f"cannot parse robot file {str(path)!r}: {e}") from e
    if root.tag != "robot":
        raise ModelError(f"malformed URDF file {str(path)!r}: root element is <{root.tag}>, expected <robot>")
    links = {link.get("name") for link in root.findall("link")}
    notes = []
    for joint in root.findall("joint"):
        parent, child = joint.find("parent"), joint.find("child")
        parent_link = parent.get("link") if parent is not None else None
        child_link = child.get("link") if child is not None else None
        if parent_link not in links:
            raise ModelError(
                f"robot file {str(path)!r}: joint {joint.get('name')!r} hangs off link {parent_link!r}, which the "
                "file does not define"
            )
        if child_link not in links:
            root.remove(joint)
            notes.append(
                f"robot file {str(path)!r}: joint {joint.get('name')!r} leads to link {child_link!r}, which the file "
                "does not define (it may come from another file, e.g. a xacro include); the joint is dropped"
            )
    return UrdfFile(path, root, notes)


def _package_dirs(path: Path) -> list[tuple[Path, str]]:
    """Folders searched for ``package://`` packages, each with where it comes from."""
    out: list[tuple[Path, str]] = []
    for entry in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep):
        if entry:
            out.append((Path(entry), "ROS_PACKAGE_PATH"))
    folder = path.resolve().parent
    for k, d in enumerate([folder, *folder.parents][: PACKAGE_SEARCH_DEPTH + 1]):
        out.append((d, "the robot file's folder" if k == 0 else f"{k} folder(s) above the robot file"))
    return out


def resolve_mesh_uri(uri: str, path: Path) -> tuple[Path | None, str]:
    """The file a mesh URI of the URDF ``path`` names (``None`` if not found) and how it was found."""
    if uri.startswith("package://"):
        package, _, rest = uri[len("package://") :].partition("/")
        for d, origin in _package_dirs(path):
            for package_dir in (d / package, d if d.name == package else None):
                if package_dir is not None and (package_dir / rest).is_file():
                    return package_dir / rest, f"package://{package} -> {package_dir} ({origin})"
        return None, f"package://{package} not found in ROS_PACKAGE_PATH or near the robot file"
    f = Path(uri[len("file://") :]) if uri.startswith("file://") else Path(uri)
    if not f.is_absolute():
        f = path.resolve().parent / f
    return (f, "") if f.is_file() else (None, f"{f} does not exist")


@dataclass
class MujocoUrdf:
    """The URDF text MuJoCo compiles, the vertices [m] of the collision meshes it cannot decode (by the
    absolute file name the text gives them) and notes on the meshes and stand-in boxes."""

    text: str
    vertices: dict[str, np.ndarray]
    notes: list[str]


def mujoco_urdf(urdf: UrdfFile) -> MujocoUrdf:
    """The URDF as MuJoCo gets it (see :func:`mujoco_urdf_spec`), with notes on the meshes.

    Found meshes get absolute file names; visuals are dropped, and so are collision geoms whose mesh
    cannot be found or read (a format MuJoCo does not decode and reflexarm does not convert, a broken
    ``.dae``); ``.dae`` meshes are read as their vertices (MuJoCo collides with their convex hull, as with
    an STL). Each link with a mass and no collision geometry left (none in the file, or its meshes
    dropped) gets a stand-in box. The file's own ``<mujoco>`` block is replaced by one that discards
    visuals, keeps fixed-joint links as bodies (so tool and sensor links stay addressable) and never
    derives inertia from geometry (as Pinocchio does not).
    """
    root = copy.deepcopy(urdf.root)
    found: dict[str, str] = {}
    missing: dict[str, str] = {}
    unreadable: dict[str, str] = {}
    vertices: dict[str, np.ndarray] = {}
    dropped = 0
    for link in root.iter("link"):
        for element in link.findall("visual"):
            link.remove(element)
        for element in link.findall("collision"):
            mesh = element.find("geometry/mesh")
            if mesh is None:
                continue
            uri = mesh.get("filename", "")
            f, how = resolve_mesh_uri(uri, urdf.path)
            problem = how if f is None else _mesh_problem(f.resolve(), vertices)
            if problem:
                (missing if f is None else unreadable)[uri] = problem
                link.remove(element)
                dropped += f is None
                continue
            mesh.set("filename", str(f.resolve()))  # type: ignore[union-attr]  # f is None has a problem
            if how:
                found[how.split(" -> ")[0]] = how
    bare = [link for link in root.iter("link") if link.find("collision") is None]
    boxed = _inertia_boxes(root, bare)
    for old in root.findall("mujoco"):
        root.remove(old)
    block = ET.SubElement(root, "mujoco")
    ET.SubElement(
        block, "compiler", discardvisual="true", fusestatic="false", inertiafromgeom="false", strippath="false"
    )
    where = f"robot file {str(urdf.path)!r}"
    notes = _mesh_notes(where, found, (missing, dropped), unreadable, vertices, boxed)
    return MujocoUrdf(ET.tostring(root, encoding="unicode"), vertices, notes)


def mujoco_urdf_spec(urdf: UrdfFile) -> tuple[mujoco.MjSpec, list[str]]:
    """The MjSpec of a URDF as the plant compiles it (see :func:`mujoco_urdf`): ``.dae`` meshes given to
    MuJoCo as their vertices, whose convex hull MuJoCo collides with, as it does with an STL's.

    Raises:
        ModelError: MuJoCo cannot parse the rewritten file (its message names the file).
    """
    out = mujoco_urdf(urdf)
    try:
        spec = mujoco.MjSpec.from_string(out.text)
    except Exception as e:  # MuJoCo raises ValueError with the parser's text
        raise ModelError(f"MuJoCo cannot parse robot file {str(urdf.path)!r}: {e}") from e
    for mesh in spec.meshes:
        points = out.vertices.get(mesh.file)
        if points is not None:
            mesh.file = ""
            mesh.uservert = points.ravel()
    return spec, out.notes


#: Mesh files MuJoCo decodes itself (it matches these suffixes exactly: ``.Stl`` is refused).
MUJOCO_MESH_SUFFIXES = (".stl", ".STL", ".obj", ".OBJ", ".msh", ".MSH")


def _mesh_problem(f: Path, vertices: dict[str, np.ndarray]) -> str:
    """Why MuJoCo cannot use the mesh file ``f`` ("" if it can); a ``.dae`` is read into ``vertices``."""
    if f.suffix in MUJOCO_MESH_SUFFIXES:
        return ""
    if f.suffix.lower() == ".dae":
        try:
            vertices[str(f)] = _hull_points(collada_vertices(f))
        except ModelError as e:
            return str(e)
        return ""
    return f"{f.name}: MuJoCo reads STL, OBJ and MSH meshes, and reflexarm converts COLLADA (.dae); not {f.suffix!r}"


def _hull_points(points: np.ndarray) -> np.ndarray:
    """The vertices of the convex hull of ``points`` (all of them when qhull cannot build one: MuJoCo
    then says why)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        return np.ascontiguousarray(points[ConvexHull(points).vertices])
    except (QhullError, ValueError):
        return np.ascontiguousarray(points)


def _mesh_notes(
    where: str,
    found: dict[str, str],
    missing_dropped: tuple[dict[str, str], int],
    unreadable: dict[str, str],
    vertices: dict[str, np.ndarray],
    boxed: list[str],
) -> list[str]:
    notes = [f"{where}: mesh package resolved: {how}" for how in found.values()]
    missing, dropped = missing_dropped
    if missing:
        notes.append(
            f"{where}: {len(missing)} mesh file(s) not found ({_shown(sorted(missing))}); the {dropped} collision "
            "geom(s) using them were dropped (meshes only shape contact; masses and inertias come from the <inertial> "
            "elements)"
        )
    if unreadable:
        notes.append(
            f"{where}: {len(unreadable)} mesh file(s) cannot be read ({_shown(list(unreadable.values()))}); the "
            "collision geom(s) using them were dropped"
        )
    if vertices:
        names = sorted(Path(f).name for f in vertices)
        notes.append(
            f"{where}: {len(vertices)} COLLADA (.dae) collision mesh(es) ({_shown(names)}) given to MuJoCo as "
            "their vertices (it collides with their convex hull, as with an STL)"
        )
    if boxed:
        notes.append(
            f"{where}: in the plant, {len(boxed)} link(s) without collision geometry (in the file, or after the "
            f"meshes above) ({_shown(boxed, 4)}) touch the scene through a box with the link's mass and inertia "
            "(centred at its centre of mass, along its principal axes, no larger than the link's reach)"
        )
    return notes


def _shown(items: list[str], count: int = 3) -> str:
    return ", ".join(items[:count]) + (f" and {len(items) - count} more" if len(items) > count else "")


def _inertia_boxes(root: ET.Element, links: list[ET.Element]) -> list[str]:
    """Give each link a collision box of uniform density with its mass and rotational inertia; return the
    names of the links that got one (links without a positive mass or inertia get none)."""
    named = []
    for link in links:
        if link.find("collision") is not None:
            continue
        box = inertia_box(link, _child_origins(root, str(link.get("name"))))
        if box is None:
            continue
        xyz, rpy, size = box
        collision = ET.SubElement(link, "collision", name=f"{link.get('name')}_inertia_box")
        ET.SubElement(collision, "origin", xyz=" ".join(f"{v:.9g}" for v in xyz), rpy=" ".join(f"{v:.9g}" for v in rpy))
        ET.SubElement(ET.SubElement(collision, "geometry"), "box", size=" ".join(f"{v:.9g}" for v in size))
        named.append(str(link.get("name")))
    return named


def _child_origins(root: ET.Element, link: str) -> list[np.ndarray]:
    out = []
    for joint in root.findall("joint"):
        parent, origin = joint.find("parent"), joint.find("origin")
        if parent is not None and parent.get("link") == link:
            try:
                out.append(
                    np.array(
                        [float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()]
                    )
                )
            except ValueError:
                continue
    return out


def stand_in_half_sides(mass: float, principal: np.ndarray, reach: float) -> np.ndarray:
    """Half sides of the box of uniform density with principal inertias ``principal`` and ``mass``, each
    kept within [MIN_HALF_SIDE, reach + REACH_MARGIN].

    For a box of sides a, b, c and mass m, I_a = m (b^2 + c^2) / 12 etc., so a^2 = 6 (I_b + I_c - I_a) / m.
    """
    squares = np.maximum(6.0 * (principal.sum() - 2.0 * principal) / mass, 0.0)
    return np.clip(0.5 * np.sqrt(squares), MIN_HALF_SIDE, max(MIN_HALF_SIDE, reach + REACH_MARGIN))


def inertia_box(
    link: ET.Element, child_origins: list[np.ndarray] | tuple[()] = ()
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(origin xyz, origin rpy, full side lengths) of a URDF link's stand-in contact box: the box with its
    ``<inertial>`` (see :func:`stand_in_half_sides`), along the principal axes, at the centre of mass.

    ``child_origins``: the origins of the joints to its children (link frame), which bound its size.
    ``None`` without a positive mass.
    """
    inertial = link.find("inertial")
    mass = inertial.find("mass") if inertial is not None else None
    tensor = inertial.find("inertia") if inertial is not None else None
    if inertial is None or mass is None or tensor is None:
        return None
    try:
        m = float(mass.get("value", "0"))
        i = {k: float(tensor.get(k, "0")) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
        origin = inertial.find("origin")
        xyz = np.array([float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()])
        rpy = np.array([float(v) for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()])
    except ValueError:
        return None
    if not m > 0.0 or xyz.shape != (3,) or rpy.shape != (3,):
        return None
    inertia = np.array([[i["ixx"], i["ixy"], i["ixz"]], [i["ixy"], i["iyy"], i["iyz"]], [i["ixz"], i["iyz"], i["izz"]]])
    principal, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1.0
    reach = max(float(np.linalg.norm(xyz - c)) for c in [np.zeros(3), *child_origins])
    frame = _rpy_matrix(rpy) @ axes  # principal axes in the link frame
    return xyz, _matrix_rpy(frame), 2.0 * stand_in_half_sides(m, principal, reach)


def _rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx  # URDF: fixed-axis roll, then pitch, then yaw


def _matrix_rpy(R: np.ndarray) -> np.ndarray:
    pitch = np.arcsin(np.clip(-R[2, 0], -1.0, 1.0))
    if abs(R[2, 0]) < 1.0 - 1e-12:
        return np.array([np.arctan2(R[2, 1], R[2, 2]), pitch, np.arctan2(R[1, 0], R[0, 0])])
    return np.array([0.0, pitch, np.arctan2(-R[0, 1], R[1, 1])])  # gimbal lock: roll folded into yaw
