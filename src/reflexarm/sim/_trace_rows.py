"""Every k-th row of a trace block: the decimated trace of a long streamed run (private)."""

from __future__ import annotations

import dataclasses

from reflexarm.errors import ConfigError
from reflexarm.sim.trace import Trace

__all__ = ["check_every", "every_nth"]


def check_every(trace_every: object) -> int:
    """``trace_every`` as a positive int, or a ConfigError naming it."""
    if isinstance(trace_every, bool) or not isinstance(trace_every, int) or trace_every < 1:
        raise ConfigError(f"trace_every must be a positive number of ticks; got {trace_every!r}")
    return int(trace_every)


def every_nth(block: Trace, first_tick: int, every: int) -> Trace:
    """The rows of ``block`` (whose first row is tick ``first_tick`` of the run) at ticks that are multiples
    of ``every``: the same rows whatever the block size. ``every`` 1: the block itself."""
    if every == 1:
        return block
    rows = slice((-first_tick) % every, None, every)
    N = len(block)
    values = {}
    for f in dataclasses.fields(block):
        v = getattr(block, f.name)
        if f.name == "extras":
            v = {k: a[rows] for k, a in v.items()}
        elif f.name != "meta" and getattr(v, "shape", (0,))[:1] == (N,):
            v = v[rows]
        values[f.name] = v
    values["meta"] = block.meta | {"trace_every": every}  # readers that need every tick refuse the file
    return Trace(**values)
