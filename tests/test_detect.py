"""``reflexarm detect`` end to end: levels tuned by ``tune-thresholds`` on a free-motion log of one seed, then a log
with N pushes at known times (tests/impact_logs.py) gives N events with their delay and link, and a free-motion log
of another seed gives none, at 100 Hz and 1 kHz; a current-based copy gives the same events; bad input is a clear
error."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from impact_logs import impact_log
from reflexarm.cli import build_parser, main
from reflexarm.logs import save_log
from reflexarm.robots import load_robot

ROBOT = "iiwa14"
PUSHES = 8


@pytest.fixture(scope="module")
def iiwa():
    return load_robot(ROBOT)


@pytest.fixture(scope="module", params=[100.0, 1000.0], ids=["100Hz", "1kHz"])
def tuned(request, iiwa, tmp_path_factory):
    """(rate, thresholds.json, folder): levels from 120 s of free motion (seed 11, with glitches at the stops) at
    1 false alarm per hour, the detection observer at its default gain, exact form."""
    rate = request.param
    folder = tmp_path_factory.mktemp(f"detect{rate:g}")
    free = save_log(impact_log(iiwa, rate_hz=rate, duration_s=120, seed=11, glitches=6).log, folder / "free11.parquet")
    args = (f"tune-thresholds {free} --robot {ROBOT} --detection-observer-gain 100 --rate 1 --contact-rate 600 "
            f"--allow-extrapolation --no-figure --out {folder / 'thr'}")  # fmt: skip
    assert main(args.split()) == 0
    return rate, folder / "thr" / "thresholds.json", folder


def test_pushes_at_known_times_give_one_event_each_and_free_motion_none(iiwa, tuned, capsys):
    rate, thr, folder = tuned
    truth = impact_log(iiwa, rate_hz=rate, duration_s=30, seed=12, n_pulses=PUSHES, peak_range=(5.0, 8.0),
                       links=(3, 4, 5, 6), glitches=4)  # fmt: skip
    pushes = save_log(truth.log, folder / "pushes.parquet")
    free = save_log(impact_log(iiwa, rate_hz=rate, duration_s=60, seed=13, glitches=6).log, folder / "free13.parquet")
    out = folder / "out"
    assert main(["detect", str(pushes), str(free), "--robot", ROBOT, "--threshold", str(thr), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"delay resolution {1e3 / rate:.3g} ms" in printed and "k_o = 100 1/s, exact" in printed
    doc = json.loads((out / "events.json").read_text())
    by_log = {Path(d["log"]).name: d for d in doc["logs"]}
    assert by_log["free13.parquet"]["event_list"] == [], "free motion of another seed: no event"
    events = by_log["pushes.parquet"]["event_list"]
    assert len(events) == PUSHES, [e["t_detect_s"] for e in events]
    dt = 1.0 / rate
    near_link = 0
    for pulse, event in zip(truth.pulses, events, strict=True):
        # detected after the push began (to one period) and before it ended (+ one period)
        assert pulse.t0 - dt <= event["t_detect_s"] <= pulse.t0 + pulse.duration + dt, (pulse, event)
        assert 0.0 <= event["delay_s"] <= 0.05 and event["link"] in range(1, iiwa.n + 1)
        near_link += abs(event["link"] - (pulse.link + 1)) <= 1
    # the isolated link is the pushed one or its neighbour (a force near a joint's axis shifts it by one, the
    # isolation's documented limit); measured 8/8 at both rates with this seed
    assert near_link >= PUSHES - 1
    assert (out / "pushes_residuals.png").is_file() and (out / "free13_residuals.png").is_file()
    rows = pd.read_csv(out / "events.csv")
    assert len(rows) == PUSHES and {"t_detect_s", "delay_s", "link", "force_N", "peak_ratio"} <= set(rows.columns)


def test_a_current_based_copy_gives_the_same_events(iiwa, tuned, tmp_path):
    if "--torque-from" not in build_parser()._subparsers._group_actions[0].choices["detect"].format_help():
        pytest.skip("the log options have no --torque-from current yet")
    rate, thr, _ = tuned
    log = impact_log(iiwa, rate_hz=rate, duration_s=20, seed=21, n_pulses=5, peak_range=(5.0, 8.0)).log
    gains = np.linspace(0.5, 2.0, iiwa.n)  # [Nm/A]
    torque = save_log(log, tmp_path / "torque.csv")
    table = pd.read_csv(torque)
    for j in range(iiwa.n):
        table[f"current_{j + 1}"] = table.pop(f"tau_{j + 1}") / gains[j]
    current = tmp_path / "current.csv"
    table.to_csv(current, index=False, float_format="%.12g")
    found = {}
    from_current = ["--torque-from", "current", "--gains", ",".join(f"{g:.17g}" for g in gains)]
    for name, path, extra in (("torque", torque, []), ("current", current, from_current)):
        out = tmp_path / name
        assert main(["detect", str(path), "--robot", ROBOT, "--threshold", str(thr), "--no-figure", "--out", str(out),
                     *extra]) == 0  # fmt: skip
        found[name] = [(e["t_detect_s"], e["joints"], e["link"]) for e in
                       json.loads((out / "events.json").read_text())["logs"][0]["event_list"]]  # fmt: skip
    assert len(found["torque"]) == 5 and found["current"] == found["torque"]


def _csv(tmp_path: Path, log, name: str = "log.csv") -> Path:
    return save_log(log, tmp_path / name)


def test_bad_input_is_a_clear_error(iiwa, tmp_path, capsys):
    log = impact_log(iiwa, rate_hz=100.0, duration_s=5, seed=31).log
    base = ["--robot", ROBOT, "--threshold", "5", "--no-figure", "--out", str(tmp_path / "out")]
    table = pd.read_csv(_csv(tmp_path, log))
    # joint-named columns of another arm
    named = table.rename(columns={f"q_{j + 1}": f"position_elbow_{j}" for j in range(iiwa.n)})
    named.to_csv(tmp_path / "names.csv", index=False)
    assert main(["detect", str(tmp_path / "names.csv"), *base]) == 2
    assert "q_1" in capsys.readouterr().err  # names the column it looked for
    nan = table.copy()
    nan.loc[100, "dq_3"] = np.nan
    nan.to_csv(tmp_path / "nan.csv", index=False)
    assert main(["detect", str(tmp_path / "nan.csv"), *base]) == 2
    err = capsys.readouterr().err
    assert "dq_3" in err and "100" in err, err
    back = table.copy()
    back.loc[200, "t"] = back.loc[150, "t"]
    back.to_csv(tmp_path / "back.csv", index=False)
    assert main(["detect", str(tmp_path / "back.csv"), *base]) == 2
    assert "time" in capsys.readouterr().err.lower()
    assert main(["detect", str(_csv(tmp_path, log)), *base[:2], "--threshold", "1,2,3"]) == 2
    assert "--threshold has 3 levels; robot 'iiwa14' has 7 joints" in capsys.readouterr().err


def test_one_level_for_every_joint_runs_without_coverage_and_says_so(iiwa, tmp_path, capsys):
    log = _csv(tmp_path, impact_log(iiwa, rate_hz=100.0, duration_s=10, seed=41, n_pulses=2, peak_range=(6.0, 8.0)).log)
    out = tmp_path / "out"
    assert main(["detect", str(log), "--robot", ROBOT, "--threshold", "6", "--no-figure", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "warning: no coverage stored with the levels" in captured.err
    doc = json.loads((out / "events.json").read_text())
    assert doc["method"]["zeta_Nm"] == [6.0] * iiwa.n and doc["method"]["observer"]["detection_observer_gain"] == 100.0
    assert doc["logs"][0]["delay_resolution_s"] == pytest.approx(0.01)
