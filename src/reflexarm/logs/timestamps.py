"""Time stamps as robots write them: the unit (s, ms, us, ns) and the epoch offset.

A log's time column may count seconds, milliseconds, microseconds or nanoseconds, from the log's start
or from the Unix epoch (ROS header stamps, host clocks). :func:`relative_seconds` turns it into seconds
from the log's first sample, exactly for integer stamps (the first stamp is subtracted in integer
arithmetic before converting: a float64 holds a nanosecond epoch stamp only to ~256 ns), and says in a
note what it did.

The unit, unless given (``time_unit``, or a unit suffix of the column name such as ``t_ns``), is
inferred:

1. **epoch magnitude**: a first stamp between 2000-01-01 and 2100-01-01 in one of the units that
   pass 2. (e.g. 1.7e9 s, 1.7e18 ns) names that unit;
2. **sample spacing**: the median step in each unit is taken as the sample period; units
   whose period lies outside :data:`PLAUSIBLE_PERIOD` are excluded, so are us and ns for non-integer
   stamps; of those left, the one whose period is nearest 1 ms (the usual joint-log rate) on a log
   scale is chosen, and when more than one was left the note and a :class:`TimeUnitWarning` say so.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from reflexarm.errors import DataError

__all__ = [
    "EPOCH_RANGE_S",
    "PLAUSIBLE_PERIOD",
    "TIME_UNITS",
    "TimeUnitWarning",
    "relative_seconds",
    "unit_from_name",
]

#: Seconds per unit of the time units a log may use.
TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
#: First stamps in this range [s] (2000-01-01 to 2100-01-01 UTC) are taken as Unix epoch times.
EPOCH_RANGE_S = (946_684_800.0, 4_102_444_800.0)
#: Sample periods [s] a joint log can plausibly have: 20 kHz to 10 Hz (a slower log cannot carry
#: what identification needs below the default 10 Hz cutoff).
PLAUSIBLE_PERIOD = (5e-5, 0.1)


class TimeUnitWarning(UserWarning):
    """The time unit of a log was inferred from an ambiguous spacing; pass the unit to be sure."""


def unit_from_name(column: str) -> str | None:
    """The unit a time column's name states (``t_ns``, ``time_us``, ``stamp_ms``, ``t_s``), else None."""
    for unit in TIME_UNITS:
        if column.lower().endswith(f"_{unit}") or column.lower().endswith(f"[{unit}]"):
            return unit
    return None


def relative_seconds(
    raw: np.ndarray, *, where: str, column: str = "t", unit: str | None = None
) -> tuple[np.ndarray, str | None]:
    """Seconds from the first sample, and a note saying what was done (None if nothing was).

    Args:
        raw: the stamps as read (integers or floats), in file order.
        where: the log's name, for messages.
        column: the column (or field) the stamps came from, for messages.
        unit: ``"s"``, ``"ms"``, ``"us"`` or ``"ns"``; None: from the column name, else inferred (see
            the module docstring).

    Raises:
        DataError: an unknown ``unit``, non-finite stamps, or (inferring) a spacing no unit explains.
    """
    arr = _checked_stamps(raw, where=where, column=column, unit=unit)
    integer = arr.dtype.kind in "iu"
    arr, rel, offset_raw, offset_text = _from_first(arr)
    # the unit: given, else stated by the column name, else inferred
    how = "given"
    if unit is None:
        unit = unit_from_name(column)
        how = f"from the column name {column!r}"
    ambiguous: list[str] = []
    if unit is None:
        unit, how, ambiguous = _infer_unit(offset_raw, rel, integer or bool(np.all(arr == np.round(arr))), where)
    scale = TIME_UNITS[unit]
    snapped = None if integer else _snap_quantized(rel, float(np.spacing(np.max(np.abs(arr)))))
    if snapped is not None:
        rel, shift = snapped
    t = rel * scale
    offset_s = offset_raw * scale
    # the note: what was inferred, subtracted and snapped
    parts = []
    if unit != "s" or ambiguous or how.startswith("inferred: the first"):
        parts.append(f"in {unit} ({how})")
    if offset_raw != 0.0:
        epoch = EPOCH_RANGE_S[0] <= offset_s <= EPOCH_RANGE_S[1]
        parts.append(
            f"made relative to the first sample (subtracted {offset_text} {unit}"
            + (f" = {_utc(offset_s)}, a Unix epoch time" if epoch else f" = {offset_s:.9g} s")
            + ")"
        )
    if snapped is not None:
        parts.append(
            f"float stamps of this magnitude resolve only {np.spacing(np.max(np.abs(arr))) * scale:.2g} s: put on "
            f"their {float(np.median(np.diff(t))) * 1e3:.6g} ms grid (largest shift {shift * scale:.2g} s)"
        )
    if ambiguous:
        msg = (
            f"{where}: the spacing of the time stamps ({column}) fits more than one unit ({', '.join(ambiguous)}); "
            f"took {unit}, "
            f"the period nearest 1 ms ({float(np.median(np.diff(t))) * 1e3:.4g} ms); pass the time unit to be sure"
        )
        warnings.warn(msg, TimeUnitWarning, stacklevel=3)
        parts.append(msg.split(": ", 1)[1])
    note = f"{where}: time stamps ({column}): " + "; ".join(parts) if parts else None
    return t, note


def _checked_stamps(raw: np.ndarray, *, where: str, column: str, unit: str | None) -> np.ndarray:
    """``raw`` as an array, after checking ``unit`` is known and the stamps are there and finite (DataError)."""
    if unit is not None and unit not in TIME_UNITS:
        raise DataError(
            f"{where}: unknown time unit {unit!r}; choose one of {', '.join(TIME_UNITS)}",
            source=where,
            value=unit,
            expected=tuple(TIME_UNITS),
        )
    arr = np.asarray(raw)
    if arr.size == 0:
        raise DataError(f"{where}: the log has no samples")
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        row = int(np.argmax(~np.isfinite(arr)))
        raise DataError(
            f"{where}: column {column!r} row {row} is {arr[row]!r}; time stamps must be finite",
            source=where,
            column=column,
            row=row,
            value=float(arr[row]),
            expected="a finite number",
        )
    return arr


def _from_first(arr: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, str]:
    """(the stamps, as floats unless integers; the stamps less the first, in the stamps' unit; the first stamp;
    the first stamp as text for the note). Integer stamps are subtracted in integer arithmetic before
    converting, so a nanosecond epoch stamp loses nothing."""
    if arr.dtype.kind in "iu":
        offset_text = str(int(arr[0]))
        return arr, (arr.astype(np.int64) - np.int64(arr[0])).astype(float), float(arr[0]), offset_text
    arr = arr.astype(float)
    offset_raw = float(arr[0])
    return arr, arr - arr[0], offset_raw, f"{offset_raw:.17g}"


def _snap_quantized(rel: np.ndarray, resolution: float) -> tuple[np.ndarray, float] | None:
    """Float stamps whose deviation from a uniform grid is within their own float resolution (epoch
    seconds in float64 hold ~2.4e-7 s) are put on that grid: (grid times, largest shift), else None.

    The grid's step is the span over the whole number of steps (each step rounded to whole periods of
    the median step), exact to the resolution over the log's length; gaps of whole periods stay gaps.
    """
    steps = np.diff(rel)
    if steps.size == 0 or resolution <= 0:
        return None
    median = float(np.median(steps))
    if not median > 0 or resolution < 1e-9 * median:  # quantization invisible at this magnitude
        return None
    ticks = np.round(steps / median)
    if np.any(ticks < 1):
        return None
    step = float(rel[-1] - rel[0]) / float(ticks.sum())
    grid = rel[0] + step * np.r_[0.0, np.cumsum(ticks)]
    shift = float(np.max(np.abs(rel - grid)))
    if shift > 4 * resolution:  # jitter beyond the float resolution is the robot's: left to re-timing
        return None
    return grid, shift


def _infer_unit(first: float, rel: np.ndarray, whole: bool, where: str) -> tuple[str, str, list[str]]:
    steps = np.diff(rel)
    steps = steps[steps > 0]
    if steps.size == 0:
        return "s", "assumed: the stamps do not advance", []
    step = float(np.median(steps))
    lo, hi = PLAUSIBLE_PERIOD
    fits = [u for u, s in TIME_UNITS.items() if lo <= step * s <= hi and (whole or u in ("s", "ms"))]
    if not fits:
        raise DataError(
            f"{where}: cannot tell the time unit: the median step {step:.6g} is a sample period outside "
            f"{lo:g}..{hi:g} s in every unit ({', '.join(TIME_UNITS)}); pass the time unit",
            source=where,
            value=step,
            expected=tuple(TIME_UNITS),
        )
    for unit in fits:
        if EPOCH_RANGE_S[0] <= first * TIME_UNITS[unit] <= EPOCH_RANGE_S[1]:
            period = step * TIME_UNITS[unit] * 1e3  # the median step: quantized for float epoch stamps
            return (
                unit,
                f"inferred: the first stamp {first:.6g} is a Unix epoch time in {unit}, period {period:.3g} ms",
                [],
            )
    best = min(fits, key=lambda u: abs(math.log10(step * TIME_UNITS[u] / 1e-3)))
    how = f"inferred from the median step {step:.6g} = {step * TIME_UNITS[best] * 1e3:.4g} ms"
    return best, how, (fits if len(fits) > 1 else [])


def _utc(seconds: float) -> str:
    import datetime

    stamp = datetime.datetime.fromtimestamp(seconds, tz=datetime.UTC)
    return stamp.strftime("%Y-%m-%d %H:%M:%S.%f UTC")
