"""Layout of the packed integer index array of ``_kernels.measurement`` (then qadr (n), vadr (n), load (nload)):
numba-free, so the plant builds it without importing the kernels."""

from __future__ import annotations

__all__ = ["IDX_COM_BODY", "IDX_FORCE", "IDX_HEADER", "IDX_N", "IDX_NLOAD", "IDX_PHYSICAL", "IDX_SITE", "IDX_TORQUE"]

IDX_N, IDX_NLOAD, IDX_FORCE, IDX_TORQUE, IDX_PHYSICAL, IDX_COM_BODY, IDX_SITE, IDX_HEADER = 0, 1, 2, 3, 4, 5, 6, 7
