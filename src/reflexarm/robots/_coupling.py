"""Coupled joints (URDF ``<mimic>``, MJCF joint equalities) and how both models treat them (private).

MuJoCo turns a URDF ``<mimic joint="L" multiplier="m" offset="o"/>`` of joint F into the equality
constraint q_F = o + m q_L; Pinocchio's URDF reader (without ``mimic=True``) makes F an ordinary joint. The
controller's model drives every arm joint with its own motor, so the two models would be two different
robots (a plant holding F to L against the controller's torque shows up as an external torque: a false
collision). Both sides therefore do the same thing:

- a coupling whose joints are both off the arm (a gripper cut off with ``tip``): both joints are locked,
  the follower by default at ``o + m`` times its leader's lock (a closed gripper stays closed), and the
  constraint goes with the locked joints (``_cut.freeze_joints``);
- a coupling that involves an arm joint: the arm joint stays an independent joint driven by its own motor
  in the model and in the plant (``drop_joint_equalities`` removes the constraint from the plant), the
  other joint, if off the arm, stays at its lock; a note says so.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import NamedTuple

import mujoco

from reflexarm.errors import ModelError

__all__ = ["Mimic", "coupling_notes", "drop_joint_equalities", "mjcf_couplings", "urdf_mimics"]


class Mimic(NamedTuple):
    """Follower position = ``offset + multiplier * leader position`` [rad or m]."""

    leader: str
    multiplier: float
    offset: float


def urdf_mimics(root: ET.Element, path: Path) -> dict[str, Mimic]:
    """The ``<mimic>`` elements of a URDF by follower joint name.

    Raises:
        ModelError: a mimic without a leader joint, of a joint the file does not define, or with a
            multiplier or offset that is not a number.
    """
    joints = {j.get("name") for j in root.findall("joint")}
    out: dict[str, Mimic] = {}
    for joint in root.findall("joint"):
        mimic = joint.find("mimic")
        if mimic is None:
            continue
        name, leader = str(joint.get("name")), mimic.get("joint")
        where = f"robot file {str(path)!r}: joint {name!r}"
        if leader not in joints:
            raise ModelError(f"{where} mimics joint {leader!r}, which the file does not define")
        try:
            out[name] = Mimic(str(leader), float(mimic.get("multiplier", "1")), float(mimic.get("offset", "0")))
        except ValueError as e:
            raise ModelError(f"{where}: <mimic> multiplier/offset must be numbers ({e})") from e
    return out


def mjcf_couplings(mj: mujoco.MjModel) -> dict[str, Mimic]:
    """The compiled MJCF's active joint equalities (q_1 = c_0 + c_1 q_2 + ...) as :class:`Mimic` by
    joint1 name (leader ``""`` for an equality that holds joint1 at c_0 alone)."""
    out: dict[str, Mimic] = {}
    for e in range(mj.neq):
        if int(mj.eq_type[e]) != int(mujoco.mjtEq.mjEQ_JOINT) or not mj.eq_active0[e]:
            continue
        follower = mj.joint(int(mj.eq_obj1id[e])).name
        leader = mj.joint(int(mj.eq_obj2id[e])).name if mj.eq_obj2id[e] >= 0 else ""
        out[follower] = Mimic(leader, float(mj.eq_data[e, 1]), float(mj.eq_data[e, 0]))
    return out


def coupling_notes(
    couplings: Mapping[str, Mimic], arm: Collection[str], locked: Mapping[str, float], where: str
) -> list[str]:
    """What the models do with each coupling that involves an arm joint, or whose locks break it."""
    notes = []
    for follower, (leader, m, o) in couplings.items():
        rule = f"joint {follower!r} follows {leader!r} in the file (q = {o:g} + {m:g} q_{leader})"
        if not leader:
            rule = f"joint {follower!r} is held at {o:g} by a joint equality in the file"
        on_arm = [j for j in (follower, leader) if j in arm]
        if on_arm:
            rest = [j for j in (follower, leader) if j and j not in arm]
            held = f"; {rest[0]!r} is locked at {locked[rest[0]]:g}" if rest and rest[0] in locked else ""
            notes.append(
                f"robot{where}: {rule}; the arm joint(s) {on_arm} are independent joints driven by their own "
                f"motors in the controller's model and in the plant (the coupling is not modelled){held}"
            )
        elif follower in locked and leader in locked:
            coupled = o + m * locked[leader]
            if abs(locked[follower] - coupled) > 1e-9:
                notes.append(
                    f"robot{where}: {rule}; it is locked at {locked[follower]:g}, not at {coupled:g} as the "
                    f"coupling gives for {leader!r} at {locked[leader]:g}"
                )
    return notes


def drop_joint_equalities(spec: mujoco.MjSpec) -> None:
    """Remove the joint equalities left in a plant's spec once the joints off the arm are frozen: they
    couple arm joints, which the controller's model drives independently (see the module docstring)."""
    for eq in list(spec.equalities):
        if eq.type == mujoco.mjtEq.mjEQ_JOINT:
            spec.delete(eq)
