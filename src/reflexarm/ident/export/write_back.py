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
whole identified inertia, expressed in its own frame. An arm cut out of a bigger file (``base``/``tip``/
``locked``): links behind a locked joint (a gripper's fingers) keep the file's inertias, since the plant
needs mass on the bodies of those joints; the moving link carries the identified inertia minus theirs
at the locked positions (refused if that leaves it no physical inertia). The copy is loaded with the
same ``base``/``tip``/``locked``.

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
from reflexarm.ident._blas_threads import DEFAULT_BLAS_THREADS
from reflexarm.ident.estimation.consistency import project_physically_consistent, pseudo_inertia
from reflexarm.ident.estimation.result import DynamicsIdentification
from reflexarm.ident.export._locked_links import link_groups, locked_links, robot_file
from reflexarm.ident.export._robot_xml import find_element, read_xml, relocate_paths, set_inertial, write_xml
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


#: How the notes of :func:`with_consistent_links` start when beta_b is realised without a projection.
_NEAREST = "link parameters"


def with_consistent_links(
    result: DynamicsIdentification, robot: RobotModel, *, threads: int | None = DEFAULT_BLAS_THREADS
) -> tuple[DynamicsIdentification, str]:
    """``result`` with :attr:`~DynamicsIdentification.physical_parameters` set, and how they were chosen.

    See the module docstring: the result's own physically consistent parameters, else the realisation
    nearest to the file's inertias if every link of it is consistent (beta_b unchanged), else the
    projection onto consistent parameters (which moves beta_b; the note says how much the fit worsens).
    For an arm cut out of a bigger file the links behind locked joints keep the file's inertias and the
    check (and projection) applies to the rest of each link. Save the model file from the returned result
    too, so that the model file and the written robot file are the same model. ``threads``: BLAS threads
    of the projection (None: as configured).
    """
    fixed = locked_links(robot).parameters if robot.source is not None else None
    own = np.zeros(10 * robot.n) if fixed is None else fixed
    if result.physical_parameters is not None and _links_consistent(result.physical_parameters - own):
        said = [n for n in result.notes if n.startswith((_NEAREST, "projected onto physically consistent"))]
        return result, said[-1] if said else "the identification's physically consistent link parameters"
    pi = result.standard_parameters(robot.inertial_parameters())
    if result.physical_parameters is None and _links_consistent(pi - own):
        how = (
            f"{_NEAREST} realising the identified base parameters nearest to the file's own inertias (every link "
            "physically consistent); combinations the data cannot split keep the file's split"
        )
        return replace(result, physical_parameters=pi, notes=result.notes + (how,)), how
    projected = project_physically_consistent(result, robot, threads=threads, fixed_parameters=fixed)
    return projected, (
        "the nearest physically consistent link parameters (the realisation nearest to the file's inertias has a "
        f"link with no physical mass distribution); {projected.notes[-1]}"
    )


def link_inertias(robot: RobotModel, pi: np.ndarray) -> dict[str, pin.Inertia]:
    """Per moving link (by name), the inertia of ``pi`` (10 per joint, about each joint frame) expressed in
    that link's own frame."""
    out = {}
    for j, (main, _) in enumerate(link_groups(robot), start=1):
        inertia_joint = pin.Inertia.FromDynamicParameters(pi[10 * (j - 1) : 10 * j])
        frame = robot.pin_model.frames[robot.pin_model.getFrameId(main, pin.FrameType.BODY)]
        out[main] = frame.placement.actInv(inertia_joint)
    return out


def _fmt(x: float) -> str:
    return f"{x:.12g}"


def write_identified_robot(
    result: DynamicsIdentification,
    robot: RobotModel,
    path: str | os.PathLike[str],
    *,
    threads: int | None = DEFAULT_BLAS_THREADS,
) -> tuple[Path, list[str]]:
    """Write a copy of ``robot``'s file with the identified inertias and friction (see the module docstring).

    Args:
        result: the identification (its friction and base parameters).
        robot: the robot it was identified for, loaded from its URDF or MJCF file.
        path: the copy (same format as the source: ``.urdf`` or ``.xml``).
        threads: BLAS threads of a projection, if one is needed (None: as configured).

    Returns:
        The path written and notes on what was done (how the link parameters were chosen, lumped links,
        clipped friction, paths rewritten). The file's model is ``with_consistent_links(result, robot)``'s
        (the same as ``result``'s unless a projection was needed; see :func:`with_consistent_links`).

    Raises:
        ModelError: no robot file, an arm cut out of a bigger file, joints or links not found in the file,
            another format than the source's.
    """
    src, fmt = robot_file(robot)
    dst = Path(path)
    want = ".urdf" if fmt == "urdf" else ".xml"
    if dst.suffix.lower() not in ((".urdf",) if fmt == "urdf" else (".xml", ".mjcf")):
        raise ModelError(f"the copy of {src.name} must be a {want} file like its source; got {str(dst)!r}")
    if result.n != robot.n or tuple(result.joint_names) != tuple(robot.joint_names):
        raise ModelError(
            f"identification of joints {list(result.joint_names)} does not fit robot {robot.name!r} "
            f"({robot.joint_names})"
        )
    result, how = with_consistent_links(result, robot, threads=threads)
    assert result.physical_parameters is not None  # set by with_consistent_links
    root = read_xml(src)
    moved = relocate_paths(root, fmt, src.parent, dst.parent)
    links = locked_links(robot)
    behind, lumped = links.behind, list(links.fixed)
    pi = np.asarray(result.physical_parameters, dtype=float)
    if links.parameters is not None:  # the locked links keep the file's inertias: the moving links carry the rest
        pi = pi - links.parameters
        _check_remainder(pi, robot, links.groups, behind)
    inertias = link_inertias(robot, pi)
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
    if lumped:
        notes.append(
            f"links fixed to a moving link ({', '.join(lumped)}) get zero mass; the moving link carries the whole "
            "identified inertia"
        )
    if behind:
        notes.append(
            f"links behind locked joints ({', '.join(sorted(behind))}) keep the file's inertias; the moving links "
            "carry the identified inertia minus theirs (at the locked positions)"
        )
    if moved:
        notes.append(f"{moved} file path(s) rewritten to resolve from {dst.parent}")
    coulomb = np.maximum(friction.coulomb, 0.0)
    viscous = np.maximum(friction.viscous, 0.0)
    _write_inertias(root, fmt, inertias, lumped, src)
    notes += _write_friction(root, fmt, robot, coulomb, viscous, src)
    dst.parent.mkdir(parents=True, exist_ok=True)
    write_xml(root, dst)
    return dst, notes


def _check_remainder(
    pi: np.ndarray, robot: RobotModel, groups: tuple[tuple[str, tuple[str, ...]], ...], behind: frozenset[str]
) -> None:
    """Guard (with_consistent_links made the rest consistent): each moving link's own part is physical."""
    for j, (main, links) in enumerate(groups):
        ev = np.linalg.eigvalsh(pseudo_inertia(pi[10 * j : 10 * j + 10]))
        if ev[0] < -_CONSISTENCY_TOL * max(abs(ev[-1]), 1e-300):
            held = [link for link in links if link in behind]
            raise ModelError(
                f"joint {j + 1} ({robot.joint_names[j]}): the identified inertia minus the file's links behind "
                f"locked joints ({', '.join(held)}) is not a physical inertia for {main!r} (mass {pi[10 * j]:.4g} kg, "
                f"smallest pseudo-inertia eigenvalue {ev[0]:.3g}); the file cannot hold it without changing those links"
            )


def _com_inertia(inertia: pin.Inertia) -> tuple[float, np.ndarray, np.ndarray]:
    return float(inertia.mass), np.asarray(inertia.lever, dtype=float), np.asarray(inertia.inertia, dtype=float)


def _write_inertias(root: ET.Element, fmt: str, inertias: dict[str, pin.Inertia], lumped: list[str], src: Path) -> None:
    tag = "link" if fmt == "urdf" else "body"
    for name, inertia in inertias.items():
        set_inertial(fmt, find_element(root, tag, name, src.name), *_com_inertia(inertia))
    for name in lumped:
        set_inertial(fmt, find_element(root, tag, name, src.name), 0.0, np.zeros(3), np.zeros((3, 3)))


def _write_friction(
    root: ET.Element, fmt: str, robot: RobotModel, coulomb: np.ndarray, viscous: np.ndarray, src: Path
) -> list[str]:
    notes = []
    for j, jname in enumerate(robot.joint_names):
        joint = find_element(root, "joint", jname, src.name)
        if fmt == "urdf":
            dyn = joint.find("dynamics")
            if dyn is None:
                dyn = ET.SubElement(joint, "dynamics")
            dyn.set("friction", _fmt(coulomb[j]))
            dyn.set("damping", _fmt(viscous[j]))
        else:
            joint.set("frictionloss", _fmt(coulomb[j]))
            joint.set("damping", _fmt(viscous[j]))
    compiler = root.find("compiler")
    if fmt == "mjcf" and compiler is not None and compiler.get("inertiafromgeom") == "true":
        compiler.set("inertiafromgeom", "auto")  # "true" would ignore the written <inertial> elements
        notes.append('compiler inertiafromgeom="true" changed to "auto" so that the written inertials count')
    return notes
