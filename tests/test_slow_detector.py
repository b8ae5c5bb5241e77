"""A detector so slow that it is practically off says so (issue 15's bad input: "detection is never silently off"):
``Controller`` warns when the detector's time scale 1/k_o + 1/K_f exceeds ``SLOW_DETECTOR_S`` on some joint."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from reflexarm.control import Controller
from reflexarm.control._setup import SLOW_DETECTOR_S


def _warnings(robot, **kw) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        Controller(robot, **kw)
    return [str(w.message) for w in caught if "time scale" in str(w.message)]


def test_the_paper_s_settings_and_fast_detectors_do_not_warn(atlas):
    assert _warnings(atlas, threshold=11.0) == []  # 5 1/s: 0.2 s
    assert _warnings(atlas, threshold=11.0, detection_observer_gain=100.0, detection_filter_gain=200.0) == []
    # no detector: nothing to warn about, however slow the observer
    assert _warnings(atlas, observer_gain=0.1, threshold=None) == []


@pytest.mark.parametrize(
    "kw, scale",
    [
        (dict(detection_observer_gain=100.0, detection_filter_gain=0.01), 100.01),  # a tiny second stage
        (dict(observer_gain=0.5), 2.0),  # a slow observer that detects
        (dict(observer_gain=0.5, detection_observer_gain=50.0), None),  # ... but a fast detection observer does
    ],
)
def test_a_slow_detector_warns_with_its_time_scale_and_joints(atlas, kw, scale):
    messages = _warnings(atlas, threshold=11.0, **kw)
    if scale is None:
        assert messages == []
        return
    assert len(messages) == 1
    assert f"is {scale:.3g} s on joint(s)" in messages[0] and atlas.joint_names[0] in messages[0]


def test_only_the_slow_joints_are_named(atlas):
    gains = np.full(atlas.n, 50.0)
    gains[2] = 1.0 / (SLOW_DETECTOR_S * 1.5)  # one joint at 1.5 x the bound
    (message,) = _warnings(atlas, threshold=11.0, detection_observer_gain=gains)
    names = atlas.joint_names
    assert f"[{names[2]!r}]" in message and f"{1.5 * SLOW_DETECTOR_S:.3g} s" in message
