"""Coulomb + viscous (+ offset) friction parameters per joint, eq. (15), as identified.

The identification's own bundle (exact sign, optional constant offsets); :meth:`FrictionParameters.to_model`
turns it into the controller's :class:`~reflexarm.robots.friction.CoulombViscousFriction`.

Joints whose friction is not known (no single-joint run: ``identify friction --joints``, or the Atlas
default of the hydraulic joints only) hold NaN, written as ``null`` by :meth:`FrictionParameters.to_dict`;
never 0, which would be a friction value. :meth:`~FrictionParameters.compute_torque` and
:meth:`~FrictionParameters.to_model` refuse them (:class:`MissingFrictionError`);
:func:`~reflexarm.ident.identify_dynamics` (sequential) estimates them in the least squares.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from reflexarm.errors import IdentificationError
from reflexarm.robots.friction import DEFAULT_VELOCITY_BAND, CoulombViscousFriction
from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "COULOMB_EFFORT_FRACTION",
    "VISCOUS_EFFORT_FRACTION",
    "FrictionParameters",
    "ImplausibleFrictionWarning",
    "MissingFrictionError",
    "check_friction_against_robot",
    "check_friction_plausibility",
]


class MissingFrictionError(IdentificationError):
    """Friction coefficients are needed for joints whose friction is not known (NaN: not identified).

    Attributes:
        joints: the 0-based joints without coefficients (messages give them 1-based).
    """

    def __init__(self, message: str, *, joints: tuple[int, ...]) -> None:
        super().__init__(message)
        self.joints = joints


def format_joints(joints: Sequence[int], joint_names: Sequence[str] | None = None) -> str:
    """0-based ``joints`` as people read them: ``"2 (elbow), 3 (wrist_1)"`` (1-based, with names if given)."""
    if joint_names is None:
        return ", ".join(str(j + 1) for j in joints)
    return ", ".join(f"{j + 1} ({joint_names[j]})" for j in joints)


@dataclass(frozen=True)
class FrictionParameters:
    """Coulomb + viscous (+ offset) friction per joint, eq. (15), exact sign.

    Attributes:
        viscous: d_v [Nms/rad] (n,); NaN for a joint whose friction is not known (see :attr:`missing`).
        coulomb: mu_C [Nm] (n,); NaN exactly where ``viscous`` is.
        offset: constant torque [Nm] (n,) or None; NaN allowed only on the joints of :attr:`missing`.
    """

    viscous: np.ndarray
    coulomb: np.ndarray
    offset: np.ndarray | None = None

    def __post_init__(self) -> None:
        v = np.asarray(self.viscous, dtype=float).reshape(-1)
        c = np.asarray(self.coulomb, dtype=float).reshape(-1)
        if v.shape != c.shape:
            raise IdentificationError(f"viscous {v.shape} and coulomb {c.shape} must have one value per joint")
        if np.any(np.isinf(v)) or np.any(np.isinf(c)) or np.any(np.isnan(v) != np.isnan(c)):
            raise IdentificationError(
                f"friction coefficients must be finite, or NaN for both d_v and mu_C of a joint whose friction is "
                f"not known; got viscous {v.tolist()}, coulomb {c.tolist()}"
            )
        object.__setattr__(self, "viscous", v)
        object.__setattr__(self, "coulomb", c)
        if self.offset is not None:
            o = np.asarray(self.offset, dtype=float).reshape(-1)
            if o.shape != v.shape:
                raise IdentificationError(f"offset {o.shape} must have one value per joint like viscous {v.shape}")
            if np.any(np.isinf(o)) or np.any(np.isnan(o) & ~np.isnan(v)):
                raise IdentificationError(
                    f"offsets must be finite on every joint with known friction (NaN only where d_v, mu_C are); "
                    f"got offset {o.tolist()}, viscous {v.tolist()}"
                )
            object.__setattr__(self, "offset", o)

    @property
    def n(self) -> int:
        return int(self.viscous.size)

    @property
    def missing(self) -> tuple[int, ...]:
        """0-based joints whose friction is not known (NaN); () when every joint has coefficients."""
        return tuple(int(j) for j in np.flatnonzero(np.isnan(self.viscous)))

    @property
    def known(self) -> tuple[int, ...]:
        """0-based joints with coefficients (the complement of :attr:`missing`)."""
        return tuple(int(j) for j in np.flatnonzero(~np.isnan(self.viscous)))

    def restricted_to(self, joints: Sequence[int]) -> FrictionParameters:
        """These coefficients on the 0-based ``joints`` only; every other joint not known (NaN).

        E.g. the result of :func:`~reflexarm.ident.friction_from_fits` (0 for joints without a fit) restricted
        to the fitted joints.
        """
        keep = np.zeros(self.n, dtype=bool)
        keep[list(joints)] = True
        off = None if self.offset is None else np.where(keep, self.offset, np.nan)
        return FrictionParameters(np.where(keep, self.viscous, np.nan), np.where(keep, self.coulomb, np.nan), off)

    def _require_complete(self, what: str) -> None:
        missing = self.missing
        if missing:
            raise MissingFrictionError(
                f"{what} needs every joint's friction; joint(s) {format_joints(missing)} (1-based) of {self.n} have "
                "none (not identified). Identify them (single-joint runs) or let identify_dynamics "
                "(method='sequential') estimate them in the least squares",
                joints=missing,
            )

    @classmethod
    def from_model(cls, friction: CoulombViscousFriction) -> FrictionParameters:
        """From a :class:`CoulombViscousFriction` (no offsets)."""
        return cls(friction.viscous.copy(), friction.coulomb.copy())

    def parameters(self) -> np.ndarray:
        """(d_v, mu_C[, offset]) stacked, the column order of :func:`compute_friction_regressor`."""
        parts = [self.viscous, self.coulomb] + ([self.offset] if self.offset is not None else [])
        return np.concatenate(parts)

    def compute_torque(self, dq: npt.ArrayLike) -> np.ndarray:
        """tau_f = d_v dq + mu_C sgn(dq) [+ offset], exact sign, for (n,) or (N, n) velocities [Nm]."""
        self._require_complete("the friction torque")
        dq = np.asarray(dq, dtype=float)
        out = self.viscous * dq + self.coulomb * np.sign(dq)
        return out + self.offset if self.offset is not None else out

    def to_model(self, velocity_band: float = DEFAULT_VELOCITY_BAND) -> CoulombViscousFriction:
        """The controller's friction model (negative coefficients clipped to 0; offsets are not part of it)."""
        self._require_complete("the controller's friction model")
        return CoulombViscousFriction(
            np.maximum(self.coulomb, 0.0), np.maximum(self.viscous, 0.0), velocity_band=velocity_band
        )

    def to_dict(self) -> dict[str, object]:
        """``viscous``, ``coulomb``, ``offset`` lists (``null`` for a joint whose value is not known)."""
        return {
            "viscous": _with_nulls(self.viscous),
            "coulomb": _with_nulls(self.coulomb),
            "offset": None if self.offset is None else _with_nulls(self.offset),
        }

    @classmethod
    def from_dict(cls, d: dict[str, object]) -> FrictionParameters:
        """From :meth:`to_dict`'s layout; ``null`` entries are joints whose friction is not known."""
        try:
            return cls(
                _from_nulls(d["viscous"]),
                _from_nulls(d["coulomb"]),
                None if d.get("offset") is None else _from_nulls(d["offset"]),
            )
        except (KeyError, TypeError, ValueError) as e:
            raise IdentificationError(f"malformed friction description: {e}") from e


def _with_nulls(values: np.ndarray) -> list[float | None]:
    return [None if np.isnan(x) else float(x) for x in values]


def _from_nulls(values: object) -> np.ndarray:
    if isinstance(values, np.ndarray):
        return values.astype(float)
    if not isinstance(values, (list, tuple)):
        raise TypeError(f"expected a list of numbers (null: not known); got {values!r}")
    return np.array([np.nan if x is None else float(x) for x in values], dtype=float)


class ImplausibleFrictionWarning(UserWarning):
    """An identified friction coefficient is negative or implausibly large for the joint.

    Attributes:
        joint: 0-based joint index (messages give it 1-based, with the joint's name).
        parameter: ``"coulomb"`` (mu_C [Nm]) or ``"viscous"`` (d_v [Nms/rad]).
        value: the identified value.
        bound: the bound it violates (0 for a negative value).
    """

    def __init__(self, message: str, *, joint: int, parameter: str, value: float, bound: float) -> None:
        super().__init__(message)
        self.joint = joint
        self.parameter = parameter
        self.value = value
        self.bound = bound


#: mu_C above this fraction of the joint's effort limit is reported as implausible: such a joint would
#: spend more than half of its motor's torque on Coulomb friction alone (the robot files shipped here have
#: 1-16 %: Panda 0.15-0.64 Nm of 12-87 Nm, Atlas arm 0.1-10.3 Nm of 25-112 Nm).
COULOMB_EFFORT_FRACTION = 0.5
#: A negative coefficient within this many standard deviations of 0 (or above -:data:`ROUND_OFF` when no
#: deviation is known) is not reported: it is 0 within the estimate's uncertainty (2: a ~95 % interval).
NEGATIVE_SIGMAS = 2.0
#: Coefficients above -this [Nm or Nms/rad] are round-off of 0 (noise-free data give ~1e-12).
ROUND_OFF = 1e-9
#: d_v times the velocity limit above this fraction of the effort limit is implausible: viscous friction
#: alone would exceed the motor's torque before the joint reaches its velocity limit.
VISCOUS_EFFORT_FRACTION = 1.0


def _implausible(
    friction: FrictionParameters, std: FrictionParameters | None, j: int, effort: float, vlim: float
) -> list[tuple[str, float, str]]:
    """(parameter, bound, why) of each implausible coefficient of joint ``j``."""
    found = []
    mu, dv = float(friction.coulomb[j]), float(friction.viscous[j])
    for parameter, value in (("coulomb", mu), ("viscous", dv)):
        sigma = 0.0 if std is None else float(getattr(std, parameter)[j])
        if value < -max(ROUND_OFF, NEGATIVE_SIGMAS * sigma):
            spread = f" ({-value / sigma:.1f} standard deviations below 0)" if sigma > 0 else ""
            found.append((
                parameter,
                0.0,
                f"is negative{spread}: friction cannot drive the joint (unmodelled effects, a torque offset or too "
                "little motion in one direction?); the controller's model clips it to 0",
            ))  # fmt: skip
    ok_effort = np.isfinite(effort) and effort > 0
    if ok_effort and mu > COULOMB_EFFORT_FRACTION * effort:
        found.append((
            "coulomb",
            COULOMB_EFFORT_FRACTION * effort,
            f"is implausibly large: above {COULOMB_EFFORT_FRACTION:g} x the effort limit {effort:.4g} Nm",
        ))  # fmt: skip
    if ok_effort and np.isfinite(vlim) and vlim > 0 and dv * vlim > VISCOUS_EFFORT_FRACTION * effort:
        found.append((
            "viscous",
            VISCOUS_EFFORT_FRACTION * effort / vlim,
            f"is implausibly large: at the velocity limit {vlim:.4g} rad/s it would take {dv * vlim:.4g} Nm, "
            f"above the effort limit {effort:.4g} Nm",
        ))  # fmt: skip
    return found


def check_friction_plausibility(
    friction: FrictionParameters,
    *,
    joint_names: Sequence[str] | None = None,
    effort_limit: npt.ArrayLike | None = None,
    velocity_limit: npt.ArrayLike | None = None,
    joints: Sequence[int] | None = None,
    std: FrictionParameters | None = None,
    source: str = "identified friction",
    stacklevel: int = 2,
) -> list[ImplausibleFrictionWarning]:
    """Warn (:class:`ImplausibleFrictionWarning`) for each negative or implausibly large coefficient.

    Negative mu_C or d_v is not friction (it would feed energy in); the controller's model clips it to 0
    (:meth:`FrictionParameters.to_model`). Too large: mu_C above :data:`COULOMB_EFFORT_FRACTION` of the
    effort limit, or d_v times the velocity limit above :data:`VISCOUS_EFFORT_FRACTION` of it (checked
    only where the limits are finite and positive).

    Args:
        friction: the coefficients.
        joint_names: names for the messages (default ``joint <k>``).
        effort_limit, velocity_limit: per joint [Nm], [rad/s] (e.g. from the robot file).
        joints: 0-based joints to check (default all).
        std: standard deviations of the estimates: a negative value within :data:`NEGATIVE_SIGMAS` of them
            of 0 is not reported (without: values above -:data:`ROUND_OFF`).
        source: what the coefficients are, for the messages.

    Returns:
        The warnings issued.
    """
    n = friction.n
    names = list(joint_names) if joint_names is not None else [f"joint {j + 1}" for j in range(n)]
    effort = np.full(n, np.inf) if effort_limit is None else np.broadcast_to(np.asarray(effort_limit, float), (n,))
    vlim = np.full(n, np.inf) if velocity_limit is None else np.broadcast_to(np.asarray(velocity_limit, float), (n,))
    issued: list[ImplausibleFrictionWarning] = []

    def warn(j: int, parameter: str, value: float, bound: float, why: str) -> None:
        unit = "Nm" if parameter == "coulomb" else "Nms/rad"
        symbol = "mu_C" if parameter == "coulomb" else "d_v"
        w = ImplausibleFrictionWarning(
            f"{source}: joint {j + 1} ({names[j]}) {parameter} friction {symbol} = {value:.4g} {unit} {why}",
            joint=j,
            parameter=parameter,
            value=value,
            bound=bound,
        )
        warnings.warn(w, stacklevel=stacklevel + 1)
        issued.append(w)

    for j in range(n) if joints is None else joints:
        for parameter, bound, why in _implausible(friction, std, j, effort[j], vlim[j]):
            warn(j, parameter, float(getattr(friction, parameter)[j]), bound, why)
    return issued


def check_friction_against_robot(
    friction: FrictionParameters,
    robot: RobotModel,
    *,
    joints: Sequence[int] | None = None,
    std: FrictionParameters | None = None,
    source: str = "identified friction",
    stacklevel: int = 2,
) -> list[ImplausibleFrictionWarning]:
    """:func:`check_friction_plausibility` with ``robot``'s joint names, effort and velocity limits."""
    return check_friction_plausibility(
        friction,
        joint_names=robot.joint_names,
        effort_limit=np.asarray(robot.pin_model.effortLimit, dtype=float),
        velocity_limit=robot.velocity_limit,
        joints=joints,
        std=std,
        source=source,
        stacklevel=stacklevel + 1,
    )
