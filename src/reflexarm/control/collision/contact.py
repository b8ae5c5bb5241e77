"""The contact estimate of the isolate and identify stages: which link, where, how hard, and what is known."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np

__all__ = ["ContactEstimate", "Determined", "sensor_estimate"]


class Determined(StrEnum):
    """What the joint residual determines about a contact.

    - ``POINT_AND_FORCE``: the link, the contact point on its surface and the force.
    - ``FORCE_ONLY``: the link and the force (every consistent point gives about the same force); the point
      is undetermined.
    - ``LINK_ONLY``: the link; point and force undetermined (too few independent residual components on a
      proximal link, a link without collision geometry, or a residual no single contact explains).
    - ``NONE``: no contact the joints can sense (no joint residual above its significance level).
    """

    POINT_AND_FORCE = "point_and_force"
    FORCE_ONLY = "force_only"
    LINK_ONLY = "link_only"
    NONE = "none"


@dataclass(frozen=True)
class ContactEstimate:
    """One contact as isolated and identified from the joint residual.

    Attributes:
        link: 0-based index of the joint whose link was hit; -1 for none.
        link_name: the link's (body's) name; ``""`` for none.
        point: (3,) contact point in the world (base) frame [m], or ``None`` when undetermined.
        force: (3,) contact force on the link in the world frame [N], or ``None`` when undetermined.
        fit_error: ``|J_c^T f - r|`` at the estimate [Nm] (for a link without geometry: the error of the best
            wrench at the link origin, a lower bound); ``nan`` for none.
        determined: what the residual determines (see :class:`Determined`).
        reason: why, in words (ranks, tolerances, "point unknown" for a link without collision geometry).
        candidate_links: links examined (the most distal significant joint's link and every link after it).
        consistent_points: number of candidate points on the link whose fit is within the tolerance of the best.
        point_spread: largest distance of those points from the estimate [m] (``nan`` when not applicable).
    """

    link: int
    link_name: str
    point: np.ndarray | None
    force: np.ndarray | None
    fit_error: float
    determined: Determined
    reason: str
    candidate_links: tuple[int, ...] = field(default=())
    consistent_points: int = 0
    point_spread: float = float("nan")

    @classmethod
    def none(cls, reason: str) -> ContactEstimate:
        """No contact the joints can sense."""
        return cls(-1, "", None, None, float("nan"), Determined.NONE, reason)

    @classmethod
    def from_dict(cls, record: dict[str, Any]) -> ContactEstimate:
        """The estimate back from :meth:`as_dict`."""
        point, force = record["point"], record["force"]
        return cls(
            int(record["link"]),
            str(record["link_name"]),
            None if point is None else np.asarray(point, dtype=float),
            None if force is None else np.asarray(force, dtype=float),
            float("nan") if record["fit_error"] is None else float(record["fit_error"]),
            Determined(record["determined"]),
            str(record["reason"]),
            tuple(int(i) for i in record["candidate_links"]),
            int(record["consistent_points"]),
            float("nan") if record["point_spread"] is None else float(record["point_spread"]),
        )

    def as_dict(self) -> dict[str, object]:
        """JSON-ready."""
        return {
            "link": self.link,
            "link_name": self.link_name,
            "point": None if self.point is None else self.point.tolist(),
            "force": None if self.force is None else self.force.tolist(),
            "fit_error": self.fit_error,
            "determined": self.determined.value,
            "reason": self.reason,
            "candidate_links": list(self.candidate_links),
            "consistent_points": self.consistent_points,
            "point_spread": self.point_spread,
        }


def sensor_estimate(sensor_frame: str, link: int, point: object, force: object) -> ContactEstimate:
    """The ContactEstimate of a contact the wrist sensor measured (the measured force, a point of its line of
    action); ``sensor_frame`` "" when the sensor has no name to give."""
    where = f" {sensor_frame!r}" if sensor_frame else ""
    return ContactEstimate(
        link,
        sensor_frame,
        np.asarray(point, dtype=float),
        np.asarray(force, dtype=float),
        0.0,
        Determined.POINT_AND_FORCE,
        f"measured by the wrist sensor{where}: force and its line of action; the point is the one of that line "
        "closest to the sensor origin",
        (link,),
    )
