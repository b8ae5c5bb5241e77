"""A subpackage's names imported from their modules on first use (PEP 562 ``__getattr__`` and ``__dir__``).

A subpackage whose modules pull in SciPy or the identification package, but whose command-line options are
registered from a light module alone, re-exports its names lazily::

    __getattr__, __dir__ = lazy_names(__name__, {"tune_thresholds": "study", ...}, globals())

``reflexarm.tuning.tune_thresholds`` then imports :mod:`reflexarm.tuning.study` on first access and keeps the
value in the package's namespace, so the next access is a plain attribute lookup.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_names"]


def lazy_names(
    package: str, sources: Mapping[str, str], namespace: dict[str, Any]
) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of ``package``.

    Args:
        package: the subpackage's dotted name (its ``__name__``).
        sources: each public name -> the module of ``package`` that defines it (``"study"`` for
            ``package.study``).
        namespace: the subpackage's ``globals()``: a name is stored there once imported; its ``__all__``
            is listed by ``__dir__``.
    """

    def __getattr__(name: str) -> object:
        module = sources.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{module}"), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *namespace["__all__"]})

    return __getattr__, __dir__
