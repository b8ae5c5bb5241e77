"""Why the retract is caught again by the paper's pushed stick: how far the contact point gets ahead of the stick.

In the link collision of ``reflexarm reaction-study`` (``--scenarios link``) the stick keeps coming at 50 mm/s
until 1.5 s after it appeared. For each study arm this runs that scene with the ``retract`` reaction (the study's
conditions: +-10 % model error, the paper's sensor noise, seed 0) and prints, from the plant's truth:

* how long (and how far) the stick still comes after detection;
* the largest lead the true contact point (fixed on the link at detection) gains over the stick's tip along the
  stick's motion in the 0.45 s after detection (the retract's time);
* the retract's planned distance (its farthest-moving point) and when the stick touches the arm again.

A lead smaller than the stick's remaining travel means the stick catches the arm again.

Run:  python examples/pushed_stick_lead.py [--arms atlas_v5_left_arm panda ...]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
import pinocchio as pin

from reflexarm.experiments.collision import LINK_SETTING, run_link_collision
from reflexarm.experiments.collision_events import collision_outcome
from reflexarm.experiments.reaction_study import STUDY_ARMS, study_arm
from reflexarm.sim import PAPER_NOISE


def lead(name: str) -> str:
    arm = study_arm(name)
    setting = replace(LINK_SETTING, reaction="retract")
    trace = run_link_collision(setting=setting, robot=arm.robot, plant_friction=arm.plant_friction, stick="pushed",
                               noise=PAPER_NOISE, seed=0)  # fmt: skip
    out = collision_outcome(trace, arm.robot, name=name)
    if out.detected_s is None or out.contact_point is None:
        return f"{name:20s} no detection"
    model = arm.robot.pin_model
    data = model.createData()
    joint = model.frames[model.getFrameId(out.contact_link)].parentJoint
    i_d = int(np.searchsorted(trace.t, out.detected_s - 1e-9))
    pin.forwardKinematics(model, data, trace.q[i_d])
    local = data.oMi[joint].actInv(np.asarray(out.contact_point))  # the contact point, fixed on its link
    tip = trace.extras["elbow_stick_tip"]
    velocity = np.gradient(tip, trace.t, axis=0)[i_d]
    u = velocity / np.linalg.norm(velocity)  # the stick's motion at detection
    scene = trace.meta["scene"][0]
    coming = scene["t_start"] + scene["duration"] - out.detected_s
    window = range(i_d, min(len(trace.t), i_d + int(round(0.45 / (trace.t[1] - trace.t[0])))))
    gaps = []
    for i in window:
        pin.forwardKinematics(model, data, trace.q[i])
        gaps.append(float((data.oMi[joint].act(local) - tip[i]) @ u))
    event = trace.meta["collision_event"]
    again = "no" if out.recontact_s is None else f"{out.recontact_s - out.detected_s:.2f} s after detection"
    return (f"{name:20s} stick comes {coming:.2f} s = {100 * scene['speed'] * coming:.1f} cm more; contact point's "
            f"lead {100 * (max(gaps) - gaps[0]):.1f} cm; retract planned {100 * event['retract_planned']:.1f} cm; "
            f"touched again: {again}")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arms", nargs="+", default=list(STUDY_ARMS), choices=STUDY_ARMS)
    for name in parser.parse_args().arms:
        print(lead(name), flush=True)


if __name__ == "__main__":
    main()
