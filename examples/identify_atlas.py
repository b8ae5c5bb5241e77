"""The paper's two-step identification on the simulated Atlas arm, and the identified model in the loop.

1. Single-joint constant-velocity runs on the MuJoCo plant, executed by the impedance controller (Fig. 5),
   give Coulomb and viscous friction per joint (Fig. 4, Table I).
2. An optimized Fourier excitation run and a different validation run; the base parameters are
   identified by the combined method (beta_I: base + friction together) and the sequential one
   (beta_II: friction from step 1, friction-corrected torques (16)-(17)); Table I analogue of the
   validation MSE per joint.
3. The sequential model is written to a file, loaded into the controller and tracks a new trajectory
   on the plant, against the +-10 % perturbed nominal model the experiments started from.

``--scenario stribeck`` adds a Stribeck/stiction term to the plant that the model does not have (see
:class:`reflexarm.experiments.identification.StribeckFriction`). Takes 2-4 minutes.

Run:  python examples/identify_atlas.py [--scenario table1|stribeck] [--out results/atlas_identification]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from reflexarm.experiments.identification import (
    HYDRAULIC_JOINTS,
    compare_methods,
    compare_tracking,
    run_identification_study,
)
from reflexarm.ident import load_identified_model, optimize_excitation
from reflexarm.ident.export.model_file import save_identified_model
from reflexarm.ident.plots import plot_friction, plot_torque_validation
from reflexarm.robots import load_robot


def main(argv: list[str] | None = None) -> dict[str, object]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", choices=("table1", "stribeck"), default="table1")
    ap.add_argument("--out", type=Path, default=Path("results/atlas_identification"))
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    robot = load_robot("atlas_v5_left_arm")
    st = run_identification_study(robot, scenario=args.scenario, n_jobs=args.jobs)
    print(
        f"{st.results['sequential'].base.n_base} base parameters; excitation condition number "
        f"{st.excitation.condition_initial:.4g} -> {st.excitation.condition_optimized:.4g}"
    )
    print("\nsingle-joint friction (fit of the constant-velocity runs):")
    for row in st.friction.table(robot.joint_names):
        print(
            f"  {row['joint']:>16}: mu_C {row['mu_C']:6.3f} Nm (true {row['mu_C_true']:5.2f}), "
            f"d_v {row['d_v']:6.3f} Nms/rad (true {row['d_v_true']:4.2f})"
        )
    print(
        f"\nvalidation MSE [Nm^2] of the saved models, both identified from the same rows (|dq_j| >= "
        f"{st.min_speed:g} rad/s), over all validation samples | the moving ones:"
    )
    for r in st.table():
        print(
            f"  {r['joint']:>16}: combined {r['mse_combined']:8.3f} | {r['mse_moving_combined']:7.3f}   "
            f"sequential {r['mse_sequential']:8.3f} | {r['mse_moving_sequential']:7.3f}"
        )
    h = st.hydraulic_mse()
    print("  hydraulic joints, mean: " + ", ".join(f"{k} {v:.3f}" for k, v in h.items()))
    print("  sequential against combined: " + compare_methods(h["combined"], h["sequential"]))
    args.out.mkdir(parents=True, exist_ok=True)
    plot_friction(
        list(st.friction.fits),
        args.out / "fig4_friction.png",
        joint_names=robot.joint_names,
        truth=(st.friction.truth.coulomb, st.friction.truth.viscous),
    )
    t0 = st.validation_log.t[0]
    plot_torque_validation(
        st.validations,
        args.out / "fig6_torques.png",
        joint_names=robot.joint_names,
        joints=HYDRAULIC_JOINTS,
        window=(t0, t0 + st.validation_trajectory.period),
    )

    # closing the loop: the sequential model as the study hands it out (physically consistent), in the controller
    nominal = st.nominal
    seq = st.results["sequential"]
    identified = load_identified_model(save_identified_model(seq, robot, args.out / "model_sequential.json"), robot)
    other = optimize_excitation(robot, maxiter=0, seed=7).initial
    tracking = {}
    for kappa_f in (1, 0):
        cmp = compare_tracking(
            robot,
            {"perturbed nominal": nominal, "identified": identified},
            other,
            20.0,
            kappa_f=kappa_f,
            extra_joint_torque=st.plant_extra,
        )
        tracking[kappa_f] = {k: v for k, v in cmp.rms_error.items()}
        print(f"\ntracking RMS error [mrad], kappa_f = {kappa_f}:")
        for name, e in cmp.rms_error.items():
            print(
                f"  {name:>17}: "
                + " ".join(f"{1e3 * x:6.2f}" for x in e)
                + f"   all {1e3 * np.sqrt(np.mean(e**2)):6.2f}"
            )
    print(f"\nwrote {args.out}/ (fig4_friction.png, fig6_torques.png, model_sequential.json)")
    return {"study": st, "tracking": tracking}


if __name__ == "__main__":
    main()
