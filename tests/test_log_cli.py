"""The identify CLI and logs: nothing is written before a problem with the logs is found."""

from __future__ import annotations

import numpy as np

from reflexarm.cli import main
from reflexarm.ident import BatchRegressor, FrictionParameters, RobotLog, save_log
from reflexarm.ident.excitation import FourierTrajectory


def test_no_model_file_is_written_when_validation_fails_on_the_logs(tmp_path, capsys, atlas):
    """A validation log whose short middle segment (between long gaps) preprocessing drops: scoring the
    model there would interpolate across the gap, so validation fails; it used to fail after the model
    files were written, now before."""
    rng = np.random.default_rng(0)
    tr = FourierTrajectory(2 * np.pi * 0.1, 0.15 * rng.normal(size=(7, 5)), 0.15 * rng.normal(size=(7, 5)), atlas.home)
    t = np.arange(0.0, 6.0, 1e-3)
    q, dq, ddq = tr.evaluate(t)
    fr = FrictionParameters.from_model(atlas.friction)
    tau = BatchRegressor(atlas).compute_regressor(q, dq, ddq) @ atlas.inertial_parameters() + fr.compute_torque(dq)
    ident = save_log(RobotLog(t, q, dq, tau), tmp_path / "ident.csv")
    # keep 0-2 s, five samples at 2.5 s, 3-6 s: gaps of ~0.5 s (> 25 periods) around a 5-sample segment
    keep = (t < 2.0) | ((t >= 2.5) & (t < 2.505)) | (t >= 3.0)
    val = save_log(RobotLog(t[keep], q[keep], dq[keep], tau[keep]), tmp_path / "val.csv")
    out = tmp_path / "out"
    args = ["identify", "dynamics", "--log", str(ident), "--validation-log", str(val), "--method", "combined"]
    code = main([*args, "--no-projection", "--out", str(out), "--quiet"])
    assert code == 2
    assert "val.csv: 5 validation sample(s) fall in a gap of the states" in capsys.readouterr().err
    assert not list(out.glob("*.json")), sorted(p.name for p in out.iterdir())
