"""Reading URDF files for both models (private): dangling joints, ``package://`` meshes, MuJoCo's copy.

- A joint whose child link is not in the file (e.g. ``neck_ry -> head`` of drcsim's ``atlas_v5.urdf``,
  whose head comes from another xacro) is dropped with a note; Pinocchio and MuJoCo then read the same
  tree. A joint whose *parent* link is missing is refused (its child would be a second root).
- Mesh URIs: ``package://PKG/rest`` is looked up in the folders of ``ROS_PACKAGE_PATH``, then in the robot
  file's folder and its parents (``DIR/PKG/rest``, or ``DIR/rest`` when ``DIR`` is named ``PKG``);
  ``file://`` and relative paths are taken from the file's folder. MuJoCo gets absolute paths; meshes
  that cannot be found are dropped with their geoms and a note (meshes only shape contact and visuals;
  the dynamics come from ``<inertial>``). Pinocchio does not read meshes for the dynamics at all.
"""

from __future__ import annotations

import copy
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from reflexarm.errors import ModelError

__all__ = ["UrdfFile", "mujoco_urdf_text", "read_urdf", "resolve_mesh_uri"]

#: How many folders above the robot file are searched for a ``package://`` package.
PACKAGE_SEARCH_DEPTH = 4


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


def mujoco_urdf_text(urdf: UrdfFile) -> tuple[str, list[str]]:
    """URDF text MuJoCo compiles from a string, with notes on the meshes.

    Found meshes get absolute file names; visuals and geoms whose mesh cannot be found are dropped; the
    file's own ``<mujoco>`` block is replaced by one that discards visuals, keeps fixed-joint links as
    bodies (so tool and sensor links stay addressable) and never derives inertia from geometry (as
    Pinocchio does not).
    """
    root = copy.deepcopy(urdf.root)
    found: dict[str, str] = {}
    missing: dict[str, str] = {}
    dropped = 0
    for link in root.iter("link"):
        for tag in ("visual", "collision"):
            for element in link.findall(tag):
                mesh = element.find("geometry/mesh")
                if mesh is None:
                    continue
                if tag == "visual":
                    link.remove(element)
                    continue
                uri = mesh.get("filename", "")
                f, how = resolve_mesh_uri(uri, urdf.path)
                if f is None:
                    missing[uri] = how
                    link.remove(element)
                    dropped += 1
                    continue
                mesh.set("filename", str(f.resolve()))
                if how:
                    found[how.split(" -> ")[0]] = how
    for old in root.findall("mujoco"):
        root.remove(old)
    block = ET.SubElement(root, "mujoco")
    ET.SubElement(
        block, "compiler", discardvisual="true", fusestatic="false", inertiafromgeom="false", strippath="false"
    )
    where = f"robot file {str(urdf.path)!r}"
    notes = [f"{where}: mesh package resolved: {how}" for how in found.values()]
    if missing:
        shown = ", ".join(sorted(missing)[:3]) + (f" and {len(missing) - 3} more" if len(missing) > 3 else "")
        notes.append(
            f"{where}: {len(missing)} mesh file(s) not found ({shown}); the {dropped} collision geom(s) using them "
            "were dropped (meshes only shape contact; masses and inertias come from the <inertial> elements)"
        )
    return ET.tostring(root, encoding="unicode"), notes
