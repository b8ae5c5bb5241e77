"""The detection residual at other observer gains, and the detector's lag measured on it.

The momentum observer (4) is the first-order filter dr/dt = k_o (tau_ext - r) of the external torque. Both
discrete forms of the :class:`~reflexarm.control.Controller` are the recursion

    r_k = a r_(k-1) + (1 - a) u_k,     u_k = (p_k - p_(k-1)) / h - beta_k   (the period's mean tau_ext + noise),

with a = e^(-k_o h) (exact form) or a = 1 - k_o h (Euler), r_0 = 0 at the first tick. The input u does not
depend on the gain, so one replay of a log through the controller at a gain K gives it back,
u_k = (r_k - a r_(k-1)) / (1 - a), and the residual of any other gain K' follows by filtering u again
(:func:`refilter`): the residual the controller would have computed at K', to round-off (a test compares it
with a replay at K'), at the cost of one linear filter instead of one controller pass per gain.

The detector's lag (:func:`synthetic_lags`): a synthetic external torque (a step or a ramp) added to the
log's input u at many ticks; the lag is the time from the tick at which the true torque first exceeds
zeta_j to the tick at which |r_j| does (the detector checks once per tick).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import numpy.typing as npt
from scipy.signal import lfilter

from reflexarm.errors import ConfigError, DataError
from reflexarm.tuning.replay import ResidualReplay

__all__ = ["DISCRETIZATIONS", "decay", "refilter", "synthetic_lags", "uniform_period"]

#: The observer forms a replay can be refiltered from and to (as ``Controller(observer_discretization=)``).
DISCRETIZATIONS = ("euler", "exact")

#: Relative spread of the sampling period within which a log counts as uniformly sampled (a simulated log's
#: periods differ by float round-off of MuJoCo's clock only).
PERIOD_SPREAD = 1e-6


def decay(gain: float, dt: float, discretization: str = "exact") -> float:
    """The recursion's a for ``gain`` k_o [1/s] at period ``dt`` [s]: e^(-k_o dt) (exact) or 1 - k_o dt (Euler).

    Raises:
        ConfigError: a non-positive gain, an unknown form, or the Euler form at k_o dt >= 1 (unstable).
    """
    if not (math.isfinite(gain) and gain > 0):
        raise ConfigError(f"observer gain must be a positive number [1/s]; got {gain!r}")
    if discretization not in DISCRETIZATIONS:
        raise ConfigError(f"unknown discretization {discretization!r}; choose one of: {', '.join(DISCRETIZATIONS)}")
    if discretization == "exact":
        return math.exp(-gain * dt)
    if gain * dt >= 1.0:
        raise ConfigError(f"the Euler observer needs k_o dt < 1; got k_o = {gain:g} 1/s at dt = {dt:g} s")
    return 1.0 - gain * dt


def uniform_period(t: npt.ArrayLike) -> bool:
    """True when the time stamps ``t`` [s] have one period (to :data:`PERIOD_SPREAD`)."""
    d = np.diff(np.asarray(t, dtype=float))
    return d.size > 0 and float(np.ptp(d)) <= PERIOD_SPREAD * float(np.median(d))


def refilter(replay: ResidualReplay, gain: float, discretization: str = "exact") -> ResidualReplay:
    """The residual of a detection observer of ``gain`` [1/s] and ``discretization`` on the same log (module
    docstring): ``replay`` must know its own gain and form (a :func:`~reflexarm.tuning.replay_residual`) and be
    uniformly sampled.

    Raises:
        DataError: the replay's gain or form is unknown (a recorded residual), or its period is not uniform
            (replay such a log at each gain instead).
    """
    if replay.detection_gain is None or replay.discretization is None:
        raise DataError(
            f"{replay.source}: its observer gain and discretization are unknown (a recorded residual?); "
            "refilter needs a replay_residual"
        )
    if not uniform_period(replay.t):
        raise DataError(f"{replay.source}: the period is not uniform; replay the log at each gain instead")
    a_from = decay(replay.detection_gain, replay.dt, replay.discretization)
    a_to = decay(gain, replay.dt, discretization)
    if a_from == a_to:
        return replay
    # r' = (1 - a') / (1 - a) * (1 - a z^-1) / (1 - a' z^-1) r, from r_0 = 0 (the first tick's residual)
    b = np.array([1.0, -a_from]) * (1.0 - a_to) / (1.0 - a_from)
    out = lfilter(b, [1.0, -a_to], replay.residual, axis=0)
    return replace(replay, residual=out, detection_gain=float(gain), discretization=discretization)


def _response(torque: np.ndarray, a: float) -> np.ndarray:
    """The recursion's response (from rest) to the per-period mean external torques ``torque``."""
    return lfilter([1.0 - a], [1.0, -a], torque)


def synthetic_lags(
    replays: list[ResidualReplay],
    levels: npt.ArrayLike,
    *,
    kind: str = "step",
    size: float = 2.0,
    slope: float = 1000.0,
    count: int = 50,
    window_s: float = 0.5,
    seed: int = 0,
) -> np.ndarray:
    """Measured lags [s] of the detector at ``levels`` (zeta per joint [Nm]) on synthetic external torques
    added to the replays' residuals, (joints, count) (NaN: not detected within ``window_s``).

    Per joint and draw: a random tick k0 of a random replay (away from its start by 5 time constants), a
    random sign, and the torque ``kind`` from the start of the period ending at tick k0: "step", ``size`` x
    zeta_j (the true torque exceeds zeta_j at once: the lag is at least one period); "ramp", ``slope`` [Nm/s]
    (it exceeds zeta_j at zeta_j / slope). The lag counts from that time to the end of the first period whose
    tick has |r_j| > zeta_j, the residual being the replay's plus the recursion's response to the torque's mean
    over each period; noise pointing along the torque can make a ramp's lag negative (kept as measured).
    """
    if kind not in ("step", "ramp"):
        raise ConfigError(f"unknown synthetic torque {kind!r}; choose 'step' or 'ramp'")
    rng = np.random.default_rng(seed)
    zeta = np.broadcast_to(np.asarray(levels, dtype=float), (replays[0].residual.shape[1],))
    dt, gain = replays[0].dt, replays[0].detection_gain
    if gain is None or replays[0].discretization is None:
        raise DataError("synthetic_lags needs replays of a known gain and discretization")
    a = decay(gain, dt, replays[0].discretization)
    w = int(math.ceil(window_s / dt))
    skip = int(math.ceil(5.0 / gain / dt))
    usable = [r for r in replays if r.t.size > skip + w + 1]
    if not usable:
        raise DataError(f"the replays are shorter than {(skip + w + 1) * dt:g} s; no room for a synthetic torque")
    ends = dt * np.arange(1, w + 1)  # end of each period after the torque's start [s]
    lags = np.full((zeta.size, count), np.nan)
    for j in range(zeta.size):
        if kind == "step":
            torque, t_cross = np.full(w, size * zeta[j]), 0.0
        else:  # the mean of slope * t over each period
            torque, t_cross = slope * (ends - dt / 2.0), zeta[j] / slope
        resp = _response(torque, a)
        for c in range(count):
            rep = usable[int(rng.integers(len(usable)))]
            k0 = int(rng.integers(skip, rep.t.size - w))
            sign = 1.0 if rng.random() < 0.5 else -1.0
            over = np.flatnonzero(np.abs(rep.residual[k0 : k0 + w, j] + sign * resp) > zeta[j])
            if over.size:
                lags[j, c] = ends[over[0]] - t_cross
    return lags
