"""The live node's coverage warning (issue 17 item 5) without DDS: the node's per-tick check flags the same joints
as ``reflexarm detect``'s check of a whole log (two implementations of one rule), once per joint, and reads the
coverage a thresholds.json stores."""

from __future__ import annotations

import json

import numpy as np

from reflexarm.detect.coverage import JointCoverage, check_coverage
from reflexarm.ros.coverage_watch import CoverageWatch

N = 4


def _coverage() -> list[JointCoverage]:
    return [
        JointCoverage(0, "j1", -1.0, 1.0, 1.5, 0.5, 0.6),
        JointCoverage(1, "j2", 0.2, 0.9, 0.8, 0.2, 0.3),
        JointCoverage(2, "j3", 0.0, 0.005, 0.01, 0.0, 0.0),  # did not move in the tuning logs
        JointCoverage(3, "j4", -2.0, 2.0, 2.0, 0.7, 0.8),
    ]


def test_the_node_flags_the_joints_detect_flags():
    rng = np.random.default_rng(4)
    coverage = _coverage()
    for trial in range(20):
        t = np.arange(500) * 1e-3
        amplitude = rng.uniform(0.2, 2.5, N)
        q = amplitude * np.sin(2 * np.pi * rng.uniform(0.2, 1.0, N) * t[:, None] + rng.uniform(0, 6, N))
        dq = np.gradient(q, t, axis=0)
        expected = {o.joint for o in check_coverage(t, q, dq, coverage)}
        watch = CoverageWatch(coverage, N)
        flagged: list[str] = []
        for k in range(t.size):
            flagged += watch.check(float(t[k]), q[k], dq[k])
        assert set(watch.warned) == expected, trial
        assert len(flagged) == len(expected)  # once per joint, however long it stays outside


def test_a_still_joint_inside_its_coverage_is_not_flagged_and_the_line_names_the_joint():
    watch = CoverageWatch(_coverage(), N)
    assert watch.check(0.0, np.array([0.0, 0.5, 0.002, 0.0]), np.zeros(N)) == []
    lines = watch.check(1.25, np.array([0.0, 0.5, 0.002, 0.0]), np.array([0.0, 0.0, 0.2, 0.0]))
    assert len(lines) == 1 and lines[0].startswith("joint 3 (j3) (a joint that did not move in the tuning logs)")
    assert "t = 1.250 s" in lines[0]


def test_the_watch_reads_a_thresholds_file(tmp_path):
    path = tmp_path / "thresholds.json"
    path.write_text(json.dumps({"collision_Nm": [5.0] * N, "coverage": [c.as_dict() for c in _coverage()]}))
    watch = CoverageWatch.from_threshold(str(path), N)
    assert watch is not None and [c.name for c in watch.coverage] == ["j1", "j2", "j3", "j4"]
    path.write_text(json.dumps({"collision_Nm": [5.0] * N}))
    assert CoverageWatch.from_threshold(str(path), N) is None  # no coverage stored: the node says so
    assert CoverageWatch.from_threshold("11", N) is None
