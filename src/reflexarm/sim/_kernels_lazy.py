"""The numba kernels of :mod:`reflexarm.sim._kernels`, imported on first use.

Importing numba and loading a cached kernel costs ~110 MB of memory (measured with ``reflexarm simulate
free-motion``: 471 -> 362 MiB peak without it); a run in the compiled loop never calls the kernels, so
``import reflexarm.sim`` and ``Plant(...)`` must not pay for them. ``kernels.name`` imports the module once and
keeps the attribute on the proxy (later lookups are plain attribute reads, as fast as the module's own).
"""

from __future__ import annotations

from typing import Any

__all__ = ["kernels"]


class _Kernels:
    """Attribute access imports :mod:`reflexarm.sim._kernels` (numba) on first use and caches the attribute."""

    def __getattr__(self, name: str) -> Any:
        from reflexarm.sim import _kernels

        value = getattr(_kernels, name)
        setattr(self, name, value)
        return value


kernels = _Kernels()
