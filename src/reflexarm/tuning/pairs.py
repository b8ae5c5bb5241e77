"""(k_o, zeta) pairs: the detection observer's gain chosen together with its levels (issue 15, item 5).

A faster detection observer lags less behind the external torque but passes more sensor noise: its residual
carries about k_o M(q) sigma_dq of velocity noise (the momentum p = M(q) dq enters (4) unfiltered, scaled by
k_o), so the levels for a false-alarm rate rise with k_o. :func:`propose_detection_pairs` makes the trade-off
visible, for every gain of a list (exact discretization, stable at any gain):

1. each free-motion log is replayed once through the :class:`~reflexarm.control.Controller`, and its residual
   refiltered to every gain (:func:`~reflexarm.tuning.refilter`: the controller's own residual at that gain);
2. per gain, :func:`~reflexarm.tuning.tune_thresholds` gives the per-joint levels for the asked rate;
3. per gain, the detector's own lag, from the time the true external torque first exceeds zeta_j to
   detection: analytic for a ramp of slope ``ramp_slope`` (:func:`~reflexarm.tuning.ramp_lag`; the slow-ramp
   bound is T = 1/k_o) and for a step of ``step_size`` x zeta_j (T ln(s / (s - 1))), and measured with such a
   ramp and step added to held-out logs (:func:`~reflexarm.tuning.synthetic_lags`: the noise included);
4. per gain, the false alarms on held-out logs (other noise and model seeds than the tuning logs), counted
   as :func:`~reflexarm.tuning.heldout.count_alarms` does (excursions closer than 5 / k_o are one alarm).

With a second stage on the detection residual (``ObserverSettings.detection_filter_gain`` K_f), every pair is
(k_o, the same K_f): the logs are replayed once without it (a first-order residual, which refilters to any
gain and stage), refiltered to each k_o followed by the stage; the analytic lags are the cascade's
(:func:`~reflexarm.tuning.ramp_lag` bounded by 1/k_o + 1/K_f) and the declustering gap 5 x (1/k_o + 1/K_f).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from reflexarm.errors import ConfigError
from reflexarm.logs.robot_log import RobotLog
from reflexarm.robots.robot_model import RobotModel
from reflexarm.tuning.defaults import DEFAULT_CONTACT_RATE, DEFAULT_METHOD, DEFAULT_RATE
from reflexarm.tuning.delays import detection_delay, ramp_lag
from reflexarm.tuning.gains import refilter, synthetic_lags, uniform_period
from reflexarm.tuning.heldout import count_alarms
from reflexarm.tuning.replay import ObserverSettings, ResidualReplay, load_free_motion_log, replay_residual
from reflexarm.tuning.study import ThresholdProposal, tune_thresholds

__all__ = ["DEFAULT_DETECTION_GAINS", "DetectionPairs", "GainPair", "parse_gains", "propose_detection_pairs"]

#: Gains a study compares by default [1/s]: the paper's 5 up to the DLR humanoids' 500 (a 2 ms time constant).
DEFAULT_DETECTION_GAINS = (5.0, 20.0, 50.0, 100.0, 200.0, 500.0)
#: Default ramp slope of the lag [Nm/s]: a contact that builds 50 Nm in 50 ms.
DEFAULT_RAMP_SLOPE = 1000.0
#: Default step of the lag, in multiples of zeta_j (analytic lag T ln 2).
DEFAULT_STEP_SIZE = 2.0

Item = RobotLog | ResidualReplay | str | os.PathLike[str]


def parse_gains(text: str | Sequence[float]) -> tuple[float, ...]:
    """Gains [1/s] from "5,50,500" (or a sequence), each positive and finite, sorted, duplicates removed."""
    try:
        values = [float(v) for v in (text.split(",") if isinstance(text, str) else text)]
    except ValueError:
        raise ConfigError(f"detection gains are a comma list of positive numbers [1/s]; got {text!r}") from None
    if not values or not all(math.isfinite(v) and v > 0 for v in values):
        raise ConfigError(f"detection gains must be positive numbers [1/s]; got {text!r}")
    return tuple(sorted(set(values)))


@dataclass
class GainPair:
    """One (k_o, zeta) pair: the levels tuned at ``gain`` and what they give (module docstring);
    ``detection_filter_gain``: K_f [1/s] of the residual's second stage the levels were tuned with (None: none)."""

    gain: float
    proposal: ThresholdProposal = field(repr=False)
    ramp_lag_s: list[float]
    step_lag_s: float
    measured_step_lag_s: np.ndarray = field(repr=False)
    measured_ramp_lag_s: np.ndarray = field(repr=False)
    heldout: dict[str, Any] | None = None
    detection_filter_gain: float | None = None

    @property
    def collision(self) -> np.ndarray:
        """zeta per joint [Nm] at this gain."""
        return self.proposal.collision

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: the gain and its levels (the form read back by ``--threshold FILE``), lags, alarms."""

        def stat(x: np.ndarray, q: float) -> float | None:
            x = x[np.isfinite(x)]
            return float(np.quantile(x, q)) if x.size else None

        return {
            "detection_observer_gain": self.gain,
            "observer_discretization": "exact",
            "time_constant_s": 1.0 / self.gain,
            "detection_filter_gain": self.detection_filter_gain,
            "collision_Nm": [float(v) for v in self.collision],
            "contact_Nm": [float(v) for v in self.proposal.contact],
            "ramp_lag_s": self.ramp_lag_s,
            "ramp_lag_max_s": max(self.ramp_lag_s),
            "step_lag_s": self.step_lag_s,
            "measured_step_lag_median_s": stat(self.measured_step_lag_s, 0.5),
            "measured_step_lag_max_s": stat(self.measured_step_lag_s, 1.0),
            "measured_ramp_lag_median_s": stat(self.measured_ramp_lag_s, 0.5),
            "measured_ramp_lag_max_s": stat(self.measured_ramp_lag_s, 1.0),
            "undetected_synthetic": int(np.sum(~np.isfinite(self.measured_step_lag_s)))
            + int(np.sum(~np.isfinite(self.measured_ramp_lag_s))),
            "heldout": self.heldout,
            "notes": list(self.proposal.notes),
        }


@dataclass
class DetectionPairs:
    """What :func:`propose_detection_pairs` returns: one :class:`GainPair` per gain and the test inputs."""

    pairs: list[GainPair]
    rate_per_hour: float
    ramp_slope: float
    step_size: float
    sources: list[str]
    heldout_sources: list[str]
    #: the detection observer's own friction band [rad/s] the residuals had (ObserverSettings), None: none
    detection_friction_band: float | None = None
    #: K_f [1/s] of the detection residual's second stage at every gain (ObserverSettings), None: none
    detection_filter_gain: float | None = None

    def pair(self, gain: float) -> GainPair:
        """The pair tuned at ``gain`` [1/s] (ConfigError naming the gains if there is none)."""
        for p in self.pairs:
            if math.isclose(p.gain, gain, rel_tol=1e-9):
                return p
        raise ConfigError(f"no pair at k_o = {gain:g} 1/s; gains: {', '.join(f'{p.gain:g}' for p in self.pairs)}")

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready, with the test inputs stated (``detection_pairs`` of ``thresholds.json``)."""
        kf = self.detection_filter_gain
        stage = "" if kf is None else f", then the second stage of K_f = {kf:g} 1/s (c = exp(-K_f dt))"
        ramp = (
            "T (1 + W0(-exp(-(1 + zeta / (slope T))))), T = 1/k_o"
            if kf is None
            else "the root of the cascade's ramp response (poles -k_o, -K_f), T = 1/k_o + 1/K_f"
        )
        return {
            "method": {
                "residual": "each log replayed once through the Controller (exact discretization), its residual "
                f"refiltered to each gain (r_k = a r_k-1 + (1 - a) u_k, a = exp(-k_o dt)){stage}",
                "levels": f"tune_thresholds at each gain, {self.rate_per_hour:g} false alarms/h for the arm",
                "ramp_lag": f"analytic, a ramp of {self.ramp_slope:g} Nm/s from 0: {ramp}; T bounds the lag of "
                "any ramp",
                "step_lag": f"analytic, a step of {self.step_size:g} x zeta: T ln(s / (s - 1)) (the cascade's root "
                "with a second stage)",
                "measured_lags": "the same step and ramp added to the held-out residuals (tuning logs without "
                "held-out logs) at random ticks and signs, from the true torque exceeding zeta_j to the first "
                "tick with |r_j| > zeta_j",
                "heldout": "alarms of the arm (any joint over its level; excursions closer than 5 x (1/k_o + "
                "1/K_f) are one, 1/K_f with a second stage) on logs of other seeds than the tuning logs",
            },
            "rate_per_hour": self.rate_per_hour,
            "detection_friction_band": self.detection_friction_band,
            "detection_filter_gain": self.detection_filter_gain,
            "ramp_slope_Nm_per_s": self.ramp_slope,
            "step_size_times_zeta": self.step_size,
            "logs": self.sources,
            "heldout_logs": self.heldout_sources,
            "pairs": [p.as_dict() for p in self.pairs],
        }

    def rows(self) -> list[dict[str, Any]]:
        """One flat row per gain (for CSV and the printed table)."""
        rows = []
        for p in self.pairs:
            d = p.as_dict()
            h = d.pop("heldout") or {}
            d.pop("notes")
            levels, contact = d.pop("collision_Nm"), d.pop("contact_Nm")
            d.pop("ramp_lag_s")
            d["max_collision_Nm"], d["min_collision_Nm"] = max(levels), min(levels)
            d["collision_Nm"] = " ".join(f"{v:.4g}" for v in levels)
            d["max_contact_Nm"] = max(contact)
            d.update({f"heldout_{k}": v for k, v in h.items() if not isinstance(v, (dict, list))})
            rows.append(d)
        return rows


def _replay_once(item: Item, robot: RobotModel, s: ObserverSettings, load: Callable[[Any], RobotLog]) -> Any:
    """A replay at ``s`` (exact, no second stage) if ``item`` refilters, else the log itself (replayed at each
    gain later); a residual given is kept as it is (refiltered from its own gain and stage)."""
    if isinstance(item, ResidualReplay):
        return item
    log = item if isinstance(item, RobotLog) else load(item)
    if not uniform_period(log.t):
        return log
    return replay_residual(log, robot, s)


def _at_gain(item: Any, s: ObserverSettings, robot: RobotModel) -> ResidualReplay:
    """The detector's residual at ``s`` (its detection gain, exact, and its second stage): ``item`` refiltered
    if it is a replay, else replayed."""
    if isinstance(item, ResidualReplay):
        return refilter(item, s.detection_gain, "exact", s.detection_filter_gain)
    return replay_residual(item, robot, s)


def _heldout_alarms(replays: list[ResidualReplay], levels: np.ndarray, gap_s: float) -> dict[str, Any]:
    """Alarms of the arm on the held-out ``replays`` at ``levels`` [Nm], excursions closer than ``gap_s`` one."""
    alarms, per_joint, hours = 0, np.zeros(levels.size, dtype=int), 0.0
    for r in replays:
        c = count_alarms(r.residual, levels, r.dt, gap_s)
        alarms += int(c["alarms"])  # type: ignore[call-overload]
        per_joint += np.array([c["alarms_per_joint"][str(j + 1)] for j in range(levels.size)])  # type: ignore[index]
        hours += r.duration / 3600.0
    return {
        "duration_s": hours * 3600.0,
        "alarms": alarms,
        "alarms_per_hour": alarms / hours if hours > 0 else None,
        "alarms_per_joint": [int(v) for v in per_joint],
        "gap_s": gap_s,
    }


def propose_detection_pairs(
    logs: Sequence[Item],
    robot: RobotModel,
    gains: Sequence[float] = DEFAULT_DETECTION_GAINS,
    *,
    heldout: Sequence[Item] = (),
    settings: ObserverSettings | None = None,
    rate_per_hour: float = DEFAULT_RATE,
    contact_rate_per_hour: float = DEFAULT_CONTACT_RATE,
    ramp_slope: float = DEFAULT_RAMP_SLOPE,
    step_size: float = DEFAULT_STEP_SIZE,
    lag_draws: int = 50,
    method: str = DEFAULT_METHOD,
    allow_extrapolation: bool = False,
    seed: int = 0,
    load: Callable[[str | os.PathLike[str]], RobotLog] | None = None,
) -> DetectionPairs:
    """Levels per joint for each detection gain, with the lag and held-out false alarms each gives (module
    docstring). ``logs`` and ``heldout``: free-motion logs, files or exact-form replays (of other seeds);
    ``settings``: the slow observer and model terms (its detection gain and form are set per pair; its
    ``detection_filter_gain``, if any, is every pair's second stage).

    Raises:
        ConfigError: no gain, a bad gain, slope or step size; the errors of :func:`tune_thresholds`.
    """
    gain_list = parse_gains(gains)
    if not (math.isfinite(ramp_slope) and ramp_slope > 0 and math.isfinite(step_size) and step_size > 1):
        raise ConfigError(f"ramp_slope must be > 0 [Nm/s] and step_size > 1 [x zeta]; got {ramp_slope}, {step_size}")
    base = replace(settings or ObserverSettings(), observer_discretization="exact")
    # the reference replay is first-order (no stage): refilter takes it to any gain and stage
    ref = replace(base, detection_observer_gain=gain_list[-1], detection_filter_gain=None)
    read = load or (lambda path: load_free_motion_log(path, robot))
    tune_items = [_replay_once(x, robot, ref, read) for x in logs]
    held_items = [_replay_once(x, robot, ref, read) for x in heldout]
    pairs = []
    for gain in gain_list:
        s = replace(base, detection_observer_gain=gain)
        reps = [_at_gain(x, s, robot) for x in tune_items]
        held = [_at_gain(x, s, robot) for x in held_items]
        proposal = tune_thresholds(
            reps, robot, settings=s, rate_per_hour=rate_per_hour, contact_rate_per_hour=contact_rate_per_hour,
            method=method, allow_extrapolation=allow_extrapolation, seed=seed,
        )  # fmt: skip
        proposal.replays = []  # the refiltered residuals are not kept (one per gain)
        zeta = proposal.collision
        lag_on = held or reps
        draws = {"count": lag_draws, "seed": seed}
        t_f, gap = s.filter_time_constant, s.declustering_gap
        step_lag = detection_delay(1.0, step_size, 1.0 / gain, filter_time_constant=t_f)
        assert step_lag is not None  # a step of step_size > 1 times zeta always crosses it
        pairs.append(
            GainPair(
                gain=gain,
                proposal=proposal,
                ramp_lag_s=[ramp_lag(float(z), ramp_slope, 1.0 / gain, t_f) for z in zeta],
                step_lag_s=step_lag,
                measured_step_lag_s=synthetic_lags(lag_on, zeta, kind="step", size=step_size, **draws),
                measured_ramp_lag_s=synthetic_lags(lag_on, zeta, kind="ramp", slope=ramp_slope, **draws),
                heldout=_heldout_alarms(held, zeta, gap) if held else None,
                detection_filter_gain=s.detection_filter_gain,
            )
        )  # fmt: skip
    return DetectionPairs(
        pairs, float(rate_per_hour), float(ramp_slope), float(step_size),
        [getattr(x, "source", str(x)) for x in tune_items], [getattr(x, "source", str(x)) for x in held_items],
        base.detection_friction_band, base.detection_filter_gain,
    )  # fmt: skip
