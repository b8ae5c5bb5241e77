"""Collisions in recorded logs (``reflexarm detect``): the observer replayed at the log's own rate, one-sample
glitches recognised, collision events with their link and force, and the coverage the levels were tuned on.

The stages, in order: :mod:`~reflexarm.detect.glitches` -> the replay (:func:`~reflexarm.tuning.replay_residual`)
-> :mod:`~reflexarm.detect.events` -> :mod:`~reflexarm.detect.coverage`; :mod:`~reflexarm.detect.run` strings
them together. Names are imported from their modules on first use (the command line registers ``detect`` from
:mod:`reflexarm.detect.defaults` alone).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from reflexarm._lazy import lazy_names

if TYPE_CHECKING:
    from reflexarm.detect.coverage import JointCoverage, Outside, check_coverage, measure_coverage
    from reflexarm.detect.defaults import DEFAULT_DETECTION_GAIN, SHORTEST_IMPACT_S
    from reflexarm.detect.events import DetectedEvent, find_events
    from reflexarm.detect.glitches import Glitch, find_glitches, repair_glitches
    from reflexarm.detect.result import LogDetection
    from reflexarm.detect.run import DetectionReport, detect_collisions

__all__ = [
    "DEFAULT_DETECTION_GAIN",
    "SHORTEST_IMPACT_S",
    "DetectedEvent",
    "DetectionReport",
    "Glitch",
    "JointCoverage",
    "LogDetection",
    "Outside",
    "check_coverage",
    "detect_collisions",
    "find_events",
    "find_glitches",
    "measure_coverage",
    "repair_glitches",
]

_SOURCES = {
    **dict.fromkeys(("JointCoverage", "Outside", "check_coverage", "measure_coverage"), "coverage"),
    **dict.fromkeys(("DEFAULT_DETECTION_GAIN", "SHORTEST_IMPACT_S"), "defaults"),
    **dict.fromkeys(("DetectedEvent", "find_events"), "events"),
    **dict.fromkeys(("Glitch", "find_glitches", "repair_glitches"), "glitches"),
    "LogDetection": "result",
    **dict.fromkeys(("DetectionReport", "detect_collisions"), "run"),
}


__getattr__, __dir__ = lazy_names(__name__, _SOURCES, globals())
