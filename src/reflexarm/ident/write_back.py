"""The identified model written into a copy of the user's robot file (URDF or MJCF).

:func:`write_identified_robot` copies the robot file the identification was made for and replaces

* each moving link's inertial (mass, centre of mass, inertia about it) by the identified, physically
  consistent ones: URDF ``<inertial>`` (``<origin xyz>``, ``<mass>``, full ``<inertia>``), MJCF body
  ``<inertial pos mass fullinertia>``;
* each joint's friction by the identified Coulomb and viscous coefficients: URDF ``<dynamics friction
  damping>``, MJCF joint ``frictionloss`` and ``damping``;

and leaves everything else as it was (kinematics, limits, geometry, armature, springs, actuators). Paths
to meshes and included files are rewritten so that they still resolve from the copy's folder.

Which inertias. Identification determines only the base parameters beta_b: the combinations of the 10 n
link parameters that move the joints. Infinitely many link parameter sets give the same beta_b, hence
the same M(q), C(q, dq) and g(q); the data cannot split a combination (e.g. a link's mass from the
next link's first moment, or anything of link 1 except its inertia about the first axis). The file gets
one realisation: the identification's physically consistent one if it has it
(:func:`~reflexarm.ident.project_physically_consistent` sets it), else the one nearest to the file's own
inertias (:meth:`~reflexarm.ident.BaseParameters.standard_from_base`) when every link of it is
physically consistent, else the projection is run here. The parts the data cannot see thus stay at (or
near) the file's values; every realisation gives the controller and the plant the same torques.

Links fixed rigidly to a moving link (a URDF fixed joint, an MJCF body without joint) are lumped into it
by the identification; in the copy their inertial is set to zero mass and the moving link carries the
whole identified inertia, expressed in its own frame.

Friction: coefficients below 0 are written as 0 (as the controller's model clips them); offsets are not
friction and are not written.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from reflexarm.errors import ModelError
from reflexarm.ident._robot_xml import read_xml, relocate_paths, write_xml
from reflexarm.ident.consistency import project_physically_consistent, pseudo_inertia
from reflexarm.ident.identification_result import DynamicsIdentification
from reflexarm.robots.robot_model import RobotModel

__all__ = ["link_inertias", "with_consistent_links", "write_identified_robot"]

#: A link's pseudo-inertia counts as physically consistent when its smallest eigenvalue is above
#: -this fraction of its largest (round-off of parameters that are exactly on the boundary, e.g. a point mass).
_CONSISTENCY_TOL = 1e-9


def _links_consistent(pi: np.ndarray) -> bool:
    for k in range(pi.size // 10):
        ev = np.linalg.eigvalsh(pseudo_inertia(pi[10 * k : 10 * k + 10]))
        if ev[0] < -_CONSISTENCY_TOL * max(abs(ev[-1]), 1e-300):
            return False
    return True


def with_consistent_links(result: DynamicsIdentification, robot: RobotModel) -> tuple[DynamicsIdentification, str]:
    """``result`` with :attr:`~DynamicsIdentification.physical_parameters` set, and how they were chosen.

    See the module docstring: the result's own physically consistent parameters, else the realisation
    nearest to the file's inertias if every link of it is consistent (beta_b unchanged), else the
    projection onto consistent parameters (which moves beta_b; the note says how much the fit worsens).
    Save the model file from the returned result too, so that the model file and the written robot
    file are the same model.
    """
    if result.physical_parameters is not None:
        return result, "the identification's physically consistent link parameters (projection of the estimate)"
    pi = result.standard_parameters(robot.inertial_parameters())
    if _links_consistent(pi):
        return replace(result, physical_parameters=pi), (
            "the link parameters realising the identified base parameters nearest to the file's own inertias "
            "(every link physically consistent); combinations the data cannot split keep the file's split"
        )
    projected = project_physically_consistent(result, robot)
    return projected, (
        "the nearest physically consistent link parameters (the realisation nearest to the file's inertias has a "
        f"link with no physical mass distribution); {projected.notes[-1]}"
    )


def _body_frames(robot: RobotModel, joint: int) -> list[pin.Frame]:
    """BODY frames moved by ``joint`` (1-based Pinocchio joint index): the moving link first."""
    return [f for f in robot.pin_model.frames if f.type == pin.FrameType.BODY and f.parentJoint == joint]


def link_inertias(robot: RobotModel, pi: np.ndarray) -> dict[str, pin.Inertia]:
    """Per moving link (by name), the inertia of ``pi`` expressed in that link's own frame."""
    out = {}
    for j in range(1, robot.pin_model.njoints):
        frames = _body_frames(robot, j)
        if not frames:
            raise ModelError(
                f"joint {robot.joint_names[j - 1]!r} moves no link of {robot.name!r}; cannot write it back"
            )
        inertia_joint = pin.Inertia.FromDynamicParameters(pi[10 * (j - 1) : 10 * j])
        out[frames[0].name] = frames[0].placement.actInv(inertia_joint)
    return out


def _lumped_links(robot: RobotModel) -> list[str]:
    return [f.name for j in range(1, robot.pin_model.njoints) for f in _body_frames(robot, j)[1:]]


def _fmt(x: float) -> str:
    return f"{x:.12g}"


def _check_robot(robot: RobotModel) -> Path:
    if robot.source is None or not Path(robot.source).is_file():
        raise ModelError(f"robot {robot.name!r} has no robot file to copy (source {robot.source!r})")
    cut = {k: getattr(robot, k, None) for k in ("base", "tip", "locked")}
    if any(cut.values()):
        raise ModelError(
            f"robot {robot.name!r} was cut from its file ({', '.join(f'{k}={v!r}' for k, v in cut.items() if v)}); "
            "writing identified inertias back into the whole file is not supported (the locked links are lumped "
            "into the arm's): use the model file (model_<method>.json) with the same --base/--tip/--lock"
        )
    return Path(robot.source)


def write_identified_robot(
    result: DynamicsIdentification,
    robot: RobotModel,
    path: str | os.PathLike[str],
) -> tuple[Path, list[str]]:
    """Write a copy of ``robot``'s file with the identified inertias and friction (see the module docstring).

    Args:
        result: the identification (its friction and base parameters).
        robot: the robot it was identified for, loaded from its URDF or MJCF file.
        path: the copy (same format as the source: ``.urdf`` or ``.xml``).

    Returns:
        The path written and notes on what was done (how the link parameters were chosen, lumped links,
        clipped friction, paths rewritten). The file's model is ``with_consistent_links(result, robot)``'s
        (the same as ``result``'s unless a projection was needed; see :func:`with_consistent_links`).

    Raises:
        ModelError: no robot file, an arm cut out of a bigger file, joints or links not found in the file,
            another format than the source's.
    """
    src = _check_robot(robot)
    dst = Path(path)
    fmt = "urdf" if src.suffix.lower() == ".urdf" else "mjcf"
    want = ".urdf" if fmt == "urdf" else ".xml"
    if dst.suffix.lower() not in ((".urdf",) if fmt == "urdf" else (".xml", ".mjcf")):
        raise ModelError(f"the copy of {src.name} must be a {want} file like its source; got {str(dst)!r}")
    if result.n != robot.n or tuple(result.joint_names) != tuple(robot.joint_names):
        raise ModelError(
            f"identification of joints {list(result.joint_names)} does not fit robot {robot.name!r} "
            f"({robot.joint_names})"
        )
    result, how = with_consistent_links(result, robot)
    assert result.physical_parameters is not None  # set by with_consistent_links
    inertias = link_inertias(robot, result.physical_parameters)
    friction = result.friction
    notes = [how]
    clipped = [
        f"joint {j + 1} ({robot.joint_names[j]}) {name} {v:.4g}"
        for j in range(robot.n)
        for name, v in (("mu_C", friction.coulomb[j]), ("d_v", friction.viscous[j]))
        if v < 0
    ]
    if clipped:
        notes.append("negative friction written as 0: " + ", ".join(clipped))
    if friction.offset is not None:
        notes.append("torque offsets are not friction and are not in the file")
    lumped = _lumped_links(robot)
    if lumped:
        notes.append(
            f"links fixed to a moving link ({', '.join(lumped)}) get zero mass; the moving link carries the whole "
            "identified inertia"
        )
    root = read_xml(src)
    moved = relocate_paths(root, fmt, src.parent, dst.parent)
    if moved:
        notes.append(f"{moved} file path(s) rewritten to resolve from {dst.parent}")
    coulomb = np.maximum(friction.coulomb, 0.0)
    viscous = np.maximum(friction.viscous, 0.0)
    if fmt == "urdf":
        _write_urdf(root, robot, inertias, lumped, coulomb, viscous, src)
    else:
        notes += _write_mjcf(root, robot, inertias, lumped, coulomb, viscous, src)
    dst.parent.mkdir(parents=True, exist_ok=True)
    write_xml(root, dst)
    return dst, notes


def _find(root: ET.Element, tag: str, name: str, src: Path) -> ET.Element:
    for el in root.iter(tag):
        if el.get("name") == name:
            return el
    raise ModelError(f"{src.name}: no <{tag} name={name!r}> found (included from another file?); cannot write it back")


def _com_inertia(inertia: pin.Inertia) -> tuple[float, np.ndarray, np.ndarray]:
    return float(inertia.mass), np.asarray(inertia.lever, dtype=float), np.asarray(inertia.inertia, dtype=float)


def _write_urdf(
    root: ET.Element,
    robot: RobotModel,
    inertias: dict[str, pin.Inertia],
    lumped: list[str],
    coulomb: np.ndarray,
    viscous: np.ndarray,
    src: Path,
) -> None:
    def set_inertial(link: ET.Element, m: float, c: np.ndarray, inertia: np.ndarray) -> None:
        for old in link.findall("inertial"):
            link.remove(old)
        el = ET.Element("inertial")
        el.text, el.tail = "\n      ", link.text or "\n    "
        ET.SubElement(el, "origin", xyz=" ".join(_fmt(x) for x in c), rpy="0 0 0").tail = "\n      "
        ET.SubElement(el, "mass", value=_fmt(m)).tail = "\n      "
        names = (("ixx", 0, 0), ("ixy", 0, 1), ("ixz", 0, 2), ("iyy", 1, 1), ("iyz", 1, 2), ("izz", 2, 2))
        ET.SubElement(el, "inertia", {k: _fmt(inertia[a, b]) for k, a, b in names}).tail = "\n    "
        link.insert(0, el)

    for name, inertia in inertias.items():
        set_inertial(_find(root, "link", name, src), *_com_inertia(inertia))
    for name in lumped:
        set_inertial(_find(root, "link", name, src), 0.0, np.zeros(3), np.zeros((3, 3)))
    for j, jname in enumerate(robot.joint_names):
        joint = _find(root, "joint", jname, src)
        dyn = joint.find("dynamics")
        if dyn is None:
            dyn = ET.SubElement(joint, "dynamics")
        dyn.set("friction", _fmt(coulomb[j]))
        dyn.set("damping", _fmt(viscous[j]))


def _write_mjcf(
    root: ET.Element,
    robot: RobotModel,
    inertias: dict[str, pin.Inertia],
    lumped: list[str],
    coulomb: np.ndarray,
    viscous: np.ndarray,
    src: Path,
) -> list[str]:
    notes = []
    compiler = root.find("compiler")
    if compiler is not None and compiler.get("inertiafromgeom") == "true":
        compiler.set("inertiafromgeom", "auto")  # "true" would ignore the written <inertial> elements
        notes.append('compiler inertiafromgeom="true" changed to "auto" so that the written inertials count')

    def set_inertial(body: ET.Element, m: float, c: np.ndarray, inertia: np.ndarray) -> None:
        el = body.find("inertial")
        if el is None:
            el = ET.Element("inertial")
            el.tail = body.text or "\n"
            body.insert(0, el)
        for key in list(el.attrib):
            del el.attrib[key]
        el.set("pos", " ".join(_fmt(x) for x in c))
        el.set("mass", _fmt(m))
        full = (inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2])
        el.set("fullinertia", " ".join(_fmt(x) for x in full))

    for name, inertia in inertias.items():
        set_inertial(_find(root, "body", name, src), *_com_inertia(inertia))
    for name in lumped:
        set_inertial(_find(root, "body", name, src), 0.0, np.zeros(3), np.zeros((3, 3)))
    for j, jname in enumerate(robot.joint_names):
        joint = _find(root, "joint", jname, src)
        joint.set("frictionloss", _fmt(coulomb[j]))
        joint.set("damping", _fmt(viscous[j]))
    return notes
