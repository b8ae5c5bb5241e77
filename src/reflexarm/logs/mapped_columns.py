"""The columns a column mapping names in a table log: by position in the file, or by a name template.

A mapping (:mod:`reflexarm.logs.column_mapping` parses it) is the first place
:func:`~reflexarm.logs.columns.plan_columns` looks for a signal. Each entry names its columns in one of two ways:

* **positions**, 0-based as the file's columns stand (``t=0,q=1:7,dq=7:13``; a header-less file has
  nothing else): one column for ``t``, one per joint for a joint signal, six for ``wrench``; a position
  beyond the file's columns, or a count that does not match, is a :class:`~reflexarm.errors.DataError`
  naming the entry, what it names and what was expected;
* a **template**: ``q=position_{joint}`` (``{joint}``, ``{i}``, ``{i0}``), ``wrench={ros_axis}``
  (``{axis}``, ``{ros_axis}``), ``t=stamp_ns``; each name is looked up as every other column name is
  (without case, ``/`` ``.`` ``[i]`` alike, by any tail after a separator: :class:`ColumnIndex`), and a name
  the file does not hold is a DataError listing the file's columns.

What a mapping found goes into the plan's notes (joint signals and time by position, joint signals by
template), with its scale when it has one.
"""

from __future__ import annotations

from reflexarm.errors import ConfigError, DataError
from reflexarm.logs._joint_state_columns import _MEANING, _norm
from reflexarm.logs.column_mapping import ColumnSpec
from reflexarm.logs.robot_log import WRENCH_COLUMNS

__all__ = ["ROS_AXES", "ColumnIndex", "mapped_joint_signal", "mapped_time", "mapped_wrench"]

#: The wrench components as a ROS ``geometry_msgs/Wrench`` names them, in the order of ``WRENCH_COLUMNS``.
ROS_AXES = ("force.x", "force.y", "force.z", "torque.x", "torque.y", "torque.z")


class ColumnIndex:
    """Columns by normalized name and by every normalized tail after a separator."""

    def __init__(self, columns: list[str], where: str) -> None:
        self.where = where
        self.columns = list(columns)
        self.by_key: dict[str, list[str]] = {}
        self.full: dict[str, str] = {}
        for c in columns:
            n = _norm(c)
            self.full.setdefault(n, c)
            parts = n.split(".")
            for k in range(len(parts)):
                self.by_key.setdefault(".".join(parts[k:]), []).append(c)

    def find(self, name: str) -> str | None:
        key = _norm(name)
        if key in self.full:
            return self.full[key]
        hits = self.by_key.get(key, [])
        if len(hits) > 1:
            raise DataError(
                f"{self.where}: {len(hits)} columns match {name!r}: {', '.join(map(repr, hits))}; "
                "name the one to use with a column mapping (--columns)",
                source=self.where,
                column=tuple(hits),
                expected=name,
            )
        return hits[0] if hits else None


def mapped_time(
    idx: ColumnIndex, columns: list[str], spec: ColumnSpec, where: str, notes: list[str]
) -> tuple[str, ...]:
    """The time column the mapping's ``t`` entry ``spec`` names (a position is noted in ``notes``)."""
    if spec.positions is not None:
        (at,) = _by_position("t", spec, idx, where, 1)
        notes.append(f"{where}: time from column {spec.describe()} ({at!r})")
        return (at,)
    explicit = str(spec.template)
    named = idx.find(explicit)
    if named is None:
        raise DataError(
            f"{where}: time column {explicit!r} (column mapping t=) missing; found: {', '.join(columns)}",
            source=where,
            column=explicit,
            expected=tuple(columns),
        )
    return (named,)


def mapped_joint_signal(
    s: str,
    idx: ColumnIndex,
    n: int,
    joint_names: tuple[str, ...] | None,
    spec: ColumnSpec,
    where: str,
    notes: list[str],
) -> tuple[str, ...]:
    """The ``n`` columns of joint signal ``s`` that the mapping's entry ``spec`` names, in the model's joint order,
    noted in ``notes`` (with the scale, if any)."""
    scaled = "" if spec.scale == 1.0 else f", times {spec.scale:g}"
    if spec.positions is not None:
        cols = _by_position(s, spec, idx, where, n)
        notes.append(f"{where}: {_MEANING[s]} from columns {spec.describe()} by position ({', '.join(cols)}){scaled}")
        return cols
    template = str(spec.template)
    if joint_names is None and "{joint}" in template:
        raise ConfigError(f"column mapping {s}={template!r} uses {{joint}} but no joint names are known")
    names = joint_names or tuple("" for _ in range(n))
    wanted = [template.format(joint=names[j], i=j + 1, i0=j) for j in range(n)]
    found = [idx.find(w) for w in wanted]
    missing = [w for w, f in zip(wanted, found, strict=True) if f is None]
    if missing:
        raise DataError(
            f"{where}: column(s) {', '.join(map(repr, missing))} of the mapping {s}={template!r} missing; "
            f"found: {', '.join(idx.full.values())}",
            source=where,
            column=tuple(missing),
            expected=tuple(idx.full.values()),
        )
    notes.append(f"{where}: {_MEANING[s]} from columns {template!r} (mapping){scaled}")
    return tuple(f for f in found if f is not None)


def mapped_wrench(idx: ColumnIndex, spec: ColumnSpec, where: str) -> list[str]:
    """The six wrench columns (fx fy fz mx my mz) that the mapping's ``wrench`` entry ``spec`` names."""
    if spec.positions is not None:
        return list(_by_position("wrench", spec, idx, where, len(WRENCH_COLUMNS)))
    template = str(spec.template)
    wanted = [template.format(axis=a, ros_axis=r) for a, r in zip(WRENCH_COLUMNS, ROS_AXES, strict=True)]
    found = [idx.find(w) for w in wanted]
    missing = [w for w, f in zip(wanted, found, strict=True) if f is None]
    if missing:
        raise DataError(f"{where}: wrench column(s) {', '.join(map(repr, missing))} of the mapping "
                        f"wrench={template!r} missing")  # fmt: skip
    return [f for f in found if f is not None]


def _by_position(key: str, spec: ColumnSpec, idx: ColumnIndex, where: str, expected: int | None) -> tuple[str, ...]:
    """The columns at ``spec.positions`` (0-based, as they stand in the file), ``expected`` of them."""
    assert spec.positions is not None
    names = idx.columns
    positions = spec.positions
    if positions[-1] >= len(names):
        raise DataError(
            f"{where}: column mapping {key}={spec.describe()} reaches column {positions[-1]} (counted from 0); the "
            f"file has {len(names)} columns (0..{len(names) - 1})",
            source=where,
            column=key,
            value=positions[-1],
            expected=len(names),
        )
    if expected is not None and len(positions) != expected:
        what = "joints" if key != "wrench" else "wrench components (fx fy fz mx my mz)"
        raise DataError(
            f"{where}: column mapping {key}={spec.describe()} names {len(positions)} column(s) "
            f"({', '.join(str(k) for k in positions)}); there are {expected} {what}: give one column each "
            "(positions START:STOP, 0-based, STOP excluded)",
            source=where,
            column=key,
            value=len(positions),
            expected=expected,
        )
    return tuple(names[k] for k in positions)
