"""Collision thresholds from the user's own free-motion data (``reflexarm tune-thresholds``).

:func:`tune_thresholds` replays the product's observer on free-motion logs (:func:`replay_residual`),
fits the tail of each joint's |residual| (:mod:`reflexarm.tuning.tail`) and proposes a collision and a
lower contact level per joint for false-alarm rates the user gives, with the detection delay each implies.
:func:`record_free_motion_log` writes such logs in simulation (the built-in Atlas arm).
"""

from reflexarm.tuning.delays import FORCE_DIRECTIONS, detection_delay, force_step_delays
from reflexarm.tuning.free_motion_log import FreeMotionRun, record_free_motion_log
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
    DEFAULT_CONTACT_RATE,
    DEFAULT_METHOD,
    DEFAULT_RATE,
    MAX_EXTRAPOLATION,
    JointThresholds,
    LogTooShortError,
    ThresholdProposal,
    tune_thresholds,
)
from reflexarm.tuning.tail import METHODS, TailFit, cluster_maxima, fit_tail

__all__ = [
    "DEFAULT_CONTACT_RATE",
    "DEFAULT_METHOD",
    "DEFAULT_RATE",
    "FORCE_DIRECTIONS",
    "MAX_EXTRAPOLATION",
    "METHODS",
    "FreeMotionRun",
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
    "record_free_motion_log",
    "recorded_residual",
    "replay_residual",
    "tune_thresholds",
]
