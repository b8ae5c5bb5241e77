"""Isolation and identification in the C++ core: :class:`CoreContactIsolator` (``reflexarm::ContactIsolator``).

The same algorithm as :class:`~reflexarm.control.collision.isolate.ContactIsolator` (see its module docstring),
ported to C++ (``cpp/src/isolation.cpp``): buffers sized once at construction, an ``isolate`` that allocates
nothing. Same constructor, same :class:`~reflexarm.control.collision.contact.ContactEstimate` (reason text
included); the Python class stays the plain implementation the tests compare it with
(``tests/test_isolation_core.py``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

import reflexarm._core as _core
from reflexarm.control.collision.contact import ContactEstimate, Determined
from reflexarm.control.collision.isolate import RELATIVE_TOLERANCE, ContactIsolator
from reflexarm.errors import ConfigError
from reflexarm.robots.collision_geometry import CollisionGeometry
from reflexarm.robots.robot_model import RobotModel

__all__ = ["CoreContactIsolator", "estimate_from_core"]

#: ``determined`` codes of the core (``reflexarm::Determined``), in order.
_DETERMINED = (Determined.POINT_AND_FORCE, Determined.FORCE_ONLY, Determined.LINK_ONLY, Determined.NONE)
#: ``cause`` codes of the core (``reflexarm::IsolationCause``).
_NO_SIGNIFICANT_JOINT, _NO_GEOMETRY, _FORCE_RANK, _FORCES_DISAGREE, _NO_SINGLE_CONTACT = 1, 2, 3, 4, 5


class CoreContactIsolator(ContactIsolator):
    """:class:`ContactIsolator` whose :meth:`isolate` runs in the C++ core (same arguments, same results).

    Args:
        robot: the controller's model.
        significance: per-joint level [Nm] above which a residual component counts (scalar or (n,), positive).
        geometry: the links' collision surfaces; default ``link_collision_geometry(robot, spacing=spacing)``.
        spacing: candidate point spacing [m] when ``geometry`` is not given.
        fit_tolerance: absolute part of the fit tolerance, >= 0 (weighted norm).
        relative_tolerance: relative part, a fraction of |W r|, >= 0.
        friction_coefficient: mu of the friction cone at the contact.
        cone_edges: generators of the linearised friction cone, >= 3.

    Raises:
        ConfigError: as :class:`ContactIsolator`, or a model the core cannot take (one dof per joint needed).
    """

    def __init__(
        self,
        robot: RobotModel,
        *,
        significance: npt.ArrayLike,
        geometry: CollisionGeometry | None = None,
        spacing: float = 0.01,
        fit_tolerance: float = 0.0,
        relative_tolerance: float = RELATIVE_TOLERANCE,
        friction_coefficient: float = 0.5,
        cone_edges: int = 8,
    ) -> None:
        super().__init__(
            robot,
            significance=significance,
            geometry=geometry,
            spacing=spacing,
            fit_tolerance=fit_tolerance,
            relative_tolerance=relative_tolerance,
            friction_coefficient=friction_coefficient,
            cone_edges=cone_edges,
        )
        if self.geometry.n != self.n:
            raise ConfigError(f"geometry has {self.geometry.n} links; the robot {robot.name!r} has {self.n} joints")
        points = [np.ascontiguousarray(s.points, dtype=float).reshape(-1, 3) for s in self.geometry.links]
        normals = [np.ascontiguousarray(s.normals, dtype=float).reshape(-1, 3) for s in self.geometry.links]
        try:
            self._core = _core.ContactIsolator(
                robot.pin_model.saveToString(),
                points,
                normals,
                np.ascontiguousarray(self.significance, dtype=float),
                self.fit_tolerance,
                self.relative_tolerance,
                self.identifier.friction_coefficient,
                self.identifier.cone_edges,
            )
        except ValueError as e:  # the core's ConfigError: the checks above should have caught it
            raise ConfigError(f"the C++ core refused the isolator's parameters: {e}") from e

    def isolate(self, q: npt.ArrayLike, residual: npt.ArrayLike) -> ContactEstimate:
        """Contact link, point and force from the residual at configuration ``q`` (in the C++ core).

        Args:
            q: (n,) joint positions [rad].
            residual: (n,) the observer's estimate of tau_ext [Nm].

        Raises:
            SignalError: wrong shape or type, or a non-finite value (naming the joints).
        """
        qa, r = self._check(q, "q"), self._check(residual, "residual")
        return self._estimate(self._core.isolate(np.ascontiguousarray(qa), np.ascontiguousarray(r)))

    def _estimate(self, out: dict[str, Any]) -> ContactEstimate:
        """The core's result dict as the ContactEstimate (and reason text) of the Python isolator."""
        return estimate_from_core(out, self.geometry)


def estimate_from_core(out: dict[str, Any], geometry: CollisionGeometry) -> ContactEstimate:
    """A ``reflexarm::ContactEstimateData`` (as the bindings' dict) as the ContactEstimate, with the reason text of
    the Python isolator (``geometry``: the surfaces the core was given, for the links' names)."""
    cause = int(out["cause"])
    if cause == _NO_SIGNIFICANT_JOINT:
        return ContactEstimate.none(
            "no joint residual above its significance level: no contact the joints can sense "
            f"(max |r_j| / level_j = {float(out['max_significance_ratio']):.3g})"
        )
    link = int(out["link"])
    first = int(out["first_candidate"])
    candidates = tuple(range(first, first + int(out["candidate_count"])))
    surface = geometry.links[link]
    count = int(out["consistent_points"])
    spread = float(out["point_spread"])
    tol = float(out["tolerance"])
    rank_text = f"the link's Jacobian has rank {out['link_rank']} (5 needed for point and force)"
    along = (
        f"over the {count} consistent point(s) (up to {spread * 100:.1f} cm apart) the force varies by "
        f"{float(out['force_variation']) * 100:.1f} % and {float(out['direction_variation_deg']):.1f} deg"
    )
    determined = _DETERMINED[int(out["determined"])]
    if cause == _NO_GEOMETRY:
        reason = (
            f"point unknown: link {surface.link_name!r} (joint {surface.joint_name!r}) has no collision "
            "geometry; force undetermined"
        )
    elif cause == _FORCE_RANK:
        reason = (
            f"point undetermined, force undetermined: J_c^T has rank {out['force_rank']} at the best point (3 "
            f"needed for the force); {rank_text}"
        )
    elif cause == _FORCES_DISAGREE:
        reason = f"point undetermined, force undetermined: {rank_text}; {along}"
    elif cause == _NO_SINGLE_CONTACT:
        reason = (
            f"no single contact force on links {candidates[0]}..{candidates[-1]} explains the residual (weighted "
            f"best fit error {float(out['best_fit']):.3g} > tolerance {tol:.3g}): several contacts, an external "
            "moment or a model error beyond the tolerance; point undetermined, force undetermined"
        )
    elif determined is Determined.FORCE_ONLY:
        reason = f"point undetermined: {rank_text}; {along}"
    else:
        reason = (
            f"{rank_text}; {count} candidate point(s) within {tol:.3g} Nm of the best fit, up to "
            f"{spread * 100:.1f} cm from it"
        )
    point, force = out["point"], out["force"]
    return ContactEstimate(
        link,
        surface.link_name,
        None if point is None else np.asarray(point),
        None if force is None else np.asarray(force),
        float(out["fit_error"]),
        determined,
        reason,
        candidates,
        count,
        spread,
    )
