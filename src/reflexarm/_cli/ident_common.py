"""Helpers shared by the identification commands (``excite``, ``identify``, ``validate``)."""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from reflexarm._cli.robot_options import DEFAULT_ROBOT, add_robot_options, load_robot_from_args
from reflexarm.errors import ConfigError


def robot_args(p: argparse.ArgumentParser) -> None:
    add_robot_options(p, default=DEFAULT_ROBOT)


def load_robot_arg(args: argparse.Namespace) -> Any:
    return load_robot_from_args(args)


def write_csv(path: Path, rows: list[dict[str, object]]) -> Path:
    if not rows:
        return path
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if v is None else v) for k, v in r.items()})
    return path


def to_json(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): to_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_json(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    return obj


def write_json(path: Path, obj: Any) -> Path:
    path.write_text(json.dumps(to_json(obj), indent=1))
    return path


def parse_floats(text: str | None, what: str) -> list[float] | None:
    if text is None:
        return None
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError as e:
        raise ConfigError(f"{what} must be comma-separated numbers; got {text!r}") from e


def parse_joints(text: str, n: int) -> list[int]:
    try:
        js = [int(x) - 1 for x in text.split(",") if x.strip()]
    except ValueError as e:
        raise ConfigError(f"--joints must be comma-separated 1-based joint numbers; got {text!r}") from e
    bad = [j + 1 for j in js if not 0 <= j < n]
    if bad:
        raise ConfigError(f"joint(s) {bad} out of range; the robot has joints 1..{n}")
    twice = sorted({j + 1 for j in js if js.count(j) > 1})
    if twice:
        raise ConfigError(f"joint(s) {twice} given more than once in {text!r}; give each joint once")
    return js


def say(args: argparse.Namespace, msg: str) -> None:
    if not args.quiet:
        print(msg, file=sys.stderr)


def friction_file(robot: Any, friction: Any, rows: list[dict[str, object]], why_missing: str) -> dict[str, object]:
    """The content of friction.json: d_v, mu_C (``null`` for joints not identified) and which joints were.

    ``why_missing`` says why the joints without a fit have none (e.g. "not run (--joints 1)").
    """
    from reflexarm.ident.friction.parameters import format_joints

    doc: dict[str, object] = {
        "robot": robot.name,
        "joint_names": robot.joint_names,
        **friction.to_dict(),
        "identified_joints": [j + 1 for j in friction.known],
        "fits": rows,
    }
    if friction.missing:
        doc["not_identified"] = {
            "joints": [j + 1 for j in friction.missing],
            "note": f"joint(s) {format_joints(friction.missing, robot.joint_names)} {why_missing}: their d_v, mu_C are "
            "null (not identified, not 0). 'identify dynamics --friction' estimates them with the base parameters "
            "in the sequential method; to fix them too, run them: --joints "
            + ",".join(str(j + 1) for j in range(robot.n)),
        }
    return doc


def load_friction(path: str | None, robot: Any) -> Any:
    """Friction parameters from a friction.json of 'identify friction' (without the pose-specific offsets).

    Joints not identified are NaN (:attr:`FrictionParameters.missing`): ``null`` in the file, or in a file
    written before they were marked (0 for every joint not run), the joints its ``fits`` do not list. A file
    of other joint names than ``robot``'s is noted (the same arm may name its joints differently).
    """
    if path is None:
        return None
    from reflexarm.ident import FrictionParameters
    from reflexarm.ident.friction.parameters import format_joints

    name = Path(path).name
    try:
        d = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ConfigError(f"cannot read friction file {path!r}: {e}") from e
    fr = FrictionParameters.from_dict(d)
    fr = FrictionParameters(fr.viscous, fr.coulomb, None)  # offsets of single-joint runs are pose-specific
    if fr.n != robot.n:
        raise ConfigError(f"{name} has friction for {fr.n} joints; robot {robot.name!r} has {robot.n}")
    fitted = _fitted_joints(d, name, robot.n)
    if "identified_joints" not in d and fitted is not None and not fr.missing and set(fitted) != set(range(fr.n)):
        fr = fr.restricted_to(fitted)
        print(
            f"{name}: no record of which joints were identified (written by an older reflexarm); its fits cover "
            f"joint(s) {format_joints(fitted, robot.joint_names)}: the 0 of joint(s) "
            f"{format_joints(fr.missing, robot.joint_names)} are taken as not identified"
        )
    names = d.get("joint_names")
    if isinstance(names, list) and list(names) != list(robot.joint_names):
        print(f"{name}: identified on joints {', '.join(map(str, names))}; robot {robot.name!r} has "
              f"{', '.join(robot.joint_names)}: check that it is the same arm")  # fmt: skip
    return fr


def _fitted_joints(d: dict[str, Any], name: str, n: int) -> list[int] | None:
    """0-based joints of friction.json's ``fits`` rows (``"joint": "3 (elbow)"``), or None without them."""
    rows = d.get("fits")
    if not isinstance(rows, list):
        return None
    joints = []
    for row in rows:
        text = str(row.get("joint", "")) if isinstance(row, dict) else ""
        head = text.split(" ", 1)[0]
        if not head.isdigit() or not 1 <= int(head) <= n:
            raise ConfigError(
                f"{name}: a fit's joint must be a 1-based joint number 1..{n} (e.g. '3 (elbow)'); got {text!r}"
            )
        joints.append(int(head) - 1)
    return sorted(set(joints))


def for_controller(result: Any, robot: Any, nominal: Any, args: argparse.Namespace) -> Any:
    """The result to write for the controller and into the robot file copy: physically consistent links.

    The link parameters realising beta_b nearest to ``nominal``'s if every link of them is physically
    consistent, else the projection onto consistent parameters (said so; it moves beta_b). With
    ``--no-projection`` the least-squares estimate as it is.
    """
    from reflexarm.ident.export.write_back import with_consistent_links

    if getattr(args, "no_projection", False):
        return result
    consistent, how = with_consistent_links(result, nominal, threads=None)  # the command sets --threads
    if consistent.beta_b is not result.beta_b:
        print(f"{result.method}: the model file and robot copy hold {how}")
        from reflexarm.ident.estimation.identify import explain_projection

        if why := explain_projection(result, consistent):
            print(f"{result.method}: {why}")
    return consistent


def write_robot_copy(result: Any, robot: Any, out: Path, args: argparse.Namespace) -> tuple[str | None, list[str]]:
    """Write ``robot_<method>.urdf|.xml`` (the identified inertias and friction in a copy of the robot file).

    Returns the file name and the notes on what was written (how the links were chosen, what the data
    cannot split, clipped friction, lumped links), or None and the reason when no copy can be written (a
    robot without a file, links the file cannot hold, ``--no-projection``: the file needs consistent links).
    """
    from reflexarm.errors import ModelError
    from reflexarm.ident.export.write_back import write_identified_robot

    if getattr(args, "no_projection", False):
        why = "no robot file copy with --no-projection (a robot file needs physically consistent links)"
        print(f"{result.method}: {why}")
        return None, [why]
    source = getattr(robot, "source", None)
    suffix = ".urdf" if source is not None and Path(source).suffix.lower() == ".urdf" else ".xml"
    try:
        path, notes = write_identified_robot(
            result, robot, out / f"robot_{result.method}{suffix}", threads=None
        )  # the command sets --threads
    except ModelError as e:
        print(f"{result.method}: no robot file copy written: {e}")
        return None, [f"not written: {e}"]
    for note in notes:
        say(args, f"{path.name}: {note}")
    return path.name, notes


def export_excitation_csv(args: argparse.Namespace, robot: Any, design: Any) -> Path:
    """``excite --csv OUT --rate HZ``: the excitation (``--periods`` periods) sampled and checked, as CSV."""
    from reflexarm._cli.common import format_table
    from reflexarm.ident.excitation.export import sample_excitation, write_excitation_csv

    trajectory = design.trajectory.with_periods(args.periods)
    amax = design.bounds.get("max_acceleration", args.max_acceleration)
    sampled = sample_excitation(trajectory, robot, rate=args.rate, max_acceleration=amax, limits=design.limits)
    path = write_excitation_csv(sampled, args.csv)
    print(
        f"\nexcitation sampled at {args.rate:g} Hz (base frequency {trajectory.base_frequency_hz:g} Hz, "
        f"{trajectory.n_harmonics} harmonics up to {trajectory.n_harmonics * trajectory.base_frequency_hz:g} Hz, "
        f"{args.periods} period(s) of {trajectory.period:g} s): {sampled.t.size:,} rows -> {path}"
    )
    print("columns: t [s], position_<joint> [rad], velocity_<joint> [rad/s], acceleration_<joint> [rad/s^2]")
    print("smallest distance to each limit over the samples (position/velocity: the robot file's; acceleration: "
          "the excitation's bound):")  # fmt: skip
    print(
        format_table(
            sampled.margin_rows(),
            [
                ("joint", "joint", "{}"),
                ("position_margin", "position [rad]", "{:.4f}"),
                ("velocity_margin", "velocity [rad/s]", "{:.4f}"),
                ("acceleration_margin", "acceleration [rad/s^2]", "{:.4f}"),
                ("torque_margin", "torque [Nm]", "{:.4f}"),
            ],
        )
    )
    return path
