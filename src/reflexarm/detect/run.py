"""Collisions in recorded logs: the stages of ``reflexarm detect`` for one log, and the report over several.

read (``reflexarm.logs``) -> glitches (:mod:`~reflexarm.detect.glitches`, recognised and repaired) -> replay (the
product's observer at the log's own period, exact discretization: :func:`~reflexarm.tuning.replay_residual`, the
whole log in one call of the C++ core, :func:`reflexarm.control.replay`) -> events
(:mod:`~reflexarm.detect.events`: detect, onset, isolate, identify) ->
coverage (:mod:`~reflexarm.detect.coverage`: does the log stay inside what the levels were tuned on).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from reflexarm.detect.coverage import JointCoverage, check_coverage
from reflexarm.detect.events import DetectedEvent, find_events
from reflexarm.detect.glitches import repair_glitches
from reflexarm.detect.result import LogDetection
from reflexarm.errors import ConfigError
from reflexarm.logs.robot_log import RobotLog
from reflexarm.robots.robot_model import RobotModel
from reflexarm.tuning.replay import ObserverSettings, replay_residual

__all__ = ["DetectionReport", "LogDetection", "detect_collisions"]


def _isolate(events: list[DetectedEvent], q: np.ndarray, t: np.ndarray, model: RobotModel, zeta: np.ndarray,
             share: float) -> list[DetectedEvent]:  # fmt: skip
    """The events with the collision pipeline's contact estimate at their peak sample."""
    if not events:
        return events
    from reflexarm.control.collision import ContactIsolator
    from reflexarm.control.collision.classify import controller_geometry

    geometry = controller_geometry(model)
    if geometry is None:
        return events
    isolator = ContactIsolator(model, significance=share * zeta, geometry=geometry)
    out = []
    for e in events:
        k = int(np.searchsorted(t, e.t_peak))
        out.append(replace(e, estimate=isolator.isolate(q[k], e.contact_residual)))
    return out


def detect_collisions(
    log: RobotLog,
    model: RobotModel,
    threshold: npt.ArrayLike,
    *,
    settings: ObserverSettings,
    coverage: Sequence[JointCoverage] | None = None,
    isolate: bool = True,
    significance_share: float | None = None,
) -> LogDetection:
    """The collision events of one log (module docstring).

    Args:
        log: the log, in ``model``'s joint order (q, dq, tau_m; a wrench with kappa_ext).
        model: the controller's model (identified, else the robot file's).
        threshold: zeta per joint [Nm] (scalar or (n,)).
        settings: the observers; the detection observer (``detection_observer_gain``, else ``observer_gain``) is
            the one whose residual is checked; always run in the exact discretization, at the log's own period.
        coverage: the tuning logs' coverage (from the thresholds file): joints along which the log leaves it are
            listed in ``outside``.
        isolate: isolate and identify each event (needs the robot file's collision geometry).
        significance_share: residual components above this share of zeta count for isolation (default the
            controller's, ``SIGNIFICANCE_SHARE``).

    Raises:
        ConfigError: a log of another joint count, a non-positive level.
    """
    from reflexarm.control.collision import SIGNIFICANCE_SHARE

    if log.n != model.n:
        raise ConfigError(f"{log.source} has {log.n} joints; the robot {model.name!r} has {model.n}")
    zeta = np.broadcast_to(np.asarray(threshold, dtype=float), (model.n,)).copy()
    if not np.all(np.isfinite(zeta) & (zeta > 0)):
        raise ConfigError(f"threshold must be positive torques [Nm]; got {zeta.tolist()}")
    s = replace(settings, observer_discretization="exact")
    repaired, glitches = repair_glitches(log)
    replay = replay_residual(repaired, model, s)
    gap = max(2, int(math.ceil(s.declustering_gap / replay.dt - 1e-9)))  # the tuning's, at least two samples
    events = find_events(replay.t, replay.residual, zeta, gap)
    if isolate:
        share = SIGNIFICANCE_SHARE if significance_share is None else float(significance_share)
        events = _isolate(events, repaired.q, replay.t, model, zeta, share)
    outside = [] if coverage is None else check_coverage(log.t, log.q, log.dq, coverage)
    return LogDetection(log.source, replay.t, replay.residual, zeta, replay.dt, s, events, glitches, outside,
                        replay.fault_ticks, list(model.joint_names), list(repaired.notes))  # fmt: skip


@dataclass
class DetectionReport:
    """The detections of several logs with the settings they share."""

    logs: list[LogDetection]
    method: dict[str, Any]

    def rows(self) -> list[dict[str, object]]:
        """One row per event, over every log."""
        return [e.row(d.source, d.joint_names) for d in self.logs for e in d.events]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: the method and settings, per log its summary and events."""
        return {
            "method": self.method,
            "logs": [
                {**d.summary(), "event_list": [e.as_dict(d.source, d.joint_names) for e in d.events]} for d in self.logs
            ],
        }

    def write(self, out: str | Path, *, figure: bool = True) -> dict[str, Path]:
        """``events.csv``, ``events.json`` and (``figure``) one ``<log>_residuals.png`` per log in ``out``."""
        import pandas as pd

        folder = Path(out)
        folder.mkdir(parents=True, exist_ok=True)
        files = {"csv": folder / "events.csv", "json": folder / "events.json"}
        rows = self.rows()
        columns = None if rows else ["log", "t_detect_s", "t_onset_s", "delay_s", "joints", "link", "force_N"]
        pd.DataFrame(rows, columns=columns).to_csv(files["csv"], index=False, float_format="%.6g")
        files["json"].write_text(json.dumps(self.as_dict(), indent=2, default=_json_default))
        if figure:
            from reflexarm.detect.plots import plot_detection

            for i, d in enumerate(self.logs):
                stem = Path(d.source).stem or f"log{i + 1}"
                files[f"figure_{i + 1}"] = plot_detection(d, folder / f"{stem}_residuals.png")
        return files


def _json_default(value: object) -> object:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON-able: {type(value).__name__}")
