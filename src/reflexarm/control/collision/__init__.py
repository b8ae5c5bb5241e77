"""The collision event pipeline after the observer, one stage per module, in the order a collision flows:

``detect`` (levels on the residual, eq. (12)) -> ``isolate`` (which link) -> ``identify`` (contact point and
wrench) -> ``classify`` (measured end-effector contact vs unmeasured link collision) -> ``react`` (gravity,
brake, retract, compliant), all filling one :class:`~reflexarm.control.collision.event.CollisionEvent`.
The real-time tick runs these stages in the C++ core (``cpp/src/``); the modules here are its Python face and
the plain implementations the tests compare it with.
"""

from reflexarm.control.collision.classify import SIGNIFICANCE_SHARE, estimate_contact
from reflexarm.control.collision.contact import ContactEstimate, Determined
from reflexarm.control.collision.detect import CollisionDetector
from reflexarm.control.collision.event import CollisionEvent
from reflexarm.control.collision.identify import ContactIdentifier
from reflexarm.control.collision.isolate import ContactIsolator
from reflexarm.control.collision.react import REACTIONS, ReactionSettings, check_reaction

__all__ = [
    "REACTIONS",
    "SIGNIFICANCE_SHARE",
    "CollisionDetector",
    "CollisionEvent",
    "ContactEstimate",
    "ContactIdentifier",
    "ContactIsolator",
    "Determined",
    "ReactionSettings",
    "check_reaction",
    "estimate_contact",
]
