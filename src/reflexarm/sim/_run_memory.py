"""How much memory an in-memory closed-loop run needs, checked before anything is allocated (private).

:func:`~reflexarm.sim.run_fast`, :func:`~reflexarm.sim.run_compiled` and the Python loop keep every tick of
the run (the :class:`~reflexarm.sim.Trace` and the buffers it is copied from). A duration whose rows cannot
fit raises a :class:`~reflexarm.errors.ConfigError` naming the size and the way out (a streamed run) instead
of a raw ``MemoryError`` (or the machine swapping) after a partial allocation.
"""

from __future__ import annotations

import os

from reflexarm.errors import ConfigError

__all__ = ["available_bytes", "check_log_memory", "check_memory", "run_bytes"]


def run_bytes(ticks: int, n: int) -> int:
    """Bytes an in-memory run of ``ticks`` ticks of an ``n``-joint arm keeps at its peak (an upper estimate).

    Per tick: the recorder's rows (t, 9 joint fields, wrench, f_ext_ee, the collision flags), the reference's
    accelerations, the compiled loop's mode/fault rows, the sensor noise (3n + 9) and the tick times, copied
    once more into the returned Trace, and the mode and fault texts (~100 bytes).
    """
    floats = 1 + 9 * n + 6 + 3 + n + 5 + (3 * n + 9) + 4
    per_tick = 2 * (8 * floats + n + 1 + 8) + 100
    return int(ticks) * per_tick


def available_bytes() -> int | None:
    """Memory the system can give now (Linux ``MemAvailable``; else physical memory), or None if unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(ticks: int, n: int, what: str) -> None:
    """ConfigError if ``ticks`` rows of an ``n``-joint run would not fit in the memory available now.

    Raises:
        ConfigError: the message names the run, its ticks, the bytes needed and available, and the streamed
            alternative (``stream_fast``), whose memory does not grow with the duration.
    """
    need = run_bytes(ticks, n)
    have = available_bytes()
    if have is None or need <= have:
        return
    raise ConfigError(
        f"{what}: {ticks:,} ticks keep ~{need / 1e9:.3g} GB in memory; {have / 1e9:.3g} GB are available. For a "
        "run this long use reflexarm.sim.stream_fast (statistics in C++ and the trace streamed to a Parquet file, "
        "in memory that does not grow with the duration) or a shorter duration"
    )


def check_log_memory(ticks: int, n: int, what: str) -> None:
    """ConfigError if a log of ``ticks`` measurements (t, q, dq, tau_m, wrench) would not fit in memory."""
    need = int(ticks) * 8 * (1 + 3 * n + 6)
    have = available_bytes()
    if have is None or need <= have:
        return
    raise ConfigError(
        f"{what}: a log of {ticks:,} ticks needs ~{need / 1e9:.3g} GB in memory; {have / 1e9:.3g} GB are available: "
        "record a shorter duration (several logs can be pooled)"
    )
