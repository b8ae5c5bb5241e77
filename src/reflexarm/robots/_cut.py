"""Cutting a serial arm out of a robot tree (private): base and tip links, every other joint locked.

The controller's model is Pinocchio's reduced model (``pin.buildReducedModel``): the joints off the
base..tip chain are locked at given positions and the bodies they carried stay, rigidly attached at that
configuration, with their mass (a gripper beyond the tip adds to the last link; links before the base
and other limbs become part of the fixed world). A floating base (a free joint) is fixed where the file
puts it. The plant does the same to its MjSpec (:func:`freeze_joints`): each locked joint is deleted and
its body's frame moved by the joint's motion at the locked position, so both models are one robot.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

from reflexarm.errors import ModelError
from reflexarm.robots._coupling import Mimic, coupling_notes

__all__ = ["ChainCut", "cut_chain", "frame_notes", "freeze_joints", "link_names", "needs_cut"]


@dataclass(frozen=True)
class ChainCut:
    """Where an arm was cut out of its robot file.

    Attributes:
        base: link the arm starts from (fixed in the world).
        tip: last link of the arm.
        locked: joint name -> position [rad or m] at which each joint off the chain is held (a free
            joint is held at the file's pose and listed with ``nan``).
        notes: what the cut changed that a user should know (clipped locks, a fixed floating base).
        beyond_tip: frame name -> the locked joints between the tip link and that frame, for each frame
            that hangs below the tip behind a locked joint (a finger link of a cut-off gripper).
    """

    base: str
    tip: str
    locked: Mapping[str, float]
    notes: tuple[str, ...] = field(default=())
    beyond_tip: Mapping[str, tuple[str, ...]] = field(default_factory=dict)

    def as_dict(self) -> dict[str, object]:
        """``{"base", "tip", "locked"}``, JSON-ready (free joints omitted from ``locked``)."""
        return {
            "base": self.base,
            "tip": self.tip,
            "locked": {k: float(v) for k, v in self.locked.items() if np.isfinite(v)},
        }


def link_names(model: pin.Model) -> list[str]:
    """Names of the body (link) frames, in the model's order."""
    return [f.name for f in model.frames if f.type == pin.FrameType.BODY]


def needs_cut(model: pin.Model) -> bool:
    """Whether the model is something other than a fixed-base serial chain of 1-DoF joints."""
    return any(model.nvs[j] != 1 or model.parents[j] != j - 1 for j in range(1, model.njoints))


def _body_frame(model: pin.Model, link: str, role: str, where: str) -> int:
    if link == model.frames[0].name:  # the world (MJCF: when the first body already moves)
        return 0
    if not model.existFrame(link, pin.FrameType.BODY):
        raise ModelError(f"unknown {role} link {link!r}{where}; links are: {', '.join(link_names(model))}")
    return int(model.getFrameId(link, pin.FrameType.BODY))


def _frame_ancestors(model: pin.Model, fid: int) -> list[int]:
    """Frame ids from ``fid`` up to the universe frame (inclusive)."""
    out = [fid]
    while out[-1] != 0 and len(out) <= len(model.frames):
        out.append(int(model.frames[out[-1]].parentFrame))
    return out


def _root_link(model: pin.Model, tip_fid: int) -> str:
    """The default base: the root link, or the link a floating-base joint carries (the tip's first link
    below its last free joint)."""
    bodies = [f for f in _frame_ancestors(model, tip_fid) if model.frames[f].type == pin.FrameType.BODY]
    free = [j for j in model.supports[model.frames[tip_fid].parentJoint] if j > 0 and model.nvs[j] != 1]
    if free:
        bodies = [f for f in bodies if model.frames[f].parentJoint == free[-1]] or bodies
    elif model.frames[bodies[-1]].parentJoint != 0:  # an MJCF whose first body moves: the arm starts at the world
        return str(model.frames[0].name)
    return str(model.frames[bodies[-1]].name)


def _leaves(model: pin.Model, below_joint: int) -> list[str]:
    """Links of the subtree of ``below_joint`` that no other link hangs from."""
    bodies = [i for i, f in enumerate(model.frames) if f.type == pin.FrameType.BODY]
    inner = {a for i in bodies for a in _frame_ancestors(model, i)[1:]}
    return [
        model.frames[i].name
        for i in bodies
        if i not in inner and below_joint in model.supports[model.frames[i].parentJoint]
    ]


def _chain_joints(model: pin.Model, base: str, tip: str, where: str) -> list[int]:
    base_fid = _body_frame(model, base, "base", where)
    tip_fid = _body_frame(model, tip, "tip", where)
    if base_fid not in _frame_ancestors(model, tip_fid):
        raise ModelError(
            f"tip link {tip!r}{where} does not hang below base link {base!r}: the path from the root to {tip!r} "
            f"is {' -> '.join(reversed([model.frames[f].name for f in _frame_ancestors(model, tip_fid)[:-1]]))}"
        )
    above = set(model.supports[model.frames[base_fid].parentJoint])
    chain = [int(j) for j in model.supports[model.frames[tip_fid].parentJoint] if j not in above]
    if not chain:
        raise ModelError(f"no joint moves between base link {base!r} and tip link {tip!r}{where}")
    for j in chain:
        if model.nvs[j] != 1:
            raise ModelError(
                f"joint {model.names[j]!r} between {base!r} and {tip!r}{where} has {model.nvs[j]} DoF; the arm's "
                "joints must be 1-DoF (revolute or prismatic)"
            )
    return chain


def cut_chain(
    model: pin.Model,
    *,
    base: str | None,
    tip: str | None,
    locked: Mapping[str, float] | None,
    defaults: Mapping[str, float],
    path: Path,
    couplings: Mapping[str, Mimic] | None = None,
) -> tuple[pin.Model, ChainCut, list[int]]:
    """The reduced model of the base..tip chain, the cut's description and the chain's joint ids in
    ``model`` (in order).

    ``locked`` positions override ``defaults`` (e.g. the file's "home" keyframe), which override 0 (for
    the follower of a locked joint in ``couplings``, a URDF ``<mimic>``: its position for the leader's
    lock); each is clipped to the joint's limits with a note, and couplings the cut does not keep are
    named in a note (see ``_coupling.py``). With ``tip=None`` the model must be serial apart from a
    floating base (which is then fixed) and the tip is its last link; ``base=None`` starts the arm at the
    root link (or the link a floating base carries).

    Raises:
        ModelError: unknown link or joint, a tip not below the base, a lock on a chain joint, a tree
            without ``tip``.
    """
    where = f" in {str(path)!r}"
    if tip is None:
        free = [j for j in range(1, model.njoints) if model.nvs[j] != 1]
        serial = all(model.parents[j] == j - 1 for j in range(1, model.njoints))
        if not serial or free not in ([], [1]):
            first = 0 if base is None else model.frames[_body_frame(model, base, "base", where)].parentJoint
            raise ModelError(
                f"robot{where} is not a serial chain{'' if base is None else f' below {base!r}'}: name the arm's "
                f"tip link (tip=..., --tip); leaf links are: {', '.join(_leaves(model, int(first)))}"
            )
        tip = max(link_names(model), key=lambda name: int(model.frames[model.getFrameId(name)].parentJoint))
    if base is None:
        base = _root_link(model, _body_frame(model, tip, "tip", where))
    chain = _chain_joints(model, base, tip, where)
    names = list(model.names)
    unknown = sorted(set(locked or {}) - set(names[1:]))
    if unknown:
        raise ModelError(f"cannot lock unknown joint(s) {unknown}{where}; joints are: {', '.join(names[1:])}")
    on_chain = sorted({names[j] for j in chain} & set(locked or {}))
    if on_chain:
        raise ModelError(
            f"joint(s) {on_chain} are on the arm from {base!r} to {tip!r}{where}; only joints off the chain can be "
            "locked"
        )
    q_ref, values, notes = _lock_values(model, chain, locked or {}, defaults, where, couplings or {})
    notes += coupling_notes(couplings or {}, {names[j] for j in chain}, values, where)
    base_fid = _body_frame(model, base, "base", where)
    base_joint = model.frames[base_fid].parentJoint
    below_root = [names[j] for j in model.supports[base_joint] if j > 0 and model.nvs[j] == 1]
    if below_root:
        up = _frame_ancestors(model, base_fid)
        root = str(model.frames[[f for f in up if model.frames[f].type == pin.FrameType.BODY][-1]].name)
        notes.append(
            f"robot{where}: the arm's base link {base!r} is held fixed in the world (the world frame is the root "
            f"link {root!r}'s); the joint(s) between them {below_root} are locked like the others"
        )
    lock_ids = [j for j in range(1, model.njoints) if j not in chain]
    reduced = pin.buildReducedModel(model, lock_ids, q_ref) if lock_ids else model.copy()
    reduced.name = model.name
    return reduced, ChainCut(base, tip, values, tuple(notes), _beyond_tip(model, tip)), chain


def _beyond_tip(model: pin.Model, tip: str) -> dict[str, tuple[str, ...]]:
    """Frames below the tip link behind a joint (which the cut locks), with those joints."""
    tip_fid = int(model.getFrameId(tip, pin.FrameType.BODY))
    tip_joint = int(model.frames[tip_fid].parentJoint)
    out = {}
    for fid, frame in enumerate(model.frames):
        if tip_fid not in _frame_ancestors(model, fid) or fid == tip_fid:
            continue
        between = [str(model.names[j]) for j in model.supports[frame.parentJoint] if j > tip_joint]
        if between:
            out[str(frame.name)] = tuple(between)
    return out


def _lock_values(
    model: pin.Model,
    chain: list[int],
    locked: Mapping[str, float],
    defaults: Mapping[str, float],
    where: str,
    couplings: Mapping[str, Mimic],
) -> tuple[np.ndarray, dict[str, float], list[str]]:
    """The reference configuration of the reduction, the lock of each joint off the chain (``nan`` for a
    free or ball joint, held at its neutral pose) and notes (clipped locks, fixed floating bases).
    Followers of a coupling come after their leaders."""
    q_ref = pin.neutral(model)
    values: dict[str, float] = {}
    notes: list[str] = []
    off_chain = [j for j in range(1, model.njoints) if j not in chain]
    for j in sorted(off_chain, key=lambda j: str(model.names[j]) in couplings):
        name = str(model.names[j])
        if model.nqs[j] != 1:
            if name in locked:
                raise ModelError(
                    f"joint {name!r}{where} has {model.nqs[j]} coordinates; it cannot be locked at a value"
                )
            values[name] = float("nan")
            notes.append(
                f"robot{where}: the floating base joint {name!r} is fixed at the file's pose (the arm's base does "
                "not move)"
                if model.nvs[j] == 6
                else f"robot{where}: joint {name!r} ({model.nvs[j]} DoF) is locked at its neutral position"
            )
            continue
        iq = model.idx_qs[j]
        wanted = float(locked.get(name, defaults.get(name, 0.0)))
        coupling = couplings.get(name)
        if coupling is not None and name not in locked and coupling.leader in values:
            wanted = coupling.offset + coupling.multiplier * values[coupling.leader]
        lo, hi = float(model.lowerPositionLimit[iq]), float(model.upperPositionLimit[iq])
        value = float(np.clip(wanted, lo, hi))
        if value != wanted:
            notes.append(
                f"robot{where}: joint {name!r} locked at {value:g} (its limit) instead of {wanted:g}; limits "
                f"[{lo:g}, {hi:g}]"
            )
        q_ref[iq] = value
        values[name] = value
    return q_ref, values, notes


def frame_notes(model: pin.Model, frames: tuple[str, str], cut: ChainCut | None, path: Path) -> tuple[str, ...]:
    """Refuse an end-effector or sensor frame (``frames``) of the arm's model that does not move with the arm;
    explain one past the tip of ``cut``.

    Raises:
        ModelError: the frame is fixed in the world (on the base, or on another limb of a cut robot).
    """
    notes = []
    labels = {frames[0]: "end-effector and sensor" if frames[0] == frames[1] else "end-effector"}
    labels.setdefault(frames[1], "sensor")
    for frame, label in labels.items():
        if model.frames[model.getFrameId(frame)].parentJoint == 0:
            raise ModelError(
                f"the {label} frame {frame!r} of {str(path)!r} does not move with the arm (it is fixed in the "
                "world: on the base, or off the arm cut out of the file); name a frame on the arm (`reflexarm robots "
                "FILE` lists them)"
            )
        behind = cut.beyond_tip.get(frame) if cut is not None else None
        if behind and cut is not None:
            notes.append(
                f"robot in {str(path)!r}: the {label} frame {frame!r} lies past the tip link {cut.tip!r}, behind the "
                f"locked joint(s) {list(behind)}: it moves rigidly with {cut.tip!r}, where the locks put it"
            )
    return tuple(notes)


# ---------------------------------------------------------------------- the plant's side
def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    return np.asarray(pin.AngleAxis(angle, axis / np.linalg.norm(axis)).matrix())


def freeze_joints(spec: mujoco.MjSpec, values: Mapping[str, float], path: Path) -> None:
    """Delete the joints ``values`` names from ``spec``, moving each body by its joints' motion at the
    locked positions (``nan``: a free/ball joint, left at the file's pose); keyframes, the actuators and
    sensors of those joints and joint equalities follow.

    Raises:
        ModelError: MuJoCo has no such joint, or a body mixes locked and moving joints.
    """
    if not values:
        return
    where = f"robot file {str(path)!r}"
    try:
        mj = spec.compile()
    except Exception as e:
        raise ModelError(f"MuJoCo cannot compile {where}: {e}") from e
    named = {name: float(v) for name, v in values.items() if np.isfinite(v)}
    missing = [name for name in named if spec.joint(name) is None]
    if missing:
        joints = [j.name for j in spec.joints]
        raise ModelError(f"{where}: MuJoCo has no joint(s) {missing} to lock; its joints are {joints}")
    # free and ball joints (Pinocchio names them itself; MuJoCo's may be unnamed) are never on the arm
    multi = (int(mujoco.mjtJoint.mjJNT_FREE), int(mujoco.mjtJoint.mjJNT_BALL))
    frozen = {j for j in range(mj.njnt) if mj.joint(j).name in named or int(mj.jnt_type[j]) in multi}
    by_body: dict[str, list[int]] = {}
    for j in sorted(frozen):
        by_body.setdefault(mj.body(int(mj.jnt_bodyid[j])).name, []).append(j)
    for body_name, jids in by_body.items():
        body = spec.body(body_name)
        joints = list(body.joints)
        if len(joints) != len(jids):
            moving = [j.name for j in joints if j.name not in named]
            raise ModelError(
                f"{where}: body {body_name!r} has locked joints and moving joint(s) {moving}; lock all or none of them"
            )
        bid = mj.body(body_name).id
        R = np.asarray(pin.Quaternion(*mj.body_quat[bid]).matrix())  # (w, x, y, z)
        p = np.array(mj.body_pos[bid], dtype=float)
        for joint, jid in zip(joints, jids, strict=True):  # the spec's order is the compiled order
            kind = int(mj.jnt_type[jid])
            motion = named.get(joint.name, 0.0) - float(mj.qpos0[mj.jnt_qposadr[jid]])
            anchor, axis = np.array(mj.jnt_pos[jid]), np.array(mj.jnt_axis[jid])
            if kind == int(mujoco.mjtJoint.mjJNT_HINGE):
                Rj = _rotation(axis, motion)
                p, R = p + R @ (anchor - Rj @ anchor), R @ Rj
            elif kind == int(mujoco.mjtJoint.mjJNT_SLIDE):
                p = p + R @ axis * motion
            spec.delete(joint)
        if body.frame is not None:
            raise ModelError(f"{where}: body {body_name!r} sits in a <frame>; locking its joints is not supported")
        quat = pin.Quaternion(R)
        body.pos = p
        body.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT
        body.quat = np.array([quat.w, quat.x, quat.y, quat.z])
    _drop_what_refers_to(spec, mj, frozen)


def _drop_what_refers_to(spec: mujoco.MjSpec, mj: mujoco.MjModel, frozen: set[int]) -> None:
    """Delete from ``spec`` what refers to the deleted joints ``frozen`` (compiled ids): their motors and
    sensors, joint equalities (a URDF ``<mimic>``), fixed tendons over them (a gripper's coupling tendon)
    with the actuators, sensors and equalities of those tendons; keyframes keep the rest."""
    tendons = {
        t
        for t in range(mj.ntendon)
        for w in range(int(mj.tendon_adr[t]), int(mj.tendon_adr[t] + mj.tendon_num[t]))
        if int(mj.wrap_type[w]) == int(mujoco.mjtWrap.mjWRAP_JOINT) and int(mj.wrap_objid[w]) in frozen
    }
    moves = {int(mujoco.mjtTrn.mjTRN_JOINT): frozen, int(mujoco.mjtTrn.mjTRN_JOINTINPARENT): frozen}
    moves[int(mujoco.mjtTrn.mjTRN_TENDON)] = tendons
    driven = [a for a in range(mj.nu) if int(mj.actuator_trnid[a, 0]) in moves.get(int(mj.actuator_trntype[a]), ())]
    for actuator in [spec.actuators[a] for a in driven]:  # motors of locked joints go with them
        spec.delete(actuator)
    _remap_keys(spec, mj, [j for j in range(mj.njnt) if j not in frozen], [a for a in range(mj.nu) if a not in driven])
    joint_names = {mj.joint(j).name for j in frozen}
    tendon_names = {mj.tendon(t).name for t in tendons}
    for sensor in list(spec.sensors):
        gone = joint_names if sensor.objtype == mujoco.mjtObj.mjOBJ_JOINT else set()
        gone = tendon_names if sensor.objtype == mujoco.mjtObj.mjOBJ_TENDON else gone
        if sensor.objname in gone:
            spec.delete(sensor)
    for eq in list(spec.equalities):  # a URDF <mimic> comes as a joint equality whose objtype is left unset
        gone = joint_names if eq.type == mujoco.mjtEq.mjEQ_JOINT else set()
        gone = tendon_names if eq.type == mujoco.mjtEq.mjEQ_TENDON else gone
        if {eq.name1, eq.name2} & gone:
            spec.delete(eq)
    for tendon in [spec.tendons[t] for t in sorted(tendons)]:
        spec.delete(tendon)


def _remap_keys(spec: mujoco.MjSpec, mj: mujoco.MjModel, kept: list[int], kept_actuators: list[int]) -> None:
    """Keep, in each keyframe, the qpos/qvel entries of the joints and the ctrl of the actuators that stay."""
    sizes = {int(mujoco.mjtJoint.mjJNT_FREE): (7, 6), int(mujoco.mjtJoint.mjJNT_BALL): (4, 3)}
    qidx: list[int] = []
    vidx: list[int] = []
    for j in kept:
        nq, nv = sizes.get(int(mj.jnt_type[j]), (1, 1))
        qidx += range(int(mj.jnt_qposadr[j]), int(mj.jnt_qposadr[j]) + nq)
        vidx += range(int(mj.jnt_dofadr[j]), int(mj.jnt_dofadr[j]) + nv)
    for key in spec.keys:
        if len(key.qpos) == mj.nq:
            key.qpos = np.asarray(key.qpos)[qidx]
        if len(key.qvel) == mj.nv:
            key.qvel = np.asarray(key.qvel)[vidx]
        if len(key.ctrl) == mj.nu:
            key.ctrl = np.asarray(key.ctrl)[kept_actuators]
