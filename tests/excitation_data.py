"""A fixed excitation trajectory for the identification tests (data, not an optimizer run).

``data/atlas_excitation.json`` holds the Fourier coefficients of an optimized excitation of the Atlas arm,
written once. Tests read them instead of calling :func:`reflexarm.ident.optimize_excitation`: the
optimizer's path (SLSQP over a BLAS-evaluated cost) depends on the CPU's BLAS kernels and thread count,
so the same call gives a different trajectory on another machine (see the file's ``about``).
"""

from __future__ import annotations

import json
from pathlib import Path

from reflexarm.ident import FourierTrajectory

DATA = Path(__file__).parent / "data" / "atlas_excitation.json"


def fixed_excitation() -> tuple[FourierTrajectory, float]:
    """The fixed excitation (one period) and the condition number of its base regressor stored with it."""
    doc = json.loads(DATA.read_text())
    return FourierTrajectory.from_dict(doc["trajectory"]), float(doc["condition_optimized"])
