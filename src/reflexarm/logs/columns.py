"""Which column of a table log holds which signal: the schema, joint-named columns, ROS exports, a mapping.

A table log (CSV, Parquet) needs a time column and, per joint of the robot (in the model's order),
a position, a velocity and a measured torque; accelerations and the six wrist-wrench components are
optional. :func:`plan_columns` finds them, in this order for each signal:

1. an explicit **mapping** (``columns={"q": "position_{joint}", "t": "stamp_ns"}``, on the command line
   ``--columns q=position_{joint},t=stamp_ns``): a template per signal; ``{joint}`` is the joint's name,
   ``{i}`` its number from 1, ``{i0}`` its index from 0; for ``wrench`` ``{axis}`` is fx fy fz mx my mz
   and ``{ros_axis}`` force.x .. torque.z; ``t`` names a column. Or **positions** in the file, 0-based with
   the end excluded (``t=0,q=1:7,dq=7:13``; header-less files have nothing else), and a **scale** after
   ``*`` (``tau=trq_{i}*0.001``); parsed by :mod:`reflexarm.logs.column_mapping`, looked up in the file by
   :mod:`reflexarm.logs.mapped_columns`;
2. the **schema** of :mod:`reflexarm.logs.files`: ``q_1 .. q_n`` (1-based), or ``q_0 .. q_{n-1}``
   (0-based, recognized when ``q_0`` exists, and said so);
3. **joint-named** columns (the joint names must be known): ``position_<joint>``, ``<joint>/position``,
   ``<joint>.position``, ``<joint>_pos``, ``<joint>_position``, ``q_<joint>`` (velocity: ``velocity``,
   ``vel``, ``dq``; torque: ``effort``, ``eff``, ``torque``, ``tau``; acceleration: ``acceleration``,
   ``acc``, ``ddq``);
4. the **ROS 2 JointState array layout** of topic-echo and bag-to-CSV exports: ``position.0`` /
   ``position[0]`` / ``position0`` (velocity, effort likewise) with the joint names in ``name.0`` ..;
   joints are then mapped by name row by row (the order may change between rows; rows that hold none
   of the robot's joints, e.g. a gripper's, are left out with a note); without name columns the array
   index is the model's joint order (said so). Array columns (Parquet lists, one JointState message per
   row) are first expanded to ``position.0``, ... by :mod:`reflexarm.logs.tables`.

Names are compared without case and with ``/``, ``.`` and ``[i]`` alike, and a column also matches by
any tail after a ``/`` or ``.`` (so ``/joint_states/shz/position`` matches ``shz/position``). Time:
``t``, ``time``, ``timestamp``, ``stamp``, ``__time`` (PlotJuggler), ``%time`` (ROS 1 rostopic),
``header.stamp`` or the pair ``header.stamp.sec`` + ``header.stamp.nanosec``, optionally with a unit
suffix (``t_ns``). Wrench: ``fx .. mz``, ``force.x .. torque.z`` (also ``wrench.force.x``),
``force_x .. torque_z``.

**Motor currents** instead of torques (``torque_from="current"``): the signal ``current`` is found as
``tau`` is (mapping key ``current``, ``current_1..n``, ``current_<joint>``, ``<joint>/current``, ``cur``
likewise, or the JointState layout's effort field), and the reader multiplies it by per-joint gains.

Columns that match nothing needed are not an error: they are left out with a note naming them. A
missing signal is a :class:`~reflexarm.errors.DataError` naming what was looked for.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from reflexarm.errors import ConfigError, DataError
from reflexarm.logs._joint_state_columns import (
    _MEANING,
    _STATE_FIELD,
    JointStateLayout,
    _find_layout,
    _use_layout,
)
from reflexarm.logs.column_mapping import (
    JOINT_SIGNALS,
    ColumnSpec,
    check_column_mapping,
    parse_column_mapping,
    parse_column_spec,
)
from reflexarm.logs.mapped_columns import (
    ROS_AXES,
    ColumnIndex,
    mapped_joint_signal,
    mapped_time,
    mapped_wrench,
)
from reflexarm.logs.robot_log import WRENCH_COLUMNS

__all__ = [
    "JOINT_SIGNALS",
    "TORQUE_SOURCES",
    "ColumnPlan",
    "JointStateLayout",
    "parse_column_mapping",
    "plan_columns",
]

#: Where the measured torque comes from: torque columns, or motor currents times per-joint gains.
TORQUE_SOURCES = ("torque", "current")
_REQUIRED = ("q", "dq", "tau")
_WORDS = {
    "q": ("position", "pos", "q"),
    "dq": ("velocity", "vel", "dq"),
    "tau": ("effort", "eff", "torque", "tau"),
    "ddq": ("acceleration", "acc", "ddq"),
    "current": ("current", "cur"),
}
_WRENCH_ALIASES = {
    a: (a, r, r.replace(".", "_"), f"{a[0]}_{a[1]}") + ((f"t{a[1]}",) if a[0] == "m" else ())
    for a, r in zip(WRENCH_COLUMNS, ROS_AXES, strict=True)
}
_TIME_NAMES = ("t", "time", "timestamp", "stamp", "__time", "%time", "header.stamp", "field.header.stamp")
_TIME_PAIRS = (("header.stamp.sec", "header.stamp.nanosec"), ("header.stamp.secs", "header.stamp.nsecs"))


@dataclass(frozen=True)
class ColumnPlan:
    """Where each signal is: ``time`` (one column, or the sec/nanosec pair), ``joints[signal]`` the
    column of each joint in the model's order (signals of the JointState layout are in ``layout``),
    ``wrench`` the six wrench columns or None; ``ignored`` the columns left out; ``notes`` what was
    recognized (for the reader's report); ``scale[signal]`` the factor a mapping's ``*SCALE`` gives its
    values (signals without one are not listed). With motor currents (``torque_from="current"``)
    ``joints["current"]`` replaces ``joints["tau"]``."""

    time: tuple[str, ...]
    time_unit: str | None
    joints: dict[str, tuple[str, ...]]
    n_joints: int
    joint_names: tuple[str, ...] | None
    layout: JointStateLayout | None = None
    wrench: tuple[str, ...] | None = None
    ignored: tuple[str, ...] = ()
    notes: tuple[str, ...] = field(default=())
    scale: dict[str, float] = field(default_factory=dict)


def plan_columns(
    columns: list[str],
    *,
    where: str,
    n_joints: int | None = None,
    joint_names: tuple[str, ...] | None = None,
    mapping: dict[str, str] | None = None,
    torque_from: str = "torque",
) -> ColumnPlan:
    """Find every signal among ``columns`` (see the module docstring).

    ``torque_from="current"`` looks for motor currents (mapping key ``current``, ``current_1..n``,
    ``current_<joint>``, ..., or the JointState layout's effort) instead of torques.

    Raises:
        DataError: no time column, a required signal missing for some joint (naming what was looked
            for), a joint count that does not match ``n_joints``, an ambiguous name, positions beyond
            the file's columns or of the wrong count.
        ConfigError: a malformed ``mapping``, an unknown ``torque_from``, a ``current`` mapping without
            ``torque_from="current"``.
    """
    specs = _specs(mapping or {}, torque_from)
    required = ("q", "dq", "current") if torque_from == "current" else _REQUIRED
    signals = ("q", "dq", "current", "ddq") if torque_from == "current" else JOINT_SIGNALS
    if joint_names is not None:
        joint_names = tuple(joint_names)
        if n_joints is not None and n_joints != len(joint_names):
            raise ConfigError(f"n_joints {n_joints} but {len(joint_names)} joint names given")
        n_joints = len(joint_names)
    idx = ColumnIndex(columns, where)
    notes: list[str] = []
    used: set[str] = set()
    time, unit = _find_time(idx, columns, specs.get("t"), where, notes)
    used.update(time)
    layout = _find_layout(columns)
    q_spec = specs.get("q")
    if n_joints is None and q_spec is not None and q_spec.positions is not None:
        n_joints = len(q_spec.positions)
    n = n_joints if n_joints is not None else _infer_n(columns, layout, where)
    count = _schema_count(columns)
    if count is not None and count != n and "q" not in specs:
        _refuse_schema_count(idx, columns, count, n, required, where)
    joints, from_layout = _joint_signals(signals, required, idx, n, joint_names, specs, layout, count, where, notes)
    plan_layout = None
    if from_layout:
        assert layout is not None
        plan_layout = _layout_plan(layout, from_layout, n, joint_names, where, notes)
        used.update(plan_layout.names)
        for cols in plan_layout.fields.values():
            used.update(cols)
    for cols in joints.values():
        used.update(cols)
    wrench = _find_wrench(idx, specs.get("wrench"), where)
    if wrench is not None:
        used.update(wrench)
        if tuple(wrench) != WRENCH_COLUMNS:
            notes.append(f"{where}: wrist wrench from columns {', '.join(wrench)}")
    ignored = tuple(c for c in columns if c not in used)
    if ignored:
        notes.append(f"{where}: ignored {len(ignored)} column(s) no signal needs: {', '.join(ignored)}")
    return ColumnPlan(
        time=time,
        time_unit=unit,
        joints=joints,
        n_joints=n,
        joint_names=joint_names,
        layout=plan_layout,
        wrench=None if wrench is None else tuple(wrench),
        ignored=ignored,
        notes=tuple(notes),
        scale={k: v.scale for k, v in specs.items() if v.scale != 1.0},
    )


def _joint_signals(
    signals: tuple[str, ...],
    required: tuple[str, ...],
    idx: ColumnIndex,
    n: int,
    joint_names: tuple[str, ...] | None,
    specs: dict[str, ColumnSpec],
    layout: JointStateLayout | None,
    count: int | None,
    where: str,
    notes: list[str],
) -> tuple[dict[str, tuple[str, ...]], list[str]]:
    """(the columns of each joint signal found by mapping, schema or name; the signals left to the JointState
    layout); a required signal found nowhere raises :class:`DataError` naming what was looked for."""
    columns = idx.columns
    joints: dict[str, tuple[str, ...]] = {}
    from_layout: list[str] = []
    for s in signals:
        found = _find_joint_signal(s, idx, n, joint_names, specs.get(s), where, notes)
        if found is not None:
            joints[s] = found
        elif layout is not None and _layout_field(s) in layout.fields:
            from_layout.append(s)
        elif s in required and count is not None:
            missing = next(f"{s}_{j}" for j in range(1, n + 1) if idx.full.get(f"{s}_{j}") is None)
            raise DataError(
                f"{where}: column {missing!r} missing; found: {', '.join(columns)}",
                source=where,
                column=missing,
                expected=tuple(columns),
            )
        elif s in required:
            looked, message = _missing(s, n, joint_names, columns, where)
            raise DataError(message, source=where, column=looked, expected=tuple(columns))
    return joints, from_layout


def _specs(mapping: dict[str, str], torque_from: str) -> dict[str, ColumnSpec]:
    """The mapping's entries parsed, checked against the torque source."""
    check_column_mapping(mapping)
    if torque_from not in TORQUE_SOURCES:
        raise ConfigError(f"unknown torque source {torque_from!r}; choose one of: {', '.join(TORQUE_SOURCES)}")
    if "current" in mapping and torque_from != "current":
        raise ConfigError(
            f"column mapping current={mapping['current']!r} names motor currents: read the torque from them with "
            "torque_from='current' and per-joint gains (--torque-from current --gains G1,G2,.. [Nm/A])"
        )
    return {k: parse_column_spec(k, v) for k, v in mapping.items()}


def _layout_plan(
    layout: JointStateLayout,
    signals: list[str],
    n: int,
    joint_names: tuple[str, ...] | None,
    where: str,
    notes: list[str],
) -> JointStateLayout:
    """The JointState layout's columns of ``signals`` (motor currents from its effort field), noted."""
    plan, note = _use_layout(layout, [_layout_field(s) for s in signals], n, joint_names, where)
    if "current" in signals:
        plan = JointStateLayout(plan.names, {("current" if k == "tau" else k): v for k, v in plan.fields.items()})
        note += "; the effort field taken as motor currents"
    notes.append(note)
    return plan


def _layout_field(s: str) -> str:
    """The JointState layout's field of signal ``s`` (motor currents come in the effort field)."""
    return "tau" if s == "current" else s


def _refuse_schema_count(
    idx: ColumnIndex, columns: list[str], count: int, n: int, required: tuple[str, ...], where: str
) -> None:
    for s in required:  # a column missing among the log's own joints is named first
        for j in range(1, count + 1):
            if idx.full.get(f"{s}_{j}") is None and idx.full.get(f"{s}_{j - 1}") is None:
                raise DataError(
                    f"{where}: column '{s}_{j}' missing; found: {', '.join(columns)}",
                    source=where,
                    column=f"{s}_{j}",
                    expected=tuple(columns),
                )
    raise DataError(
        f"{where}: the log has {count} joints (q_1..q_{count}); the robot has {n}",
        source=where,
        column="q",
        value=count,
        expected=n,
    )


def _find_time(
    idx: ColumnIndex, columns: list[str], spec: ColumnSpec | None, where: str, notes: list[str]
) -> tuple[tuple[str, ...], str | None]:
    if spec is not None:
        return mapped_time(idx, columns, spec, where, notes), None
    if "t" in columns:
        return ("t",), None
    for sec, nsec in _TIME_PAIRS:
        a, b = idx.find(sec), idx.find(nsec)
        if a is not None and b is not None:
            notes.append(f"{where}: time from the header stamps {a} + {b} (ns)")
            return (a, b), "ns"
    for base in _TIME_NAMES:
        for suffix in ("", "_s", "_ms", "_us", "_ns"):
            c = idx.find(base + suffix)
            if c is not None:
                if c != "t":
                    notes.append(f"{where}: time from column {c!r}")
                return (c,), None
    raise DataError(
        f"{where}: no time column: looked for {', '.join(_TIME_NAMES)} (optionally with a unit suffix such as "
        f"t_ns) and header.stamp.sec + header.stamp.nanosec; found: {', '.join(columns)}; name it with "
        "a column mapping (--columns t=NAME)",
        source=where,
        column=_TIME_NAMES,
        expected=tuple(columns),
    )


def _schema_count(columns: list[str]) -> int | None:
    """Joint count of the schema's numbered position columns (q_1..q_n, or q_0..q_{n-1}), None if none."""
    numbers = [int(m.group(1)) for c in columns if (m := re.fullmatch(r"q_(\d+)", c.strip().lower()))]
    if not numbers:
        return None
    return max(numbers) + (1 if 0 in numbers else 0)


def _infer_n(columns: list[str], layout: JointStateLayout | None, where: str) -> int:
    count = _schema_count(columns)
    if count is not None:
        return count
    if layout is not None and not layout.names:
        return len(layout.fields["q"])
    if layout is not None:
        raise DataError(
            f"{where}: the JointState columns ({', '.join(layout.names[:3])}, ...) name the joints; give the "
            "robot's joint names (the robot) to map them"
        )
    raise DataError(
        f"{where}: no joint columns (q_1, dq_1, tau_1, ...) found and no joint names given to look for joint-named "
        f"columns; found: {', '.join(columns)}"
    )


def _find_joint_signal(
    s: str,
    idx: ColumnIndex,
    n: int,
    joint_names: tuple[str, ...] | None,
    spec: ColumnSpec | None,
    where: str,
    notes: list[str],
) -> tuple[str, ...] | None:
    if spec is not None:
        return mapped_joint_signal(s, idx, n, joint_names, spec, where, notes)
    schema = [idx.full.get(f"{s}_{j}") for j in range(1, n + 1)]
    zero = [idx.full.get(f"{s}_{j}") for j in range(n)]
    if zero[0] is not None and all(c is not None for c in zero):
        notes.append(f"{where}: columns {s}_0..{s}_{n - 1} numbered from 0: taken as joints 1..{n}")
        return tuple(c for c in zero if c is not None)
    if all(c is not None for c in schema):
        return tuple(c for c in schema if c is not None)
    if joint_names is None:
        return None
    best: tuple[int, str, list[str | None]] | None = None
    for template_ in _name_templates(s):
        found = [idx.find(template_.format(joint=name)) for name in joint_names]
        hits = sum(f is not None for f in found)
        if hits == n:
            cols = tuple(f for f in found if f is not None)
            notes.append(f"{where}: {_MEANING[s]} from joint-named columns {_matched_pattern(cols, joint_names)}")
            return cols
        if hits and (best is None or hits > best[0]):
            best = (hits, template_, found)
    if best is not None and s in _REQUIRED:
        _, template_, found = best
        missing = [joint_names[j] for j, f in enumerate(found) if f is None]
        present = [(f, name) for f, name in zip(found, joint_names, strict=True) if f is not None]
        pattern = _matched_pattern(tuple(f for f, _ in present), tuple(name for _, name in present))
        raise DataError(
            f"{where}: {_MEANING[s]} columns {pattern!r} found for "
            f"{n - len(missing)} of the {n} joints; missing for joint(s) {', '.join(map(repr, missing))} "
            f"(looked for {', '.join(repr(template_.format(joint=m)) for m in missing[:3])})",
            source=where,
            column=template_.format(joint=missing[0]),
            joint=missing[0],
        )
    return None


def _matched_pattern(columns: tuple[str, ...], joint_names: tuple[str, ...]) -> str:
    """The columns as they are spelled, with each joint's name replaced by ``<joint>``
    (``shoulder_pan_joint/position`` -> ``<joint>/position``); differing spellings are listed."""
    patterns: list[str] = []
    for column, name in zip(columns, joint_names, strict=True):
        i = column.lower().rfind(name.lower())
        pattern = column if i < 0 else f"{column[:i]}<joint>{column[i + len(name) :]}"
        if pattern not in patterns:
            patterns.append(pattern)
    return " / ".join(patterns)


def _name_templates(s: str) -> list[str]:
    out = []
    for w in _WORDS[s]:
        out += [f"{w}_{{joint}}", f"{{joint}}.{w}", f"{{joint}}_{w}"]
    return out


def _missing(
    s: str, n: int, joint_names: tuple[str, ...] | None, columns: list[str], where: str
) -> tuple[tuple[str, ...], str]:
    """(the names looked for, the message) for a required signal found nowhere."""
    looked = [f"{s}_1..{s}_{n}", f"{s}_0..{s}_{n - 1}"]
    if joint_names is not None:
        j0 = joint_names[0]
        looked += [t.format(joint=j0) for t in _name_templates(s)]
    if s in _STATE_FIELD or s == "current":
        looked.append(f"{_STATE_FIELD.get(s, 'effort')}.0 (JointState layout)")
    return tuple(looked), (
        f"{where}: no {_MEANING[s]} columns: looked for {', '.join(looked)}"
        + (f" (for joint 1, {joint_names[0]!r}; likewise the others)" if joint_names else "")
        + f"; found: {', '.join(columns)}; a column mapping (--columns {s}=TEMPLATE) names them"
    )


def _find_wrench(idx: ColumnIndex, spec: ColumnSpec | None, where: str) -> list[str] | None:
    if spec is not None:
        return mapped_wrench(idx, spec, where)
    found = []
    for a in WRENCH_COLUMNS:
        hit = None
        for alias in _WRENCH_ALIASES[a]:
            hit = idx.find(alias)
            if hit is not None:
                break
        found.append(hit)
    if all(f is None for f in found):
        return None
    if any(f is None for f in found):
        missing = [a for a, f in zip(WRENCH_COLUMNS, found, strict=True) if f is None]
        raise DataError(
            f"{where}: wrench column(s) {', '.join(missing)} missing (give all six or none)",
            source=where,
            column=tuple(missing),
        )
    return [f for f in found if f is not None]
