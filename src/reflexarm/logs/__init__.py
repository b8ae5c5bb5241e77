"""Robot logs in: load CSV / Parquet / npz / ROS 2 bags, validate, repair, resample, filter and differentiate.

Used by identification, threshold tuning, detection and the ROS node; imports nothing above it.

The log schema (columns, units, the npz layout) is documented once, in :mod:`reflexarm.logs.files`.
Logs as robots export them are read too: joint-named columns, the ROS 2 JointState layout and an
explicit column mapping (:mod:`reflexarm.logs.columns`), time stamps in s/ms/us/ns and from the
Unix epoch, made relative to the log's first sample (:mod:`reflexarm.logs.timestamps`), and rosbag2
(sqlite3) and MCAP bags (:mod:`reflexarm.logs.bags`). :func:`load_log` reports in the log's
``notes`` what it recognized, converted and left out.

Header-less files are mapped by position (``t=0,q=1:7,...``), a column may carry a scale
(:mod:`reflexarm.logs.column_mapping`), and motor currents times per-joint gains may stand for the torque
(:mod:`reflexarm.logs.motor_current`).

Validation is strict and every error names the file, the column or row and the problem; exact repeats
are dropped and host time stamps that jitter by less than half a period are put on the robot's grid with
a :class:`LogRepairWarning` (unless ``repair=False``); other irregular stamps are kept as the log's own.
:mod:`reflexarm.logs.robot_log` describes each check and repair; :mod:`reflexarm.logs.plausibility` and
:mod:`reflexarm.logs.units` hold a log against its robot (limits, units).

:func:`preprocess_log` then resamples to a uniform grid (positions by cubic Hermite interpolation with
the measured velocities as slopes, velocities by a cubic spline, the other signals linearly; only gaps
are actually filled when the log is already on the grid). Gaps longer than ``max_gap`` (default
:data:`~reflexarm.logs.preprocessing.DEFAULT_MAX_GAP_PERIODS` periods) are not filled: they split the
log into segments, each resampled, filtered and differentiated on its own, and the grid's size is
checked against :data:`~reflexarm.logs.preprocessing.MAX_GRID_FACTOR` before anything is allocated.
It then filters with a zero-phase Butterworth low-pass (``scipy.signal.filtfilt``, order 4, default
cutoff :data:`DEFAULT_CUTOFF_HZ` for q, dq and ddq),
and derives ddq as the central difference of the filtered dq. The torques are filtered with the same
filter for identification (the regressor and the torque then see the same filter, Gautier's parallel
filtering); the raw torques stay available for validation.
"""

from __future__ import annotations

from reflexarm.logs.columns import parse_column_mapping
from reflexarm.logs.files import load_log, save_log
from reflexarm.logs.preprocessing import DEFAULT_CUTOFF_HZ, DEFAULT_FILTER_ORDER, preprocess_log
from reflexarm.logs.robot_log import WRENCH_COLUMNS, LogRepairWarning, RobotLog

# The pipeline's pieces live in their own modules (robot_log: the validated log and its repairs;
# log_files: loading and saving; log_columns / log_tables: finding the signals in a table; log_bags:
# ROS 2 bags; _timestamps: time units and epochs; preprocessing: resampling, filtering,
# differentiation) and are re-exported here, where they have always been imported from.
from reflexarm.logs.timestamps import TIME_UNITS, TimeUnitWarning

__all__ = [
    "DEFAULT_CUTOFF_HZ",
    "DEFAULT_FILTER_ORDER",
    "TIME_UNITS",
    "WRENCH_COLUMNS",
    "LogRepairWarning",
    "RobotLog",
    "TimeUnitWarning",
    "load_log",
    "parse_column_mapping",
    "preprocess_log",
    "save_log",
]
