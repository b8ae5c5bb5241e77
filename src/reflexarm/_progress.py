"""When to draw a progress bar: only when asked for and only on a terminal.

A tqdm bar redraws itself by carriage returns; written into a log file (``reflexarm demo 2> run.log``,
a CI job, a batch scheduler) it becomes thousands of lines. Every progress bar of the package asks
:func:`show_progress` first, so ``--quiet`` (``progress=False``) and a redirected stderr both silence it.
"""

from __future__ import annotations

import sys
from typing import TextIO

__all__ = ["show_progress"]


def show_progress(requested: bool = True, stream: TextIO | None = None) -> bool:
    """True when a progress bar should be drawn.

    Args:
        requested: the caller's wish (``progress=`` argument; False for ``--quiet``).
        stream: where the bar would be drawn; default ``sys.stderr`` (tqdm's default), looked up at call
            time so that a redirected or captured stderr counts.

    Returns:
        ``requested`` and the stream is an interactive terminal (``isatty()``); False for a file, a pipe,
        a closed stream or one without ``isatty``.
    """
    if not requested:
        return False
    target = sys.stderr if stream is None else stream
    if target is None:
        return False
    try:
        return bool(target.isatty())
    except (AttributeError, ValueError, OSError):  # no isatty, or a closed stream
        return False
