"""The vertices of a COLLADA (``.dae``) mesh (private): what MuJoCo, which decodes no COLLADA, needs of a
collision mesh.

MuJoCo collides with the convex hull of a mesh, so a collision mesh is fully described by its vertex
positions. A ``.dae`` file is XML: each ``<geometry><mesh>`` names its positions (``<vertices><input
semantic="POSITION" source="#..."/>``, a ``<source>`` holding a ``<float_array>``); the visual scene places
each geometry through its nodes' ``<matrix>``, ``<translate>``, ``<rotate>`` and ``<scale>``; ``<unit
meter="...">`` gives the length unit. The vertices are returned in metres, in the file's coordinates, as
the ROS tools (RViz, Gazebo) show them: the ``<up_axis>`` is not applied (it is ``Z_UP`` in the ROS
description packages looked at, where it changes nothing).
"""

from __future__ import annotations

import functools
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from reflexarm.errors import ModelError

__all__ = ["collada_vertices"]

#: Nesting depth of ``<instance_node>`` references followed (a reference cycle ends there) [-].
MAX_NODE_DEPTH = 32


def _tag(element: ET.Element) -> str:
    return element.tag.rsplit("}", 1)[-1]


def _children(element: ET.Element, tag: str) -> Iterator[ET.Element]:
    return (c for c in element if _tag(c) == tag)


def _first(element: ET.Element | None, *path: str) -> ET.Element | None:
    for tag in path:
        if element is None:
            return None
        element = next(_children(element, tag), None)
    return element


def _floats(element: ET.Element | None, count: int | None = None) -> np.ndarray:
    values = np.array((element.text or "").split() if element is not None else [], dtype=float)
    if count is not None and values.size != count:
        raise ValueError(f"<{_tag(element) if element is not None else '?'}> has {values.size} numbers, not {count}")
    return values


def _rotation(axis: np.ndarray, degrees: float) -> np.ndarray:
    norm = float(np.linalg.norm(axis))
    if norm == 0.0:
        return np.eye(4)
    x, y, z = axis / norm
    a = np.radians(degrees)
    c, s, t = np.cos(a), np.sin(a), 1.0 - np.cos(a)
    out = np.eye(4)
    out[:3, :3] = [
        [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
    ]
    return out


def _node_transform(node: ET.Element) -> np.ndarray:
    """The node's local transform: its transform elements multiplied in document order."""
    out = np.eye(4)
    for element in node:
        tag = _tag(element)
        step = np.eye(4)
        if tag == "matrix":
            step = _floats(element, 16).reshape(4, 4)  # row-major
        elif tag == "translate":
            step[:3, 3] = _floats(element, 3)
        elif tag == "rotate":
            r = _floats(element, 4)
            step = _rotation(r[:3], float(r[3]))
        elif tag == "scale":
            step[:3, :3] = np.diag(_floats(element, 3))
        elif tag in ("lookat", "skew"):
            raise ValueError(f"node {node.get('id')!r} has a <{tag}> transform, which is not read")
        out = out @ step
    return out


def _positions(geometry: ET.Element) -> np.ndarray:
    """(k, 3) vertex positions of one ``<geometry>`` (an empty array for a spline or a geometry without mesh)."""
    mesh = _first(geometry, "mesh")
    if mesh is None:
        return np.zeros((0, 3))
    sources = {s.get("id"): s for s in _children(mesh, "source")}
    vertices = _first(mesh, "vertices")
    inputs = list(_children(vertices, "input")) if vertices is not None else []
    position = next((i for i in inputs if i.get("semantic") == "POSITION"), None)
    source = sources.get((position.get("source") or "").lstrip("#")) if position is not None else None
    if source is None:
        raise ValueError(f"geometry {geometry.get('id')!r} has no POSITION source under <vertices>")
    accessor = _first(source, "technique_common", "accessor")
    stride = int(accessor.get("stride", "3")) if accessor is not None else 3
    values = _floats(_first(source, "float_array"))
    if stride < 3 or values.size % stride:
        raise ValueError(f"geometry {geometry.get('id')!r}: {values.size} position numbers with stride {stride}")
    return values.reshape(-1, stride)[:, :3]


def _placed(
    node: ET.Element, parent: np.ndarray, geometries: dict[str, np.ndarray], nodes: dict[str, ET.Element], depth: int
) -> Iterator[np.ndarray]:
    """The vertices of every geometry instanced under ``node``, in the scene's coordinates."""
    if depth > MAX_NODE_DEPTH:
        raise ValueError(f"<instance_node> references nest deeper than {MAX_NODE_DEPTH} (a cycle?)")
    pose = parent @ _node_transform(node)
    for element in node:
        tag = _tag(element)
        if tag == "instance_geometry":
            points = geometries.get((element.get("url") or "").lstrip("#"))
            if points is not None and points.size:
                yield points @ pose[:3, :3].T + pose[:3, 3]
        elif tag == "node":
            yield from _placed(element, pose, geometries, nodes, depth + 1)
        elif tag == "instance_node":
            target = nodes.get((element.get("url") or "").lstrip("#"))
            if target is not None:
                yield from _placed(target, pose, geometries, nodes, depth + 1)


def _scene(root: ET.Element) -> ET.Element | None:
    """The visual scene the file instances (``<scene><instance_visual_scene url>``), else its first one."""
    scenes = [s for lib in _children(root, "library_visual_scenes") for s in _children(lib, "visual_scene")]
    wanted = _first(root, "scene", "instance_visual_scene")
    url = (wanted.get("url") or "").lstrip("#") if wanted is not None else ""
    return next((s for s in scenes if s.get("id") == url), scenes[0] if scenes else None)


@functools.lru_cache(maxsize=64)
def _read(path: str, mtime_ns: int, size: int) -> np.ndarray:
    root = ET.parse(path).getroot()
    if _tag(root) != "COLLADA":
        raise ValueError(f"root element is <{_tag(root)}>, expected <COLLADA>")
    unit = _first(root, "asset", "unit")
    metre = float(unit.get("meter", "1")) if unit is not None else 1.0
    geometries = {
        str(g.get("id")): _positions(g)
        for lib in _children(root, "library_geometries")
        for g in _children(lib, "geometry")
    }
    nodes = {str(n.get("id")): n for n in root.iter() if _tag(n) == "node" and n.get("id")}
    scene = _scene(root)
    parts = list(_placed(scene, np.eye(4), geometries, nodes, 0)) if scene is not None else []
    if not parts:  # no scene (or nothing instanced in it): the geometries as written
        parts = [p for p in geometries.values() if p.size]
    points = metre * np.concatenate(parts) if parts else np.zeros((0, 3))
    if points.shape[0] < 4 or not np.all(np.isfinite(points)):
        raise ValueError(f"{points.shape[0]} finite vertices; a collision mesh needs at least 4")
    points.setflags(write=False)
    return points


def collada_vertices(path: Path) -> np.ndarray:
    """(k, 3) vertex positions [m] of every mesh the COLLADA file's scene places (read-only; cached per file
    version).

    Raises:
        ModelError: the file cannot be read, is not COLLADA, or has fewer than 4 finite vertices; the
            message names the file and the problem.
    """
    try:
        stat = path.stat()
        return _read(str(path.resolve()), stat.st_mtime_ns, stat.st_size)
    except (OSError, ET.ParseError, ValueError) as e:
        raise ModelError(f"cannot read the COLLADA mesh {str(path)!r}: {e}") from e
