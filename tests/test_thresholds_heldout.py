"""Issue 9 item 5 on the simulated Atlas arm: thresholds tuned on a free-motion log give no false alarm on a
held-out 10-minute run and still detect the demo's cinderblock collision (slow: ~18 simulated minutes)."""

from __future__ import annotations

import numpy as np
import pytest

from reflexarm.experiments.collision import controller_model
from reflexarm.tuning import record_free_motion_log, tune_thresholds
from reflexarm.tuning.heldout import demo_collision_with, heldout_free_motion

#: A rate whose per-joint return period (7 joints / 6 per hour = 70 min) an 8-minute log may carry
#: (MAX_EXTRAPOLATION = 10 asks for 7 min); the lead's note uses 30 min of logs at 2 per hour.
RATE_PER_HOUR = 6.0


@pytest.mark.slow
def test_tuned_thresholds_hold_on_a_heldout_run_and_detect_the_demo_collision(atlas):
    model, _ = controller_model(atlas, 0.1, 0)  # the paper's 10 % model error, the user's controller model
    train = record_free_motion_log(480.0, motion="hydraulic", model=model, seed=1)
    prop = tune_thresholds(train.log, model, rate_per_hour=RATE_PER_HOUR, contact_rate_per_hour=60.0)
    zeta = prop.collision
    # held out: other sensor noise, 10 minutes, detection online at the proposed zeta
    held = heldout_free_motion(zeta, model, duration=600.0, seed=100, motion="hydraulic", compare={"11 Nm": 11.0})
    online = held["online"]
    assert isinstance(online, dict)
    assert online["false_alarm_events"] == 0, f"false alarm at zeta = {zeta.round(3).tolist()}: {online}"
    # the offline count on the replayed residual agrees with the online detector
    offline = held["offline"]
    assert isinstance(offline, dict) and offline["proposed"]["alarms"] == 0
    # the demo collision (cinderblock, reaction (13)) is still detected, no later than with 11 Nm everywhere
    rows = {r["threshold"]: r for r in demo_collision_with({"proposed": zeta.tolist(), "11 Nm": 11.0}, model)}
    assert rows["proposed"]["detection_s"] is not None, "the proposed zeta misses the demo collision"
    assert rows["11 Nm"]["detection_s"] is not None
    if np.all(zeta <= 11.0):  # lower levels everywhere cannot detect later
        assert rows["proposed"]["detection_s"] <= rows["11 Nm"]["detection_s"] + 1e-9
