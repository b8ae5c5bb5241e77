"""A collision setting (:class:`~reflexarm.experiments.collision.CollisionSetting`) with the command line's
detection and reaction, and its console line (``demo``, ``simulate ee-collision|link-collision``)."""

from __future__ import annotations

from typing import Any

from reflexarm._cli.common import DetectionChoice, changed_settings, detector_text


def with_detection(setting: Any, detection: DetectionChoice) -> Any:
    """``setting`` with the command line's detection settings, if it detects at all."""
    from dataclasses import replace

    if setting.threshold is None:
        return setting
    return replace(
        setting,
        threshold=detection.threshold,
        observer_gain=setting.observer_gain if detection.observer_gain is None else detection.observer_gain,
        detection_observer_gain=detection.detection_observer_gain,
        reaction=detection.reaction,
        observer_discretization=detection.observer_discretization,
        detection_friction_band=detection.detection_friction_band,
        detection_filter_gain=detection.detection_filter_gain,
        reaction_settings=detection.reaction_settings,
    )


def setting_line(setting: Any) -> str:
    """The console line of a collision setting: stiffness, detection (levels, gains, friction band), reaction."""
    if setting.threshold is None:
        return f"[{setting.name}] k = {setting.stiffness:g} Nm/rad, detection off"
    zeta = setting.threshold
    zeta_text = ", ".join(f"{v:.3g}" for v in zeta) if isinstance(zeta, tuple) else f"{zeta:g}"
    gains = f"k_o = {setting.observer_gain:g} 1/s" + detector_text(
        setting.detection_observer_gain, setting.detection_friction_band, setting.detection_filter_gain
    )
    return (
        f"[{setting.name}] k = {setting.stiffness:g} Nm/rad, detection zeta = {zeta_text} Nm, {gains}, "
        f"reaction {setting.reaction}{changed_settings(setting.reaction_settings)}"
    )
