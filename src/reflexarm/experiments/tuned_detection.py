"""Tuned detection for the collision experiments: a (k_o, zeta) pair per arm from a ``detection_study.json``.

``reflexarm detection-study`` tunes per-joint levels zeta_j for each detection observer gain k_o on an arm's own
free-motion logs and counts their false alarms in a held-out hour. :func:`load_tuned_detection` reads one pair per
arm back from its JSON so that another experiment (``reflexarm reaction-study --detection-study``) runs its
contacts with the levels a user would deploy, on the model errors they were tuned on.

The pair of an arm: the gain given, or (``gain=None``) the smallest gain whose analytic ramp lag (a 1000 Nm/s ramp,
the largest over the joints) is within :data:`~reflexarm.experiments.detection_study.TARGET_LAG_S` and whose
held-out hour had no false alarm; without such a gain, the one with the smallest ramp lag among those without
false alarms.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from reflexarm._validation import read_json_file
from reflexarm.detect.defaults import DETECTION_LAG_TARGET_S as TARGET_LAG_S
from reflexarm.errors import ConfigError

__all__ = ["TunedDetection", "choose_pair", "load_tuned_detection", "pair_at_gain"]



@dataclass(frozen=True)
class TunedDetection:
    """One arm's detection pair: the detection observer's gain [1/s], its per-joint levels [Nm] (model order),
    the model seed the levels were tuned on (None: tuned across models, any seed), where it came from, and what the
    study measured for it (held-out false alarms per hour, the analytic ramp lag [s]); ``friction_band``: the
    detection observer's own friction band [rad/s] the levels were tuned with (None: the paper's kappa_f = 0);
    ``filter_gain``: K_f [1/s] of the detection residual's second stage they were tuned with (None: none)."""

    arm: str
    gain: float
    levels: tuple[float, ...]
    model_seed: int | None
    source: str
    alarms_per_hour: float | None
    ramp_lag_s: float | None
    friction_band: float | None = None
    filter_gain: float | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready (the study's conditions)."""
        return {
            "detection_observer_gain_per_s": self.gain,
            "levels_Nm": list(self.levels),
            "model_seed": self.model_seed,
            "source": self.source,
            "heldout_alarms_per_hour": self.alarms_per_hour,
            "ramp_lag_max_s": self.ramp_lag_s,
            "detection_friction_band_rad_s": self.friction_band,
            "detection_filter_gain_per_s": self.filter_gain,
        }


def _number(value: object) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def _alarms(pair: dict[str, Any]) -> float | None:
    held = pair.get("heldout")
    return _number(held.get("alarms_per_hour")) if isinstance(held, dict) else None


def pair_at_gain(pairs: object, gain: float) -> dict[str, Any] | None:
    """The entry of ``pairs`` (the ``"pairs"`` list of a ``DetectionPairs.as_dict()``: a detection study's per arm,
    a thresholds.json's ``detection_pairs``) tuned at ``gain`` [1/s], if any."""
    for pair in pairs if isinstance(pairs, list) else []:
        k = _number(pair.get("detection_observer_gain")) if isinstance(pair, dict) else None
        if k is not None and math.isclose(k, gain, rel_tol=1e-9):
            return pair
    return None


def choose_pair(pairs: Sequence[dict[str, Any]], gain: float | None, arm: str, where: str) -> dict[str, Any]:
    """The pair of ``pairs`` (a detection study's ``pairs.pairs`` of one arm) at ``gain`` [1/s], or by the rule of
    the module's docstring when ``gain`` is None.

    Raises:
        ConfigError: no pair at ``gain`` (naming the gains there are), or none without held-out false alarms.
    """
    gains = [_number(p.get("detection_observer_gain")) for p in pairs]
    if gain is not None:
        found = pair_at_gain(list(pairs), gain)
        if found is not None:
            return found
        have = ", ".join(f"{k:g}" for k in gains if k is not None) or "none"
        raise ConfigError(f"{where}: arm {arm!r} has no pair tuned at k_o = {gain:g} 1/s (gains: {have})")
    clean = [
        p
        for p, k in zip(pairs, gains, strict=True)
        if k is not None and k > 0.0 and _alarms(p) == 0.0 and _number(p.get("ramp_lag_max_s")) is not None
    ]
    if not clean:
        raise ConfigError(
            f"{where}: arm {arm!r} has no pair without held-out false alarms (or the study ran no held-out hour); "
            "give --detection-gain"
        )
    fast = [p for p in clean if float(p["ramp_lag_max_s"]) <= TARGET_LAG_S]
    if fast:
        return min(fast, key=lambda p: float(p["detection_observer_gain"]))
    return min(clean, key=lambda p: float(p["ramp_lag_max_s"]))


def _levels(pair: dict[str, Any], joints: Sequence[str], arm: str, where: str) -> tuple[float, ...]:
    raw = pair.get("collision_Nm")
    values = [_number(v) for v in raw] if isinstance(raw, list) else []
    if len(values) != len(joints) or any(v is None or not math.isfinite(v) or v <= 0.0 for v in values):
        raise ConfigError(
            f"{where}: arm {arm!r}'s levels at k_o = {pair.get('detection_observer_gain')} must be {len(joints)} "
            f"positive torques [Nm] (one per joint); got {raw!r}"
        )
    return tuple(float(v) for v in values if v is not None)


def load_tuned_detection(
    path: str | Path, arms: Sequence[str], robots_joints: Mapping[str, Sequence[str]], gain: float | None = None
) -> dict[str, TunedDetection]:
    """Each arm's :class:`TunedDetection` from the ``detection_study.json`` at ``path``.

    Args:
        path: the JSON written by ``reflexarm detection-study``, or the folder it is in.
        arms: the arms wanted (each must be in the file).
        robots_joints: per arm, the joint names of the robot the levels will run on (checked against the file's).
        gain: the detection gain [1/s] for every arm; None: each arm's pair by the module's rule.

    Raises:
        ConfigError: a missing or malformed file, an arm not in it, other joints, no pair at ``gain``, levels that are
            not one positive torque per joint, a gain that is not positive.
    """
    where = f"--detection-study {str(path)!r}"
    if gain is not None and (not math.isfinite(gain) or gain <= 0.0):
        raise ConfigError(f"--detection-gain must be a positive gain [1/s]; got {gain:g}")
    p = Path(path)
    if p.is_dir() and (p / "detection_study.json").is_file():  # the study's output folder
        p = p / "detection_study.json"
    doc = read_json_file(p, where)
    studied = doc.get("arms") if isinstance(doc, dict) else None
    if not isinstance(studied, dict):
        raise ConfigError(f"{where} is not a detection study (no 'arms'; write one with 'reflexarm detection-study')")
    out = {}
    for arm in arms:
        a = studied.get(arm)
        if not isinstance(a, dict):
            raise ConfigError(f"{where} has no arm {arm!r} (it has: {', '.join(studied) or 'none'})")
        joints = list(robots_joints[arm])
        if a.get("joints") != joints:
            raise ConfigError(f"{where}: arm {arm!r} was tuned for joints {a.get('joints')!r}, not {joints!r}")
        table = a.get("pairs")
        pairs = table.get("pairs") if isinstance(table, dict) else None
        if not isinstance(pairs, list) or not all(isinstance(x, dict) for x in pairs):
            raise ConfigError(f"{where}: arm {arm!r} has no tuned pairs")
        pair = choose_pair(pairs, gain, arm, where)
        band = a.get("detection_friction_band")
        if band is not None and (_number(band) is None or not math.isfinite(band) or band <= 0.0):
            raise ConfigError(f"{where}: arm {arm!r}'s detection_friction_band must be a positive band [rad/s] or "
                              f"null; got {band!r}")  # fmt: skip
        kf = a.get("detection_filter_gain")
        if kf is not None and (_number(kf) is None or not math.isfinite(kf) or kf <= 0.0):
            raise ConfigError(f"{where}: arm {arm!r}'s detection_filter_gain must be a positive gain [1/s] or null; "
                              f"got {kf!r}")  # fmt: skip
        seeds = a.get("model_seeds")
        seed = seeds.get("arm_model_seed") if isinstance(seeds, dict) else None
        out[arm] = TunedDetection(
            arm=arm,
            gain=float(pair["detection_observer_gain"]),
            levels=_levels(pair, joints, arm, where),
            model_seed=int(seed) if isinstance(seed, int) and not isinstance(seed, bool) else None,
            source=str(p),
            alarms_per_hour=_alarms(pair),
            ramp_lag_s=_number(pair.get("ramp_lag_max_s")),
            friction_band=_number(band),
            filter_gain=_number(kf),
        )
    return out
