"""One-sample glitches in a robot log: recognised, listed and repaired before the observer sees them.

Real free-motion logs carry single samples no motion can produce (issue 17: a velocity sign flip at a stop,
motor-current spikes of up to 193 Nm at the stops of a 100 Hz log). Through a fast observer each becomes a
residual spike as large as a hit: it would set the tuned levels and be an alarm. Two kinds are recognised:

* **velocity glitch** (joint j, sample k): dq_j[k] stands out of the straight line through its neighbours,
  d_k = dq_j[k] - (dq_j[k-1] + dq_j[k+1]) / 2, by more than :data:`OUTLIER_FACTOR` robust standard deviations of
  d_j (1.4826 x its median absolute deviation) and by more than :data:`SPIKE_RATIO` times the neighbours' own
  |d_{k-1}|, |d_{k+1}| (a spike of height h gives h there and h/2 beside; the edge of a step h/2 at both). No
  force makes a velocity jump away and back in one sample (the arm's inertia integrates forces; a hit steps the
  velocity or bends it), so this holds anywhere in the motion. (The positions cannot tell: at 1 kHz their
  difference quotient is noisier than a sign flip of a slow joint.) A smaller glitch is not recognised: at
  2 mrad/s velocity noise, one below ~0.025 rad/s, which still reaches a 1 kHz residual as a spike of about
  (1 - exp(-k_o dt)) M_jj |d| / dt.
* **torque glitch** (a current spike): tau_j[k] is such a one-sample outlier of the torque; it is one joint's
  (every other joint's d at that sample stays within :data:`CALM_FACTOR` robust standard deviations, below
  :data:`CALM_SHARE` of the spike, or is no peak of its own |d|: a contact's torque J^T f reaches several joints
  at once, each peaking at its sample); and the joint is
  *at a stop* (dq_j changes sign within k-1..k+1, or |dq_j| there stays below :data:`STOP_SHARE` of the joint's
  largest |dq| in the log). A hit during motion can be one sample long at 100 Hz and is left alone; at a stop a
  one-sample torque spike is taken as a glitch. When the log's period is below half the shortest impact
  (:data:`~reflexarm.detect.defaults.SHORTEST_IMPACT_S`), no impact fits in one sample and a one-sample spike is a
  glitch anywhere.

A glitch is repaired by the mean of its two neighbours; the list says what was changed (sample, time, joint,
kind, logged and repaired value). A contact that happens to be one sample long at a stop is taken for a glitch:
a stated limit of telling them apart from one sample.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from reflexarm.detect.defaults import SHORTEST_IMPACT_S
from reflexarm.logs.robot_log import RobotLog

__all__ = [
    "CALM_FACTOR",
    "CALM_SHARE",
    "OUTLIER_FACTOR",
    "SPIKE_RATIO",
    "STOP_SHARE",
    "Glitch",
    "find_glitches",
    "repair_glitches",
]

#: A sample is an outlier beyond this many robust standard deviations of its signal's one-sample inconsistency
#: (10: a Gaussian sample goes that far about once in 10^23).
OUTLIER_FACTOR = 10.0
#: A one-sample spike of height h gives d = h at its sample and -h/2 at each neighbour; the edge of a step of
#: height h gives h/2 and -h/2: a sample is a spike when its |d| exceeds this multiple of its neighbours'.
SPIKE_RATIO = 1.5
#: A torque spike is one joint's: at its sample every other joint's one-sample inconsistency stays below this many
#: robust standard deviations (a contact's J^T f reaches several joints at once).
CALM_FACTOR = 4.0
#: ... or below this share of the spike's (a friction switch at another joint's reversal can coincide with it).
CALM_SHARE = 0.1
#: A joint is at a stop where |dq| stays below this share of its largest |dq| in the log.
STOP_SHARE = 0.05
#: Smallest robust standard deviations used [rad/s, Nm] (a noiseless simulated signal has a MAD of ~0).
_FLOOR = {"velocity": 1e-4, "torque": 1e-3}


@dataclass(frozen=True)
class Glitch:
    """One repaired sample: 0-based ``sample`` and ``joint``, its time [s], ``kind`` ("velocity" or "torque"),
    the logged and the repaired value [rad/s or Nm]."""

    sample: int
    t: float
    joint: int
    kind: str
    logged: float
    repaired: float

    def as_dict(self) -> dict[str, object]:
        """JSON-ready (joint 1-based under ``joint``)."""
        return {"t_s": self.t, "sample": self.sample, "joint": self.joint + 1, "kind": self.kind,
                "logged": self.logged, "repaired": self.repaired}  # fmt: skip


def _robust_std(d: np.ndarray, floor: float) -> np.ndarray:
    """1.4826 x median absolute deviation of each row of ``d`` (n, m), at least ``floor``."""
    deviation = d.copy()
    med = np.median(deviation, axis=1, overwrite_input=True)
    np.subtract(d, med[:, None], out=deviation)
    np.abs(deviation, out=deviation)
    return np.maximum(1.4826 * np.median(deviation, axis=1, overwrite_input=True), floor)


class _Outliers(NamedTuple):
    """A signal's one-sample outliers: ``a`` (n, N-2) the |one-sample inconsistency| of every joint at every
    interior sample, ``sigma`` (n,) its robust standard deviation per joint, ``peak`` (n, N-2) where |d| is at
    least its neighbours' (a local peak), and the outliers' ``joint`` and interior ``sample`` (rows 1..N-2 of
    the log are 0..N-3 here)."""

    a: np.ndarray
    sigma: np.ndarray
    joint: np.ndarray
    sample: np.ndarray

    def peak(self, joints: slice | np.ndarray, samples: np.ndarray) -> np.ndarray:
        """Whether |d| at these samples is at least its neighbours' (beyond the ends: 0)."""
        a, m = self.a, self.a.shape[1]
        left = np.where(samples > 0, a[joints, np.maximum(samples - 1, 0)], 0.0)
        right = np.where(samples < m - 1, a[joints, np.minimum(samples + 1, m - 1)], 0.0)
        return a[joints, samples] >= np.maximum(left, right)  # type: ignore[no-any-return]


def _one_sample_outliers(x: np.ndarray, floor: float) -> _Outliers:
    """The interior samples of ``x`` (N, n) that stand out of the line through their neighbours by more than
    OUTLIER_FACTOR robust standard deviations and SPIKE_RATIO times the neighbours' own. The signal is worked on
    joint by joint (transposed: the medians partition contiguous rows) and the outliers are few: the spike test
    looks at the samples beyond OUTLIER_FACTOR only (the same numbers as over every sample)."""
    xt = np.ascontiguousarray(x.T)
    d = np.add(xt[:, :-2], xt[:, 2:])  # x[k] - 0.5 * (x[k-1] + x[k+1]), the same operations in place
    d *= 0.5
    np.subtract(xt[:, 1:-1], d, out=d)
    del xt
    sigma = _robust_std(d, floor)
    a = np.abs(d, out=d)
    joint, sample = np.nonzero(a > OUTLIER_FACTOR * sigma[:, None])
    m = a.shape[1]
    left = np.where(sample > 0, a[joint, np.maximum(sample - 1, 0)], 0.0)
    right = np.where(sample < m - 1, a[joint, np.minimum(sample + 1, m - 1)], 0.0)
    spike = a[joint, sample] > SPIKE_RATIO * np.maximum(left, right)
    return _Outliers(a, sigma, joint[spike], sample[spike])


def _velocity_glitches(log: RobotLog) -> tuple[np.ndarray, np.ndarray]:
    out = _one_sample_outliers(log.dq, _FLOOR["velocity"])
    return out.joint, out.sample


def _torque_glitches(log: RobotLog, period: float) -> tuple[np.ndarray, np.ndarray]:
    out = _one_sample_outliers(log.measured_torque, _FLOOR["torque"])
    joint, sample, a, sigma = out.joint, out.sample, out.a, out.sigma
    # a hit moves several joints' torques at once (J^T f), each peaking at its sample; a friction switch elsewhere
    # is far smaller than a spike; another joint's spike one sample away only shoulders this one
    at = a[:, sample]  # (n, spikes): every joint at each spike's sample
    everyone = np.arange(a.shape[0])[:, None]
    peak = out.peak(everyone, np.broadcast_to(sample, at.shape))
    stirred = (at > CALM_FACTOR * sigma[:, None]) & (at > CALM_SHARE * np.max(at, axis=0, keepdims=True)) & peak
    alone = stirred.sum(axis=0) == 1
    joint, sample = joint[alone], sample[alone]
    if period < 0.5 * SHORTEST_IMPACT_S:
        return joint, sample
    dq = log.dq
    fastest = np.max(np.abs(dq), axis=0)[joint]
    around = dq[sample[:, None] + np.arange(3), joint[:, None]]  # log samples k-1, k, k+1 of each spike
    slow = np.abs(around) <= STOP_SHARE * fastest[:, None]
    sign = np.sign(around)
    at_stop = (sign[:, 0] * sign[:, 2] < 0) | slow.all(axis=1)
    return joint[at_stop], sample[at_stop]


def find_glitches(log: RobotLog) -> list[Glitch]:
    """The one-sample glitches of ``log`` (module docstring), in time order; velocity ones first at a sample."""
    if log.t.size < 5:
        return []
    period = float(np.median(np.diff(log.t)))
    found: list[Glitch] = []
    for kind, (joints, samples), signal in (
        ("velocity", _velocity_glitches(log), log.dq),
        ("torque", _torque_glitches(log, period), log.measured_torque),
    ):
        for k, j in zip(samples.tolist(), joints.tolist(), strict=True):
            s = k + 1
            repaired = 0.5 * float(signal[s - 1, j] + signal[s + 1, j])
            found.append(Glitch(s, float(log.t[s]), j, kind, float(signal[s, j]), repaired))
    found.sort(key=lambda g: (g.sample, g.kind != "velocity", g.joint))
    return found


def repair_glitches(log: RobotLog) -> tuple[RobotLog, list[Glitch]]:
    """``log`` with its glitches replaced by the mean of their neighbours, and the list of them (the same log
    object when there is none)."""
    glitches = find_glitches(log)
    if not glitches:
        return log, []
    dq, tau = log.dq.copy(), log.measured_torque.copy()
    for g in glitches:
        (dq if g.kind == "velocity" else tau)[g.sample, g.joint] = g.repaired
    kinds = {k: sum(g.kind == k for g in glitches) for k in ("velocity", "torque")}
    note = (
        f"{len(glitches)} one-sample glitch(es) repaired by their neighbours' mean: {kinds['velocity']} velocity "
        f"spike(s), {kinds['torque']} one-joint torque spike(s) at a stop"
    )
    fixed = replace(log, dq=dq, tau=tau, tau_raw=None, notes=(*log.notes, note))
    return fixed, glitches
