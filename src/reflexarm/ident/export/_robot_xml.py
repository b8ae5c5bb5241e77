"""Reading and writing a robot file (URDF or MJCF) as XML, keeping its comments, and moving its file paths.

Used by :mod:`reflexarm.ident.export.write_back`, which writes a copy of a robot file in another folder: the
mesh, texture and include paths of the copy must still point at the original files.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from reflexarm.errors import ModelError

#: MJCF elements whose ``file`` is looked up in a compiler directory (MuJoCo: meshdir for meshes, skins
#: and height fields, texturedir for textures; assetdir sets both).
_MJCF_FILE_DIRS = {"mesh": "meshdir", "skin": "meshdir", "hfield": "meshdir", "texture": "texturedir"}
#: URI schemes left alone (resolved by ROS or absolute).
_SCHEMES = ("package://", "file://", "http://", "https://", "model://")


def read_xml(path: Path) -> ET.Element:
    """The file's root element, comments kept; ModelError if it is not XML."""
    parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
    try:
        return ET.parse(path, parser=parser).getroot()
    except (OSError, ET.ParseError) as e:
        raise ModelError(f"cannot read robot file {str(path)!r} as XML: {e}") from e


def write_xml(root: ET.Element, path: Path) -> Path:
    ET.ElementTree(root).write(path, encoding="unicode", xml_declaration=False)
    return path


def _moved(value: str, src_dir: Path, dst_dir: Path) -> str | None:
    """``value`` (a path relative to ``src_dir``) relative to ``dst_dir``; None if nothing to do."""
    if not value or value.startswith(_SCHEMES) or os.path.isabs(value):
        return None
    target = os.path.normpath(os.path.join(src_dir.resolve(), value))
    return Path(os.path.relpath(target, dst_dir.resolve())).as_posix()


def relocate_paths(root: ET.Element, fmt: str, src_dir: Path, dst_dir: Path) -> int:
    """Rewrite the relative file paths of a robot file moved from ``src_dir`` to ``dst_dir``; how many."""
    if src_dir.resolve() == dst_dir.resolve():
        return 0
    count = 0

    def move(el: ET.Element, attr: str) -> None:
        nonlocal count
        new = _moved(el.get(attr, ""), src_dir, dst_dir)
        if new is not None:
            el.set(attr, new)
            count += 1

    if fmt == "urdf":
        for el in root.iter("mesh"):
            move(el, "filename")
        return count
    dirs: set[str] = set()
    for compiler in root.iter("compiler"):
        for attr in ("meshdir", "texturedir", "assetdir"):
            if compiler.get(attr):
                dirs.add(attr)
                move(compiler, attr)
    for el in root.iter():
        if not isinstance(el.tag, str) or "file" not in el.attrib:
            continue
        governing = _MJCF_FILE_DIRS.get(el.tag)
        if governing is not None and (governing in dirs or "assetdir" in dirs):
            continue  # resolved through the (moved) compiler directory
        move(el, "file")
    return count


def _fmt(x: float) -> str:
    return f"{x:.12g}"


def find_element(root: ET.Element, tag: str, name: str, where: str) -> ET.Element:
    """The ``<tag name=name>`` element; ModelError naming the file if there is none."""
    for el in root.iter(tag):
        if el.get("name") == name:
            return el
    raise ModelError(f"{where}: no <{tag} name={name!r}> found (included from another file?); cannot write it back")


def set_inertial(fmt: str, el: ET.Element, mass: float, com: np.ndarray, inertia: np.ndarray) -> None:
    """Replace the inertial of URDF link / MJCF body ``el``: mass [kg], COM [m] and inertia about the COM
    [kg m^2] in the link's frame (URDF ``<inertial>`` with full ``<inertia>``, MJCF ``fullinertia``)."""
    if fmt == "urdf":
        for old in el.findall("inertial"):
            el.remove(old)
        new = ET.Element("inertial")
        new.text, new.tail = "\n      ", el.text or "\n    "
        ET.SubElement(new, "origin", xyz=" ".join(_fmt(x) for x in com), rpy="0 0 0").tail = "\n      "
        ET.SubElement(new, "mass", value=_fmt(mass)).tail = "\n      "
        names = (("ixx", 0, 0), ("ixy", 0, 1), ("ixz", 0, 2), ("iyy", 1, 1), ("iyz", 1, 2), ("izz", 2, 2))
        ET.SubElement(new, "inertia", {k: _fmt(inertia[a, b]) for k, a, b in names}).tail = "\n    "
        el.insert(0, new)
        return
    inertial = el.find("inertial")
    if inertial is None:
        inertial = ET.Element("inertial")
        inertial.tail = el.text or "\n"
        el.insert(0, inertial)
    for key in list(inertial.attrib):
        del inertial.attrib[key]
    inertial.set("pos", " ".join(_fmt(x) for x in com))
    inertial.set("mass", _fmt(mass))
    full = (inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2])
    if any(full[3:]):
        inertial.set("fullinertia", " ".join(_fmt(x) for x in full))
    else:
        # MuJoCo refuses an all-zero fullinertia ("inertia must have positive eigenvalues") but takes a zero
        # diaginertia: the massless body a fixed link leaves when its inertia is lumped into its parent
        inertial.set("diaginertia", " ".join(_fmt(x) for x in full[:3]))


def behind_locked_joint(root: ET.Element, fmt: str, link: str, main: str, locked: set[str]) -> bool:
    """True if a joint named in ``locked`` lies on the path from link/body ``main`` down to ``link``."""
    if not locked:
        return False
    if fmt == "urdf":
        parent = {}
        for joint in root.iter("joint"):
            p, c = joint.find("parent"), joint.find("child")
            if p is not None and c is not None:
                parent[c.get("link")] = (joint.get("name"), p.get("link"))
        current = link
        while current != main and current in parent:
            joint_name, current = parent[current]  # type: ignore[assignment]
            if joint_name in locked:
                return True
        return False
    body_parent = {child: body for body in root.iter("body") for child in body.findall("body")}
    body: ET.Element | None = next((b for b in root.iter("body") if b.get("name") == link), None)
    while body is not None and body.get("name") != main:
        if any(j.get("name") in locked for j in body.findall("joint")):
            return True
        body = body_parent.get(body)
    return False
