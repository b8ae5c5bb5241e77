"""Identification in ten lines: a log in, base parameters + friction out, a model file the controller loads.

The log here is made up on the spot (the built-in Panda following a random Fourier trajectory, torques
from its own model plus Coulomb/viscous friction and sensor noise) and written as CSV in the documented
schema (t, q_i, dq_i, tau_i); with your robot, point ``load_log`` at your file instead.

Run:  python examples/identify_quickstart.py [--out results/quickstart]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from reflexarm.control import Controller
from reflexarm.ident import (
    BatchRegressor,
    RobotLog,
    identify_dynamics,
    load_identified_model,
    load_log,
    optimize_excitation,
    preprocess_log,
    project_physically_consistent,
    save_identified_model,
    save_log,
    validate_model,
)
from reflexarm.robots import load_robot


def make_log(robot, seed: int, duration: float = 30.0) -> RobotLog:
    """A stand-in for a real robot log (see the module docstring)."""
    rng = np.random.default_rng(seed)
    traj = optimize_excitation(robot, maxiter=0, seed=seed).initial.with_periods(3)
    t = np.arange(0.0, duration, 1e-3)
    q, dq, ddq = traj.evaluate(t)
    tau = BatchRegressor(robot).compute_regressor(q, dq, ddq) @ robot.inertial_parameters()
    tau += robot.friction.coulomb * np.sign(dq) + robot.friction.viscous * dq
    return RobotLog(
        t,
        q + rng.uniform(-1e-4, 1e-4, q.shape),
        dq + rng.uniform(-5e-3, 5e-3, dq.shape),
        tau + rng.uniform(-0.05, 0.05, tau.shape),
        source=f"made-up log {seed}",
    )


def main(argv: list[str] | None = None) -> float:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("results/quickstart"))
    args = ap.parse_args(argv)
    robot = load_robot("panda")
    save_log(make_log(robot, seed=0), args.out / "identification.csv")
    save_log(make_log(robot, seed=1), args.out / "validation.csv")

    log = preprocess_log(load_log(args.out / "identification.csv", n_joints=robot.n))  # filter, ddq
    result = identify_dynamics(robot, log, method="combined")  # base parameters + Coulomb + viscous, eq. (18)
    result = project_physically_consistent(result, robot)  # M(q) positive definite everywhere
    check = load_log(args.out / "validation.csv", n_joints=robot.n)
    val = validate_model(result, robot, check, states=preprocess_log(check))
    print(f"{result.base.n_base} base parameters; validation RMSE per joint [Nm]: {np.round(val.rmse, 3)}")

    path = save_identified_model(result, robot, args.out / "model.json")
    controller = Controller(load_identified_model(path), stiffness=300.0, threshold=None, reaction="none")
    print(f"wrote {path}; the controller runs on {controller.robot!r}")
    return val.pooled_rmse


if __name__ == "__main__":
    main()
