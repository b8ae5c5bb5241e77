"""The ROS 2 JointState array layout of topic-echo and bag-to-CSV exports (``name.0``, ``position.0`` or
``position[0]``, ...), for :mod:`reflexarm.logs.columns`."""

from __future__ import annotations

import re
from dataclasses import dataclass

from reflexarm.errors import DataError

_MEANING = {
    "q": "position",
    "dq": "velocity",
    "tau": "measured torque",
    "ddq": "acceleration",
    "current": "motor current",
}
_STATE_FIELD = {"q": "position", "dq": "velocity", "tau": "effort"}
_ARRAY_RE = re.compile(r"^(?:.*\.)?(name|position|velocity|effort)\.?(\d+)$")


def _norm(name: str) -> str:
    return re.sub(r"\[(\d+)\]", r".\1", name.strip().lower().replace("/", ".")).strip(".")


@dataclass(frozen=True)
class JointStateLayout:
    """The JointState array layout: ``fields[signal][k]`` is the column of array element k; ``names[k]``
    the column of the joint name of element k (empty: element k is joint k of the model)."""

    names: tuple[str, ...]
    fields: dict[str, tuple[str, ...]]


def _find_layout(columns: list[str]) -> JointStateLayout | None:
    names: dict[int, str] = {}
    fields: dict[str, dict[int, str]] = {}
    for c in columns:
        m = _ARRAY_RE.match(_norm(c))
        if m is None:
            continue
        k = int(m.group(2))
        if m.group(1) == "name":
            names[k] = c
        else:
            sig = {v: s for s, v in _STATE_FIELD.items()}[m.group(1)]
            fields.setdefault(sig, {})[k] = c
    if "q" not in fields:
        return None
    size = max(max(f) for f in fields.values()) + 1
    return JointStateLayout(
        names=tuple(names[k] for k in sorted(names)) if names else (),
        fields={s: tuple(f[k] for k in sorted(f)) for s, f in fields.items() if len(f) == size},
    )


def _use_layout(
    layout: JointStateLayout, signals: list[str], n: int, joint_names: tuple[str, ...] | None, where: str
) -> tuple[JointStateLayout, str]:
    size = len(layout.fields["q"])
    for s in signals:
        if len(layout.fields[s]) != size:
            raise DataError(f"{where}: JointState {_STATE_FIELD[s]} columns have {len(layout.fields[s])} elements, "
                            f"position has {size}")  # fmt: skip
    fields = {s: layout.fields[s] for s in signals}
    if layout.names:
        if len(layout.names) != size:
            raise DataError(f"{where}: {len(layout.names)} JointState name columns for {size} position columns")
        note = (
            f"{where}: {', '.join(_MEANING[s] for s in signals)} from the JointState layout "
            f"({layout.fields['q'][0]}, ..., joint names in {layout.names[0]}, ...), mapped by name row by row"
        )
        return JointStateLayout(layout.names, fields), note
    if size != n:
        raise DataError(
            f"{where}: the JointState columns hold {size} joints ({layout.fields['q'][0]} ..); the robot has {n}"
        )
    note = (
        f"{where}: {', '.join(_MEANING[s] for s in signals)} from the JointState layout ({layout.fields['q'][0]}, ...) "
        "without name columns: element k taken as joint k + 1 of the model"
    )
    return JointStateLayout((), fields), note
