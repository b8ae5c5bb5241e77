"""Isolation and identification over seeded random contacts (issue 15): correct link, point and force errors.

Each contact: a random posture uniform within the joint limits, a random link with collision geometry
(uniform over those links), a random point on its surface (a uniform draw on the file's contact geoms,
:func:`~reflexarm.robots.collision_geometry.link_collision_geometry` with a seed and a 4 mm cell, so true
points are not the controller's 1 cm candidates), a force of 20-100 N (uniform) in a direction uniform
within the friction cone (``contact_friction``, default 0.5: a physical contact force lies in its friction
cone; ``inf`` gives any direction into the surface). The true external torque is ``J_c^T f``.

Variants:

- ``exact``: residual = J_c^T f, isolation at the true q, significance 1e-6 Nm per joint (perfect sensing).
- ``noisy`` (the paper's noise and model error): the controller's model is the true one perturbed by
  :func:`~reflexarm.robots.perturbation.perturb_model` (+-``model_error``, one of 8 seeded draws per
  contact); the residual is ``J_c^T f + g_true(q) - g_hat(q) + e`` with the residual's noise at one tick of
  the paper's observer in a static contact ``e = K_o M(q) e_dq + dg/dq(q) e_q + e_tau`` (K_o = 5 1/s;
  e_q, e_dq, e_tau uniform within +-3.4e-4 rad, +-5.5e-2 rad/s, +-7.3e-2 Nm per joint, the paper's sensor
  noise; the momentum p = M dq enters the residual through K_o unfiltered; tau_m noise is taken unfiltered,
  an upper bound); isolation runs at the measured q + e_q with the perturbed model. The significance level
  per joint is the largest |g_true - g_hat + e| over 2000 free-motion postures (other seeds): the level a
  detector tuned on free motion would use; the absolute fit tolerance is the 99th percentile of its norm
  weighted by the isolator's W = min(level) / level.

A contact is *sensed* if some joint's residual exceeds its significance; the correct-link rate is taken
among sensed contacts. Its *link is sensed* if the true torque on the contact link's own joint (the most
distal joint the contact moves) exceeds that joint's significance: otherwise that joint's residual is
indistinguishable from model error and noise, the residual carries no information on whether the contact is
on that link or on a more proximal one that explains the rest of the residual, and the isolator can only name
the range of links it examined (``ContactEstimate.candidate_links``: from the most distal significant joint's
link on). The summary gives the correct-link rate among link-sensed contacts beside the rate among all
sensed ones, and for the others how often the true link is among the candidates. Point and force errors are
taken on contacts isolated to the right link where the estimate says ``point_and_force``; force errors also
where it says ``force_only``.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from reflexarm.control.collision.contact import ContactEstimate, Determined
from reflexarm.control.collision.identify import compute_link_kinematics
from reflexarm.control.collision.isolate import ContactIsolator
from reflexarm.errors import ConfigError
from reflexarm.robots.collision_geometry import CollisionGeometry, link_collision_geometry
from reflexarm.robots.perturbation import perturb_model
from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "Contact",
    "IsolationStudy",
    "ResidualNoise",
    "contact_torque",
    "draw_contacts",
    "isolation_figure",
    "run_isolation_study",
    "write_isolation_study",
]

#: Significance level of the exact variant [Nm]: above round-off, below any real torque.
EXACT_SIGNIFICANCE = 1e-6
#: Cell size of the true contact points [m] (a random draw per cell).
TRUTH_SPACING = 0.004
#: Model-error draws per study (contact c uses draw c mod this).
MODEL_DRAWS = 8
#: Free-motion postures used to set the noisy variant's significance level.
FREE_MOTION_POSTURES = 2000


@dataclass(frozen=True)
class ResidualNoise:
    """The residual's noise at one tick of the paper's observer in a static contact (see the module docstring)."""

    observer_gain: float = 5.0
    q: float = 3.4e-4
    dq: float = 5.5e-2
    tau_m: float = 7.3e-2


@dataclass(frozen=True)
class Contact:
    """One true contact: posture, link (0-based joint), point and inward-pushing force (world), J_c^T f."""

    q: np.ndarray
    link: int
    point: np.ndarray
    normal: np.ndarray
    force: np.ndarray
    torque: np.ndarray


def contact_torque(robot: RobotModel, q: np.ndarray, link: int, point: np.ndarray, force: np.ndarray) -> np.ndarray:
    """J_c^T f for a force on ``link`` at a world ``point`` [Nm]."""
    kin = compute_link_kinematics(robot, q)
    J = kin.jacobians[link]
    Jp = J[:3] + np.cross(J[3:].T, point - kin.origins[link]).T
    return np.asarray(Jp.T @ force)


def _limits(robot: RobotModel) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = robot.lower_limit, robot.upper_limit
    return np.where(np.isfinite(lo), lo, -np.pi), np.where(np.isfinite(hi), hi, np.pi)


def _cone_direction(normal: np.ndarray, friction: float, rng: np.random.Generator) -> np.ndarray:
    """A unit direction uniform over the cone of half-angle atan(friction) about -normal."""
    cos_max = 1.0 / math.sqrt(1.0 + friction**2) if math.isfinite(friction) else 0.0
    c = rng.uniform(cos_max, 1.0)  # uniform over the spherical cap
    phi = rng.uniform(0.0, 2.0 * np.pi)
    a = -normal
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(a, helper)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(a, t1)
    s = math.sqrt(max(0.0, 1.0 - c * c))
    return np.asarray(c * a + s * (math.cos(phi) * t1 + math.sin(phi) * t2))


def draw_contacts(
    robot: RobotModel,
    truth: CollisionGeometry,
    count: int,
    seed: int,
    *,
    force_range: tuple[float, float] = (20.0, 100.0),
    contact_friction: float = 0.5,
) -> list[Contact]:
    """``count`` seeded random contacts (see the module docstring)."""
    rng = np.random.default_rng(seed)
    lo, hi = _limits(robot)
    links = [s.joint for s in truth.links if s.has_geometry]
    if not links:
        raise ConfigError(f"robot {robot.name!r} has no link with collision geometry")
    out = []
    for _ in range(count):
        q = rng.uniform(lo, hi)
        link = int(links[rng.integers(len(links))])
        surface = truth.links[link]
        k = int(rng.integers(surface.size))
        kin = compute_link_kinematics(robot, q)
        R, o = kin.rotations[link], kin.origins[link]
        point, normal = R @ surface.points[k] + o, R @ surface.normals[k]
        force = rng.uniform(*force_range) * _cone_direction(normal, contact_friction, rng)
        out.append(Contact(q, link, point, normal, force, contact_torque(robot, q, link, point, force)))
    return out


def _gravity_jacobian(model: RobotModel, q: np.ndarray, h: float = 1e-6) -> np.ndarray:
    n = model.n
    out = np.empty((n, n))
    for c in range(n):
        e = np.zeros(n)
        e[c] = h
        out[:, c] = (model.compute_gravity(q + e) - model.compute_gravity(q - e)) / (2.0 * h)
    return out


def _disturbance(
    true: RobotModel, model: RobotModel, q: np.ndarray, noise: ResidualNoise, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """(g_true - g_hat + e, measured q) at one posture."""
    n = true.n
    e_q = rng.uniform(-noise.q, noise.q, n)
    e_dq = rng.uniform(-noise.dq, noise.dq, n)
    e_tau = rng.uniform(-noise.tau_m, noise.tau_m, n)
    e = noise.observer_gain * model.compute_mass_matrix(q) @ e_dq + _gravity_jacobian(model, q) @ e_q + e_tau
    return true.compute_gravity(q) - model.compute_gravity(q) + e, q + e_q


@dataclass
class IsolationStudy:
    """Per-contact rows and the per-arm/per-link summary of one variant."""

    robot: str
    variant: str
    settings: dict[str, Any]
    rows: list[dict[str, Any]] = field(default_factory=list)
    summary: dict[str, Any] = field(default_factory=dict)


def _stats(values: Sequence[float]) -> dict[str, float | int | None]:
    a = np.asarray(values, dtype=float)
    if a.size == 0:
        return {"count": 0, "median": None, "p90": None}
    return {"count": int(a.size), "median": float(np.median(a)), "p90": float(np.percentile(a, 90))}


def _summarise(rows: list[dict[str, Any]], n: int, names: list[str]) -> dict[str, Any]:
    def block(sub: list[dict[str, Any]]) -> dict[str, Any]:
        sensed = [r for r in sub if r["sensed"]]
        correct = [r for r in sensed if r["correct"]]
        pf = [r for r in correct if r["determined"] == Determined.POINT_AND_FORCE.value]
        ff = [r for r in correct if r["determined"] in (Determined.POINT_AND_FORCE.value, Determined.FORCE_ONLY.value)]
        wrong = [r for r in sensed if not r["correct"]]
        link_sensed = [r for r in sensed if not r["own_joint_insignificant"]]
        hidden = [r for r in sensed if r["own_joint_insignificant"]]
        return {
            "contacts": len(sub),
            "sensed": len(sensed),
            "not_sensed": len(sub) - len(sensed),
            "correct_link_rate": len(correct) / len(sensed) if sensed else None,
            "link_sensed": len(link_sensed),
            "correct_link_rate_link_sensed": (
                sum(1 for r in link_sensed if r["correct"]) / len(link_sensed) if link_sensed else None
            ),
            "link_not_sensed": len(hidden),
            "link_not_sensed_true_in_candidates": sum(1 for r in hidden if r["true_link_in_candidates"]),
            "wrong_link": len(wrong),
            "wrong_more_proximal_explained": sum(
                1 for r in wrong if int(r["estimated_link"]) < int(r["link"]) and r["explained"]
            ),
            "wrong_axis_crossing": sum(1 for r in wrong if r["own_joint_insignificant"]),
            "determined": {d.value: sum(1 for r in correct if r["determined"] == d.value) for d in Determined},
            "point_error_m": _stats([float(r["point_error"]) for r in pf]),
            "force_error_pct": _stats([float(r["force_error_pct"]) for r in ff]),
            "direction_error_deg": _stats([float(r["direction_error_deg"]) for r in ff]),
        }

    out = block(rows)
    out["per_link"] = {f"{i}:{names[i]}": block([r for r in rows if r["link"] == i]) for i in range(n)}
    return out


def _significance(
    robot: RobotModel, models: list[RobotModel], noise: ResidualNoise, seed: int
) -> tuple[np.ndarray, float]:
    rng = np.random.default_rng([seed, 1])
    lo, hi = _limits(robot)
    samples = np.array(
        [
            _disturbance(robot, models[k % len(models)], rng.uniform(lo, hi), noise, rng)[0]
            for k in range(FREE_MOTION_POSTURES)
        ]
    )
    level = np.abs(samples).max(axis=0)
    weighted = samples * (level.min() / level)
    return level, float(np.percentile(np.linalg.norm(weighted, axis=1), 99))


def run_isolation_study(
    robot: RobotModel,
    *,
    contacts: int = 1000,
    seed: int = 0,
    noise: bool = False,
    model_error: float = 0.0,
    spacing: float = 0.01,
    contact_friction: float = 0.5,
    geometry: CollisionGeometry | None = None,
) -> IsolationStudy:
    """Isolate and identify ``contacts`` seeded random contacts on ``robot`` (see the module docstring).

    Args:
        robot: the true arm.
        contacts: number of contacts, > 0.
        seed: seed of the contacts (and of the noise and model errors).
        noise: add the residual noise of the paper's sensors.
        model_error: level of the model errors (0.1 = +-10 %), >= 0.
        spacing: the controller's candidate point spacing [m].
        contact_friction: friction coefficient of the true contact forces' cone (``inf``: any inward direction).
        geometry: the controller's collision geometry (default: sampled at ``spacing``).
    """
    if isinstance(contacts, bool) or not isinstance(contacts, int) or contacts <= 0:
        raise ConfigError(f"contacts must be a positive integer; got {contacts!r}")
    if not (math.isfinite(model_error) and 0.0 <= model_error < 1.0):
        raise ConfigError(f"model_error must be in [0, 1) (0.1 = +-10 %); got {model_error!r}")
    exact = not noise and model_error == 0.0
    truth = link_collision_geometry(robot, spacing=TRUTH_SPACING, seed=seed)
    geometry = geometry if geometry is not None else link_collision_geometry(robot, spacing=spacing)
    drawn = draw_contacts(robot, truth, contacts, seed, contact_friction=contact_friction)
    residual_noise = ResidualNoise() if noise else ResidualNoise(observer_gain=0.0, q=0.0, dq=0.0, tau_m=0.0)
    models = (
        [perturb_model(robot, model_error, seed=1000 * seed + k) for k in range(MODEL_DRAWS)]
        if model_error
        else [robot]
    )
    if exact:
        significance, fit_tolerance = np.full(robot.n, EXACT_SIGNIFICANCE), 0.0
    else:
        significance, fit_tolerance = _significance(robot, models, residual_noise, seed)
    isolators = [
        ContactIsolator(m, significance=significance, geometry=geometry, fit_tolerance=fit_tolerance) for m in models
    ]
    rng = np.random.default_rng([seed, 2])
    names = [s.link_name for s in geometry.links]
    study = IsolationStudy(
        robot.name,
        "exact" if exact else "noisy",
        {
            "contacts": contacts,
            "seed": seed,
            "noise": asdict(residual_noise) if noise else None,
            "model_error": model_error,
            "spacing": spacing,
            "truth_spacing": TRUTH_SPACING,
            "contact_friction": contact_friction,
            "friction_coefficient": isolators[0].identifier.friction_coefficient,
            "significance": significance.tolist(),
            "fit_tolerance": fit_tolerance,
            "relative_tolerance": isolators[0].relative_tolerance,
            "candidate_points": geometry.point_counts().tolist(),
            "links_without_geometry": list(geometry.links_without_geometry()),
        },
    )
    for i, c in enumerate(drawn):
        k = i % len(models)
        if exact:
            r, q_meas = c.torque, c.q
        else:
            d, q_meas = _disturbance(robot, models[k], c.q, residual_noise, rng)
            r = c.torque + d
        est = isolators[k].isolate(q_meas, r)
        row = _row(i, c, est, names[c.link], significance)
        study.rows.append(row)
    study.summary = _summarise(study.rows, robot.n, names)
    return study


def _row(index: int, c: Contact, est: ContactEstimate, link_name: str, significance: np.ndarray) -> dict[str, Any]:
    """One contact's row: the truth beside the estimate and their errors."""
    f_true = float(np.linalg.norm(c.force))
    return {
        "index": index,
        "link": c.link,
        "link_name": link_name,
        "estimated_link": est.link,
        "sensed": est.determined != Determined.NONE,
        "correct": est.link == c.link,
        "determined": est.determined.value,
        "explained": "no single contact" not in est.reason,
        "own_joint_insignificant": bool(abs(c.torque[c.link]) <= significance[c.link]),
        "true_link_in_candidates": c.link in est.candidate_links,
        "force_true_N": f_true,
        "fit_error_Nm": est.fit_error,
        "point_error": float(np.linalg.norm(est.point - c.point)) if est.point is not None else float("nan"),
        "force_error_pct": float(100.0 * abs(np.linalg.norm(est.force) - f_true) / f_true)
        if est.force is not None
        else float("nan"),
        "direction_error_deg": _angle(est.force, c.force) if est.force is not None else float("nan"),
    }


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    c = float(a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), np.finfo(float).tiny))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def isolation_figure(studies: Sequence[IsolationStudy]) -> Any:
    """Correct-link rate per link and the contact-point error distribution, one colour per variant."""
    from reflexarm.experiments.plots import plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    width = 0.8 / max(1, len(studies))
    for v, s in enumerate(studies):
        per_link = s.summary["per_link"]
        labels = list(per_link)
        rates = [per_link[k]["correct_link_rate"] for k in labels]
        x = np.arange(len(labels)) + v * width
        ax1.bar(x, [np.nan if r is None else 100.0 * r for r in rates], width, label=s.variant)
        ax1.set_xticks(np.arange(len(labels)) + 0.4 - width / 2, [k.split(":")[1] for k in labels], rotation=45)
        errs = np.sort([float(r["point_error"]) for r in s.rows if np.isfinite(float(r["point_error"]))])
        if errs.size:
            ax2.plot(100.0 * errs, np.arange(1, errs.size + 1) / errs.size, label=s.variant)
    ax1.set_ylabel("correct link [%] (sensed contacts)")
    ax1.set_ylim(0, 105)
    ax1.axhline(99, color="k", lw=0.5, ls="--")
    ax1.legend()
    ax2.set_xlabel("contact point error [cm] (point_and_force, correct link)")
    ax2.set_ylabel("fraction")
    ax2.axvline(2.0, color="k", lw=0.5, ls="--")
    ax2.legend()
    fig.suptitle(f"isolation study: {studies[0].robot}" if studies else "isolation study")
    fig.tight_layout()
    return fig


def write_isolation_study(studies: Sequence[IsolationStudy], out: str | Path) -> list[Path]:
    """``isolation_<robot>.json`` (settings and summaries), ``.csv`` (one row per contact) and ``.png``."""
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    stem = f"isolation_{studies[0].robot}"
    json_path, csv_path, png_path = (folder / f"{stem}.{ext}" for ext in ("json", "csv", "png"))
    json_path.write_text(
        json.dumps(
            {s.variant: {"robot": s.robot, "settings": s.settings, "summary": s.summary} for s in studies},
            indent=2,
            default=float,
        )
    )
    with csv_path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=["variant", *studies[0].rows[0].keys()])
        writer.writeheader()
        for s in studies:
            for row in s.rows:
                writer.writerow({"variant": s.variant, **row})
    fig = isolation_figure(studies)
    fig.savefig(png_path, dpi=120)
    from reflexarm.experiments.plots import plt

    plt.close(fig)
    return [json_path, csv_path, png_path]
