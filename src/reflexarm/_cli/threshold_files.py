"""Detection settings read from the command line or from a file of ``tune-thresholds`` / ``detection-study``:
the levels (``--threshold``), and the observer settings the levels were tuned with (the detection observer's own
friction band, the detection residual's second stage), each checked."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import TYPE_CHECKING

from reflexarm.errors import ConfigError

if TYPE_CHECKING:
    from reflexarm.robots import RobotModel

__all__ = [
    "add_detector_options",
    "detection_band",
    "filter_gain",
    "read_threshold",
    "tuned_filter_gain",
    "tuned_friction_band",
]


def add_detector_options(g: argparse._ActionsContainer, *, default: str, needs: str = "") -> None:
    """``--detection-friction-band RAD_S`` and ``--detection-filter-gain K_F``: what the detector's residual is made
    of besides the observer's gain (the detection observer's own friction model, the residual's second stage);
    ``default``: what each is when not given (``{what}``: "off" or "none"), ``needs``: what the band needs."""
    g.add_argument(
        "--detection-friction-band", type=float, default=None, metavar="RAD_S",
        help="the detection observer subtracts the friction model in this velocity band [rad/s] (detection_kappa_f"
        f" = 1; e.g. 0.1, wider than the velocity noise{needs}) ({default.format(what='off')})",
    )  # fmt: skip
    g.add_argument(
        "--detection-filter-gain", type=float, default=None, metavar="K_F",
        help="the detector looks at the detection residual filtered once more by a first-order stage of this gain "
        "[1/s] (a second-order observer with poles k_o and K_F; Controller(detection_filter_gain); e.g. 200) "
        f"({default.format(what='none')})",
    )  # fmt: skip


def read_threshold(
    value: str, robot: RobotModel, gain: float | None = None
) -> tuple[float | tuple[float, ...], str, float | None]:
    """(zeta, its source, the detecting k_o it was tuned for) from ``--threshold``: a number [Nm], a comma
    list with one positive level per joint of ``robot``, or a ``thresholds.json`` of ``tune-thresholds``
    (its ``collision_Nm``, checked against the robot's joints by count and, when the file has them, names).
    A file with (k_o, zeta) pairs (``tune-thresholds --detection-gains``) gives the pair tuned at ``gain``,
    the detecting k_o of the run [1/s], when it has one; else its top-level levels.

    Raises:
        ConfigError: a non-positive or non-finite level, a list of the wrong length, a missing or malformed
            file, a file for other joints.
    """
    text = str(value).strip()
    path = Path(text)
    if path.suffix.lower() == ".json" or path.is_file():
        return _read_threshold_file(path, robot, gain)
    parts = [s.strip() for s in text.split(",")]
    try:
        levels = [float(s) for s in parts]
    except ValueError:
        raise ConfigError(
            f"--threshold expects a level [Nm], a comma list of {robot.n} levels or a thresholds.json file; "
            f"got {text!r}"
        ) from None
    bad = [v for v in levels if not math.isfinite(v) or v <= 0.0]
    if bad:
        raise ConfigError(f"--threshold levels must be positive torques [Nm]; got {text!r}")
    if len(levels) == 1:
        return levels[0], "command line", None
    if len(levels) != robot.n:
        raise ConfigError(
            f"--threshold has {len(levels)} levels; robot {robot.name!r} has {robot.n} joints "
            f"({', '.join(robot.joint_names)})"
        )
    return tuple(levels), "command line", None


def _pair_at(doc: object, gain: float | None) -> dict[str, object] | None:
    """The ``detection_pairs`` entry of a thresholds file tuned at ``gain`` [1/s], if any."""
    from reflexarm.experiments.tuned_detection import pair_at_gain

    if gain is None or not isinstance(doc, dict) or not isinstance(doc.get("detection_pairs"), dict):
        return None
    return pair_at_gain(doc["detection_pairs"].get("pairs"), gain)


def _read_threshold_file(
    path: Path, robot: RobotModel, gain: float | None = None
) -> tuple[tuple[float, ...], str, float | None]:
    from reflexarm._validation import read_json_file

    doc = read_json_file(path, f"--threshold {str(path)!r}")
    pair = _pair_at(doc, gain)
    if pair is not None:
        doc = {**doc, "collision_Nm": pair.get("collision_Nm"), "observer": {"detection_observer_gain": gain}}
    levels = doc.get("collision_Nm") if isinstance(doc, dict) else None
    if not isinstance(levels, list) or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in levels):
        raise ConfigError(
            f"--threshold: {str(path)!r} has no 'collision_Nm' list of numbers (write it with 'reflexarm "
            "tune-thresholds')"
        )
    if len(levels) != robot.n:
        raise ConfigError(
            f"--threshold: {str(path)!r} has {len(levels)} levels; robot {robot.name!r} has {robot.n} joints"
        )
    names = [j.get("name") for j in doc.get("joints", []) if isinstance(j, dict)]
    if len(names) == robot.n and names != list(robot.joint_names):
        raise ConfigError(
            f"--threshold: {str(path)!r} is for joints {names}; robot {robot.name!r} has {list(robot.joint_names)}"
        )
    if not all(math.isfinite(v) and v > 0.0 for v in levels):
        raise ConfigError(f"--threshold: {str(path)!r} has non-positive levels {levels}")
    observer = doc.get("observer") if isinstance(doc.get("observer"), dict) else {}
    tuned = observer.get("detection_observer_gain") or observer.get("observer_gain")
    label = str(path) if pair is None else f"{path} (its pair at detection k_o = {gain:g} 1/s)"
    return tuple(float(v) for v in levels), label, None if tuned is None else float(tuned)


def _positive_or_none(value: object, what: str) -> float | None:
    """None, or ``value`` as a positive finite number; else a ConfigError saying it must be ``what``."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ConfigError(f"{what}; got {value!r}")
    return float(value)


def detection_band(value: object) -> float | None:
    """``--detection-friction-band`` (or a file's) checked: None, or a positive finite velocity band [rad/s]."""
    return _positive_or_none(value, "--detection-friction-band must be a positive velocity band [rad/s]")


def filter_gain(value: object) -> float | None:
    """``--detection-filter-gain`` (or a file's) checked: None, or a positive finite K_f [1/s]."""
    return _positive_or_none(value, "--detection-filter-gain must be a positive gain [1/s]")


def _tuned_observer_value(value: str, key: str) -> float | None:
    """The number ``key`` of a thresholds.json's observer settings (what its levels were tuned with), if any: None
    when the file has no such setting (or null); a ConfigError when it has one that is not a positive number (the
    levels would be applied to another residual than the one they were tuned on)."""
    from reflexarm._validation import read_json_file

    doc = read_json_file(Path(str(value).strip()), f"--threshold {value!r}")
    observer = doc.get("observer") if isinstance(doc, dict) else None
    v = observer.get(key) if isinstance(observer, dict) else None
    return _positive_or_none(v, f"--threshold {value!r}: its observer setting {key} must be a positive number or null")


def tuned_friction_band(value: str) -> float | None:
    """The detection friction band a thresholds.json's levels were tuned with (its observer settings), if any."""
    return _tuned_observer_value(value, "detection_friction_band")


def tuned_filter_gain(value: str) -> float | None:
    """The K_f [1/s] of the detection residual's second stage a thresholds.json's levels were tuned with, if any."""
    return _tuned_observer_value(value, "detection_filter_gain")
