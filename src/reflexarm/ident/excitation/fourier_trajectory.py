"""Finite Fourier series joint trajectories (Swevers et al. 1997), the excitation's shape [28].

Each joint follows

    q_i(t)   = q0_i + sum_l [ a_il / (l w_f) sin(l w_f t) - b_il / (l w_f) cos(l w_f t) ]
    dq_i(t)  = sum_l [ a_il cos(l w_f t) + b_il sin(l w_f t) ]
    ddq_i(t) = sum_l l w_f [ -a_il sin(l w_f t) + b_il cos(l w_f t) ]

with base frequency w_f [rad/s] and L harmonics: periodic with period 2 pi / w_f, so it ends where it
starts. :mod:`reflexarm.ident.excitation.design` optimizes the coefficients.

Units. In Python the trajectory holds w_f in rad/s (:attr:`FourierTrajectory.base_frequency`, the
symbol of the equations; :attr:`FourierTrajectory.base_frequency_hz` is f_f = w_f / (2 pi) in Hz, the
unit of ``reflexarm excite --base-frequency``). Files store Hz under a key that says so
(``"base_frequency_hz"``, with ``"period_s"``); files written before that hold ``"base_frequency"`` in
rad/s and are converted when read.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from reflexarm.errors import ConfigError
from reflexarm.signals import Reference

__all__ = ["FourierTrajectory"]


@dataclass(frozen=True)
class FourierTrajectory:
    """A finite Fourier series trajectory per joint (see the module docstring); has ``sample(t)``.

    Attributes:
        base_frequency: w_f [rad/s].
        a, b: coefficients (n, L) [rad/s].
        offset: q0 (n,) [rad].
        periods: how many periods the trajectory lasts (it holds its start/end pose outside).
    """

    base_frequency: float
    a: np.ndarray
    b: np.ndarray
    offset: np.ndarray
    periods: int = 1

    def __post_init__(self) -> None:
        a = np.atleast_2d(np.asarray(self.a, dtype=float))
        b = np.atleast_2d(np.asarray(self.b, dtype=float))
        q0 = np.asarray(self.offset, dtype=float).reshape(-1)
        if a.shape != b.shape or a.shape[0] != q0.size:
            raise ConfigError(f"a {a.shape}, b {b.shape} must be (n, L) with n = len(offset) = {q0.size}")
        if not (np.isfinite(self.base_frequency) and self.base_frequency > 0):
            raise ConfigError(f"base_frequency must be a positive number [rad/s]; got {self.base_frequency!r}")
        if int(self.periods) < 1:
            raise ConfigError(f"periods must be >= 1; got {self.periods!r}")
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "offset", q0)
        object.__setattr__(self, "base_frequency", float(self.base_frequency))
        object.__setattr__(self, "periods", int(self.periods))

    @property
    def n(self) -> int:
        return int(self.offset.size)

    @property
    def n_harmonics(self) -> int:
        return int(self.a.shape[1])

    @property
    def base_frequency_hz(self) -> float:
        """f_f = w_f / (2 pi) [Hz]."""
        return self.base_frequency / (2.0 * np.pi)

    @classmethod
    def from_hz(
        cls, base_frequency_hz: float, a: npt.ArrayLike, b: npt.ArrayLike, offset: npt.ArrayLike, periods: int = 1
    ) -> FourierTrajectory:
        """The trajectory of base frequency f_f [Hz] (w_f = 2 pi f_f)."""
        return cls(2.0 * np.pi * float(base_frequency_hz), np.asarray(a), np.asarray(b), np.asarray(offset), periods)

    @property
    def period(self) -> float:
        """2 pi / w_f [s]."""
        return 2.0 * np.pi / self.base_frequency

    @property
    def duration(self) -> float:
        """periods * period [s]."""
        return self.periods * self.period

    @property
    def start(self) -> np.ndarray:
        """q(0) = q(duration) [rad]."""
        return self.evaluate(np.zeros(1))[0][0]

    def evaluate(self, t: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, dq, ddq), each (N, n), at times ``t`` (N,) [s]; held at the start pose outside [0, duration]."""
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        inside = (tt >= 0.0) & (tt <= self.duration)
        tc = np.where(inside, tt, 0.0)
        w = self.base_frequency
        lw = w * np.arange(1, self.n_harmonics + 1)  # (L,)
        S = np.sin(np.outer(tc, lw))  # (N, L)
        C = np.cos(np.outer(tc, lw))
        q = self.offset + (S / lw) @ self.a.T - (C / lw) @ self.b.T
        dq = C @ self.a.T + S @ self.b.T
        ddq = (-S * lw) @ self.a.T + (C * lw) @ self.b.T
        dq[~inside] = 0.0
        ddq[~inside] = 0.0
        return q, dq, ddq

    def sample(self, t: float) -> Reference:
        """The reference at time ``t`` [s] (the interface of the closed-loop runner; scalar fast path)."""
        if not 0.0 <= t <= self.duration:
            return Reference(self.start, np.zeros(self.n), np.zeros(self.n))
        lw = self.base_frequency * np.arange(1, self.n_harmonics + 1)
        S = np.sin(lw * t)
        C = np.cos(lw * t)
        q = self.offset + self.a @ (S / lw) - self.b @ (C / lw)
        dq = self.a @ C + self.b @ S
        ddq = self.b @ (C * lw) - self.a @ (S * lw)
        return Reference(q, dq, ddq)

    def with_periods(self, periods: int) -> FourierTrajectory:
        return FourierTrajectory(self.base_frequency, self.a, self.b, self.offset, periods)

    def check_limits(
        self,
        lower: npt.ArrayLike,
        upper: npt.ArrayLike,
        max_velocity: npt.ArrayLike,
        max_acceleration: npt.ArrayLike,
        *,
        rate: float = 1000.0,
    ) -> dict[str, float]:
        """Largest use of each limit on the trajectory sampled at ``rate`` [Hz]: values <= 1 are within.

        Returns ``{"position", "velocity", "acceleration"}``: max over joints and samples of
        (distance from the range centre / half range), |dq| / max_velocity and |ddq| / max_acceleration.
        """
        t = np.arange(0.0, self.period, 1.0 / rate)
        q, dq, ddq = self.evaluate(t)
        lo, hi = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        return {
            "position": float(np.max(np.abs(q - mid) / half)),
            "velocity": float(np.max(np.abs(dq) / np.asarray(max_velocity, dtype=float))),
            "acceleration": float(np.max(np.abs(ddq) / np.asarray(max_acceleration, dtype=float))),
        }

    def to_dict(self) -> dict[str, object]:
        """JSON form: the base frequency in Hz (``base_frequency_hz``) and the period in s."""
        return {
            "base_frequency_hz": self.base_frequency_hz,
            "period_s": self.period,
            "a": self.a.tolist(),
            "b": self.b.tolist(),
            "offset": self.offset.tolist(),
            "periods": self.periods,
        }

    @classmethod
    def from_dict(cls, d: dict[str, object]) -> FourierTrajectory:
        """From :meth:`to_dict`'s form, or an older one with ``base_frequency`` in rad/s (converted)."""
        try:
            if "base_frequency_hz" in d:
                w = 2.0 * np.pi * float(d["base_frequency_hz"])  # type: ignore[arg-type]
            else:
                w = float(d["base_frequency"])  # type: ignore[arg-type]  # files before the unit was named: rad/s
            return cls(
                w,
                np.asarray(d["a"], dtype=float),
                np.asarray(d["b"], dtype=float),
                np.asarray(d["offset"], dtype=float),
                int(d.get("periods", 1)),  # type: ignore[call-overload]
            )
        except (KeyError, TypeError, ValueError) as e:
            raise ConfigError(f"malformed Fourier trajectory: {e}") from e

    def save(self, path: str | os.PathLike[str]) -> Path:
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(json.dumps(self.to_dict(), indent=1))
        return p

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> FourierTrajectory:
        p = Path(path)
        try:
            d = json.loads(p.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise ConfigError(f"cannot read trajectory file {str(p)!r}: {e}") from e
        if "trajectory" in d:
            d = d["trajectory"]
        return cls.from_dict(d)
