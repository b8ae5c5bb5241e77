"""Robot logs in: load CSV / Parquet / npz, validate, repair, resample, filter and differentiate.

Log schema (SI units, the robot model's joint order, joints numbered from 1 as in the paper):

======================  ==========================================================  ========
column (CSV, Parquet)   meaning                                                     required
======================  ==========================================================  ========
``t``                   time [s], non-decreasing                                    yes
``q_1`` .. ``q_n``      joint positions [rad]                                       yes
``dq_1`` .. ``dq_n``    joint velocities [rad/s]                                    yes
``tau_1`` .. ``tau_n``  measured joint (motor) torques tau_m [Nm]                   yes
``ddq_1`` .. ``ddq_n``  joint accelerations [rad/s^2] (else derived, see below)     no
``fx fy fz mx my mz``   wrist wrench on the arm beyond the sensor, sensor frame      no
                        [N, Nm] (removed from the torques as tau_ext, eq. (14))
======================  ==========================================================  ========

An ``.npz`` file holds arrays instead of columns: ``t`` (N,), ``q``, ``dq``, ``tau`` (N, n), optional
``ddq`` (N, n) and ``wrench`` (N, 6).

Validation is strict and every error names the file, the column or row and the problem
(:class:`~reflexarm.errors.DataError`): missing or unknown columns, joint columns that are not 1..n,
a joint count that does not match the robot, NaN/inf, time going backwards, a column or array whose
dtype is not a number (booleans, text, objects, complex, dates: a boolean column is not taken as 0/1),
values beyond the absolute plausibility bounds of :mod:`reflexarm.ident.plausibility` (e.g. |tau| >
1e6 Nm; :class:`~reflexarm.errors.ImplausibleDataError` lists the rows, columns and values). Rows are
reported 0-based among the data rows (for a CSV file, row r is on line r + 2). The bounds relative to a
robot's limits are applied by :func:`~reflexarm.ident.identify_dynamics`, which knows the robot.

Real logs are messy, so two defects are repaired (with a :class:`LogRepairWarning` saying what was done)
instead of rejected, unless ``repair=False``:

* **exact repeats**: a row whose every value except the time equals the previous row is the same robot
  sample read twice by the host; it is dropped.
* **jittery host time stamps**: when the steps are not (close to) multiples of one period, the samples
  are re-timed on a grid of the nominal period T (the median step). The log itself says how many periods
  lie between two samples where that is unambiguous: the measured displacement over the mean measured
  velocity, ``dt = (dq_mean . delta_q) / |dq_mean|^2``, when it lands within 0.2 T of a whole number
  of periods. Those step counts are aligned with the host clock (which is right on average but jitters
  locally) by a Viterbi search over each sample's tick (``_align_ticks``), so the result neither
  drifts from the host clock nor follows its jitter. The warning reports the largest shift and how much
  better delta_q and dq dt agree afterwards; if no alignment stays within :data:`MAX_RETIME_SHIFT`
  periods of the host clock, the host time is kept.

:func:`preprocess_log` then resamples to a uniform grid (positions by cubic Hermite interpolation with
the measured velocities as slopes, velocities by a cubic spline, the other signals linearly; only gaps
are actually filled when the log is already on the grid). Gaps longer than ``max_gap`` (default
:data:`~reflexarm.ident.preprocessing.DEFAULT_MAX_GAP_PERIODS` periods) are not filled: they split the
log into segments, each resampled, filtered and differentiated on its own, and the grid's size is
checked against :data:`~reflexarm.ident.preprocessing.MAX_GRID_FACTOR` before anything is allocated.
It then filters with a zero-phase Butterworth low-pass (``scipy.signal.filtfilt``, order 4, default
cutoff :data:`DEFAULT_CUTOFF_HZ` for q, dq and ddq),
and derives ddq as the central difference of the filtered dq. The torques are filtered with the same
filter for identification (the regressor and the torque then see the same filter, Gautier's parallel
filtering); the raw torques stay available for validation.
"""

from __future__ import annotations

# The pipeline's pieces live in their own modules (robot_log: the validated log and its repairs;
# log_files: loading and saving; preprocessing: resampling, filtering, differentiation) and are
# re-exported here, where they have always been imported from.
from reflexarm.ident.log_files import load_log, save_log
from reflexarm.ident.preprocessing import DEFAULT_CUTOFF_HZ, DEFAULT_FILTER_ORDER, preprocess_log
from reflexarm.ident.robot_log import WRENCH_COLUMNS, LogRepairWarning, RobotLog

__all__ = [
    "DEFAULT_CUTOFF_HZ",
    "DEFAULT_FILTER_ORDER",
    "WRENCH_COLUMNS",
    "LogRepairWarning",
    "RobotLog",
    "load_log",
    "preprocess_log",
    "save_log",
]
