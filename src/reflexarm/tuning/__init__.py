"""Collision thresholds from the user's own free-motion data (``reflexarm tune-thresholds``).

:func:`tune_thresholds` replays the product's observer on free-motion logs (:func:`replay_residual`),
fits the tail of each joint's |residual| (:mod:`reflexarm.tuning.tail`) and proposes a collision and a
lower contact level per joint for false-alarm rates the user gives, with the detection delay each implies.
:func:`propose_detection_pairs` does so for a list of detection observer gains, the (k_o, zeta) pairs with
the lag and held-out false alarms of each (:mod:`reflexarm.tuning.pairs`).
:func:`record_free_motion_log` writes such logs in simulation (the built-in Atlas arm).

The names below are imported from their modules on first use: the study pulls in SciPy and the
identification package, while ``reflexarm tune-thresholds`` registers its options from
:mod:`reflexarm.tuning.defaults` alone.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from reflexarm._lazy import lazy_names

if TYPE_CHECKING:
    from reflexarm.tuning.defaults import DEFAULT_CONTACT_RATE, DEFAULT_METHOD, DEFAULT_RATE
    from reflexarm.tuning.delays import FORCE_DIRECTIONS, detection_delay, force_step_delays, ramp_lag
    from reflexarm.tuning.free_motion_log import FreeMotionRun, record_free_motion_log
    from reflexarm.tuning.gains import refilter, synthetic_lags
    from reflexarm.tuning.pairs import (
        DEFAULT_DETECTION_GAINS,
        DetectionPairs,
        GainPair,
        parse_gains,
        propose_detection_pairs,
    )
    from reflexarm.tuning.replay import (
        ObserverSettings,
        ResidualReplay,
        ThresholdWarning,
        is_trace_file,
        load_free_motion_log,
        recorded_residual,
        replay_residual,
    )
    from reflexarm.tuning.study import (
        MAX_EXTRAPOLATION,
        JointThresholds,
        LogTooShortError,
        ThresholdProposal,
        tune_thresholds,
    )
    from reflexarm.tuning.tail import METHODS, TailFit, cluster_maxima, fit_tail

__all__ = [
    "DEFAULT_CONTACT_RATE",
    "DEFAULT_DETECTION_GAINS",
    "DEFAULT_METHOD",
    "DEFAULT_RATE",
    "FORCE_DIRECTIONS",
    "MAX_EXTRAPOLATION",
    "METHODS",
    "DetectionPairs",
    "FreeMotionRun",
    "GainPair",
    "JointThresholds",
    "LogTooShortError",
    "ObserverSettings",
    "ResidualReplay",
    "TailFit",
    "ThresholdProposal",
    "ThresholdWarning",
    "cluster_maxima",
    "detection_delay",
    "fit_tail",
    "force_step_delays",
    "is_trace_file",
    "load_free_motion_log",
    "parse_gains",
    "propose_detection_pairs",
    "ramp_lag",
    "record_free_motion_log",
    "recorded_residual",
    "refilter",
    "replay_residual",
    "synthetic_lags",
    "tune_thresholds",
]

#: The module of each public name.
_SOURCES = {
    **dict.fromkeys(("FORCE_DIRECTIONS", "detection_delay", "force_step_delays", "ramp_lag"), "delays"),
    **dict.fromkeys(("refilter", "synthetic_lags"), "gains"),
    **dict.fromkeys(
        ("DEFAULT_DETECTION_GAINS", "DetectionPairs", "GainPair", "parse_gains", "propose_detection_pairs"), "pairs"
    ),
    **dict.fromkeys(("DEFAULT_CONTACT_RATE", "DEFAULT_METHOD", "DEFAULT_RATE"), "defaults"),
    **dict.fromkeys(("FreeMotionRun", "record_free_motion_log"), "free_motion_log"),
    **dict.fromkeys(
        (
            "ObserverSettings",
            "ResidualReplay",
            "ThresholdWarning",
            "is_trace_file",
            "load_free_motion_log",
            "recorded_residual",
            "replay_residual",
        ),
        "replay",
    ),
    **dict.fromkeys(
        ("MAX_EXTRAPOLATION", "JointThresholds", "LogTooShortError", "ThresholdProposal", "tune_thresholds"), "study"
    ),
    **dict.fromkeys(("METHODS", "TailFit", "cluster_maxima", "fit_tail"), "tail"),
}


__getattr__, __dir__ = lazy_names(__name__, _SOURCES, globals())
