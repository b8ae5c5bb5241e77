"""Closing the loop on the simulated plant: identify from a logged excitation run, write the model file,
load it into the controller, and track better than with the perturbed nominal model."""

from __future__ import annotations

import numpy as np
import pytest

from reflexarm.experiments.identification import MOVING_SPEED, compare_tracking, simulate_log
from reflexarm.ident import (
    FrictionParameters,
    compute_base_parameters,
    identify_dynamics,
    load_identified_model,
    optimize_excitation,
    preprocess_log,
    project_physically_consistent,
    save_identified_model,
)
from reflexarm.robots import perturb_model


@pytest.mark.slow
def test_identified_model_tracks_better_than_the_perturbed_nominal(atlas, tmp_path):
    base = compute_base_parameters(atlas)
    nominal = perturb_model(atlas, 0.1, seed=0)  # the user's model before identification (+-10 %)
    design = optimize_excitation(atlas, base=base, n_harmonics=4, n_grid=100, n_samples=60, maxiter=12, seed=0)
    traj = design.trajectory.with_periods(2)
    raw, _ = simulate_log(atlas, traj, traj.duration, controller_model=nominal, seed=1)
    # friction as the single-joint runs give it (they match Table I within ~1 %, test_ident_friction.py)
    friction = FrictionParameters.from_model(atlas.friction)
    res = identify_dynamics(
        atlas, preprocess_log(raw), method="sequential", friction=friction, base=base, min_speed=MOVING_SPEED
    )
    res = project_physically_consistent(res, nominal)
    path = save_identified_model(res, atlas, tmp_path / "atlas_model.json")
    identified = load_identified_model(path, atlas)
    other = optimize_excitation(atlas, base=base, maxiter=0, seed=7).initial  # not the identification trajectory
    cmp = compare_tracking(atlas, {"nominal": nominal, "identified": identified}, other, 10.0, kappa_f=1, seed=3)
    rms = {k: float(np.sqrt(np.mean(v**2))) for k, v in cmp.rms_error.items()}
    assert rms["identified"] < 0.8 * rms["nominal"], rms
