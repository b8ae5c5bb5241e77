"""The explicit column mapping of a table log: ``{"q": "position_{joint}", "t": "stamp_ns"}``, on the
command line ``--columns q=position_{joint},t=stamp_ns`` (placeholders in :mod:`reflexarm.logs.columns`).

Each entry ``KEY=SPEC`` names where a signal is, by name or by position, optionally with a scale:

* a **template** of column names: ``q=position_{joint}`` (``{joint}`` the joint's name, ``{i}`` its number
  from 1, ``{i0}`` its index from 0; ``wrench`` takes ``{axis}`` fx..mz and ``{ros_axis}`` force.x..torque.z;
  ``t`` is one column's name);
* **positions** in the file, counted from 0 as the file's columns stand (header-less files have nothing
  else): ``t=0``; ``q=1:7`` the columns 1 to 6 (the end is excluded, as in Python), one per joint in the
  model's order; ``q=1:13:2`` every second column from 1 (interleaved q, dq); ``wrench=20:26``;
* a **scale** after ``*``, which the column's values are multiplied by: ``tau=trq_{i}*0.001`` (mNm),
  ``q=1:7*0.0174533`` (degrees), ``tau=cur_{i}*0.1`` (a motor current times one gain for every joint;
  per-joint gains: ``torque_from="current"`` with ``gains``, on the command line ``--torque-from current
  --gains ...``).

Keys: ``t``, ``q``, ``dq``, ``tau``, ``ddq``, ``current`` (motor currents [A], alias ``cur``) and ``wrench``.
"""

from __future__ import annotations

import re
import string
from typing import NamedTuple

from reflexarm.errors import ConfigError

__all__ = [
    "JOINT_SIGNALS",
    "MAPPING_KEYS",
    "ColumnSpec",
    "check_column_mapping",
    "parse_column_mapping",
    "parse_column_spec",
]

#: Per-joint signals of a log: positions, velocities, measured torques (required), accelerations.
JOINT_SIGNALS = ("q", "dq", "tau", "ddq")
#: Keys of a column mapping (``cur`` is read as ``current``).
MAPPING_KEYS = ("t", *JOINT_SIGNALS, "current", "wrench")
_ALIASES = {"cur": "current"}
_JOINT_PLACEHOLDERS = ("joint", "i", "i0")
_PLACEHOLDERS = {
    "t": (),
    "wrench": ("axis", "ros_axis"),
    "current": _JOINT_PLACEHOLDERS,
    **{s: _JOINT_PLACEHOLDERS for s in JOINT_SIGNALS},
}
_POSITIONS = re.compile(r"^(\d+)(?::(\d+))?(?::(\d+))?$")


class ColumnSpec(NamedTuple):
    """One mapping entry: a name ``template`` or 0-based ``positions`` (a ``range``), and a ``scale``."""

    template: str | None
    positions: range | None
    scale: float

    def describe(self) -> str:
        """As the user wrote it (``trq_{i}``, ``1:7``, with ``*scale`` unless 1)."""
        if self.positions is not None:
            r = self.positions
            text = (
                str(r.start)
                if len(r) == 1 and r.step == 1
                else f"{r.start}:{r.stop}" + (f":{r.step}" if r.step != 1 else "")
            )
        else:
            text = str(self.template)
        return text if self.scale == 1.0 else f"{text}*{self.scale:g}"


def parse_column_mapping(text: str | None) -> dict[str, str]:
    """``"q=position_{joint},dq=velocity_{joint},t=stamp_ns"`` as a dict (the ``--columns`` option)."""
    if text is None or not text.strip():
        return {}
    out: dict[str, str] = {}
    for part in text.split(","):
        if "=" not in part:
            raise ConfigError(
                f"column mapping entry {part.strip()!r} is not KEY=SPEC (e.g. q=position_{{joint}} or q=1:7); "
                f"keys: {', '.join(MAPPING_KEYS)}"
            )
        key, template = (s.strip() for s in part.split("=", 1))
        key = _ALIASES.get(key, key)
        if key in out:
            raise ConfigError(f"column mapping key {key!r} given twice in {text!r}")
        out[key] = template
    check_column_mapping(out)
    return out


def parse_column_spec(key: str, spec: str) -> ColumnSpec:
    """One entry's SPEC (see the module docstring) as a :class:`ColumnSpec`.

    Raises:
        ConfigError: a scale that is not a finite non-zero number, an empty or reversed position range.
    """
    scale = 1.0
    body = spec.strip()
    if "*" in body:
        body, factor = (s.strip() for s in body.rsplit("*", 1))
        try:
            scale = float(factor)
        except ValueError as e:
            raise ConfigError(
                f"column mapping {key}={spec!r}: the scale after '*' must be a number; got {factor!r}"
            ) from e
        if not (scale == scale and abs(scale) not in (0.0, float("inf"))):
            raise ConfigError(f"column mapping {key}={spec!r}: the scale must be finite and non-zero; got {factor!r}")
        if key == "t":
            raise ConfigError(f"column mapping t={spec!r}: time takes no scale; give its unit (--time-unit s|ms|us|ns)")
    m = _POSITIONS.match(body)
    if m is None:
        return ColumnSpec(body, None, scale)
    start = int(m.group(1))
    stop = int(m.group(2)) if m.group(2) is not None else start + 1
    step = int(m.group(3)) if m.group(3) is not None else 1
    if step < 1 or stop <= start:
        raise ConfigError(
            f"column mapping {key}={spec!r}: positions START:STOP[:STEP] need STOP > START and STEP >= 1 (0-based, "
            "STOP excluded: q=1:7 is columns 1 to 6)"
        )
    return ColumnSpec(None, range(start, stop, step), scale)


def check_column_mapping(mapping: dict[str, str]) -> None:
    """Refuse unknown keys and placeholders (:class:`ConfigError` naming them and the choices)."""
    for key, spec in mapping.items():
        if key not in _PLACEHOLDERS:
            raise ConfigError(f"unknown column mapping key {key!r}; keys: {', '.join(MAPPING_KEYS)} (cur = current)")
        parsed = parse_column_spec(key, spec)
        if parsed.template is None:
            if key == "t" and parsed.positions is not None and len(parsed.positions) != 1:
                raise ConfigError(f"column mapping t={spec!r}: the time is one column (e.g. t=0)")
            continue
        template = parsed.template
        try:
            names = [f for _, f, _, _ in string.Formatter().parse(template) if f is not None]
        except ValueError as e:
            raise ConfigError(f"column mapping {key}={spec!r} is not a valid template: {e}") from e
        allowed = _PLACEHOLDERS[key]
        bad = [n for n in names if n not in allowed]
        if bad:
            choices = ", ".join("{" + a + "}" for a in allowed) or "none (a column name)"
            raise ConfigError(f"column mapping {key}={spec!r}: unknown placeholder {{{bad[0]}}}; allowed: {choices}")
        if allowed and not names and key != "t":
            raise ConfigError(
                f"column mapping {key}={spec!r} names one column for all joints; use a placeholder ("
                + ", ".join("{" + a + "}" for a in allowed)
                + ") or positions (e.g. 1:7)"
            )
