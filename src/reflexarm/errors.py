"""One exception hierarchy for reflexarm.

Every error a user can see derives from :class:`ReflexArmError`. Messages name the value received,
the value expected and, where there is a finite set, the valid choices.
"""

from __future__ import annotations

__all__ = [
    "ConfigError",
    "DataError",
    "IdentificationError",
    "ImplausibleDataError",
    "ModelError",
    "NonFiniteEstimateError",
    "PoorlyDeterminedInertiaWarning",
    "ReflexArmError",
    "SignalError",
    "SimulationError",
]


class ReflexArmError(Exception):
    """Base class of every error raised by reflexarm."""


class ModelError(ReflexArmError):
    """A robot description cannot be loaded or does not fit (unknown robot, malformed file, missing frame)."""


class ConfigError(ReflexArmError, ValueError):
    """A parameter has the wrong shape, sign or value (gains, switches, levels, addresses)."""


class DataError(ReflexArmError, ValueError):
    """A log or time series is malformed (missing columns, NaN/inf, time going backwards).

    Attributes (None where they do not apply): ``source`` the log's name; ``column`` the column, field,
    topic or array concerned (for a missing signal: the names looked for); ``row`` the 0-based data
    row; ``joint`` the joint's name; ``value`` what was found; ``expected`` what was expected (a value,
    a description or the valid choices).
    """

    def __init__(
        self,
        message: str,
        *,
        source: str | None = None,
        column: object = None,
        row: int | None = None,
        joint: str | None = None,
        value: object = None,
        expected: object = None,
    ) -> None:
        super().__init__(message)
        self.source = source
        self.column = column
        self.row = row
        self.joint = joint
        self.value = value
        self.expected = expected


class IdentificationError(ReflexArmError):
    """An identification problem cannot be solved as posed."""


class ImplausibleDataError(DataError):
    """Logged values beyond a plausibility bound; ``samples`` holds the offending cells (source, row,
    time, column, value, bound), the first ones found."""

    def __init__(self, message: str, samples: tuple[object, ...] = ()) -> None:
        super().__init__(message)
        self.samples = samples


class NonFiniteEstimateError(IdentificationError):
    """Identification produced NaN/inf parameters; ``samples`` holds the rows that most likely caused it
    (source, row, time, column, value, typical magnitude of that column)."""

    def __init__(self, message: str, samples: tuple[object, ...] = ()) -> None:
        super().__init__(message)
        self.samples = samples


class PoorlyDeterminedInertiaWarning(UserWarning):
    """The identification data determine M(q) poorly
    (:mod:`reflexarm.ident.estimation.inertia_determinacy`): disturbance compensation with the model is risky.
    Attributes: ``median`` and ``max`` of the 1-sigma relative uncertainty u(q) over the postures,
    ``worst_posture`` (0-based joint order), ``threshold``."""

    def __init__(self, message: str, *, median: float, max: float, worst_posture: object, threshold: float) -> None:
        super().__init__(message)
        self.median = median
        self.max = max
        self.worst_posture = worst_posture
        self.threshold = threshold


class SimulationError(ReflexArmError):
    """The simulated plant failed (diverged, unknown scene, bad scene parameters)."""


class SignalError(ReflexArmError, ValueError):
    """A signal given to a real-time call has the wrong type or shape (a programming error, raised at once).

    Attributes:
        signal: the signal's name, e.g. ``"measurement dq"`` or ``"reference q_d"``.
        received: what was received (a shape, a dtype or a type name).
        expected: what was expected.
    """

    def __init__(self, signal: str, received: object, expected: str, detail: str = "") -> None:
        self.signal = signal
        self.received = received
        self.expected = expected
        message = f"{signal} must be {expected}; got {received}"
        super().__init__(message + (f" ({detail})" if detail else ""))
