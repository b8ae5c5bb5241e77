"""The links and frames of a robot file, as a tree: what a user can pick as base, tip and end effector."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import pinocchio as pin

from reflexarm.robots._cut import _frame_ancestors
from reflexarm.robots._loading import build_tree_model

__all__ = ["FileFrame", "list_frames"]


@dataclass(frozen=True)
class FileFrame:
    """One link (or other named frame, e.g. an MJCF site) of a robot file.

    Attributes:
        name: the frame's name (a link's name for links).
        kind: ``"link"`` or ``"frame"`` (a site or other frame fixed on ``parent``).
        parent: the link it hangs from (``None`` for the root link).
        joint: the moving joint directly before it (``None`` if fixed to ``parent``).
        depth: number of moving joints between the root and it.
        children: number of links hanging directly from it (0 for a leaf, 2 or more at a branch).
    """

    name: str
    kind: str
    parent: str | None
    joint: str | None
    depth: int
    children: int

    @property
    def is_leaf(self) -> bool:
        return self.kind == "link" and self.children == 0

    @property
    def is_branch(self) -> bool:
        return self.children > 1


def list_frames(path: str | os.PathLike[str]) -> list[FileFrame]:
    """Every link and named frame of a URDF/MJCF file, root first, in the file's (depth-first) order."""
    model, _ = build_tree_model(Path(path))
    body = pin.FrameType.BODY
    wanted = [i for i, f in enumerate(model.frames) if f.type in (body, pin.FrameType.OP_FRAME) and i != 0]

    def parent_link(i: int) -> int | None:
        up = [a for a in _frame_ancestors(model, i)[1:] if model.frames[a].type == body]
        return up[0] if up else None

    parents = {i: parent_link(i) for i in wanted}
    out = []
    for i in wanted:
        f = model.frames[i]
        p = parents[i]
        moved = p is None or model.frames[p].parentJoint != f.parentJoint
        joint = int(f.parentJoint)
        out.append(
            FileFrame(
                name=str(f.name),
                kind="link" if f.type == body else "frame",
                parent=None if p is None else str(model.frames[p].name),
                joint=str(model.names[joint]) if moved and joint > 0 else None,
                depth=sum(1 for j in model.supports[joint] if j > 0),
                children=sum(1 for k in wanted if parents[k] == i and model.frames[k].type == body),
            )
        )
    return out
