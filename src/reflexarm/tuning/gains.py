"""The detection residual at other observer gains, and the detector's lag measured on it.

The momentum observer (4) is the first-order filter dr/dt = k_o (tau_ext - r) of the external torque. Both
discrete forms of the :class:`~reflexarm.control.Controller` are the recursion

    r_k = a r_(k-1) + (1 - a) u_k,     u_k = (p_k - p_(k-1)) / h - beta_k   (the period's mean tau_ext + noise),

with a = e^(-k_o h) (exact form) or a = 1 - k_o h (Euler), r_0 = 0 at the first tick. The input u does not
depend on the gain, so one replay of a log through the controller at a gain K gives it back,
u_k = (r_k - a r_(k-1)) / (1 - a), and the residual of any other gain K' follows by filtering u again
(:func:`refilter`): the residual the controller would have computed at K', to round-off (a test compares it
with a replay at K'), at the cost of one linear filter instead of one controller pass per gain.

With a second stage on the detection residual (``Controller(detection_filter_gain=K_f)``), the detector sees

    r2_k = c r2_(k-1) + (1 - c) r_k,     c = e^(-K_f h) (always the zero-order-hold form), r2_0 = 0,

a second filter of the same u with real poles at a and c. Both stages are linear and start from rest (r_0 =
r2_0 = 0), so :func:`refilter` undoes a replay's stages and applies others in one filter: exact to round-off.

The detector's lag (:func:`synthetic_lags`): a synthetic external torque (a step or a ramp) added to the
log's input u at many ticks; the lag is the time from the tick at which the true torque first exceeds
zeta_j to the tick at which |r_j| (|r2_j| with the stage) does (the detector checks once per tick).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import numpy.typing as npt
from scipy.signal import lfilter

from reflexarm.errors import ConfigError, DataError
from reflexarm.tuning.replay import ResidualReplay, check_filter_gain

__all__ = ["DISCRETIZATIONS", "decay", "refilter", "stage_decay", "synthetic_lags", "uniform_period"]

#: The observer forms a replay can be refiltered from and to (as ``Controller(observer_discretization=)``).
DISCRETIZATIONS = ("euler", "exact")

#: Relative spread of the sampling period within which a log counts as uniformly sampled (a simulated log's
#: periods differ by float round-off of MuJoCo's clock only).
PERIOD_SPREAD = 1e-6
#: A synthetic torque starts this many sums of time constants (1/k_o + 1/K_f) after a replay's start, where
#: the residual's start from rest has settled: a step response is within e^-5 = 0.7 % of its end there with
#: one stage, closer with two.
SETTLE_TIME_CONSTANTS = 5.0


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


def stage_decay(filter_gain: float | None, dt: float) -> float | None:
    """The second stage's c = e^(-K_f dt) for ``filter_gain`` K_f [1/s] at period ``dt`` [s]; None without one.

    Raises:
        ConfigError: a K_f that is not a finite number > 0.
    """
    kf = check_filter_gain(filter_gain)
    return None if kf is None else math.exp(-kf * dt)


def _cascade(poles: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """Numerator and denominator (in z^-1) of the unit-DC-gain cascade prod_p (1 - p) / (1 - p z^-1)."""
    den = np.array([1.0])
    for p in poles:
        den = np.convolve(den, [1.0, -p])
    return np.array([math.prod(1.0 - p for p in poles)]), den


def refilter(
    replay: ResidualReplay, gain: float, discretization: str = "exact", filter_gain: float | None = None
) -> ResidualReplay:
    """The residual of a detection observer of ``gain`` [1/s] and ``discretization``, followed by a second stage
    of ``filter_gain`` K_f [1/s] (None: none), on the same log (module docstring).

    The replay's own stages are undone (its observer's a, and its second stage's c when
    ``replay.detection_filter_gain`` is set), the new ones applied, from rest: poles both have are kept as they
    are (not divided out and back). ``replay`` must know its own gain and form (a
    :func:`~reflexarm.tuning.replay_residual`) and be uniformly sampled; it is returned as it is when nothing
    changes.

    Raises:
        ConfigError: a bad gain, form or K_f.
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
    c_from, c_to = stage_decay(replay.detection_filter_gain, replay.dt), stage_decay(filter_gain, replay.dt)
    undo = [decay(replay.detection_gain, replay.dt, replay.discretization)] + ([] if c_from is None else [c_from])
    apply = [decay(gain, replay.dt, discretization)] + ([] if c_to is None else [c_to])
    for p in list(undo):  # a pole both cascades have stays (exactly: the same gain at the same period)
        if p in apply:
            undo.remove(p)
            apply.remove(p)
    kf = None if filter_gain is None else float(filter_gain)
    labels = (float(gain), discretization, kf)
    if not undo and not apply:  # the same cascade (its stages perhaps named in the other order)
        if (replay.detection_gain, replay.discretization, replay.detection_filter_gain) == labels:
            return replay
        return replace(replay, detection_gain=labels[0], discretization=discretization, detection_filter_gain=kf)
    # r' = H_to / H_from r from rest (r_0 = 0 at the first tick): the inverse of the old stages is a finite filter
    num_from, den_from = _cascade(undo)
    num_to, den_to = _cascade(apply)
    out = lfilter(np.convolve(den_from, num_to) / num_from[0], den_to, replay.residual, axis=0)
    return replace(replay, residual=out, detection_gain=labels[0], discretization=discretization,
                   detection_filter_gain=kf)  # fmt: skip


def _response(torque: np.ndarray, poles: list[float]) -> np.ndarray:
    """The detector's residual's response (from rest) to the per-period mean external torques ``torque``: the
    observer (pole a) and the second stage (pole c), if any."""
    num, den = _cascade(poles)
    return lfilter(num, den, torque)


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

    The residual is the detector's: the observer of the replays' gain and form, then their second stage
    (``detection_filter_gain``), if any. Per joint and draw: a random tick k0 of a random replay (away from its
    start by :data:`SETTLE_TIME_CONSTANTS` x (1/k_o + 1/K_f), the sum of the time constants), a random sign, and
    the torque ``kind`` from the start of the period ending at tick k0: "step", ``size`` x zeta_j (the true
    torque exceeds zeta_j at once: the lag is at least one period); "ramp", ``slope`` [Nm/s] (it exceeds zeta_j
    at zeta_j / slope). The lag counts from that time to the end of the first period whose tick has
    |r_j| > zeta_j, the residual being the replay's plus the cascade's response to the torque's mean over each
    period; noise pointing along the torque can make a ramp's lag negative (kept as measured).
    """
    if kind not in ("step", "ramp"):
        raise ConfigError(f"unknown synthetic torque {kind!r}; choose 'step' or 'ramp'")
    rng = np.random.default_rng(seed)
    zeta = np.broadcast_to(np.asarray(levels, dtype=float), (replays[0].residual.shape[1],))
    dt, gain = replays[0].dt, replays[0].detection_gain
    if gain is None or replays[0].discretization is None:
        raise DataError("synthetic_lags needs replays of a known gain and discretization")
    kf = replays[0].detection_filter_gain
    c_stage = stage_decay(kf, dt)
    poles = [decay(gain, dt, replays[0].discretization)] + ([] if c_stage is None else [c_stage])
    w = int(math.ceil(window_s / dt))
    skip = int(math.ceil(SETTLE_TIME_CONSTANTS * (1.0 / gain + (0.0 if kf is None else 1.0 / kf)) / dt))
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
        resp = _response(torque, poles)
        for c in range(count):
            rep = usable[int(rng.integers(len(usable)))]
            k0 = int(rng.integers(skip, rep.t.size - w))
            sign = 1.0 if rng.random() < 0.5 else -1.0
            over = np.flatnonzero(np.abs(rep.residual[k0 : k0 + w, j] + sign * resp) > zeta[j])
            if over.size:
                lags[j, c] = ends[over[0]] - t_cross
    return lags
