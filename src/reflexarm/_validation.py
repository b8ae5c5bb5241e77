"""Argument checks shared by the public constructors (checked once, then trusted in hot paths)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError


def as_vector(
    value: npt.ArrayLike,
    n: int,
    name: str,
    *,
    positive: bool = False,
    nonnegative: bool = False,
) -> np.ndarray:
    """Return ``value`` as a float vector of length ``n`` (scalars broadcast), checking finiteness and sign.

    Raises:
        ConfigError: naming ``name``, the received shape or value and what was expected.
    """
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{name} must be numeric; got {value!r}") from e
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.ndim == 2 and arr.shape == (n, n):
        if not np.allclose(arr, np.diag(np.diag(arr))):
            raise ConfigError(f"{name} must be diagonal; got a full {n}x{n} matrix")
        arr = np.diag(arr).copy()
    if arr.shape != (n,):
        raise ConfigError(f"{name} must have shape ({n},) (one value per joint) or be a scalar; got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} must be finite; got {arr.tolist()}")
    if positive and np.any(arr <= 0.0):
        raise ConfigError(f"{name} must be positive; got {arr.tolist()}")
    if nonnegative and np.any(arr < 0.0):
        raise ConfigError(f"{name} must be non-negative; got {arr.tolist()}")
    return arr.copy()


def as_switch(value: object, name: str) -> int:
    """Return a 0/1 switch (the paper's kappa_*), rejecting anything else."""
    if isinstance(value, (bool, np.bool_)):
        return int(value)
    if isinstance(value, (int, np.integer, float, np.floating)) and float(value) in (0.0, 1.0):
        return int(value)
    raise ConfigError(f"{name} must be 0 or 1; got {value!r}")


def as_positive_scalar(value: object, name: str) -> float:
    """Return a finite positive float."""
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{name} must be a positive number; got {value!r}") from e
    if not np.isfinite(x) or x <= 0.0:
        raise ConfigError(f"{name} must be a positive number; got {value!r}")
    return x


def read_json_file(path: Path, what: str) -> Any:
    """The JSON document in the file ``path``; ``what`` names it in the error (e.g. ``"--threshold 'x.json'"``).

    Raises:
        ConfigError: no such file, or not a readable JSON text.
    """
    if not path.is_file():
        raise ConfigError(f"{what}: no such file")
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ConfigError(f"{what} is not a JSON file: {e}") from e
