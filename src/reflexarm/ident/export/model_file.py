"""The identified model on disk: base parameters + friction, in a JSON file the controller loads.

File format (``"format": "reflexarm-identified-model"``, version 1), JSON:

* ``robot``: name, ``source`` (a built-in robot's name, or the robot file's path relative to the model
  file's folder, so that the folder can move with its robot file; version 1 files hold absolute paths and
  still load), frames, joint names, and ``base``, ``tip``, ``locked`` when the arm was cut out of a
  bigger file;
* ``identification``: the :class:`~reflexarm.ident.DynamicsIdentification` (method, base-parameter map,
  beta_b with names, friction, noise variances, condition number, notes);
* ``standard_parameters``: 10 n inertial parameters consistent with beta_b, the ones nearest to the
  robot file's nominal values (see :meth:`BaseParameters.standard_from_base`): any such vector gives
  the same M(q), C, g, so the controller can use it as an ordinary :class:`RobotModel`;
* ``friction_model``: Coulomb mu_C, viscous d_v and the smooth-sign band of the controller's
  :class:`CoulombViscousFriction` (negative identified coefficients clipped to 0; offsets are not part
  of it).

:func:`load_identified_model` returns the :class:`RobotModel` to hand to
:class:`reflexarm.control.Controller`, after checking that the file fits the robot (joint names, and
that the standard parameters reproduce the stored base parameters).
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from reflexarm.errors import ModelError
from reflexarm.ident.estimation.identify import DynamicsIdentification, PhysicalConsistencyWarning, mass_matrix_margin
from reflexarm.robots.friction import CoulombViscousFriction
from reflexarm.robots.loader import builtin_robots, load_robot
from reflexarm.robots.robot_model import RobotModel

__all__ = ["FORMAT", "load_identified_model", "read_identified_model", "resolve_robot_source", "save_identified_model"]

FORMAT = "reflexarm-identified-model"
#: Version written: 2 stores the robot file relative to the model file (1: absolute); both are read.
VERSION = 2
READABLE_VERSIONS = (1, 2)
#: Description of the arm cut out of its file (set by load_robot's base/tip/locked), stored when set.
_CUT_KEYS = ("base", "tip", "locked")

#: Relative tolerance on the base parameters re-computed from the stored standard parameters.
_CONSISTENCY_RTOL = 1e-8


def _robot_source(robot: RobotModel, model_path: Path) -> str:
    """A built-in robot's name, or the robot file relative to the model file's folder (POSIX separators)."""
    b = builtin_robots().get(robot.name)
    if b is not None and robot.source is not None and Path(robot.source).resolve() == b.path.resolve():
        return robot.name
    if robot.source is None:
        return robot.name
    return Path(os.path.relpath(Path(robot.source).resolve(), model_path.parent.resolve())).as_posix()


def resolve_robot_source(source: str, model_path: str | os.PathLike[str]) -> str:
    """The ``load_robot`` argument of a stored source: a built-in name, an absolute path (version 1
    files) as it is, a relative path against the model file's folder."""
    if source in builtin_robots() or os.path.isabs(source):
        return source
    return str(Path(model_path).parent / source)


def _cut_description(robot: RobotModel) -> dict[str, Any]:
    """``base``, ``tip``, ``locked`` of an arm cut out of its file (none if it was not cut)."""
    args = robot.load_arguments()
    return {k: args[k] for k in _CUT_KEYS if args.get(k) is not None}


def save_identified_model(
    result: DynamicsIdentification,
    robot: RobotModel,
    path: str | os.PathLike[str],
    *,
    extra: dict[str, object] | None = None,
) -> Path:
    """Write the identified model of ``robot`` to ``path`` (JSON, see the module docstring).

    Args:
        result: the identification.
        robot: the robot it was identified for (its nominal inertias pick the standard parameters).
        path: output file (``.json``).
        extra: more JSON-serialisable facts to store (e.g. validation metrics).
    """
    if result.n != robot.n or tuple(robot.joint_names) != tuple(result.joint_names):
        raise ModelError(
            f"identification of joints {list(result.joint_names)} does not fit robot {robot.name!r} "
            f"with joints {robot.joint_names}"
        )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PhysicalConsistencyWarning)
        model = result.to_robot_model(robot)
    margin = mass_matrix_margin(model)
    if margin <= 0:
        warnings.warn(
            f"{Path(path).name}: the {result.method} base parameters give a mass matrix that is not positive "
            f"definite in the joint range (smallest eigenvalue ratio {margin:.3g}); the file is written, but "
            "load_identified_model will refuse it",
            PhysicalConsistencyWarning,
            stacklevel=2,
        )
    p = Path(path)
    doc = {
        "format": FORMAT,
        "version": VERSION,
        "robot": {
            "name": robot.name,
            "source": _robot_source(robot, p),
            "ee_frame": robot.ee_frame,
            "sensor_frame": robot.sensor_frame,
            "joint_names": robot.joint_names,
            **_cut_description(robot),
        },
        "identification": result.to_dict(),
        "standard_parameter_names": robot.inertial_parameter_names(),
        "standard_parameters": model.inertial_parameters().tolist(),
        "mass_matrix_margin": margin,
        "friction_model": {
            "coulomb": model.friction.coulomb.tolist(),
            "viscous": model.friction.viscous.tolist(),
            "velocity_band": model.friction.velocity_band,
        },
        "extra": extra or {},
    }
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(doc, indent=1))
    return p


def read_identified_model(path: str | os.PathLike[str]) -> tuple[DynamicsIdentification, dict[str, Any]]:
    """The stored identification and the whole JSON document."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except FileNotFoundError as e:
        raise ModelError(f"identified model file {str(p)!r} does not exist") from e
    except (OSError, json.JSONDecodeError) as e:
        raise ModelError(f"cannot read identified model file {str(p)!r}: {e}") from e
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ModelError(f'{p.name}: not a reflexarm identified model (expected "format": "{FORMAT}")')
    if doc.get("version") not in READABLE_VERSIONS:
        raise ModelError(
            f"{p.name}: unsupported identified-model version {doc.get('version')!r}; this reflexarm reads "
            f"{', '.join(str(v) for v in READABLE_VERSIONS)}"
        )
    try:
        result = DynamicsIdentification.from_dict(doc["identification"])
    except Exception as e:
        raise ModelError(f"{p.name}: malformed identification section: {e}") from e
    return result, doc


def _stored_robot(doc: dict[str, Any], path: str | os.PathLike[str]) -> RobotModel:
    info = doc.get("robot", {})
    src = info.get("source")
    if not src:
        raise ModelError(f"{Path(path).name}: no robot source stored; pass robot=")
    cut = {k: info[k] for k in _CUT_KEYS if info.get(k)}
    return load_robot(
        resolve_robot_source(src, path), ee_frame=info.get("ee_frame"), sensor_frame=info.get("sensor_frame"), **cut
    )


def load_model_robot(path: str | os.PathLike[str]) -> RobotModel:
    """The robot a model file was identified for, as its file stores it (the robot file relative to the
    model file's folder, frames, and base/tip/locked): the nominal model, not the identified one."""
    _, doc = read_identified_model(path)
    return _stored_robot(doc, path)


def load_identified_model(
    path: str | os.PathLike[str], robot: RobotModel | None = None, *, allow_inconsistent: bool = False
) -> RobotModel:
    """The controller's :class:`RobotModel` from an identified-model file.

    Args:
        path: the JSON file written by :func:`save_identified_model`.
        robot: the robot (default: loaded from the file's ``robot.source``, relative to the model file's
            folder, with its frames and, if stored, ``base``, ``tip`` and ``locked``).
        allow_inconsistent: load even if M(q) is not positive definite somewhere in the joint range
            (for analysis; a controller cannot use such a model).

    Raises:
        ModelError: unreadable file, wrong format, joints that do not match, standard parameters that
            do not reproduce the stored base parameters, or (unless ``allow_inconsistent``) a mass matrix
            that is not positive definite.
    """
    result, doc = read_identified_model(path)
    name = Path(path).name
    if robot is None:
        robot = _stored_robot(doc, path)
    if tuple(robot.joint_names) != tuple(result.joint_names):
        raise ModelError(
            f"{name}: identified for joints {list(result.joint_names)}; robot {robot.name!r} has {robot.joint_names}"
        )
    pi = np.asarray(doc.get("standard_parameters", []), dtype=float)
    if pi.size != 10 * robot.n:
        raise ModelError(f"{name}: expected {10 * robot.n} standard parameters; found {pi.size}")
    beta = result.base.base_from_standard(pi)
    scale = np.maximum(np.abs(result.beta_b), np.abs(result.beta_b).max() * 1e-6)
    if np.any(np.abs(beta - result.beta_b) > _CONSISTENCY_RTOL * scale + 1e-12):
        raise ModelError(f"{name}: the standard parameters do not reproduce the stored base parameters (edited file?)")
    fm = doc.get("friction_model", {})
    try:
        friction = CoulombViscousFriction(
            np.asarray(fm["coulomb"], dtype=float),
            np.asarray(fm["viscous"], dtype=float),
            float(fm.get("velocity_band", robot.friction.velocity_band)),
        )
    except Exception as e:
        raise ModelError(f"{name}: malformed friction_model: {e}") from e
    model = robot.with_inertial_parameters(pi).with_friction(friction)
    if not allow_inconsistent:
        margin = mass_matrix_margin(model)
        if margin <= 0:
            raise ModelError(
                f"{name}: the identified parameters give a mass matrix that is not positive definite in the joint "
                f"range (smallest eigenvalue ratio {margin:.3g}); the controller cannot use this model "
                "(pass allow_inconsistent=True to load it for analysis)"
            )
    return model
