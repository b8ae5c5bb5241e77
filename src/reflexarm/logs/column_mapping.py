"""The explicit column mapping of a table log: ``{"q": "position_{joint}", "t": "stamp_ns"}``, on the
command line ``--columns q=position_{joint},t=stamp_ns`` (placeholders in :mod:`reflexarm.logs.columns`)."""

from __future__ import annotations

import string

from reflexarm.errors import ConfigError

__all__ = ["JOINT_SIGNALS", "MAPPING_KEYS", "check_column_mapping", "parse_column_mapping"]

#: Per-joint signals of a log: positions, velocities, measured torques (required), accelerations.
JOINT_SIGNALS = ("q", "dq", "tau", "ddq")
#: Keys of a column mapping.
MAPPING_KEYS = ("t", *JOINT_SIGNALS, "wrench")
_PLACEHOLDERS = {"t": (), "wrench": ("axis", "ros_axis"), **{s: ("joint", "i", "i0") for s in JOINT_SIGNALS}}


def parse_column_mapping(text: str | None) -> dict[str, str]:
    """``"q=position_{joint},dq=velocity_{joint},t=stamp_ns"`` as a dict (the ``--columns`` option)."""
    if text is None or not text.strip():
        return {}
    out: dict[str, str] = {}
    for part in text.split(","):
        if "=" not in part:
            raise ConfigError(
                f"column mapping entry {part.strip()!r} is not KEY=TEMPLATE (e.g. q=position_{{joint}}); "
                f"keys: {', '.join(MAPPING_KEYS)}"
            )
        key, template = (s.strip() for s in part.split("=", 1))
        out[key] = template
    check_column_mapping(out)
    return out


def check_column_mapping(mapping: dict[str, str]) -> None:
    """Refuse unknown keys and placeholders (:class:`ConfigError` naming them and the choices)."""
    for key, template in mapping.items():
        if key not in _PLACEHOLDERS:
            raise ConfigError(f"unknown column mapping key {key!r}; keys: {', '.join(MAPPING_KEYS)}")
        try:
            names = [f for _, f, _, _ in string.Formatter().parse(template) if f is not None]
        except ValueError as e:
            raise ConfigError(f"column mapping {key}={template!r} is not a valid template: {e}") from e
        allowed = _PLACEHOLDERS[key]
        bad = [n for n in names if n not in allowed]
        if bad:
            choices = ", ".join("{" + a + "}" for a in allowed) or "none (a column name)"
            raise ConfigError(
                f"column mapping {key}={template!r}: unknown placeholder {{{bad[0]}}}; allowed: {choices}"
            )
        if allowed and not names and key != "t":
            raise ConfigError(
                f"column mapping {key}={template!r} names one column for all joints; use a placeholder: "
                + ", ".join("{" + a + "}" for a in allowed)
            )
