"""Identify the real Franka Emika Panda from Gaz et al.'s excitation log; validate on held-out data.

The log (``../shared/reference/panda_gaz2019``, see its SOURCES.md) is 21 s of a Fourier excitation at
~1 kHz: joint positions, velocities and the link-side torque sensor readings tau_J. It is messy the way
real logs are: 1,131 rows repeat the previous sample and the host time stamps jitter (steps of 1 to
9 ms); :class:`reflexarm.ident.RobotLog` repairs both and says so.

The first 60 % of the samples identify 43 base parameters plus Coulomb, viscous and an offset per joint
(the combined method: there are no single-joint runs for this robot), weighted least squares with
per-joint noise variances estimated from an unweighted pass; the last 40 % validate. The least-squares
estimate is then projected onto physically consistent parameters (its M(q) is not positive definite
everywhere), and that model is written for the controller.

Run:  python examples/identify_panda.py [DATA_DIR] [--out results/panda]
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np

from reflexarm.ident import (
    RobotLog,
    identify_dynamics,
    mass_matrix_margin,
    preprocess_log,
    project_physically_consistent,
    save_log,
    validate_model,
)
from reflexarm.ident.export.model_file import save_identified_model
from reflexarm.ident.plots import plot_torque_validation
from reflexarm.robots import load_robot

DEFAULT_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "reference" / "panda_gaz2019"


def load_gaz_log(folder: Path) -> tuple[RobotLog, float]:
    """The log as a RobotLog (repaired, with warnings) and the time that splits the raw rows 60/40."""
    t = np.loadtxt(folder / "exciting_traj_time.txt")
    q = np.loadtxt(folder / "exciting_traj_positions.txt").reshape(-1, 7)
    dq = np.loadtxt(folder / "exciting_traj_velocity.txt").reshape(-1, 7)
    tau = np.loadtxt(folder / "exciting_traj_torques.txt").reshape(-1, 7)
    split_time = float(t[int(round(0.6 * t.size))])  # first raw sample of the validation part
    return RobotLog.from_arrays(t, q, dq, tau, source="panda_gaz2019"), split_time


def main(argv: list[str] | None = None) -> dict[str, object]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--out", type=Path, default=Path("results/panda"))
    args = ap.parse_args(argv)
    robot = load_robot("panda")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        log, split_time = load_gaz_log(args.data)
    for w in caught:
        print(f"repair: {w.message}")
    # filter + differentiate the whole record (inputs only), identify on the first 60 %, validate on the rest
    states = preprocess_log(log)
    ident = states.select(states.t < split_time)
    validation = log.select(log.t >= split_time)  # raw (repaired) samples, unfiltered torque as reference
    result = identify_dynamics(robot, ident, method="combined", offset=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the least-squares model is checked explicitly here
        margin = mass_matrix_margin(result.to_robot_model(robot))
    # the least-squares estimate need not be physically consistent; project it (in the fit's metric)
    consistent = project_physically_consistent(result, robot)
    val = validate_model(result, robot, validation, states=states, label="least squares")
    val_c = validate_model(consistent, robot, validation, states=states, label="physically consistent")
    print(
        f"\n{robot.name}: {result.base.n_base} base parameters + {3 * robot.n} friction parameters "
        f"(Coulomb, viscous, offset), condition number {result.condition_number:.3g}"
    )
    print(f"{'joint':>6} {'RMSE [Nm]':>10} {'RMSE/std':>9} {'consistent':>11} {'std(tau) [Nm]':>14}")
    for j, (row, row_c) in enumerate(zip(val.table(), val_c.table(), strict=True)):
        print(f"{j + 1:>6} {row['rmse']:>10.3f} {row['nrmse']:>9.3f} {row_c['rmse']:>11.3f} {row['torque_std']:>14.3f}")
    print(
        f"pooled validation RMSE over 7 joints ({val.t.size:,} samples): {val.pooled_rmse:.4f} Nm least squares "
        f"(M(q) eigenvalue margin {margin:.3g}), {val_c.pooled_rmse:.4f} Nm physically consistent"
    )
    args.out.mkdir(parents=True, exist_ok=True)
    save_identified_model(consistent, robot, args.out / "model_panda.json", extra={"pooled_rmse": val_c.pooled_rmse})
    plot_torque_validation(
        {"least squares": val, "physically consistent": val_c},
        args.out / "fig6_panda.png",
        joint_names=robot.joint_names,
        window=(split_time, split_time + 3.0),
    )
    save_log(log, args.out / "panda_gaz2019.parquet")  # the repaired log in the documented schema, for the CLI
    print(f"wrote {args.out}/ (model_panda.json, fig6_panda.png, panda_gaz2019.parquet)")
    return {
        "rmse": val.rmse,
        "nrmse": val.nrmse,
        "pooled_rmse": val.pooled_rmse,
        "pooled_rmse_consistent": val_c.pooled_rmse,
        "result": result,
    }


if __name__ == "__main__":
    main()
