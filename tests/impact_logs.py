"""Generated robot logs with short impacts at known times, for the tests of ``reflexarm detect``.

Independent of the detector: the arm follows a free periodic motion (two harmonics per joint, period 4 s, within
the velocity limits); the logged motor torque is the robot file's inverse dynamics (Pinocchio RNEA, the "arm")
plus a repeating model error (a friction-like and a position-like term per joint, the same function of the state
for every seed: the error of one arm against its model) minus the external torque of short half-sine force
pulses pushed into a link's collision surface along its inward normal (tau_ext = J_p(q)^T f), as a stiff
position-controlled arm shows a hit in its currents. Sensor noise on q, dq and tau; optional one-sample
glitches at the joints' stops: a velocity sign flip or a current spike.

The truth each test compares with (pulse times, links, peak torques, glitch samples) comes from here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from reflexarm.control.collision.classify import controller_geometry
from reflexarm.logs import RobotLog
from reflexarm.robots import RobotModel

#: Period of the free motion [s].
MOTION_PERIOD = 4.0
#: Sensor noise (standard deviations): q [rad], dq [rad/s], tau [Nm].
NOISE = (1e-5, 2e-3, 0.1)


@dataclass(frozen=True)
class Pulse:
    """One force pulse: start [s], duration [s], 0-based link (joint) index, its peak |tau_ext_j| over the
    logged samples per joint [Nm] and the force's magnitude [N]."""

    t0: float
    duration: float
    link: int
    peak_torque: np.ndarray
    force: float


@dataclass(frozen=True)
class ImpactLog:
    """A generated log and its truth: pulses, the model error's amplitude per joint [Nm], glitches (sample,
    joint, kind)."""

    log: RobotLog
    pulses: tuple[Pulse, ...]
    error_amplitude: np.ndarray
    glitches: tuple[tuple[int, int, str], ...]

    def eligible(self, factor: float = 3.0) -> list[Pulse]:
        """The pulses whose logged torque exceeds ``factor`` times the model error on some joint."""
        return [p for p in self.pulses if np.any(p.peak_torque > factor * self.error_amplitude)]


def _motion(robot: RobotModel, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q, dq, ddq of the periodic motion (fixed: the same task for every seed)."""
    rng = np.random.default_rng(1234)
    home = np.array(
        [0.0, 0.6, 0.0, -1.3, 0.0, 1.0, 0.0][: robot.n] if robot.name.startswith("iiwa") else np.zeros(robot.n)
    )
    w = 2.0 * math.pi / MOTION_PERIOD
    amp = rng.uniform(0.3, 0.5, robot.n)
    phase, phase2 = rng.uniform(0, 2 * math.pi, robot.n), rng.uniform(0, 2 * math.pi, robot.n)
    tt = t[:, None]
    q = home + amp * np.sin(w * tt + phase) + 0.3 * amp * np.sin(2 * w * tt + phase2)
    dq = amp * w * np.cos(w * tt + phase) + 0.6 * amp * w * np.cos(2 * w * tt + phase2)
    ddq = -amp * w**2 * np.sin(w * tt + phase) - 1.2 * amp * w**2 * np.sin(2 * w * tt + phase2)
    return q, dq, ddq


def model_error(q: np.ndarray, dq: np.ndarray, amplitude: float) -> np.ndarray:
    """The repeating model error [Nm]: 0.6 A tanh(dq / 0.05) + 0.4 A cos(q + c_j), |error| <= A."""
    c = np.linspace(0.0, 2.0, q.shape[1])
    return amplitude * (0.6 * np.tanh(dq / 0.05) + 0.4 * np.cos(q + c))


def _point_jacobian(robot: RobotModel, data: pin.Data, link: int, point_local: np.ndarray) -> tuple[np.ndarray, ...]:
    """(J_p (3, n), world point, world rotation of the joint frame) of a point fixed to joint ``link``'s frame
    (kinematics already computed in ``data``)."""
    model = robot.pin_model
    placement = data.oMi[link + 1]
    p = placement.rotation @ point_local + placement.translation
    J = pin.getJointJacobian(model, data, link + 1, pin.LOCAL_WORLD_ALIGNED)
    r = p - placement.translation
    skew = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
    return J[:3] - skew @ J[3:], p, placement.rotation


def _pulse_times(rng: np.random.Generator, duration: float, n_pulses: int) -> np.ndarray:
    """Start times >= 1 s after the start, >= 0.6 s apart, the last ending 0.5 s before the end."""
    if n_pulses == 0:
        return np.zeros(0)
    span = duration - 1.5
    slot = span / n_pulses
    if slot < 0.6:
        raise ValueError(f"{n_pulses} pulses do not fit in {duration} s")
    return 1.0 + slot * np.arange(n_pulses) + rng.uniform(0.0, slot - 0.6, n_pulses)


def impact_log(
    robot: RobotModel,
    *,
    rate_hz: float,
    duration_s: float,
    seed: int,
    n_pulses: int = 0,
    error_Nm: float = 3.0,
    peak_range: tuple[float, float] = (1.0, 8.0),
    links: tuple[int, ...] = (2, 3, 4, 5, 6),
    glitches: int = 0,
    noise: bool = True,
) -> ImpactLog:
    """A log of ``duration_s`` at ``rate_hz`` (see the module docstring).

    Each pulse lasts 10-30 ms, acts on a random link of ``links`` at a random surface point, with a force
    scaled so that its largest joint torque (continuous peak) is ``peak_range`` x ``error_Nm`` (uniform).
    """
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    t = np.arange(int(round(duration_s * rate_hz))) * dt
    q, dq, ddq = _motion(robot, t)
    model, data = robot.pin_model, robot.pin_model.createData()
    tau = np.array([pin.rnea(model, data, q[k], dq[k], ddq[k]) for k in range(t.size)])
    tau += model_error(q, dq, error_Nm)
    geometry = controller_geometry(robot)
    assert geometry is not None
    pulses = []
    for t0 in _pulse_times(rng, duration_s, n_pulses):
        link = int(rng.choice(links))
        surface = geometry.links[link]
        i = int(rng.integers(surface.points.shape[0]))
        d = float(rng.uniform(0.010, 0.030))
        k_mid = int(round((t0 + d / 2) / dt))
        pin.computeJointJacobians(model, data, q[k_mid])
        J, _, rot = _point_jacobian(robot, data, link, surface.points[i])
        unit = -(rot @ surface.normals[i])  # pushed into the surface
        scale = float(np.max(np.abs(J.T @ unit)))
        force = float(rng.uniform(*peak_range)) * error_Nm / max(scale, 1e-9)
        ks = np.flatnonzero((t >= t0) & (t < t0 + d))
        peak = np.zeros(robot.n)
        for k in ks:
            pin.computeJointJacobians(model, data, q[k])
            J, _, rot = _point_jacobian(robot, data, link, surface.points[i])
            tau_ext = J.T @ (-(rot @ surface.normals[i])) * force * math.sin(math.pi * (t[k] - t0) / d)
            tau[k] -= tau_ext
            peak = np.maximum(peak, np.abs(tau_ext))
        pulses.append(Pulse(float(t0), d, link, peak, force))
    q_m, dq_m, tau_m = q.copy(), dq.copy(), tau.copy()
    if noise:
        q_m += rng.normal(0.0, NOISE[0], q.shape)
        dq_m += rng.normal(0.0, NOISE[1], q.shape)
        tau_m += rng.normal(0.0, NOISE[2], q.shape)
    marks = _add_glitches(rng, dq_m, tau_m, glitches, dt)
    log = RobotLog(t=t, q=q_m, dq=dq_m, tau=tau_m, source=f"impacts_{rate_hz:g}Hz_seed{seed}")
    amplitude = np.max(np.abs(model_error(q, dq, error_Nm)), axis=0)
    return ImpactLog(log, tuple(pulses), amplitude, tuple(marks))


def _add_glitches(
    rng: np.random.Generator, dq: np.ndarray, tau: np.ndarray, count: int, dt: float
) -> list[tuple[int, int, str]]:
    """``count`` one-sample glitches at the joints' stops (where dq changes sign): alternately a velocity sign
    flip (at the last sample before the stop where |dq| is still >= 0.1 rad/s) and a current spike of 30-150 Nm."""
    marks: list[tuple[int, int, str]] = []
    n = dq.shape[1]
    for g in range(count):
        j = int(rng.integers(n))
        stops = np.flatnonzero(np.diff(np.sign(dq[:, j])) != 0)
        stops = stops[(stops > int(1.0 / dt)) & (stops < dq.shape[0] - 5)]
        if stops.size == 0:
            continue
        k = int(rng.choice(stops))
        if any(jj == j and abs(kk - k) < int(round(0.1 / dt)) + 3 for kk, jj, _ in marks):
            continue  # one glitch per stop and joint: each stays one sample
        if g % 2 == 0:
            while k > 1 and abs(dq[k, j]) < 0.1:  # back to the last sample still at >= 0.1 rad/s
                k -= 1
            dq[k, j] = -dq[k, j]
            marks.append((k, j, "velocity"))
        else:
            tau[k, j] += float(rng.choice((-1.0, 1.0)) * rng.uniform(30.0, 150.0))
            marks.append((k, j, "torque"))
    return marks
