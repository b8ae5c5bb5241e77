"""RobotModel: what the controller *knows* about an arm, eq. (1), over Pinocchio."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from reflexarm.errors import ModelError
from reflexarm.robots._cut import ChainCut, frame_notes
from reflexarm.robots._loading import build_pinocchio_model
from reflexarm.robots._notes import warn_note
from reflexarm.robots.friction import CoulombViscousFriction

__all__ = ["RobotModel"]  # load_robot and builtin_robots: reflexarm.robots.loader (which builds on this module)

#: Inertial parameters per link, in Pinocchio's order (about the joint frame origin):
#: m, m*c_x, m*c_y, m*c_z, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz.
INERTIAL_PARAMETER_NAMES = ("m", "mx", "my", "mz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")


class RobotModel:
    """Rigid-joint arm model (1): M(q), C(q, dq), g(q), frame Jacobians, friction tau_f(dq), regressor.

    A fixed-base serial chain of 1-DoF (revolute or prismatic) joints. The joint order is the model's.
    All quantities are SI. The object owns its Pinocchio model and data; use :meth:`copy` for a second
    independent instance (e.g. for another thread).

    Joint springs (MJCF ``stiffness``/``springref``) are part of the potential term of (1): the methods
    ``compute_gravity``, ``compute_nonlinear_effects``, ``compute_inverse_dynamics`` and
    ``compute_motor_torque`` include ``K_s (q - q_s)`` (see :meth:`compute_spring_torque`); the raw
    Pinocchio functions on :attr:`pin_model` and the inertial regressor do not (Pinocchio has no springs).
    ``notes`` lists what was dropped from the file or is not modelled (each also given as a
    :class:`RobotFileWarning` when the file is loaded). ``cut`` (a ``ChainCut`` or ``None``) records the
    base and tip links and the locked joints of an arm cut out of a larger robot file.
    """

    def __init__(
        self,
        model: pin.Model,
        *,
        ee_frame: str,
        sensor_frame: str | None = None,
        friction: CoulombViscousFriction | None = None,
        name: str = "",
        source: Path | None = None,
        home: npt.ArrayLike | None = None,
        spring_stiffness: npt.ArrayLike | None = None,
        spring_reference: npt.ArrayLike | None = None,
        notes: tuple[str, ...] | list[str] = (),
        cut: ChainCut | None = None,
    ) -> None:
        where = f" in {str(source)!r}" if source else ""
        if model.nq != model.nv:
            unbounded = [
                model.names[j]
                for j in range(1, model.njoints)
                if model.joints[j].shortname().startswith("JointModelRUB")
            ]
            hint = (
                f"; joint(s) {unbounded} are unbounded (continuous) revolute joints with nq=2: load the file with "
                "load_robot/RobotModel.from_file, which reads them as revolute joints with infinite limits"
                if unbounded
                else " (remove the free/ball joints)"
            )
            raise ModelError(
                f"robot{where} has nq={model.nq} != nv={model.nv}: only fixed-base arms with 1-DoF "
                f"joints are supported{hint}"
            )
        if model.nv == 0:
            raise ModelError(f"robot{where} has no joints")
        for j in range(1, model.njoints):
            if model.nvs[j] != 1:
                raise ModelError(
                    f"joint {model.names[j]!r}{where} has {model.nvs[j]} DoF; only 1-DoF joints are supported"
                )
            if model.parents[j] != j - 1:
                raise ModelError(
                    f"robot{where} is not a serial chain: joint {model.names[j]!r} hangs off "
                    f"{model.names[model.parents[j]]!r}, not off the previous joint {model.names[j - 1]!r}; "
                    "cut the arm out with base=/tip= (--base/--tip)"
                )
        self._model = model
        self._data = model.createData()
        self.name = name or model.name
        self.source = source
        frames = [f.name for f in model.frames]
        self.ee_frame = ee_frame
        self.sensor_frame = sensor_frame or ee_frame
        for label, f in (("end-effector", self.ee_frame), ("sensor", self.sensor_frame)):
            if not model.existFrame(f):
                raise ModelError(f"unknown {label} frame {f!r}{where}; frames are: {', '.join(frames)}")
        self.ee_frame_id = model.getFrameId(self.ee_frame)
        self.sensor_frame_id = model.getFrameId(self.sensor_frame)
        n = model.nv
        if friction is None:
            friction = CoulombViscousFriction(
                np.maximum(np.asarray(model.friction, dtype=float), 0.0),
                np.maximum(np.asarray(model.damping, dtype=float), 0.0),
            )
        if friction.n != n:
            raise ModelError(f"friction model has {friction.n} joints; robot{where} has {n}")
        self.friction = friction
        self.home = np.zeros(n) if home is None else np.asarray(home, dtype=float).copy()
        self._spring_k = _joint_vector(spring_stiffness, n, "spring_stiffness", where, nonnegative=True)
        self._spring_q = _joint_vector(spring_reference, n, "spring_reference", where)
        self._has_springs = bool(np.any(self._spring_k != 0.0))
        self.notes = tuple(notes)
        self.cut = cut

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_file(
        cls,
        path: str | os.PathLike[str],
        *,
        ee_frame: str | None,
        sensor_frame: str | None = None,
        friction: CoulombViscousFriction | None = None,
        name: str = "",
        home: npt.ArrayLike | None = None,
        base: str | None = None,
        tip: str | None = None,
        locked: Mapping[str, float] | None = None,
    ) -> RobotModel:
        """Load a URDF or MJCF file (see :func:`load_robot`); notes are given as :class:`RobotFileWarning`."""
        p = Path(path)
        model, loaded = build_pinocchio_model(p, base=base, tip=tip, locked=locked)
        if ee_frame is None and loaded.cut is None:
            last = [f.name for f in model.frames if f.parentJoint == model.njoints - 1]
            raise ModelError(
                f"loading {str(p)!r}: name the end-effector frame (ee_frame=..., --ee-frame); frames on the last "
                f"joint {model.names[model.njoints - 1]!r}: {', '.join(last)} (`reflexarm robots FILE` lists them all)"
            )
        robot = cls(
            model,
            ee_frame=ee_frame or loaded.cut.tip,  # type: ignore[union-attr]  # checked above
            sensor_frame=sensor_frame,
            friction=friction,
            name=name or p.stem,
            source=p,
            home=home,
            spring_stiffness=loaded.spring_stiffness,
            spring_reference=loaded.spring_reference,
            notes=loaded.notes,
            cut=loaded.cut,
        )
        frames = (robot.ee_frame, robot.sensor_frame)
        for note in robot.notes + frame_notes(robot.pin_model, frames, robot.cut, p):
            warn_note(note, stacklevel=3)
        return robot

    def copy(self) -> RobotModel:
        """An independent copy (own Pinocchio model and data)."""
        return RobotModel(
            self._model.copy(),
            ee_frame=self.ee_frame,
            sensor_frame=self.sensor_frame,
            friction=self.friction,
            name=self.name,
            source=self.source,
            home=self.home,
            spring_stiffness=self._spring_k,
            spring_reference=self._spring_q,
            notes=self.notes,
            cut=self.cut,
        )

    def with_friction(self, friction: CoulombViscousFriction) -> RobotModel:
        """A copy with another friction model."""
        out = self.copy()
        if friction.n != self.n:
            raise ModelError(f"friction model has {friction.n} joints; robot has {self.n}")
        out.friction = friction
        return out

    def with_inertial_parameters(self, parameters: npt.ArrayLike) -> RobotModel:
        """A copy whose link inertias are set from a (10 n,) vector (see :meth:`inertial_parameters`)."""
        pi = np.asarray(parameters, dtype=float).reshape(-1)
        if pi.size != 10 * self.n:
            raise ModelError(f"expected {10 * self.n} inertial parameters (10 per joint); got {pi.size}")
        out = self.copy()
        for j in range(1, self._model.njoints):
            out._model.inertias[j] = pin.Inertia.FromDynamicParameters(pi[10 * (j - 1) : 10 * j])
        out._data = out._model.createData()
        return out

    # ------------------------------------------------------------------ facts
    @property
    def pin_model(self) -> pin.Model:
        """The underlying Pinocchio model (do not modify in place; use the ``with_*`` methods)."""
        return self._model

    @property
    def n(self) -> int:
        """Number of joints n_j."""
        return int(self._model.nv)

    @property
    def joint_names(self) -> list[str]:
        return list(self._model.names)[1:]

    @property
    def frame_names(self) -> list[str]:
        return [f.name for f in self._model.frames]

    @property
    def lower_limit(self) -> np.ndarray:
        """Joint position lower limits [rad]."""
        return np.asarray(self._model.lowerPositionLimit, dtype=float).copy()

    @property
    def upper_limit(self) -> np.ndarray:
        """Joint position upper limits [rad]."""
        return np.asarray(self._model.upperPositionLimit, dtype=float).copy()

    @property
    def velocity_limit(self) -> np.ndarray:
        """Joint velocity limits [rad/s]."""
        return np.asarray(self._model.velocityLimit, dtype=float).copy()

    @property
    def effort_limit(self) -> np.ndarray:
        """Joint torque limits [Nm]."""
        return np.asarray(self._model.effortLimit, dtype=float).copy()

    @property
    def gravity(self) -> np.ndarray:
        """Gravity vector in the base frame [m/s^2]."""
        return np.asarray(self._model.gravity.linear, dtype=float).copy()

    @gravity.setter
    def gravity(self, value: npt.ArrayLike) -> None:
        g = np.asarray(value, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise ModelError(f"gravity must be a finite 3-vector; got {value!r}")
        self._model.gravity.linear = g

    def frame_id(self, frame: str) -> int:
        """Index of a named frame; raises :class:`ModelError` listing the frames if unknown."""
        if not self._model.existFrame(frame):
            raise ModelError(f"unknown frame {frame!r}; frames are: {', '.join(self.frame_names)}")
        return int(self._model.getFrameId(frame))

    @property
    def spring_stiffness(self) -> np.ndarray:
        """Joint spring stiffness K_s (n,) [Nm/rad or N/m] (MJCF ``stiffness``; 0 without springs)."""
        return self._spring_k.copy()

    @property
    def spring_reference(self) -> np.ndarray:
        """Joint spring rest positions q_s (n,) [rad or m] (MJCF ``springref``)."""
        return self._spring_q.copy()

    @property
    def has_springs(self) -> bool:
        """Whether any joint has a spring (then :meth:`compute_spring_torque` is not zero)."""
        return self._has_springs

    # ------------------------------------------------------------------ dynamics (1)
    def _check_q(self, q: npt.ArrayLike, name: str = "q") -> np.ndarray:
        arr = np.asarray(q, dtype=float)
        if arr.shape != (self.n,):
            raise ModelError(f"{name} must have shape ({self.n},); got {arr.shape}")
        return arr

    def compute_mass_matrix(self, q: npt.ArrayLike) -> np.ndarray:
        """M(q), symmetric positive definite (n, n) [kg m^2]."""
        M = pin.crba(self._model, self._data, self._check_q(q))
        return np.triu(M) + np.triu(M, 1).T

    def compute_coriolis_matrix(self, q: npt.ArrayLike, dq: npt.ArrayLike) -> np.ndarray:
        """C(q, dq) with M_dot - 2 C skew-symmetric (n, n)."""
        C = pin.computeCoriolisMatrix(self._model, self._data, self._check_q(q), self._check_q(dq, "dq"))
        return np.array(C).reshape(self.n, self.n)

    def compute_spring_torque(self, q: npt.ArrayLike, out: np.ndarray | None = None) -> np.ndarray:
        """Joint spring torque K_s (q - q_s) (n,) [Nm], the torque the motors need to hold the springs.

        ``out``: optional (n,) float array to write into (no allocation; for a control loop).
        """
        arr = self._check_q(q)
        res = np.empty(self.n) if out is None else out
        np.subtract(arr, self._spring_q, out=res)
        np.multiply(res, self._spring_k, out=res)
        return res

    def compute_gravity(self, q: npt.ArrayLike) -> np.ndarray:
        """g(q) [Nm]: the potential term of (1), gravity plus joint springs K_s (q - q_s)."""
        qa = self._check_q(q)
        g = np.array(pin.computeGeneralizedGravity(self._model, self._data, qa))
        return g + self.compute_spring_torque(qa) if self._has_springs else g

    def compute_nonlinear_effects(self, q: npt.ArrayLike, dq: npt.ArrayLike) -> np.ndarray:
        """C(q, dq) dq + g(q) [Nm] (g with the joint springs)."""
        qa = self._check_q(q)
        h = np.array(pin.nonLinearEffects(self._model, self._data, qa, self._check_q(dq, "dq")))
        return h + self.compute_spring_torque(qa) if self._has_springs else h

    def compute_inverse_dynamics(self, q: npt.ArrayLike, dq: npt.ArrayLike, ddq: npt.ArrayLike) -> np.ndarray:
        """M ddq + C dq + g (rigid body and joint springs, no friction) [Nm]."""
        qa = self._check_q(q)
        tau = np.array(pin.rnea(self._model, self._data, qa, self._check_q(dq, "dq"), self._check_q(ddq, "ddq")))
        return tau + self.compute_spring_torque(qa) if self._has_springs else tau

    def compute_motor_torque(self, q: npt.ArrayLike, dq: npt.ArrayLike, ddq: npt.ArrayLike) -> np.ndarray:
        """tau_m of (1) with tau_ext = 0: M ddq + C dq + g + tau_f(dq) [Nm]."""
        return self.compute_inverse_dynamics(q, dq, ddq) + self.friction.compute_torque(dq)

    def compute_frame_jacobian(
        self, q: npt.ArrayLike, frame: str | None = None, *, world_aligned: bool = False
    ) -> np.ndarray:
        """6 x n Jacobian (linear; angular) of ``frame`` (default: the sensor frame).

        With ``world_aligned=False`` the twist is expressed in the frame itself (LOCAL), so that
        ``J.T @ wrench`` maps a wrench measured in that frame, about its origin, to joint torques.
        """
        fid = self.sensor_frame_id if frame is None else self.frame_id(frame)
        ref = pin.LOCAL_WORLD_ALIGNED if world_aligned else pin.LOCAL
        J = pin.computeFrameJacobian(self._model, self._data, self._check_q(q), fid, ref)
        return np.array(J).reshape(6, self.n)  # eigenpy returns a one-column matrix as a vector

    def compute_frame_pose(self, q: npt.ArrayLike, frame: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(R, p) of ``frame`` (default: the end effector) in the base frame."""
        fid = self.ee_frame_id if frame is None else self.frame_id(frame)
        pin.framesForwardKinematics(self._model, self._data, self._check_q(q))
        M = self._data.oMf[fid]
        return np.array(M.rotation), np.array(M.translation)

    # ------------------------------------------------------------------ parameters / regressor
    def inertial_parameters(self) -> np.ndarray:
        """The 10 n inertial parameters (see ``INERTIAL_PARAMETER_NAMES``), link by link."""
        return np.concatenate(
            [np.asarray(self._model.inertias[j].toDynamicParameters()) for j in range(1, self._model.njoints)]
        )

    def inertial_parameter_names(self) -> list[str]:
        return [f"{p}_{j}" for j in self.joint_names for p in INERTIAL_PARAMETER_NAMES]

    def compute_regressor(self, q: npt.ArrayLike, dq: npt.ArrayLike, ddq: npt.ArrayLike) -> np.ndarray:
        """Joint-torque regressor Y(q, dq, ddq), (n, 10 n): ``Y @ inertial_parameters() == rnea``.

        Rigid body only: with joint springs, ``compute_inverse_dynamics == Y @ pi + compute_spring_torque``.
        """
        return np.array(
            pin.computeJointTorqueRegressor(
                self._model, self._data, self._check_q(q), self._check_q(dq, "dq"), self._check_q(ddq, "ddq")
            )
        ).reshape(self.n, 10 * self.n)

    def load_arguments(self) -> dict[str, Any]:
        """Keyword arguments of :func:`load_robot` that rebuild this robot from :attr:`source` (frames, and
        ``base``/``tip``/``locked`` when it was cut): JSON-ready, for model files and reports."""
        out: dict[str, Any] = {"ee_frame": self.ee_frame, "sensor_frame": self.sensor_frame}
        if self.cut is not None:
            out.update(self.cut.as_dict())
        return out

    def __repr__(self) -> str:
        cut = f", base={self.cut.base!r}, tip={self.cut.tip!r}" if self.cut is not None else ""
        frames = f"ee_frame={self.ee_frame!r}, sensor_frame={self.sensor_frame!r}"
        return f"RobotModel({self.name!r}, n={self.n}, {frames}{cut})"


def _joint_vector(
    value: npt.ArrayLike | None, n: int, name: str, where: str, *, nonnegative: bool = False
) -> np.ndarray:
    if value is None:
        return np.zeros(n)
    arr = np.array(value, dtype=float).reshape(-1) if np.ndim(value) else np.full(n, float(value))  # type: ignore[arg-type]
    if arr.shape != (n,) or not np.all(np.isfinite(arr)) or (nonnegative and np.any(arr < 0.0)):
        raise ModelError(
            f"{name}{where} must be a finite{' non-negative' if nonnegative else ''} ({n},) array; got {value!r}"
        )
    return arr
