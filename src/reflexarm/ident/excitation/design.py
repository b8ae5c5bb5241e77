"""Excitation design [28]: finite Fourier series joint trajectories with an optimized condition number.

Each joint follows (Swevers et al. 1997)

    q_i(t)   = q0_i + sum_l [ a_il / (l w_f) sin(l w_f t) - b_il / (l w_f) cos(l w_f t) ]
    dq_i(t)  = sum_l [ a_il cos(l w_f t) + b_il sin(l w_f t) ]
    ddq_i(t) = sum_l l w_f [ -a_il sin(l w_f t) + b_il cos(l w_f t) ]

with base frequency w_f [rad/s] and L harmonics. The trajectory is periodic with period 2 pi / w_f, so
it ends where it starts; it starts and ends at rest (dq = ddq = 0 at t = 0) when ``sum_l a_il = 0`` and
``sum_l l b_il = 0``. The optimizer eliminates a_i1 and b_i1 with these two equations, so every
candidate is at rest at both ends by construction.

:func:`optimize_excitation` minimises the condition number of the base regressor stacked over samples
of one period (``scipy.optimize.minimize``, SLSQP) subject to joint position (with a margin), velocity and
acceleration limits evaluated on a dense time grid (linear in the coefficients), and to the model's joint
torques, a workspace bound and self-collision (:mod:`.limits`: nonlinear, with exact derivatives) on a
coarser grid (:class:`~.constraints.ConstraintGrid`). The best iterates are then checked at 1 kHz: a
peak of a limit between grid points joins the grid and the iterate is moved to the nearest point that
meets the refined grid (:meth:`~.constraints.ConstraintGrid.restored`), so the trajectory meets the limits
at 1 kHz by construction; the final 1 kHz check (:func:`~.constraints.best_at_1khz`) still scales the
amplitudes down if a peak is left. Its steps: :func:`excitation_limits` (the bounds), a start inside them
(:func:`_start`), the SLSQP run with its progress recorded (:func:`_minimise`), the restoration and 1 kHz
check of its best iterates, and the diagnosis of a run that stalled (:func:`~.diagnosis.diagnose_stall`:
the optimizer's own message, and which base-parameter combination the motion fails to excite).

Repeatability: a seeded call gives the same trajectory bit for bit on one machine with the same BLAS
library and thread count. On another CPU (OpenBLAS picks its kernels per CPU) or with another number
of BLAS threads the optimizer's path differs after a few iterations: measured for the Atlas arm with
L = 4 after 12 iterations, the condition number came out 48, 94 and 153 under
``OPENBLAS_CORETYPE=Haswell``, ``Nehalem`` and ``Sandybridge``, and 1 vs 2 threads changed the result
in the fifth digit. The unoptimized start (``maxiter=0``) is the same everywhere (seeded coefficients,
closed-form scaling). To run the same excitation elsewhere, save the design (``reflexarm excite``
writes excitation.json) and pass it on (``identify dynamics --excitation``).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
import scipy.optimize

from reflexarm.errors import ConfigError, ModelError
from reflexarm.ident.estimation.base_parameters import BaseParameters, compute_base_parameters
from reflexarm.ident.excitation.constraints import (
    ConstraintGrid,
    best_at_1khz,
    shrink_into_limits,
)
from reflexarm.ident.excitation.cost import Parametrisation, log_condition, log_condition_gradient
from reflexarm.ident.excitation.diagnosis import (  # noqa: F401  (re-exported: importable from here as before)
    STALLED_CONDITION,
    ExcitationStalledWarning,
    diagnose_stall,
    regressor_condition,
)
from reflexarm.ident.excitation.fourier_trajectory import FourierTrajectory
from reflexarm.ident.excitation.limits import (
    DEFAULT_CLEARANCE,
    DEFAULT_TORQUE_FRACTION,
    ArmGeometry,
    ExcitationLimits,
    LimitEvaluator,
    arm_geometry,
    default_floor,
)
from reflexarm.robots.robot_model import RobotModel

__all__ = [
    "ExcitationDesign",
    "ExcitationStalledWarning",
    "FourierTrajectory",
    "excitation_limits",
    "optimize_excitation",
]

#: Default velocity bound of an excitation trajectory [rad/s] (tighter of this and the robot's limit).
DEFAULT_MAX_VELOCITY = 1.5
#: Default acceleration bound [rad/s^2] (robot files carry no acceleration limits).
DEFAULT_MAX_ACCELERATION = 5.0
#: Default margin kept from the joint position limits [rad].
DEFAULT_POSITION_MARGIN = 0.1
#: The best feasible iterates (by the cost on the optimization's grid) restored onto the limits and checked at
#: 1 kHz after the run (:func:`~.constraints.best_at_1khz`); the one with the lowest condition number after
#: that is kept (restoring moves each iterate a little, so the best on the grid need not stay the best).
CANDIDATES_AT_1KHZ = 5


@dataclass(frozen=True)
class ExcitationDesign:
    """Result of :func:`optimize_excitation`.

    Attributes:
        trajectory: the optimized trajectory; initial: the unoptimized start.
        condition_initial, condition_optimized: condition number of the base regressor (stacked over
            ``n_samples`` samples of one period) before and after.
        limits_initial, limits_optimized: the largest use of each limit at 1 kHz (<= 1: within): position,
            velocity, acceleration (:meth:`FourierTrajectory.check_limits`) and torque (the model's).
        iterations: optimizer iterations; message: the optimizer's message.
        bounds: the position, velocity and acceleration bounds (JSON form).
        history: condition number after each iteration.
        diagnosis: why the run ended where it did, when it stalled ("" otherwise).
        limits: every bound the trajectory respects (None for a design read from an old file).
        limit_report: the worst sample of the torque, workspace and self-collision bounds at 1 kHz
            (:meth:`LimitEvaluator.report`).
        amplitude_scale: the factor the final 1 kHz check scaled the amplitudes by (1: the optimized
            trajectory met every limit at 1 kHz as it was; below 1: a peak between grid points was left).
    """

    trajectory: FourierTrajectory
    initial: FourierTrajectory
    condition_initial: float
    condition_optimized: float
    limits_initial: dict[str, float]
    limits_optimized: dict[str, float]
    iterations: int
    message: str
    bounds: dict[str, list[float]] = field(default_factory=dict)
    history: tuple[float, ...] = ()
    diagnosis: str = ""
    limits: ExcitationLimits | None = None
    limit_report: dict[str, dict[str, Any]] = field(default_factory=dict)
    amplitude_scale: float = 1.0

    def to_dict(self) -> dict[str, object]:
        return {
            "trajectory": self.trajectory.to_dict(),
            "initial": self.initial.to_dict(),
            "condition_initial": self.condition_initial,
            "condition_optimized": self.condition_optimized,
            "condition_history": list(self.history),
            "diagnosis": self.diagnosis,
            "limits_initial": self.limits_initial,
            "limits_optimized": self.limits_optimized,
            "limit_report": self.limit_report,
            "amplitude_scale_at_1khz": self.amplitude_scale,
            "iterations": self.iterations,
            "message": self.message,
            "bounds": self.bounds,
            "excitation_limits": None if self.limits is None else self.limits.to_dict(),
            "units": {
                "trajectory": "base_frequency_hz [Hz], period_s [s], a and b [rad/s], offset [rad]",
                "bounds": "lower, upper [rad], max_velocity [rad/s], max_acceleration [rad/s^2]",
                "limits": "largest use of each limit on the trajectory sampled at 1 kHz (<= 1: within)",
                "limit_report": "torque: use (<= 1 within), value [Nm]; workspace, self_collision: clearance_m [m] "
                "(>= 0 within), joints 0-based",
            },
        }


def excitation_limits(
    robot: RobotModel,
    *,
    max_velocity: npt.ArrayLike | None = None,
    max_acceleration: npt.ArrayLike = DEFAULT_MAX_ACCELERATION,
    position_margin: float = DEFAULT_POSITION_MARGIN,
    torque_fraction: float | None = DEFAULT_TORQUE_FRACTION,
    floor: float | None | str = "default",
    clearance: float = DEFAULT_CLEARANCE,
    self_collision: bool = True,
    center: np.ndarray | None = None,
) -> tuple[ExcitationLimits, ArmGeometry | None]:
    """The bounds of an excitation of ``robot`` and its collision geometry (see :func:`optimize_excitation`).

    Raises:
        ConfigError: non-positive bounds, a margin larger than a joint's range, a torque fraction outside (0, 1].
    """
    n = robot.n
    lo, hi = robot.lower_limit + position_margin, robot.upper_limit - position_margin
    unlimited = ~np.isfinite(robot.lower_limit) | ~np.isfinite(robot.upper_limit) | (robot.upper_limit > 1e6)
    lo = np.where(unlimited, -np.pi, lo)
    hi = np.where(unlimited, np.pi, hi)
    if np.any(hi <= lo):
        j = int(np.argmax(hi <= lo))
        raise ConfigError(f"position_margin {position_margin!r} rad leaves no range on joint {j + 1}")
    vmax = robot.velocity_limit if max_velocity is None else np.broadcast_to(np.asarray(max_velocity, float), (n,))
    if max_velocity is None:
        vmax = np.where(np.isfinite(vmax) & (vmax > 0), np.minimum(vmax, DEFAULT_MAX_VELOCITY), DEFAULT_MAX_VELOCITY)
    vmax = np.asarray(vmax, dtype=float)
    amax = np.broadcast_to(np.asarray(max_acceleration, dtype=float), (n,)).copy()
    if np.any(vmax <= 0) or np.any(amax <= 0):
        raise ConfigError(f"velocity and acceleration bounds must be positive; got {vmax.tolist()}, {amax.tolist()}")
    notes: list[str] = []
    effort = np.asarray(robot.effort_limit, dtype=float)
    tmax = np.full(n, np.inf)
    if torque_fraction is not None:
        if not 0.0 < torque_fraction <= 1.0:
            raise ConfigError(f"torque_fraction must be in (0, 1]; got {torque_fraction!r}")
        ok = np.isfinite(effort) & (effort > 0)
        tmax = np.where(ok, torque_fraction * effort, np.inf)
        notes.append(
            f"torque: the model's joint torque (rigid body + friction) within {100 * torque_fraction:g} % of each "
            "joint's effort limit"
            + ("" if ok.all() else f" (joints {[int(j) + 1 for j in np.flatnonzero(~ok)]} have none: unbounded)")
        )
    mid = 0.5 * (lo + hi) if center is None else np.asarray(center, dtype=float)
    geometry = None
    if floor is not None or self_collision:
        try:
            geometry = arm_geometry(robot, mid, clearance=clearance)
        except ModelError as e:  # e.g. a model built in memory: no file, no collision geometry
            notes.append(f"workspace and self-collision NOT checked: no collision geometry ({e})")
            warnings.warn(notes[-1], UserWarning, stacklevel=3)
            floor, self_collision = None, False
    if floor == "default":
        assert geometry is not None
        floor, why = default_floor(robot, geometry, mid)
        notes.append(why)
    elif floor is not None:
        floor = float(floor)  # type: ignore[arg-type]
        notes.append(f"workspace: no point of the arm below z = {floor:g} m of the base frame (+{clearance:g} m)")
    if self_collision and geometry is not None:
        notes.append(
            f"self-collision: capsules fitted to the file's MuJoCo collision geometry, {len(geometry.pairs)} link "
            f"pair(s) kept {clearance:g} m apart"
            + (f"; not checked (overlapping at the centre pose): {[(i + 1, j + 1) for i, j in geometry.excluded]}"
               if geometry.excluded else "")
        )  # fmt: skip
    limits = ExcitationLimits(lo, hi, vmax, amax, tmax, floor, clearance, self_collision, tuple(notes))  # type: ignore[arg-type]
    return limits, geometry


def optimize_excitation(
    robot: RobotModel,
    *,
    base: BaseParameters | None = None,
    base_frequency: float = 2 * np.pi * 0.1,
    n_harmonics: int = 5,
    max_velocity: npt.ArrayLike | None = None,
    max_acceleration: npt.ArrayLike = DEFAULT_MAX_ACCELERATION,
    position_margin: float = DEFAULT_POSITION_MARGIN,
    torque_fraction: float | None = DEFAULT_TORQUE_FRACTION,
    floor: float | None | str = "default",
    self_collision: bool = True,
    center: npt.ArrayLike | None = None,
    n_samples: int = 100,
    n_grid: int = 200,
    n_grid_dynamics: int = 60,
    maxiter: int = 100,
    seed: int = 0,
    initial: FourierTrajectory | None = None,
    progress: bool = False,
) -> ExcitationDesign:
    """Optimize a Fourier excitation trajectory for the condition number of the base regressor.

    Args:
        robot: the arm (kinematics, dynamics, limits, collision geometry).
        base: base-parameter map (default: computed from ``robot``).
        base_frequency: w_f [rad/s] (default 2 pi 0.1: a 10 s period).
        n_harmonics: L.
        max_velocity: |dq| bound per joint [rad/s] (default: the robot's, at most :data:`DEFAULT_MAX_VELOCITY`).
        max_acceleration: |ddq| bound per joint [rad/s^2]; position_margin: kept from the joint limits [rad].
        torque_fraction: the model's joint torques stay within this share of the effort limits (None: not
            bounded; see :data:`~reflexarm.ident.excitation.limits.DEFAULT_TORQUE_FRACTION`).
        floor: height [m] in the base frame no point of the arm may go below; ``"default"``: the base plane
            when the arm stands on it (:func:`~reflexarm.ident.excitation.limits.default_floor`); None: none.
        self_collision: keep the links apart (capsules fitted to the file's collision geometry).
        center: initial offsets q0 (default: the middle of each joint's range).
        n_samples: samples per period stacked into the regressor whose condition number is minimised.
        n_grid, n_grid_dynamics: samples per period on which the position, velocity and acceleration
            limits, and the torque, workspace and self-collision bounds are imposed.
        maxiter: optimizer iterations; seed: of the random start; initial: start from this trajectory instead.
        progress: show a progress bar over the optimizer iterations.

    Raises:
        ConfigError: bad bounds (non-positive, margin larger than a joint's range).
        IdentificationError: no trajectory meets the limits (e.g. already at rest in the centre pose).

    Warns:
        ExcitationStalledWarning: the condition number ended above :data:`STALLED_CONDITION`, with why.
    """
    n, L = robot.n, int(n_harmonics)
    if L < 2:
        raise ConfigError(f"n_harmonics must be >= 2 (one is used up by the rest conditions); got {n_harmonics!r}")
    c = None if center is None else np.asarray(center, dtype=float)
    limits, geometry = excitation_limits(
        robot, max_velocity=max_velocity, max_acceleration=max_acceleration, position_margin=position_margin,
        torque_fraction=torque_fraction, floor=floor, self_collision=self_collision, center=c,
    )  # fmt: skip
    mid = 0.5 * (limits.lower + limits.upper) if c is None else c
    if np.any(mid <= limits.lower) or np.any(mid >= limits.upper):
        raise ConfigError(f"center {np.asarray(mid).tolist()} must lie inside the joint limits minus the margin")
    base = base if base is not None else compute_base_parameters(robot)
    par = Parametrisation(n, L, base_frequency)
    period = 2 * np.pi / base_frequency
    t_cost = np.arange(n_samples) * period / n_samples
    log_cond = log_condition(robot, base, par, t_cost)
    evaluator = LimitEvaluator(robot, limits, geometry)
    grid = ConstraintGrid.uniform(par, limits, evaluator, n_grid, n_grid_dynamics)
    x0 = _start(par, limits, evaluator, mid, seed, initial, grid.t_linear)
    start = par.trajectory(x0)
    gradient = log_condition_gradient(robot, base, par, t_cost)
    res, history, candidates = _minimise(log_cond, gradient, x0, grid, maxiter, progress)
    x, report, scale = best_at_1khz(grid, candidates, log_cond)
    best = par.trajectory(x)
    cond1 = float(np.exp(log_cond(x)))
    return ExcitationDesign(
        best, start, float(np.exp(log_cond(x0))), cond1, _limit_uses(start, limits, evaluator),
        _limit_uses(best, limits, evaluator, report), int(res.get("nit", 0)), str(res.get("message", "")),
        _bounds(limits), tuple(history), diagnose_stall(robot, base, best, cond1, history, res, n_samples), limits,
        report, scale,
    )  # fmt: skip


def _bounds(limits: ExcitationLimits) -> dict[str, list[float]]:
    """The position, velocity and acceleration bounds in :attr:`ExcitationDesign.bounds`' JSON form."""
    return {
        "lower": limits.lower.tolist(),
        "upper": limits.upper.tolist(),
        "max_velocity": limits.max_velocity.tolist(),
        "max_acceleration": limits.max_acceleration.tolist(),
    }


def _start(
    par: Parametrisation,
    limits: ExcitationLimits,
    evaluator: LimitEvaluator,
    mid: np.ndarray,
    seed: int,
    initial: FourierTrajectory | None,
    t_grid: np.ndarray,
) -> np.ndarray:
    """The start x0: seeded random coefficients (or ``initial``) scaled into the linear limits (closed
    form), then shrunk about q0 until the torque, workspace and self-collision bounds hold too."""
    n, L = par.n, par.L
    if initial is None:
        rng = np.random.default_rng(seed)
        a = rng.normal(size=(n, L))
        b = rng.normal(size=(n, L))
        a, b, _ = par.unpack(par.pack(a, b, mid))
        # scale the amplitudes into the limits (q - q0, dq, ddq are all linear in (a, b))
        q, dq, ddq = FourierTrajectory(par.base_frequency, a, b, np.zeros(n)).evaluate(t_grid)
        room = np.minimum(limits.upper - mid, mid - limits.lower)
        s = 0.8 * min(
            np.min(room / np.maximum(np.abs(q).max(axis=0), 1e-12)),
            np.min(limits.max_velocity / np.maximum(np.abs(dq).max(axis=0), 1e-12)),
            np.min(limits.max_acceleration / np.maximum(np.abs(ddq).max(axis=0), 1e-12)),
        )
        x0 = par.pack(a * s, b * s, mid)
    else:
        if initial.n != n or initial.n_harmonics != L:
            raise ConfigError(f"initial trajectory has n={initial.n}, L={initial.n_harmonics}; expected n={n}, L={L}")
        x0 = par.pack(initial.a, initial.b, initial.offset)
    return shrink_into_limits(par, x0, evaluator, t_grid)[0]


def _minimise(
    log_cond: Callable[[np.ndarray], float],
    gradient: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    grid: ConstraintGrid,
    maxiter: int,
    progress: bool,
) -> tuple[scipy.optimize.OptimizeResult, list[float], list[np.ndarray]]:
    """SLSQP over the grid's constraints from x0, recording the condition number after each iteration.
    Returns the result, the history and the best iterates that meet the grid's constraints, best first (at
    most :data:`CANDIDATES_AT_1KHZ`; SLSQP may end outside the nonlinear ones; the start is always one)."""
    from reflexarm._progress import show_progress

    history: list[float] = []
    feasible_iterates = [(float(log_cond(x0)), x0)]  # the start meets the grid's limits (see _start)
    bar = None
    if show_progress(progress) and maxiter > 0:
        from tqdm import tqdm

        bar = tqdm(total=int(maxiter), desc="excitation", unit="it", leave=False)

    def step(x: np.ndarray) -> None:
        value = float(log_cond(x))
        history.append(float(np.exp(value)))
        if grid.feasible(x):
            feasible_iterates.append((value, x.copy()))
        if bar is not None:
            bar.update(1)
            bar.set_postfix(cond=f"{history[-1]:.3g}")

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            res = scipy.optimize.minimize(
                log_cond, x0, jac=gradient, method="SLSQP", constraints=grid.scipy_constraints(),
                options={"maxiter": int(maxiter), "ftol": 1e-6}, callback=step,
            )  # fmt: skip
    finally:
        if bar is not None:
            bar.close()
    if np.all(np.isfinite(res.x)) and grid.feasible(res.x):
        feasible_iterates.append((float(log_cond(res.x)), np.asarray(res.x)))
    feasible_iterates.sort(key=lambda c: c[0])
    return res, history, [x for _, x in feasible_iterates[:CANDIDATES_AT_1KHZ]]


def _limit_uses(
    trajectory: FourierTrajectory,
    limits: ExcitationLimits,
    evaluator: LimitEvaluator,
    report: dict[str, dict[str, Any]] | None = None,
) -> dict[str, float]:
    """Position, velocity, acceleration and torque use at 1 kHz (<= 1: within)."""
    uses = trajectory.check_limits(limits.lower, limits.upper, limits.max_velocity, limits.max_acceleration)
    if evaluator.torque_joints.size:
        if report is None:
            t = np.arange(0.0, trajectory.period, 1e-3)
            q, dq, ddq = trajectory.evaluate(t)
            tau = evaluator.torque(q, dq, ddq)
            j = evaluator.torque_joints
            uses["torque"] = float(np.max(np.abs(tau[:, j]) / limits.max_torque[j]))
        else:
            uses["torque"] = float(report["torque"]["use"])  # type: ignore[arg-type]
    return uses
