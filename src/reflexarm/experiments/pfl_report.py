"""The outputs of ``reflexarm pfl``: the runs (CSV/JSON), the side-by-side table of permissible speeds, a figure
per region (peak force vs speed with both limits and the analytic line) and a one-page HTML report."""

from __future__ import annotations

import csv
import html
import json
import math
from pathlib import Path
from typing import Any

from reflexarm.experiments.pfl import QS_WINDOW_S
from reflexarm.experiments.pfl_study import PflStudy, safe_speeds

__all__ = ["speed_table", "write_pfl_outputs"]


def _ok(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [r for r in rows if r.get("error") is None and r.get("peak_force_N") is not None]


def speed_table(study: PflStudy) -> list[dict[str, Any]]:
    """One row per (arm, region, contact point): the permissible speed from the standard's mass and from the
    posture-dependent mass (at the contact posture), and the simulated safe speed with detection off and with
    each reaction [m/s] (``_extrapolated``: beyond the simulated speeds, where the motion cannot go faster within
    its joint velocity limits); on a motion, its peak force at its own timing [N]; beside them, clamped: the
    largest force after ``QS_WINDOW_S`` past detection per reaction [N]."""
    out = []
    reactions = study.conditions.get("reactions", [])
    keys = dict.fromkeys((r["arm"], r["region"], r.get("contact_point", "ee")) for r in study.rows)
    for arm, region, point in keys:
        at = dict(arm=arm, region=region, contact_point=point)
        off = _ok(study.select(**at, mode="transient", detection=False))
        row: dict[str, Any] = {**at, "motion": study.conditions.get("motion", "swing")}
        first = off[0] if off else None
        row["F_T_N"] = first["F_T_N"] if first else None
        row["F_QS_N"] = first["F_QS_N"] if first else None
        row["standard_mass_kg"] = first["standard_mass_kg"] if first else None
        row["effective_mass_kg"] = first["effective_mass_kg"] if first else None
        row["v_standard_m_s"] = first["standard_permissible_speed_m_s"] if first else None
        row["v_posture_m_s"] = first["permissible_speed_m_s"] if first else None
        own = [r for r in off if "requested_speed_m_s" in r and r["requested_speed_m_s"] is None]
        if "requested_speed_m_s" in (first or {}):
            row["own_timing_speed_m_s"] = own[0]["approach_speed_m_s"] if own else None
            row["own_timing_peak_N"] = own[0]["peak_force_N"] if own else None
        sim_off = safe_speeds(off)
        row["v_sim_detection_off_m_s"] = sim_off["simulated_safe_speed_m_s"]
        row["v_sim_extrapolated"] = sim_off["extrapolated"]
        ratios = [r["peak_force_N"] / r["analytic_force_N"] for r in off if r.get("analytic_force_N")]
        row["sim_over_analytic_max"] = max(ratios) if ratios else None
        for reaction in reactions:
            rr = safe_speeds(study.select(**at, mode="transient", detection=True, reaction=reaction))
            row[f"v_sim_{reaction}_m_s"] = rr["simulated_safe_speed_m_s"]
            row[f"v_sim_{reaction}_extrapolated"] = rr["extrapolated"]
        delays = [r["detection_delay_s"] for r in _ok(study.select(**at, mode="transient"))]
        delays = [d for d in delays if d is not None and d >= 0.0]
        row["transient_detection_delay_s"] = max(delays) if delays else None
        if study.conditions.get("motion", "swing") == "swing":
            _clamped_columns(study, at, reactions, row)
        false_alarms = [r for r in study.select(**at) if r.get("detected_before_contact")]
        row["false_alarms"] = len(false_alarms)
        errors = sorted({r["error"] for r in study.select(**at) if r.get("error")})
        row["errors"] = "; ".join(errors)
        out.append(row)
    return out


def _clamped_columns(study: PflStudy, at: dict[str, Any], reactions: list[str], row: dict[str, Any]) -> None:
    for reaction in reactions:
        c = _ok(study.select(**at, mode="clamped", reaction=reaction))
        row[f"clamped_{reaction}_max_N"] = c[0]["max_force_N"] if c else None
        row[f"clamped_{reaction}_after_{QS_WINDOW_S:g}s_N"] = c[0]["max_force_after_window_N"] if c else None
        row[f"clamped_{reaction}_below_F_QS_after_s"] = c[0]["below_qs_after_detection_s"] if c else None


def _write_csv(rows: list[dict[str, Any]], path: Path) -> Path:
    keys: list[str] = list(dict.fromkeys(k for r in rows for k in r))
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in keys})
    return path


def _region_figure(study: PflStudy, region: str, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = _ok(study.select(region=region, mode="transient"))
    fig, ax = plt.subplots(figsize=(7.0, 4.5))
    keys = list(dict.fromkeys((r["arm"], r.get("contact_point", "ee")) for r in rows))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, key in enumerate(keys):
        c = colors[i % len(colors)]
        arm = key[0] if key[1] == "ee" else f"{key[0]} {key[1]}"
        mine = [r for r in rows if (r["arm"], r.get("contact_point", "ee")) == key]
        off = sorted((r for r in mine if not r["detection"]), key=lambda r: r["approach_speed_m_s"])
        v = [r["approach_speed_m_s"] for r in off]
        ax.plot(v, [r["peak_force_N"] for r in off], "o", color=c, label=f"{arm}: simulated, detection off")
        if off:  # the analytic lines are straight through 0: drawn up to past the limit F_T
            slope = off[0]["analytic_force_N"] / off[0]["approach_speed_m_s"]
            slope_std = off[0]["analytic_standard_force_N"] / off[0]["approach_speed_m_s"]
            top = max(1.1 * off[0]["F_T_N"] / slope, max(v))
            ax.plot([0.0, top], [0.0, slope * top], "-", color=c, label=f"{arm}: v sqrt(mu k), m_R(q, u)")
            ax.plot([0.0, top], [0.0, slope_std * top], ":", color=c, label=f"{arm}: m_R = M/2")
        det = [r for r in mine if r["detection"]]
        ax.plot([r["approach_speed_m_s"] for r in det], [r["peak_force_N"] for r in det], "x", color=c, alpha=0.6)
    if rows:
        ax.axhline(rows[0]["F_T_N"], color="k", lw=1.5, label=f"F_T = {rows[0]['F_T_N']:g} N")
        ax.axhline(rows[0]["F_QS_N"], color="k", ls="--", lw=1.0, label=f"F_QS = {rows[0]['F_QS_N']:g} N")
    ax.set_xlim(left=0.0)
    ax.set_ylim(bottom=0.0)
    ax.set_xlabel("approach speed [m/s]")
    ax.set_ylabel("peak contact force [N]")
    ax.set_title(f"{region}: transient contact (x: with detection and each reaction)")
    ax.legend(fontsize=6, ncol=2)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _fmt(v: Any) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return f"{v:.3g}" if isinstance(v, float) else html.escape(str(v))


def _table_html(table: list[dict[str, Any]], keys: list[str]) -> str:
    head = "".join(f"<th>{html.escape(k)}</th>" for k in keys)
    body = "".join("<tr>" + "".join(f"<td>{_fmt(r.get(k))}</td>" for k in keys) + "</tr>" for r in table)
    return f"<table><tr>{head}</tr>{body}</table>"


def _html(study: PflStudy, table: list[dict[str, Any]], figures: list[Path]) -> str:
    keys = list(table[0]) if table else []
    ident = ["arm", "region", "contact_point", "motion"]
    transient = ident + [k for k in keys if k not in ident and not k.startswith("clamped_") and k != "errors"]
    clamped = ident + ["F_QS_N"] + [k for k in keys if k.startswith("clamped_")]
    errors = sorted({r["error"] for r in study.rows if r.get("error")})
    err = "".join(f"<li>{html.escape(e)}</li>" for e in errors) or "<li>none</li>"
    figs = "".join(f'<img src="{f.name}" width="48%">' for f in figures)
    cond = html.escape(json.dumps(study.conditions, default=str))
    clamped_html = (
        f"<h3>Clamped contact (wall behind the region): largest force [N], largest force from {QS_WINDOW_S:g} s "
        "after detection [N], time after detection until the force stays below F_QS [s]</h3>"
        + _table_html(table, clamped)
        if len(clamped) > len(ident) + 1
        else "<p>No clamped runs on a motion file (the clamping runs use the demo swing).</p>"
    )
    return f"""<!doctype html><html><head><meta charset="utf-8"><title>reflexarm pfl</title>
<style>body{{font-family:sans-serif;font-size:11px;margin:12px}}table{{border-collapse:collapse;margin-bottom:8px}}
td,th{{border:1px solid #bbb;padding:2px 4px;text-align:right}}</style></head><body>
<h2>Human contact limits (ISO/TS 15066 Annex A): permissible speeds and simulated contacts</h2>
<p>Transient contact: two masses and the region's spring, F = v sqrt(mu k), v_max = F_T / sqrt(mu k),
mu = (1/m_H + 1/m_R)^-1; m_R = M/2 (standard, no payload) or m_R(q, u) = 1/(u^T J M^-1 J^T u) at the end effector
in its direction of travel at contact. Simulated: the demo swing of each arm into the region (MuJoCo plant, the
region's spring k and mass m_H; clamped: a wall behind the spring), the arm's own controller, detection and
reaction; or, on a motion (a trajectory file, an excitation), the region placed where the contact point
(ee, or link j: the point along the link with the largest speed) moves fastest, the motion at its own timing
and time-scaled (slower/faster, the same path) to each speed. Speeds [m/s], forces [N], masses [kg], times [s].
Skull and face: Table A.2 gives no transient limit;
F_QS stands in (this package's choice). "v_sim" is the speed at which the simulated peak reaches F_T
(proportional scaling of the runs; where it lies beyond them the motion is run at that speed too, and
"v_sim_extrapolated" marks where it could not be: a joint beyond its velocity limit); a reaction
can only lower it if detection comes before the peak.
"transient_detection_delay_s": the longest time from first contact to detection over the transient runs ("-":
not detected in the run); "sim_over_analytic_max": the largest simulated/analytic peak ratio, detection off.</p>
<h3>Transient contact: permissible speed [m/s]</h3>{_table_html(table, transient)}
{clamped_html}
<h3>Runs that could not be made</h3><ul>{err}</ul>
<h3>Per region: peak force vs speed</h3>{figs}
<p>Conditions: {cond}</p></body></html>"""


def write_pfl_outputs(study: PflStudy, folder: str | Path) -> dict[str, Path]:
    """Write ``pfl_runs.csv``, ``pfl_table.csv``, ``pfl.json``, ``pfl_<region>.png`` and ``pfl_report.html``."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    table = speed_table(study)
    paths = {
        "runs_csv": _write_csv(study.rows, out / "pfl_runs.csv"),
        "table_csv": _write_csv(table, out / "pfl_table.csv") if table else out / "pfl_table.csv",
        "json": out / "pfl.json",
    }
    paths["json"].write_text(
        json.dumps({"conditions": study.conditions, "table": table, "runs": study.rows}, indent=1, default=str)
    )
    figures = [
        _region_figure(study, reg, out / f"pfl_{reg}.png") for reg in dict.fromkeys(r["region"] for r in study.rows)
    ]
    for f in figures:
        paths[f.stem] = f
    paths["html"] = out / "pfl_report.html"
    paths["html"].write_text(_html(study, table, figures))
    return paths
