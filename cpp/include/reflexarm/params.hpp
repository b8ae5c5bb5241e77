// reflexarm: parameters of the controller, checked once in Controller::configure.
//
// Names follow the paper (Vorndamme et al., "Soft Robotics for the Hydraulic Atlas Arms") and the Python
// package (reflexarm.control.Controller, reflexarm.control.contract.InputBounds). Units are SI.
#pragma once

#include <limits>
#include <stdexcept>
#include <string>

#include <Eigen/Core>

namespace reflexarm
{

  /// Error in the parameters given to Controller::configure (never thrown by update()).
  class ConfigError : public std::invalid_argument
  {
  public:
    explicit ConfigError(const std::string & what)
    : std::invalid_argument(what)
    {
    }
  };

  /// What a detected collision does (latched until reset()).
  enum class Reaction
  {
    Gravity = 0,   ///< eq. (13): gravity compensation only
    Compliant = 1, ///< hold the posture at detection at low stiffness, kappa_eps -> 0 (compliant mode of Fig. 3)
    None = 2,      ///< detection is reported only
    Brake = 3,     ///< inject damping M(q)/brake_time until the arm rests, then hold where it stopped
    Retract = 4    ///< move the contact away along the residual by retract_distance, then hold there
  };
  constexpr int kReactionCount = 5;

  const char * reactionName(Reaction r) noexcept;

  /// How the momentum observer (4) is integrated over a period h.
  enum class ObserverDiscretization
  {
    /// explicit Euler of the integral (the paper's form): stable only for observer_gain * h < 1
    Euler = 0,
    /// the first-order filter's exact form r_k = e^{-K h} r_{k-1} + (1 - e^{-K h}) (p_k - p_{k-1} - h beta) / h:
    /// stable at any gain (the momentum's increment over the period is what the residual filters)
    Exact = 1
  };

  /// Settings of the reactions after a detection (Reaction) and of the guard that checks they stop the arm.
  struct ReactionParams
  {
    double brake_time = 0.05;       ///< [s] brake: closed loop ddq = -dq / brake_time (within the torque limit)
    double brake_duration = 0.25;   ///< [s] brake: damping alone this long, then hold the posture reached
    /// [m] retract: how far the contact moves along J M11^-1 J^T f (the point; the farthest from the link's end on)
    double retract_distance = 0.05;
    double max_retract_angle = 0.5; ///< [rad] retract: largest joint motion of the retract
    double retract_speed = 0.2;     ///< [m/s] retract: mean speed of the contact along its path
    /// [s] retract: longest retract; a longer plan (its joints' velocity bound) is shortened to this, its distance
    /// with it, so that the arm rests within the guard's rest_time
    double max_retract_time = 0.3;
    double velocity_fraction = 0.5; ///< reference motions of a reaction stay below this x velocity limit
    double compliant_stiffness_factor = 0.1; ///< compliant: K of the hold = this x stiffness
    double rest_time = 0.5;         ///< [s] guard: the arm must be at rest this long after detection
    double rest_energy_fraction = 0.01; ///< guard: kinetic energy at rest_time <= this x the energy at detection
    double rest_energy_floor = 1e-3;    ///< [J] guard: ... or below this (above the filtered velocity noise's energy)
    /// [s] the guard's kinetic energy is 0.5 dq_f^T p_f of dq and M(q) dq low-passed with this time constant (the
    /// paper's velocity noise, 5.5e-2 rad/s, alone gives a few mJ unfiltered on the Atlas arm, ~1e-5 J filtered)
    double energy_filter_time = 0.02;
    /// [N] a detection while the wrist sensor measures more than this force is a measured end-effector contact
    /// (class Contact, reaction contact_reaction); otherwise an unmeasured collision (class Collision)
    double contact_level = 10.0;
    double position_margin = 0.05; ///< [rad] reaction references stay this far inside the joint limits
    /// [s] a collision (not measured by the wrist sensor) is isolated from the detection residual this long after
    /// detection, when the residual has grown from the threshold towards the contact's J^T f (0: at detection);
    /// a retract that waits for the estimate (retract_waits_for_estimate) brakes until then
    double isolation_delay = 0.02;
    /// The isolation is spread over the ticks: it begins on the tick isolation_delay after detection (the
    /// residual and posture of that tick; kinematics only) and does at most this many units of its fit per following
    /// tick (ContactIsolator::step; a unit: one point's constrained fit, or kTracePoints points' traces of pass 1),
    /// then one tick chooses the link, one estimates, and the estimate is in on the next: ceil(units / this) + 3 ticks
    /// after the beginning; a retract waiting for it factorises M(q) on that tick and is planned on the next (values
    /// below 1 count as 1). 4: every isolation tick within 1.2 x the tick without geometry, the estimate 55 / 101 /
    /// 147 ticks after the beginning on Atlas, Panda, iiwa14's 2 cm geometry (32: 10 / 16 / 21); the tick costs per
    /// budget: ReactionSettings.isolation_points_per_tick (Python) and bench/bench_collision_tick.py
    int isolation_points_per_tick = 4;
    /// retract: true: brake until the isolation's estimate is in, then move the estimated point along the estimated
    /// force; false: planned on the detecting tick from the detection residual on the joints up to the most distal
    /// significant one (at least the most distal crossing one; the isolation still runs, for the event record)
    bool retract_waits_for_estimate = false;
  };

  /// Plausibility bounds of the inputs (same fields and defaults as reflexarm.control.InputBounds).
  struct InputBounds
  {
    double position_margin = 0.2;  ///< q, q_d may exceed the joint limits by this [rad]
    double velocity_factor = 10.0; ///< |dq|, |dq_d| <= this x velocity limit [-]
    double torque_factor = 3.0;    ///< |tau_m| <= this x torque limit [-]
    double max_force = 2000.0;     ///< |wrist force component| [N]
    double max_moment = 200.0;     ///< |wrist moment component| [Nm]
    double gravity_tolerance = 1.0;  ///< | |gravity| - |model gravity| | [m/s^2]
    double max_acceleration = 1000.0; ///< |ddq_d| [rad/s^2]
    double max_velocity = 100.0;   ///< |dq| bound of joints without a velocity limit [rad/s]
    double max_torque = 1e4;       ///< |tau_m| bound of joints without a torque limit [Nm]
  };

  /// Everything Controller::configure needs besides the Pinocchio model.
  ///
  /// Vectors are per joint (size n = model.nv); a vector of size 1 is broadcast to n.
  struct ControllerParams
  {
    Eigen::VectorXd stiffness = Eigen::VectorXd::Constant(1, 300.0);   ///< K [Nm/rad], > 0
    Eigen::VectorXd damping_ratio = Eigen::VectorXd::Constant(1, 0.7); ///< D_xi [-], >= 0
    Eigen::VectorXd observer_gain = Eigen::VectorXd::Constant(1, 5.0); ///< K_o [1/s], > 0
    /// K_o of a second observer used for detection only; empty: one observer does both.
    Eigen::VectorXd detection_observer_gain;
    /// The friction model in the detection observer's (6) (0/1), whatever kappa_f the law and the compensating
    /// observer run; needs detection_observer_gain. With 0 (the paper's) a sliding joint's residual carries its
    /// friction.
    int detection_kappa_f = 0;
    /// Velocity band [rad/s] of the detection observer's friction model (wider than the velocity noise, so
    /// that noise does not flip its Coulomb term); 0: friction_velocity_band.
    double detection_friction_velocity_band = 0.0;
    /// K_f [1/s] of a second stage on the detection residual: the residual the detector looks at is
    /// r_f = e^{-K_f h} r_f + (1 - e^{-K_f h}) r (always this exact form; r_f = 0 on the first tick), so it is a
    /// second-order filter of the external torque with real poles -K_o,det and -K_f (the second-order momentum
    /// observer of Haddadin et al., T-RO 2017, with real poles): about half the first order's noise at the same
    /// ramp lag. Empty: none (the paper's first order).
    Eigen::VectorXd detection_filter_gain;
    /// zeta [Nm] per joint for detection (12), > 0; empty: detection off.
    Eigen::VectorXd threshold = Eigen::VectorXd::Constant(1, 11.0);
    Reaction reaction = Reaction::Gravity;          ///< reaction to an unmeasured (link) collision
    Reaction contact_reaction = Reaction::Gravity;  ///< reaction to a contact measured by the wrist sensor
    ReactionParams reaction_params;
    ObserverDiscretization observer_discretization = ObserverDiscretization::Euler;
    int kappa_f = 0;   ///< friction compensation in (2) and (6) (0/1)
    int kappa_eps = 0; ///< disturbance compensation in (2) (0/1)
    int kappa_ext = 0; ///< wrist-wrench term in (6), "EFC" (0/1)
    double residual_limit = 30.0; ///< cut-off of the compensated residual [Nm]
    double switch_time = 0.1;     ///< kappa_eps ramp time [s]; 0 switches at once
    double dt = 1e-3;             ///< nominal control period [s]
    /// Recompute the modal damping from M(q) every this many accepted ticks. The computation is spread over
    /// min(4, damping_update_period) ticks (Controller::kDampingParts), so the new D is used from that many
    /// ticks - 1 after the M(q) it comes from (1: every tick, whole, no delay; the first tick after
    /// configure()/reset() always computes whole).
    int damping_update_period = 10;
    /// Friction model tau_f = coulomb * clip(dq / velocity_band, -1, 1) + viscous * dq.
    Eigen::VectorXd friction_coulomb = Eigen::VectorXd::Zero(1); ///< [Nm], >= 0
    Eigen::VectorXd friction_viscous = Eigen::VectorXd::Zero(1); ///< [Nms/rad], >= 0
    double friction_velocity_band = 0.02;                        ///< [rad/s], > 0
    /// Joint springs of the robot file (Pinocchio has none): g_hat(q) includes K_s (q - q_s). Empty: none.
    Eigen::VectorXd spring_stiffness; ///< K_s [Nm/rad], >= 0
    Eigen::VectorXd spring_reference; ///< q_s [rad]
    /// Index of the wrist force/torque sensor frame in model.frames (its LOCAL Jacobian is used).
    std::size_t sensor_frame_id = 0;
    /// Saturation of the command [Nm] per joint (+inf: none). Empty: the model's effort limits, joints
    /// without a finite positive one unsaturated (the Python Controller's torque_limit="model").
    Eigen::VectorXd torque_limit;
    /// Largest change of the command [Nm/s] per joint; empty: no rate limit.
    Eigen::VectorXd torque_rate_limit;
    InputBounds input_bounds;
    double period_band_low = 0.5;  ///< integrated period clipped to [low, high] x dt
    double period_band_high = 2.0;
  };

} // namespace reflexarm
