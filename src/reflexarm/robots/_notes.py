"""Giving a robot file's notes once per process (private).

Loading a robot, building each plant of an experiment and sampling its collision geometry all read the
same file and find the same things in it. Python's ``default`` warning action shows a warning once per
place in the code, but it forgets what it has shown whenever any code changes the warning filters (every
``warnings.catch_warnings()`` does), and the same note comes from several places; so the same note could
be printed several times in one command. Here each note is given once per process under the ``default``,
``once`` and ``module`` actions; ``always`` (``pytest.warns``, ``-W always``) shows every occurrence, and
``ignore``/``error`` act as usual.
"""

from __future__ import annotations

import re
import warnings

from reflexarm.robots._mjcf import RobotFileWarning

__all__ = ["warn_note"]

#: (category, text) of the notes given in this process.
_GIVEN: set[tuple[type[Warning], str]] = set()
#: The module a note is attributed to when matching filters that name a module.
_MODULE = "reflexarm.robots"


def _matches(pattern: object, text: str) -> bool:
    """A filter's message or module field: None matches all, a pattern from its start, a string exactly."""
    if pattern is None:
        return True
    if isinstance(pattern, re.Pattern):
        return pattern.match(text) is not None
    return pattern == text


def _action(category: type[Warning], text: str) -> str:
    """The action the current warning filters give ``text`` (filters naming a line number are skipped)."""
    for action, message, cat, module, lineno in warnings.filters:
        if lineno or not issubclass(category, cat):
            continue
        if not (_matches(message, text) and _matches(module, _MODULE)):
            continue
        return str(action)
    return str(getattr(warnings, "defaultaction", "default"))  # not in the stubs


def warn_note(note: str, *, category: type[Warning] = RobotFileWarning, stacklevel: int = 2) -> None:
    """Warn ``note`` (a :class:`RobotFileWarning` by default) unless it was given before in this process
    and the filters show a warning only once (see the module docstring)."""
    action = _action(category, note)
    key = (category, note)
    if action in ("default", "once", "module"):
        if key in _GIVEN:
            return
        _GIVEN.add(key)
    warnings.warn(note, category, stacklevel=stacklevel + 1)
