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


def _robust_std(x: np.ndarray, floor: float) -> np.ndarray:
    """1.4826 x median absolute deviation per column, at least ``floor``."""
    med = np.median(x, axis=0)
    return np.maximum(1.4826 * np.median(np.abs(x - med), axis=0), floor)


def _one_sample_outliers(x: np.ndarray, floor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(mask, d, sigma, peak) over the interior samples of ``x`` (N, n) (rows 1..N-2): ``mask`` those that stand out
    of the line through their neighbours by more than OUTLIER_FACTOR robust standard deviations and SPIKE_RATIO
    times the neighbours' own; ``peak`` those whose |d| is at least their neighbours' (a local peak of |d|)."""
    d = x[1:-1] - 0.5 * (x[:-2] + x[2:])
    sigma = _robust_std(d, floor)
    a = np.abs(d)
    beside = np.zeros_like(a)
    beside[1:] = a[:-1]
    beside[:-1] = np.maximum(beside[:-1], a[1:])
    mask = (a > OUTLIER_FACTOR * sigma) & (a > SPIKE_RATIO * beside)
    return mask, d, sigma, a >= beside


def _velocity_glitches(log: RobotLog) -> np.ndarray:
    return _one_sample_outliers(log.dq, _FLOOR["velocity"])[0]


def _torque_glitches(log: RobotLog, period: float) -> np.ndarray:
    spike, d, sigma, peak = _one_sample_outliers(log.measured_torque, _FLOOR["torque"])
    # a hit moves several joints' torques at once (J^T f), each peaking at its sample; a friction switch elsewhere
    # is far smaller than a spike; another joint's spike one sample away only shoulders this one
    a = np.abs(d)
    stirred = (a > CALM_FACTOR * sigma) & (a > CALM_SHARE * np.max(a, axis=1, keepdims=True)) & peak
    spike &= stirred.sum(axis=1, keepdims=True) == 1
    if period < 0.5 * SHORTEST_IMPACT_S:
        return spike
    dq = log.dq
    slow = np.abs(dq) <= STOP_SHARE * np.max(np.abs(dq), axis=0)
    sign = np.sign(dq)
    reverses = (sign[:-2] * sign[2:]) < 0
    at_stop = reverses | (slow[:-2] & slow[1:-1] & slow[2:])
    return spike & at_stop


def find_glitches(log: RobotLog) -> list[Glitch]:
    """The one-sample glitches of ``log`` (module docstring), in time order; velocity ones first at a sample."""
    if log.t.size < 5:
        return []
    period = float(np.median(np.diff(log.t)))
    found: list[Glitch] = []
    for kind, mask, signal in (
        ("velocity", _velocity_glitches(log), log.dq),
        ("torque", _torque_glitches(log, period), log.measured_torque),
    ):
        for k, j in zip(*np.nonzero(mask), strict=True):
            s = int(k) + 1
            repaired = 0.5 * float(signal[s - 1, j] + signal[s + 1, j])
            found.append(Glitch(s, float(log.t[s]), int(j), kind, float(signal[s, j]), repaired))
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
