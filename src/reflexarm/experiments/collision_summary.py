"""Summaries of the collision experiments' traces (contact, detection, forces) and the paper's numbers
beside them (Sec. III-A/B)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from reflexarm.errors import DataError
from reflexarm.sim import Trace

__all__ = [
    "CONTACT_FORCE_N",
    "CONTACT_TORQUE_NM",
    "PAPER",
    "QUASI_STATIC_WINDOW_S",
    "compare_with_paper",
    "run_name",
    "summarize_ee_collision",
    "summarize_link_collision",
    "write_outputs",
]

#: What the paper reports for the two collision experiments (Sec. III-A/B), for side-by-side tables.
#: Coll.Det: detected at t = 1.1 s on the paper's time axis, when the peak contact force of ~69 N "is
#: already reached"; link collision: contact at ~5.5 s, detection at ~5.6 s; Stiff tips the block.
PAPER: dict[str, object] = {
    "threshold_Nm": 11.0,
    "observer_gain_per_s": 5.0,
    "colldet_detection_s": 1.1,
    "colldet_peak_force_N": 69.0,
    "stiff_tipped": True,
    "link_contact_s": 5.5,
    "link_detection_s": 5.6,
    "link_delay_s": 0.1,
}


#: Window of the moving average that defines the quasi-static contact force [s]: long against the
#: impact transient (tens of ms), short against the seconds the arm pushes.
QUASI_STATIC_WINDOW_S = 0.5

#: Contact is counted when the environment pushes the tool with more than this [N] (above the wrist
#: sensor's noise band of +-2.3 N, and well below the tens of newtons of a collision).
CONTACT_FORCE_N = 5.0


#: A contact anywhere on the arm is counted when the true external torque of a joint exceeds this [Nm]
#: (the link collision's contact start; well below the 11 Nm threshold).
CONTACT_TORQUE_NM = 1.0


def _first_index(mask: np.ndarray) -> int | None:
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


def run_name(trace: Trace, default: str = "run") -> str:
    """The run's name: its setting's (``meta["setting"]["name"]``), else ``meta["name"]``, else ``default``.

    A trace recorded outside the experiment functions (a user's own run) has no setting in its meta.
    """
    setting = trace.meta.get("setting")
    if isinstance(setting, dict) and setting.get("name") is not None:
        return str(setting["name"])
    name = trace.meta.get("name")
    return default if name is None else str(name)


def summarize_ee_collision(trace: Trace) -> dict[str, object]:
    """Peak contact force, first contact, detection time and delay, block displacement, tipped.

    Works on any :class:`Trace` (e.g. a user's own run): what the experiment's metadata would add is
    None when absent (block displacement and tipping, the run's name falls back to :func:`run_name`);
    ``final_swing_error_rad`` is |q_d - q| at the end on the swing joint (``meta["swing_joint"]``,
    1-based, default 1; ``final_q1_error_rad`` on joint 1). The forces are those on the bodies beyond
    the wrist sensor (``Trace.f_ext_ee``); ``first_contact_any_s`` and ``peak_external_torque_Nm`` count a
    contact anywhere on the arm (true external joint torque above :data:`CONTACT_TORQUE_NM`), e.g. on an
    arm whose hand has no collision geometry.
    """
    if trace.t.size < 2:
        raise DataError(f"summarize_ee_collision needs a trace of at least 2 samples; got {trace.t.size}")
    f = np.linalg.norm(trace.f_ext_ee, axis=1)
    w = max(1, int(round(QUASI_STATIC_WINDOW_S / float(np.median(np.diff(trace.t))))))
    f_quasi_static = np.convolve(f, np.ones(w) / w, mode="valid")
    i_contact = _first_index(f > CONTACT_FORCE_N)
    i_det = _first_index(trace.collision)
    t_contact = None if i_contact is None else float(trace.t[i_contact])
    t_det = None if i_det is None else float(trace.t[i_det])
    i_peak = int(np.argmax(f))
    tau_ext = np.abs(trace.tau_ext).max(axis=1)
    i_any = _first_index(tau_ext > CONTACT_TORQUE_NM)
    tail = trace.t >= trace.t[-1] - 1.0
    disp = trace.meta.get("block_displacement")
    swing = int(trace.meta.get("swing_joint", 1))
    if not 1 <= swing <= trace.q.shape[1]:
        raise DataError(f"meta swing_joint must be a joint number in 1..{trace.q.shape[1]}; got {swing}")
    return {
        "run": run_name(trace),
        "peak_force_N": float(f[i_peak]),
        "peak_force_s": float(trace.t[i_peak]),
        "force_at_detection_N": None if i_det is None else float(f[i_det]),
        "quasi_static_force_N": float(f_quasi_static.max()),
        "final_force_N": float(f[tail].mean()),
        "first_contact_s": t_contact,
        "first_contact_any_s": None if i_any is None else float(trace.t[i_any]),
        "peak_external_torque_Nm": float(tau_ext.max()),
        "detection_s": t_det,
        "detection_delay_s": None if (t_det is None or t_contact is None) else t_det - t_contact,
        "detected_joints": list(np.flatnonzero(trace.collided[i_det]).tolist()) if i_det is not None else [],
        "block_displacement_m": None if disp is None else float(np.linalg.norm(np.asarray(disp, dtype=float)[:2])),
        "block_tipped": None if "tipped" not in trace.meta else bool(trace.meta["tipped"]),
        "final_q1_error_rad": float(abs(trace.q_d[-1, 0] - trace.q[-1, 0])),
        "swing_joint": swing,
        "final_swing_error_rad": float(abs(trace.q_d[-1, swing - 1] - trace.q[-1, swing - 1])),
    }


def compare_with_paper(
    ee_rows: Sequence[dict[str, object]], link_row: dict[str, object] | None = None
) -> list[dict[str, object]]:
    """Rows (quantity, paper, ours) of what Sec. III-A/B reports next to the same quantity measured here.

    ``ee_rows`` are :func:`summarize_ee_collision` rows of the three runs (by their ``run`` names);
    ``link_row`` a :func:`summarize_link_collision` row.
    """
    by = {str(r["run"]): r for r in ee_rows}
    out: list[dict[str, object]] = []

    def add(quantity: str, paper: str, ours: str) -> None:
        out.append({"quantity": quantity, "paper": paper, "ours": ours})

    def num(v: object, fmt: str) -> str:
        return "-" if v is None else fmt.format(v)

    det = by.get("Coll.Det")
    if det is not None:
        add("Coll.Det peak |f| [N]", f"~{PAPER['colldet_peak_force_N']:g}", num(det["peak_force_N"], "{:.1f}"))
        t_det, t_peak = det["detection_s"], det["peak_force_s"]
        add(
            "Coll.Det detected",
            f"t = {PAPER['colldet_detection_s']:g} s",
            "no" if t_det is None else f"t = {t_det:.3f} s, {num(det['detection_delay_s'], '{:.3f}')} s after contact",
        )
        # the paper: "at this point in time [the detection], the maximum contact force ... is already reached"
        if t_det is None:
            at_det = "-"
        elif det.get("first_contact_s", 0.0) is None:  # nothing beyond the sensor touched: no peak to time
            at_det = f"{det['force_at_detection_N']:.1f} (no contact beyond the wrist sensor)"
        else:
            at_det = (
                f"{det['force_at_detection_N']:.1f} (peak {det['peak_force_N']:.1f} N "
                f"{1000.0 * (float(t_peak) - float(t_det)):+.0f} ms)"  # type: ignore[arg-type]
            )
        add("Coll.Det |f| at detection [N]", f"~{PAPER['colldet_peak_force_N']:g} (the peak)", at_det)
    stiff = by.get("Stiff")
    if stiff is not None:
        add("Stiff tips the block", "yes", "yes" if stiff["block_tipped"] else "no")
    comp = by.get("Compliant")
    if comp is not None and stiff is not None:
        lower = float(comp["quasi_static_force_N"]) < float(stiff["quasi_static_force_N"])  # type: ignore[arg-type]
        add("Compliant: lower quasi-static force than Stiff", "yes", "yes" if lower else "no")
    if link_row is not None:
        add(
            "link collision: detection delay [s]",
            f"~{PAPER['link_delay_s']:g} ({PAPER['link_contact_s']:g} -> {PAPER['link_detection_s']:g} s)",
            num(link_row["detection_delay_s"], "{:.3f}"),
        )
    return out


def summarize_link_collision(trace: Trace) -> dict[str, object]:
    """Contact start on the elbow, detection time, delay and the joints that crossed first.

    Works on any :class:`Trace` (no experiment metadata needed)."""
    tau_ext = np.abs(trace.tau_ext).max(axis=1)
    i_contact = _first_index(tau_ext > CONTACT_TORQUE_NM)
    i_det = _first_index(trace.collision)
    t_contact = None if i_contact is None else float(trace.t[i_contact])
    t_det = None if i_det is None else float(trace.t[i_det])
    return {
        "run": "link collision",
        "contact_start_s": t_contact,
        "detection_s": t_det,
        "detection_delay_s": None if (t_det is None or t_contact is None) else t_det - t_contact,
        "detected_joints": list(np.flatnonzero(trace.collided[i_det]).tolist()) if i_det is not None else [],
        "peak_external_torque_Nm": float(tau_ext.max()),
    }


def write_outputs(out: Path, name: str, traces: Sequence[Trace], rows: Sequence[dict[str, object]]) -> None:
    """Save each trace (npz) and the summary table (JSON) into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    for i, tr in enumerate(traces):
        tr.save(out / f"{name}_{run_name(tr, f'run{i + 1}').replace('.', '').replace(' ', '_').lower()}.npz")
    (out / f"{name}_summary.json").write_text(json.dumps(list(rows), indent=2))
