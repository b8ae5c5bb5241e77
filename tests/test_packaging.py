"""The build of the C++ core (pyproject.toml [build-system]) against the runtime wheels: pins that must agree."""

from __future__ import annotations

import tomllib
from pathlib import Path

PYPROJECT = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())


def _pins(requirements: list[str]) -> dict[str, str]:
    return dict(r.replace(" ", "").split("==", 1) for r in requirements if "==" in r)


def test_build_requirements_are_the_runtime_wheels():
    # reflexarm._core links libpinocchio_default.so (no version in its name) and libboost_serialization.so.1.90.0
    # of the pin wheel at run time: libpinocchio at build time must be the same version, or a mismatch loads silently
    build, run = _pins(PYPROJECT["build-system"]["requires"]), _pins(PYPROJECT["project"]["dependencies"])
    assert build["libpinocchio"] == run["pin"]
    if "mujoco-core" in build:  # once the core links libmujoco.so.<version>
        assert build["mujoco-core"] == run["mujoco"]
    assert all("==" in r for r in PYPROJECT["build-system"]["requires"]), "build requirements are pinned exactly"

