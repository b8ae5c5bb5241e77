"""Reading and writing a robot file (URDF or MJCF) as XML, keeping its comments, and moving its file paths.

Used by :mod:`reflexarm.ident.write_back`, which writes a copy of a robot file in another folder: the
mesh, texture and include paths of the copy must still point at the original files.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

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
