"""Reading MJCF files through MuJoCo's own parser and compiler (private).

MuJoCo resolves what Pinocchio's MJCF parser may not (default classes, angle units, ``springref`` in
degrees, ``springdamper``, disable flags), so the joint facts that both the controller's model and the
plant must share are taken from MuJoCo's compiled model. Two things are changed before compiling, each
with a note:

- mesh assets whose file is absent are removed with the geoms that use them (meshes only shape
  collision and visual geometry; the dynamics come from ``<inertial>``). A body whose inertia MuJoCo
  would derive from such a geom is refused: dropping the geom would change its mass silently. A body
  left without any contact geom that way gets a box with its mass and inertia, so scenes still touch it.
- nothing else; removing the file's actuators is the plant's business (see ``sim/_builder.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from reflexarm.errors import ModelError
from reflexarm.robots._urdf import stand_in_half_sides

__all__ = ["JointFacts", "RobotFileWarning", "compile_mjcf", "joint_facts", "load_mjcf_spec"]


class RobotFileWarning(UserWarning):
    """Something in a robot file was dropped or is not modelled on both sides (the message says what)."""


@dataclass
class JointFacts:
    """Per-joint passive terms and limits of the compiled MJCF, in the order of ``joint_names``.

    ``damping``/``frictionloss``/``stiffness`` are zero where the file disables them
    (``<option><flag damper/frictionloss/spring="disable"/>``); ``gravity`` likewise.
    """

    joint_names: list[str]
    armature: np.ndarray
    damping: np.ndarray
    frictionloss: np.ndarray
    stiffness: np.ndarray
    springref: np.ndarray
    lower_limit: np.ndarray  # -inf for an unlimited joint
    upper_limit: np.ndarray
    effort_limit: np.ndarray  # inf where the file gives none
    gravity: np.ndarray
    notes: list[str] = field(default_factory=list)


def load_mjcf_spec(path: Path) -> tuple[mujoco.MjSpec, list[str]]:
    """Parse an MJCF file into an MjSpec, dropping absent meshes (and the geoms that use them).

    Returns the spec and the notes describing what was dropped.

    Raises:
        ModelError: unparsable file, or a body whose inertia would come from a dropped mesh geom.
    """
    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except Exception as e:  # MuJoCo raises ValueError with the parser's text
        raise ModelError(f"MuJoCo cannot parse robot file {str(path)!r}: {e}") from e
    return spec, _drop_missing_meshes(spec, path)


def compile_mjcf(path: Path) -> tuple[mujoco.MjModel, list[str]]:
    """Compile an MJCF file as MuJoCo sees it, absent meshes dropped (see :func:`load_mjcf_spec`)."""
    spec, notes = load_mjcf_spec(path)
    try:
        return spec.compile(), notes
    except Exception as e:
        raise ModelError(f"MuJoCo cannot compile robot file {str(path)!r}: {e}") from e


def _mesh_file(spec: mujoco.MjSpec, mesh: mujoco.MjsMesh, path: Path) -> Path | None:
    """Where MuJoCo will look for a mesh's file (``None`` for a mesh given inline)."""
    if not mesh.file:
        return None
    f = Path(mesh.file)
    if spec.strippath:
        f = Path(f.name)
    if f.is_absolute():
        return f
    meshdir = Path(spec.meshdir) if spec.meshdir else Path()
    base = meshdir if meshdir.is_absolute() else path.parent / meshdir
    return base / f


def _drop_missing_meshes(spec: mujoco.MjSpec, path: Path) -> list[str]:
    missing: dict[str, Path] = {}
    for mesh in spec.meshes:
        f = _mesh_file(spec, mesh, path)
        if f is not None and not f.is_file():
            missing[mesh.name] = f
    if not missing:
        return []
    dropped: list[mujoco.MjsGeom] = [g for g in spec.geoms if g.meshname in missing]
    from_geom = spec.compiler.inertiafromgeom
    for body in {id(g.parent): g.parent for g in dropped}.values():
        if from_geom == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE or (
            from_geom == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_AUTO and not body.explicitinertial
        ):
            lost = sorted({g.meshname for g in dropped if g.parent.name == body.name})
            raise ModelError(
                f"robot file {str(path)!r}: body {body.name!r} takes its mass and inertia from mesh geom(s) "
                f"whose file is missing ({', '.join(str(missing[m]) for m in lost)}); provide the mesh files "
                'or give the body an <inertial> element (and <compiler inertiafromgeom="auto"/>)'
            )
    contact: dict[str, mujoco.MjsGeom] = {}  # body -> its first dropped geom that takes part in contacts
    for g in dropped:
        if (g.contype or g.conaffinity) and g.parent.name not in contact:
            contact[g.parent.name] = g
    templates = {body: {"condim": g.condim, "friction": g.friction.copy()} for body, g in contact.items()}
    for g in dropped:
        spec.delete(g)
    for mesh in list(spec.meshes):
        if mesh.name in missing:
            spec.delete(mesh)
    files = sorted({str(p) for p in missing.values()})
    shown = ", ".join(files[:3]) + (f" and {len(files) - 3} more" if len(files) > 3 else "")
    notes = [
        f"robot file {str(path)!r}: {len(missing)} mesh file(s) not found ({shown}); the {len(dropped)} geom(s) "
        "using them were dropped (meshes only shape contact and visual geometry; masses and inertias come "
        "from the <inertial> elements)"
    ]
    boxed = _inertia_boxes(spec, templates)
    if boxed:
        notes.append(
            f"robot file {str(path)!r}: {len(boxed)} body(ies) left without contact geometry ({', '.join(boxed[:4])}"
            f"{' ...' if len(boxed) > 4 else ''}) touch the scene through a box with the body's mass and inertia "
            "(centred at its centre of mass, along its principal axes, no larger than the body's reach; no effect "
            "on the dynamics)"
        )
    return notes


#: Contact bits of the stand-in boxes: those of the plant's arm geoms (``sim/_builder.ARM_CONTYPE``/
#: ``ARM_CONAFFINITY``), so they collide with the scene's objects and not with each other.
STAND_IN_CONTYPE = 2
STAND_IN_CONAFFINITY = 1


def _inertia_boxes(spec: mujoco.MjSpec, templates: dict[str, dict[str, object]]) -> list[str]:
    """Add a contact box of uniform density with the body's mass and inertia to each body of ``templates``
    left without a contact geom, with that template's condim and friction; return the bodies that got one.

    Its size: :func:`reflexarm.robots._urdf.stand_in_half_sides`, bounded by the body's reach (its origin and
    its children's origins seen from the centre of mass). The body's explicit inertial keeps its dynamics
    (MuJoCo ignores geoms for the inertia of a body with an <inertial> unless inertiafromgeom="true",
    which is refused above).
    """
    if not templates:
        return []
    try:
        mj = spec.compile()
    except Exception:  # the caller's compile reports it with the file's name
        return []
    boxed = []
    for name, attributes in templates.items():
        body = spec.body(name)
        if body is None or any(g.contype or g.conaffinity for g in body.geoms):
            continue
        b = mj.body(name).id
        m, principal = float(mj.body_mass[b]), np.asarray(mj.body_inertia[b], dtype=float)
        if not m > 0.0:
            continue
        com = np.asarray(mj.body_ipos[b], dtype=float)
        ends = [np.zeros(3)] + [np.asarray(mj.body_pos[c]) for c in range(mj.nbody) if mj.body_parentid[c] == b]
        reach = max(float(np.linalg.norm(com - e)) for e in ends)
        geom = body.add_geom(
            name=f"{name}_inertia_box",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=stand_in_half_sides(m, principal, reach),
            pos=np.array(mj.body_ipos[b]),
            quat=np.array(mj.body_iquat[b]),
            rgba=[0.6, 0.6, 0.65, 1.0],
        )
        for key, value in attributes.items():
            setattr(geom, key, value)
        # boxes overlap where the real shells do not: they touch the scene but never each other (the plant's
        # arm convention, sim/_builder.py: contype 2, conaffinity 1; scene objects carry contype bit 1)
        geom.contype, geom.conaffinity = STAND_IN_CONTYPE, STAND_IN_CONAFFINITY
        boxed.append(name)
    return boxed


def joint_facts(mj: mujoco.MjModel, joint_names: list[str], path: Path) -> JointFacts:
    """Passive joint terms, effort limits and gravity of ``joint_names`` in the compiled model ``mj``.

    Raises:
        ModelError: a named joint is missing, is not a hinge/slide, or has a non-zero ``ref``.
    """
    n = len(joint_names)
    jids = np.zeros(n, dtype=int)
    for i, name in enumerate(joint_names):
        jid = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, name)
        if jid < 0:
            raise ModelError(f"robot file {str(path)!r}: MuJoCo has no joint {name!r} that Pinocchio found")
        if int(mj.jnt_type[jid]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            raise ModelError(f"robot file {str(path)!r}: joint {name!r} is not a hinge or slide joint")
        jids[i] = jid
    qadr = mj.jnt_qposadr[jids]
    dofs = mj.jnt_dofadr[jids]
    bad_ref = [(joint_names[i], float(mj.qpos0[a])) for i, a in enumerate(qadr) if mj.qpos0[a] != 0.0]
    if bad_ref:
        raise ModelError(
            f"robot file {str(path)!r}: joint(s) with a non-zero ref (reference angle) {bad_ref}: the joint "
            "value would differ between MuJoCo and Pinocchio; set ref to 0 and move the body instead"
        )
    disabled = int(mj.opt.disableflags)

    def off(bit: mujoco.mjtDisableBit) -> bool:
        return bool(disabled & int(bit))

    no_constraint = off(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT) or off(mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS)
    facts = JointFacts(
        joint_names=list(joint_names),
        armature=np.array(mj.dof_armature[dofs], dtype=float),
        damping=np.zeros(n) if off(mujoco.mjtDisableBit.mjDSBL_DAMPER) else np.array(mj.dof_damping[dofs]),
        frictionloss=np.zeros(n) if no_constraint else np.array(mj.dof_frictionloss[dofs], dtype=float),
        stiffness=np.zeros(n) if off(mujoco.mjtDisableBit.mjDSBL_SPRING) else np.array(mj.jnt_stiffness[jids]),
        springref=np.array(mj.qpos_spring[qadr], dtype=float),
        lower_limit=np.where(mj.jnt_limited[jids], mj.jnt_range[jids, 0], -np.inf),
        upper_limit=np.where(mj.jnt_limited[jids], mj.jnt_range[jids, 1], np.inf),
        effort_limit=_effort_limits(mj, jids),
        gravity=np.zeros(3) if off(mujoco.mjtDisableBit.mjDSBL_GRAVITY) else np.array(mj.opt.gravity, dtype=float),
    )
    facts.notes.extend(_unmodelled(mj, jids, joint_names, path))
    return facts


def _effort_limits(mj: mujoco.MjModel, jids: np.ndarray) -> np.ndarray:
    """|tau| limit per joint: the joint's ``actuatorfrcrange``, else the force range of the file's own
    actuator on that joint (times its gear), else inf. The smaller bound of an asymmetric range is kept."""
    out = np.full(jids.size, np.inf)
    for i, j in enumerate(jids):
        if mj.jnt_actfrclimited[j]:
            lo, hi = mj.jnt_actfrcrange[j]
            out[i] = min(abs(lo), abs(hi))
            continue
        for a in range(mj.nu):
            if (
                int(mj.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT)
                and mj.actuator_trnid[a, 0] == j
                and mj.actuator_forcelimited[a]
            ):
                lo, hi = mj.actuator_forcerange[a]
                out[i] = min(out[i], min(abs(lo), abs(hi)) * abs(mj.actuator_gear[a, 0]))
    return out


def _unmodelled(mj: mujoco.MjModel, jids: np.ndarray, names: list[str], path: Path) -> list[str]:
    """Notes on passive effects the MuJoCo plant has and the rigid-body model (1) does not."""
    where = f"robot file {str(path)!r}"
    notes = []
    dofs = mj.jnt_dofadr[jids]
    poly = [names[i] for i in range(len(names)) if np.any(mj.dof_dampingpoly[dofs[i]] != 0.0)]
    poly += [names[i] for i in range(len(names)) if np.any(mj.jnt_stiffnesspoly[jids[i]] != 0.0)]
    poly += [names[i] for i in range(len(names)) if mj.jnt_springyield[jids[i]] != 0.0]
    if poly:
        notes.append(
            f"{where}: joint(s) {sorted(set(poly))} have nonlinear damping/stiffness terms or a spring yield; "
            "the controller's model keeps only the linear spring and viscous damping"
        )
    if mj.opt.density > 0.0 or mj.opt.viscosity > 0.0:
        notes.append(
            f"{where}: fluid forces (density={mj.opt.density:g}, viscosity={mj.opt.viscosity:g}) act in the plant "
            "and are not in the controller's model"
        )
    passive_tendons = [
        mj.tendon(t).name or f"#{t}"
        for t in range(mj.ntendon)
        if mj.tendon_stiffness[t] != 0.0 or mj.tendon_damping[t] != 0.0 or mj.tendon_frictionloss[t] != 0.0
    ]
    if passive_tendons:
        notes.append(
            f"{where}: tendon(s) {passive_tendons} with stiffness/damping/friction act in the plant and are not "
            "in the controller's model"
        )
    if mj.neq > 0:
        notes.append(f"{where}: {mj.neq} equality constraint(s) act in the plant and are not in the controller's model")
    return notes
