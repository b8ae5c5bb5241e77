"""The plain-text report of a threshold study (:meth:`reflexarm.tuning.ThresholdProposal.report`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from reflexarm.tuning.replay import RECORDED_RESIDUAL

if TYPE_CHECKING:
    from reflexarm.tuning.pairs import DetectionPairs
    from reflexarm.tuning.study import ThresholdProposal

__all__ = ["format_pairs", "format_report", "joint_label"]


def joint_label(joint: int, name: str) -> str:
    """A joint as printed: 1-based number and full name, ``joint_label(0, "shoulder_pan_joint")`` ->
    ``"1 (shoulder_pan_joint)"`` (``joint`` is the 0-based index)."""
    return f"{joint + 1} ({name})" if name else str(joint + 1)


def format_report(proposal: ThresholdProposal) -> str:
    """The method, then one line per joint (1-based) with both levels, their intervals and delays."""

    def sec(v: object) -> str:
        return "never" if v is None else f"{v:.3f}"

    st, n = proposal.settings, len(proposal.joints)
    kf = st.detection_filter_gain
    stage = "" if kf is None else f", second stage K_f = {kf:g} 1/s on the residual"
    through = "" if kf is None else f" (then the root of the cascade's step response, T_f = {1.0 / kf:.4f} s)"
    if any(s.endswith(RECORDED_RESIDUAL) for s in proposal.sources):
        observer = (
            "residual recorded online by each run's controller, with the model and observer that run used "
            "(--model, --model-error and the observer options are not applied; "
            f"delays with k_o = {st.detection_gain:g} 1/s)"
        )
    else:
        observer = (
            f"observer k_o = {st.detection_gain:g} 1/s ({st.observer_discretization} form), kappa_f = {st.kappa_f}, "
            f"EFC = {st.kappa_ext}{stage}"
        )
    head = (
        f"{len(proposal.sources)} log(s), {proposal.duration_s / 60:.1f} min; "
        f"{observer}; {proposal.fault_ticks} rejected samples\n"
        f"collision level: {proposal.rate_per_hour:g} false alarms/h for the arm "
        f"({proposal.rate_per_hour / n:.3g}/h per joint); contact level: {proposal.contact_rate_per_hour:g}/h\n"
        f"tail: {proposal.method} fit of the declustered |residual| above u (90 % bootstrap interval in brackets); "
        f"delay of a {proposal.step_torque:g} Nm step: t_d = -T_o ln(1 - (zeta - b)/s), "
        f"T_o = {proposal.time_constant:.4f} s{through}, b = 0 / b = -q95 (unfavourable)\n"
    )
    labels = [joint_label(jt.joint, jt.name) for jt in proposal.joints]
    w = max([len("joint"), *(len(x) for x in labels)])
    lines = [
        f"{'joint':>{w}} {'max|r|':>7} {'collision [Nm]':>25} {'contact [Nm]':>25} "
        f"{'delay coll. [s]':>15} {'delay cont. [s]':>15}"
    ]
    for jt, label in zip(proposal.joints, labels, strict=True):
        d = jt.delays
        lines.append(
            f"{label:>{w}} {jt.fit.x_max:7.3f} "
            f"{jt.collision:8.3f} [{jt.collision_interval[0]:6.3f}, {jt.collision_interval[1]:6.3f}] "
            f"{jt.contact:8.3f} [{jt.contact_interval[0]:6.3f}, {jt.contact_interval[1]:6.3f}] "
            f"{sec(d['collision_delay_s']):>7}/{sec(d['collision_delay_unfavourable_s']):>7} "
            f"{sec(d['contact_delay_s']):>7}/{sec(d['contact_delay_unfavourable_s']):>7}"
        )
    for level, rows in proposal.force_steps.items():
        cells = ", ".join(
            f"{r['direction']} {sec(r['delay_s'])} s (joint {r['first_joint']})"
            if r["first_joint"] is not None
            else f"{r['direction']} never"
            for r in rows
        )
        lines.append(f"{proposal.step_force:g} N at the end effector, {level} level: {cells}")
    if proposal.coverage is not None:
        lines.append("coverage of the logs (range: share of the joint limits; speed: of the velocity limit):")
        lines += [c.line() for c in proposal.coverage]
    tail = "".join(f"\nnote: {x}" for x in proposal.notes)
    return head + "\n".join(lines) + tail


def format_pairs(pairs: DetectionPairs) -> str:
    """One line per detection gain: its levels, the detector's lags [ms] and the held-out false alarms."""

    def ms(v: object) -> str:
        return "  -" if v is None else f"{1e3 * float(v):5.1f}"  # type: ignore[arg-type]

    band, kf = pairs.detection_friction_band, pairs.detection_filter_gain
    own = "" if band is None else f", its friction model in a {band:g} rad/s band"
    own += "" if kf is None else f", then a second stage K_f = {kf:g} 1/s (T = 1/k_o + 1/K_f)"
    head = (
        f"(k_o, zeta) pairs (exact observer{own}): levels at {pairs.rate_per_hour:g} false alarms/h; lag from the true "
        f"torque exceeding zeta_j to detection, ramp {pairs.ramp_slope:g} Nm/s and step {pairs.step_size:g} x "
        "zeta (analytic; measured on held-out logs: median/max)\n"
    )
    lines = [
        f"{'k_o [1/s]':>9} {'T [ms]':>6} {'zeta [Nm] min..max':>19} {'ramp':>5} {'step':>5} "
        f"{'ramp meas.':>11} {'step meas.':>11} {'held-out alarms':>22}"
    ]
    for p in pairs.pairs:
        d = p.as_dict()
        h = d["heldout"]
        held = "-" if h is None else f"{h['alarms']} in {h['duration_s'] / 3600:.2f} h"
        lines.append(
            f"{p.gain:9g} {1e3 * (1.0 / p.gain + (0.0 if kf is None else 1.0 / kf)):6.1f} "
            f"{min(d['collision_Nm']):8.2f}..{max(d['collision_Nm']):8.2f} "
            f"{ms(d['ramp_lag_max_s'])} {ms(d['step_lag_s'])} "
            f"{ms(d['measured_ramp_lag_median_s'])}/{ms(d['measured_ramp_lag_max_s'])} "
            f"{ms(d['measured_step_lag_median_s'])}/{ms(d['measured_step_lag_max_s'])} {held:>22}"
        )
    return head + "\n".join(lines)
