"""Building the controller's Pinocchio model from a URDF or MJCF file, faithfully (private).

- URDF ``continuous`` joints: Pinocchio builds them as unbounded revolute joints (cos/sin, nq=2, nv=1).
  A real arm and MuJoCo report such a joint as one angle, so they are read as revolute joints with the
  same axis and infinite position limits (nq = nv = 1); their effort and velocity limits are kept.
  Joints leading to links the file does not define are dropped (see ``_urdf.py``).
- MJCF: the joint facts both sides must share (armature, damping, frictionloss, springs, effort limits,
  gravity) come from MuJoCo's compiled model (see ``_mjcf.py``); a joint-less root body's placement,
  which Pinocchio's parser drops, is restored; then M(q) and g(q) are compared with MuJoCo's, so a
  construct one parser reads differently from the other is refused instead of silently giving two
  different robots.
- A tree (humanoid, arm + gripper) or a floating base is cut to the base..tip chain, the other joints
  locked (see ``_cut.py``); for MJCF the agreement check runs on the cut model against MuJoCo's model
  with the same joints frozen.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

from reflexarm.errors import ModelError
from reflexarm.robots._coupling import coupling_notes, mjcf_couplings, urdf_mimics
from reflexarm.robots._cut import ChainCut, cut_chain, freeze_joints, needs_cut
from reflexarm.robots._mjcf import compile_mjcf, joint_facts, load_mjcf_spec
from reflexarm.robots._urdf import UrdfFile, mujoco_urdf, read_urdf

__all__ = ["LoadedFile", "build_pinocchio_model"]

#: Finite stand-in for an unbounded position limit while Pinocchio parses the rewritten URDF (urdfdom
#: refuses "inf"); replaced by +-inf right after parsing.
_UNBOUNDED = 1e300

#: M(q) and g(q) of Pinocchio and MuJoCo must agree to this relative tolerance (relative to the largest
#: entry, floor 1). Both evaluate the same exact expressions in double precision (~1e-14 observed); a
#: misread placement, axis, inertia or armature shows up at 1e-3 or more.
AGREEMENT_RTOL = 1e-8

#: The MJCF keyframe whose joint positions are the default locks of a cut.
HOME_KEYFRAME = "home"


@dataclass
class LoadedFile:
    """What a file gives beyond the Pinocchio model: joint springs, notes for the user, the cut."""

    spring_stiffness: np.ndarray
    spring_reference: np.ndarray
    notes: list[str] = field(default_factory=list)
    cut: ChainCut | None = None


def build_pinocchio_model(
    path: Path,
    *,
    base: str | None = None,
    tip: str | None = None,
    locked: Mapping[str, float] | None = None,
) -> tuple[pin.Model, LoadedFile]:
    """The Pinocchio model of a URDF or MJCF file (cut to ``base``..``tip`` when given, or when the file
    has a floating base) and the file's joint springs and notes."""
    if not path.is_file():
        raise ModelError(f"robot file {str(path)!r} does not exist")
    suffix = path.suffix.lower()
    if suffix == ".urdf":
        urdf = read_urdf(path)
        model, limit_notes = _build_urdf(urdf)
        notes = urdf.notes + limit_notes + mujoco_urdf(urdf).notes
        couplings = urdf_mimics(urdf.root, path)
        cut = None
        if base is not None or tip is not None or locked or needs_cut(model):
            model, cut, _ = cut_chain(
                model, base=base, tip=tip, locked=locked, defaults={}, path=path, couplings=couplings
            )
            notes += cut.notes
        else:
            notes += coupling_notes(couplings, list(model.names)[1:], {}, f" in {str(path)!r}")
        return model, LoadedFile(np.zeros(model.nv), np.zeros(model.nv), notes, cut)
    if suffix in (".xml", ".mjcf"):
        return _build_mjcf(path, base, tip, locked)
    raise ModelError(f"robot file {str(path)!r}: unknown format {suffix!r}; use .urdf or MJCF .xml")


def build_tree_model(path: Path) -> tuple[pin.Model, list[str]]:
    """The whole file's Pinocchio model, uncut and unchecked (to list its links), and the file's notes."""
    if not path.is_file():
        raise ModelError(f"robot file {str(path)!r} does not exist")
    if path.suffix.lower() == ".urdf":
        urdf = read_urdf(path)
        model, limit_notes = _build_urdf(urdf)
        return model, urdf.notes + limit_notes
    try:
        return pin.buildModelFromMJCF(str(path)), []
    except Exception as e:
        raise ModelError(f"cannot parse robot file {str(path)!r}: {e}") from e


# ---------------------------------------------------------------------- URDF
def _build_urdf(urdf: UrdfFile) -> tuple[pin.Model, list[str]]:
    """The Pinocchio model of a URDF with continuous joints and the open sides of ``<limit>`` elements
    without lower/upper unbounded (see :func:`_open_limits`), and notes on the latter."""
    path = urdf.path
    open_sides = _open_limits(urdf.root)
    continuous = {str(j.get("name")) for j in urdf.root.iter("joint") if j.get("type") == "continuous"}
    try:
        if not continuous and not open_sides:
            return pin.buildModelFromXML(urdf.text), []
        original = pin.buildModelFromXML(urdf.text)
        rewritten = UrdfFile(path, ET.fromstring(urdf.text))
        for joint in rewritten.root.iter("joint"):
            name = str(joint.get("name"))
            sides = ("lower", "upper") if name in continuous else open_sides.get(name, ())
            if not sides:
                continue
            joint.set("type", "revolute" if name in continuous else str(joint.get("type")))
            limit = joint.find("limit")
            if limit is None:
                limit = ET.SubElement(joint, "limit", effort="1", velocity="1")
            for side in sides:
                limit.set(side, repr(-_UNBOUNDED if side == "lower" else _UNBOUNDED))
        model = pin.buildModelFromXML(rewritten.text)
    except Exception as e:  # pinocchio raises RuntimeError/ValueError with terse text
        raise ModelError(f"cannot parse robot file {str(path)!r}: {e}") from e
    for j in range(1, model.njoints):
        name = str(model.names[j])
        sides = ("lower", "upper") if name in continuous else open_sides.get(name, ())
        iq, iv, jo = model.idx_qs[j], model.idx_vs[j], original.getJointId(name)
        if "lower" in sides:
            model.lowerPositionLimit[iq] = -np.inf
        if "upper" in sides:
            model.upperPositionLimit[iq] = np.inf
        if sides:
            ov = original.idx_vs[jo]
            model.effortLimit[iv] = original.effortLimit[ov]
            model.velocityLimit[iv] = original.velocityLimit[ov]
    notes = [
        f"robot file {str(path)!r}: joint {name!r} has a <limit> without {' and '.join(sides)}, which URDF reads as "
        f"0 (a range of [{'0' if 'lower' in sides else 'lower'}, {'0' if 'upper' in sides else 'upper'}]: "
        f"{'the joint could not move' if len(sides) > 1 else 'maybe not what was meant'}); the controller's model "
        f"and the plant take it as unbounded {_SIDE_WORDS[sides]} (MuJoCo's URDF reader sets no limit either); give "
        f"{' and '.join(f'{side}=' for side in sides)} if the joint has a range (excite keeps the motion within it)"
        for name, sides in open_sides.items()
    ]
    return model, notes


_SIDE_WORDS = {("lower",): "below", ("upper",): "above", ("lower", "upper"): "both ways"}


def _open_limits(root: ET.Element) -> dict[str, tuple[str, ...]]:
    """Revolute and prismatic joints whose ``<limit>`` lacks ``lower`` and/or ``upper``, with the sides missing.

    URDF defaults them to 0 (a revolute joint with neither would be held in [0, 0]); MuJoCo's URDF reader
    leaves such a joint unlimited. Both models take the missing side as unbounded, with a note.
    """
    out = {}
    for joint in root.iter("joint"):
        limit = joint.find("limit")
        if joint.get("type") not in ("revolute", "prismatic") or limit is None:
            continue
        sides = tuple(side for side in ("lower", "upper") if limit.get(side) is None)
        if sides:
            out[str(joint.get("name"))] = sides
    return out


# ---------------------------------------------------------------------- MJCF
def _build_mjcf(
    path: Path, base: str | None, tip: str | None, locked: Mapping[str, float] | None
) -> tuple[pin.Model, LoadedFile]:
    try:
        model = pin.buildModelFromMJCF(str(path))
    except Exception as e:
        raise ModelError(f"cannot parse robot file {str(path)!r}: {e}") from e
    mj, notes = compile_mjcf(path)
    _align_mjcf_root(model, mj, path)
    one_dof = [j for j in range(1, model.njoints) if model.nqs[j] == 1 and model.nvs[j] == 1]
    if any(model.nvs[j] not in (1, 6) for j in range(1, model.njoints)):
        return model, LoadedFile(np.zeros(model.nv), np.zeros(model.nv), notes)  # RobotModel refuses it
    names = [model.names[j] for j in one_dof]
    facts = joint_facts(mj, names, path)
    iv = [model.idx_vs[j] for j in one_dof]
    iq = [model.idx_qs[j] for j in one_dof]
    passive = (("armature", facts.armature), ("damping", facts.damping), ("friction", facts.frictionloss))
    for attribute, values in passive:
        column = np.asarray(getattr(model, attribute), dtype=float).copy()
        column[iv] = values
        setattr(model, attribute, column)
    model.gravity.linear = facts.gravity
    lower, upper = model.lowerPositionLimit.copy(), model.upperPositionLimit.copy()
    lower[iq], upper[iq] = facts.lower_limit, facts.upper_limit
    model.lowerPositionLimit, model.upperPositionLimit = lower, upper
    given = np.isfinite(facts.effort_limit)
    limits = np.asarray(model.effortLimit, dtype=float).copy()
    limits[np.asarray(iv)[given]] = facts.effort_limit[given]
    model.effortLimit = limits
    notes += facts.notes
    stiffness = dict(zip(names, facts.stiffness, strict=True))
    springref = dict(zip(names, facts.springref, strict=True))
    couplings = mjcf_couplings(mj)
    if base is None and tip is None and not locked and not needs_cut(model):
        _check_agreement(model, mj, names, path)
        notes += coupling_notes(couplings, names, {}, f" in {str(path)!r}")
        return model, LoadedFile(facts.stiffness, facts.springref, notes)
    reduced, cut, chain = cut_chain(
        model, base=base, tip=tip, locked=locked, defaults=_home(mj), path=path, couplings=couplings
    )
    spec = load_mjcf_spec(path)[0]  # its notes were given with compile_mjcf's
    freeze_joints(spec, cut.locked, path)
    try:
        frozen = spec.compile()
    except Exception as e:
        raise ModelError(
            f"MuJoCo cannot compile robot file {str(path)!r} with the joints off the arm locked: {e}"
        ) from e
    chain_names = [model.names[j] for j in chain]
    _check_agreement(reduced, frozen, chain_names, path)
    return reduced, LoadedFile(
        np.array([stiffness[n] for n in chain_names]),
        np.array([springref[n] for n in chain_names]),
        notes + list(cut.notes),
        cut,
    )


def _home(mj: mujoco.MjModel) -> dict[str, float]:
    """1-DoF joint positions of the file's "home" keyframe (empty without one)."""
    kid = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_KEY, HOME_KEYFRAME)
    if kid < 0:
        return {}
    qpos = mj.key_qpos[kid]
    hinge_slide = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    return {
        mj.joint(j).name: float(qpos[mj.jnt_qposadr[j]]) for j in range(mj.njnt) if int(mj.jnt_type[j]) in hinge_slide
    }


def _align_mjcf_root(model: pin.Model, mj: mujoco.MjModel, path: Path) -> None:
    """Restore the placement of a fixed (joint-less) root body that Pinocchio's MJCF parser drops.

    ``pin.buildModelFromMJCF`` ignores ``pos``/``quat`` of a joint-less body directly under
    ``<worldbody>``: a torso mounted at a height or tilted would silently get wrong frame poses and,
    if rotated, wrong gravity torques. MuJoCo's world pose of the first moving body is the reference. The
    correction is applied to the first joint and every frame attached to the universe, then all body
    frames are checked against MuJoCo at q = 0.
    """
    mj_data = mujoco.MjData(mj)
    mujoco.mj_kinematics(mj, mj_data)
    data = model.createData()
    q0 = pin.neutral(model)
    pin.framesForwardKinematics(model, data, q0)

    def mj_pose(name: str) -> pin.SE3 | None:
        bid = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_BODY, name)
        if bid < 0:
            return None
        return pin.SE3(mj_data.xmat[bid].reshape(3, 3).copy(), mj_data.xpos[bid].copy())

    if model.njoints > 1:
        first_body = next((f for f in model.frames if f.type == pin.FrameType.BODY and f.parentJoint == 1), None)
        ref = mj_pose(first_body.name) if first_body is not None else None
        if ref is not None and first_body is not None:
            fid = model.getFrameId(first_body.name)
            correction = ref * data.oMf[fid].inverse()
            if not correction.isIdentity(1e-12):
                model.jointPlacements[1] = correction * model.jointPlacements[1]
                for f in model.frames:
                    if f.parentJoint == 0 and f.name != "universe":
                        f.placement = correction * f.placement
                data = model.createData()
                pin.framesForwardKinematics(model, data, q0)
    for i, f in enumerate(model.frames):
        if f.type != pin.FrameType.BODY:
            continue
        ref = mj_pose(f.name)
        if ref is not None and not ref.isApprox(data.oMf[i], 1e-9):
            raise ModelError(
                f"robot file {str(path)!r}: Pinocchio and MuJoCo place body {f.name!r} differently "
                f"({data.oMf[i].translation.tolist()} vs {ref.translation.tolist()}); unsupported MJCF construct"
            )


def _check_agreement(model: pin.Model, mj: mujoco.MjModel, names: list[str], path: Path) -> None:
    """M(q) and g(q) of both readings at three seeded configurations inside the limits."""
    jids = [mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, n) for n in names]
    qadr, dofs = mj.jnt_qposadr[jids], mj.jnt_dofadr[jids]
    lo = np.where(np.isfinite(model.lowerPositionLimit), model.lowerPositionLimit, -np.pi)
    hi = np.where(np.isfinite(model.upperPositionLimit), model.upperPositionLimit, np.pi)
    rng = np.random.default_rng(0)
    d = mujoco.MjData(mj)
    data = model.createData()
    M_mj = np.zeros((mj.nv, mj.nv))
    for q in (np.zeros(model.nq), rng.uniform(lo, hi), rng.uniform(lo, hi)):
        d.qpos[:] = mj.qpos0
        d.qpos[qadr] = q
        d.qvel[:] = 0.0
        mujoco.mj_forward(mj, d)
        mujoco.mj_fullM(mj, d, M_mj)
        M = pin.crba(model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        g = pin.computeGeneralizedGravity(model, data, q)
        for label, a, b in (("M(q)", M, M_mj[np.ix_(dofs, dofs)]), ("g(q)", g, d.qfrc_bias[dofs])):
            err = float(np.abs(a - b).max())
            if not err <= AGREEMENT_RTOL * max(1.0, float(np.abs(b).max())):
                raise ModelError(
                    f"robot file {str(path)!r}: Pinocchio and MuJoCo read different dynamics ({label} differs by "
                    f"{err:.3g} at q={np.round(q, 4).tolist()}); an MJCF construct one of them does not support "
                    "(e.g. inertia from geoms, a ref angle, a non-serial structure)"
                )
