"""Isolation: which link was hit, from the joint residual r (the observer's estimate of tau_ext = J_c^T f).

A point force on link i (0-based) produces no torque on the joints after i. So:

1. **Most distal significant joint** k: the largest j with ``|r_j| > significance_j`` (the detection
   threshold, or a noise level). No such joint: a contact the joints cannot sense (``Determined.NONE``).
2. **Candidate links** k..n-1: a force whose line of action crosses the axis of joint k+1 (or of several
   intersecting wrist axes) leaves that joint's torque at zero although it acts on a more distal link, so
   the links after k are examined too.
3. **Confirmation by the transposed Jacobian**: on each candidate link every surface point is scored by the
   friction-cone fit of :mod:`reflexarm.control.collision.identify` (the exhaustive Contact Particle
   Filter score ``|W (J_p^T f - r)|``, weighted per joint by ``W = min(significance) / significance``, the
   inverse noise level, as the Contact Particle Filter weights by the noise covariance; equal levels give
   the plain norm); a link without collision geometry is scored by its best wrench at the link origin (a
   lower bound: it may have been hit, but where cannot be said).
4. **Choice**: the most proximal candidate link whose best fit is within ``tolerance`` of the best fit of
   all candidates, ``tolerance = fit_tolerance + relative_tolerance * |W r|`` (the noise level plus the
   discretisation of the candidate points: about 1 cm spacing moves the fit by a few per cent of |r|).
   When several links explain the residual equally, the joints cannot tell them apart; the most proximal
   one is the one the residual *requires* (a contact there needs no particular line of action). The links are
   fitted from the most proximal on and the fit stops once the links fitted settle this choice (:func:`settled`:
   the first of them within ``tolerance`` of their best fit is within ``tolerance`` itself, so no later link can
   change it): the same estimate as fitting every candidate, at 0.28-0.37 of its work on seeded random contacts
   of Atlas, Panda and iiwa14 with noise (``python bench/bench_isolation.py``).
5. If no candidate explains the residual within ``tolerance`` (several contacts, an external moment, a
   model error larger than the stated tolerance), the link is reported with ``LINK_ONLY`` and the reason,
   never a guessed point.

Identification on the chosen link follows (:meth:`ContactIdentifier.estimate`). Methods and sources: see
``identify.py`` (Contact Particle Filter, Manuelli and Tedrake, IROS 2016; the patented line-of-action
method of Vorndamme et al., ICRA 2017, DE 10 2017 005 080.5 / US 2020/0061835, is not used).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from reflexarm._validation import as_vector
from reflexarm.control.collision.contact import ContactEstimate, Determined
from reflexarm.control.collision.identify import ContactIdentifier, LinkFit
from reflexarm.errors import ConfigError, SignalError
from reflexarm.robots.collision_geometry import CollisionGeometry, link_collision_geometry
from reflexarm.robots.robot_model import RobotModel

__all__ = ["RELATIVE_TOLERANCE", "ContactIsolator", "settled"]

#: Default relative part of the fit tolerance (fraction of |W r|): allowance for the candidate points' ~1 cm
#: spacing, which moves the best fit of an exact residual by a few per cent of |r| (an estimate: a 0.5 cm
#: offset on a ~20 cm lever; set before the isolation study was run, not tuned on it).
RELATIVE_TOLERANCE = 0.05


def settled(fits: list[LinkFit], tolerance: float) -> bool:
    """Whether the candidate links fitted so far (the first ones, in order) settle the choice, so that the later
    links need no fit (the C++ core's ``ContactIsolator::settled``, the same rule).

    With m the best of their fits, the first of them within ``m + tolerance`` is the only one of them that can still
    be chosen (an earlier one is above ``m + tolerance >= best + tolerance``, best the best over all candidates, at
    most m); if its own fit is within ``tolerance`` it is chosen whatever the later links hold (``<= tolerance <=
    best + tolerance``, as best >= 0), and the residual is explained (best <= tolerance). The estimate is then the one
    the fit of every candidate gives.
    """
    m = min(f.best_error for f in fits)
    first = next(f for f in fits if f.best_error <= m + tolerance)
    return first.best_error <= tolerance


class ContactIsolator:
    """Isolates the contact link and identifies point and force from the residual (see the module docstring).

    Args:
        robot: the controller's model.
        significance: per-joint level [Nm] above which a residual component counts (scalar or (n,),
            positive): the detection threshold zeta, or the residual's noise level.
        geometry: the links' collision surfaces; default ``link_collision_geometry(robot, spacing=spacing)``.
        spacing: candidate point spacing [m] when ``geometry`` is not given.
        fit_tolerance: absolute part of the fit tolerance, >= 0, in the weighted norm (the norm of the residual's
            noise weighted by W; [Nm] of the least noisy joint).
        relative_tolerance: relative part, a fraction of |W r|, >= 0.
        friction_coefficient: mu of the friction cone at the contact (0.5 as in the Contact Particle Filter).
        cone_edges: generators of the linearised friction cone, >= 3.

    Raises:
        ConfigError: bad levels, tolerances, geometry of another arm.
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
        self.robot = robot
        self.n = robot.n
        self.significance = as_vector(significance, self.n, "significance", positive=True)
        #: W of the weighted fit: the inverse significance, scaled so that the least noisy joint has weight 1
        self.weights = float(self.significance.min()) / self.significance
        for name, value in (("fit_tolerance", fit_tolerance), ("relative_tolerance", relative_tolerance)):
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value >= 0.0):
                raise ConfigError(f"{name} must be a finite number >= 0; got {value!r}")
        self.fit_tolerance = float(fit_tolerance)
        self.relative_tolerance = float(relative_tolerance)
        self.geometry = geometry if geometry is not None else link_collision_geometry(robot, spacing=spacing)
        self.identifier = ContactIdentifier(
            robot, self.geometry, friction_coefficient=friction_coefficient, cone_edges=cone_edges
        )

    def _check(self, value: npt.ArrayLike, name: str) -> np.ndarray:
        arr = np.asarray(value)
        if arr.shape != (self.n,) or not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
            got = f"shape {arr.shape} dtype {arr.dtype}" if hasattr(arr, "shape") else type(value).__name__
            raise SignalError(name, got, f"a real ({self.n},) array (one value per joint)")
        arr = arr.astype(float)
        if not np.all(np.isfinite(arr)):
            bad = [i for i in range(self.n) if not np.isfinite(arr[i])]
            raise SignalError(name, arr.tolist(), "finite", f"non-finite at joint(s) {bad}")
        return arr

    def tolerance(self, residual: np.ndarray) -> float:
        """The fit tolerance for this residual (weighted norm): ``fit_tolerance + relative_tolerance * |W r|``."""
        return self.fit_tolerance + self.relative_tolerance * float(np.linalg.norm(self.weights * residual))

    def candidate_links(self, residual: npt.ArrayLike) -> tuple[int, ...]:
        """The most distal joint with a significant residual and every link after it; ``()`` if none."""
        r = self._check(residual, "residual")
        significant = np.flatnonzero(np.abs(r) > self.significance)
        return tuple(range(int(significant[-1]), self.n)) if significant.size else ()

    def fit(self, q: npt.ArrayLike, residual: npt.ArrayLike) -> list[LinkFit]:
        """The fits of every candidate link (for inspection; :meth:`isolate` uses them)."""
        qa, r = self._check(q, "q"), self._check(residual, "residual")
        kin = self.identifier.kinematics(qa)
        return [self.identifier.fit_link(kin, link, r, self.weights) for link in self.candidate_links(r)]

    def isolate(self, q: npt.ArrayLike, residual: npt.ArrayLike) -> ContactEstimate:
        """Contact link, point and force from the residual at configuration ``q``.

        Args:
            q: (n,) joint positions [rad].
            residual: (n,) the observer's estimate of tau_ext [Nm].

        Raises:
            SignalError: wrong shape or type, or a non-finite value (naming the joints).
        """
        qa, r = self._check(q, "q"), self._check(residual, "residual")
        candidates = self.candidate_links(r)
        if not candidates:
            return ContactEstimate.none(
                "no joint residual above its significance level: no contact the joints can sense "
                f"(max |r_j| / level_j = {float(np.max(np.abs(r) / self.significance)):.3g})"
            )
        kin = self.identifier.kinematics(qa)
        tol = self.tolerance(r)
        fits: list[LinkFit] = []
        for link in candidates:  # from the most proximal on, until the links fitted settle the choice
            fits.append(self.identifier.fit_link(kin, link, r, self.weights))
            if settled(fits, tol):
                break
        best = min(f.best_error for f in fits)
        chosen = next(f for f in fits if f.best_error <= best + tol)
        estimate = self.identifier.estimate(chosen, r, tol, candidate_links=candidates)
        if best <= tol:
            return estimate
        return ContactEstimate(
            estimate.link,
            estimate.link_name,
            None,
            None,
            estimate.fit_error,
            Determined.LINK_ONLY,
            f"no single contact force on links {candidates[0]}..{candidates[-1]} explains the residual (weighted "
            f"best fit error {best:.3g} > tolerance {tol:.3g}): several contacts, an external moment or a model "
            "error beyond the tolerance; point undetermined, force undetermined",
            candidates,
            estimate.consistent_points,
            estimate.point_spread,
        )
