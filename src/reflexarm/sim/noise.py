"""Sensor noise of the simulated measurements: uniform, per component, as in Sec. III-C-2 of the paper."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from reflexarm.errors import ConfigError

__all__ = ["PAPER_NOISE", "SensorNoise"]


@dataclass(frozen=True)
class SensorNoise:
    """Half-widths of uniform sensor noise: each component gets an independent ``U(-level, +level)`` sample.

    Defaults are the paper's levels, "obtained from the measurement data of the hydraulic joints"
    (Sec. III-C-2). The paper gives no level for the wrist torque; ``torque`` = 0.23 Nm is our
    assumption: the force level 2.3 N acting on a 0.1 m lever (the size of a hand).

    Attributes:
        q: joint position [rad].
        dq: joint velocity [rad/s].
        gravity: gravity vector components [m/s^2].
        tau_m: motor torque [Nm].
        force: wrist force components [N].
        torque: wrist torque components [Nm] (assumed, see above).
    """

    q: float = 3.4e-4
    dq: float = 5.5e-2
    gravity: float = 2e-4
    tau_m: float = 7.3e-2
    force: float = 2.3
    torque: float = 0.23

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            try:
                x = float(value)
            except (TypeError, ValueError) as e:
                raise ConfigError(f"noise level {f.name} must be a non-negative number; got {value!r}") from e
            if not math.isfinite(x) or x < 0.0:
                raise ConfigError(f"noise level {f.name} must be a non-negative number; got {value!r}")
            object.__setattr__(self, f.name, x)

    @classmethod
    def none(cls) -> SensorNoise:
        """No noise at all (every level 0)."""
        return cls(q=0.0, dq=0.0, gravity=0.0, tau_m=0.0, force=0.0, torque=0.0)

    def scaled(self, scale: float) -> SensorNoise:
        """All levels multiplied by ``scale`` (>= 0), e.g. the factors 1..30 of Fig. 14."""
        try:
            s = float(scale)
        except (TypeError, ValueError) as e:
            raise ConfigError(f"noise scale must be a non-negative number; got {scale!r}") from e
        if not math.isfinite(s) or s < 0.0:
            raise ConfigError(f"noise scale must be a non-negative number; got {scale!r}")
        return SensorNoise(**{f.name: getattr(self, f.name) * s for f in fields(self)})

    @property
    def is_zero(self) -> bool:
        """True if every level is 0."""
        return all(getattr(self, f.name) == 0.0 for f in fields(self))

    def as_dict(self) -> dict[str, float]:
        """The levels by name (JSON-serialisable)."""
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}


#: The paper's noise levels (Sec. III-C-2), plus the assumed wrist torque level.
PAPER_NOISE = SensorNoise()
