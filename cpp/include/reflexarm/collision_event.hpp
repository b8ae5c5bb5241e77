// reflexarm: the record of one collision, filled by the stages of the collision pipeline inside update():
// detect -> (isolate -> identify) -> classify -> react, and by the guard that checks the reaction stops the arm.
//
// One event per detection (the reaction latches until reset()). Sized once by Controller::configure; never
// allocates afterwards. Times are the measurement's stamps [s]; energies [J]; NaN where not (yet) known.
#pragma once

#include <array>
#include <cstdint>
#include <limits>

#include <Eigen/Core>

#include "reflexarm/isolation.hpp"
#include "reflexarm/params.hpp"

namespace reflexarm
{

  /// What kind of contact a detection is.
  enum class ContactClass : int
  {
    None = 0,      ///< no detection yet
    Contact = 1,   ///< the wrist sensor measures the contact: an end-effector contact (intended interaction)
    Collision = 2  ///< not measured by the wrist sensor: a collision somewhere on the arm
  };

  const char * contactClassName(ContactClass c) noexcept;

  /// Where the reaction is.
  enum class ReactionPhase : int
  {
    None = 0,       ///< no reaction (no detection, or reaction "none")
    Gravity = 1,    ///< eq. (13), for good
    Braking = 2,    ///< damping injection
    Retracting = 3, ///< moving away from the contact
    Holding = 4     ///< holding a posture (after brake / retract, or compliant)
  };

  const char * reactionPhaseName(ReactionPhase p) noexcept;

  struct CollisionEvent
  {
    static constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

    bool detected = false;  ///< a detection happened since reset()
    double t_detect = kNaN; ///< stamp of the detecting tick
    Eigen::Matrix<std::uint8_t, Eigen::Dynamic, 1> joints; ///< 1 where |residual| > threshold at detection
    int n_joints = 0;
    /// The most distal joint whose |residual| exceeds its threshold at detection: a force on link i gives no
    /// torque on the joints after i, so the contact is on this joint's link or a later one (isolation's start).
    int distal_joint = -1;
    ContactClass contact_class = ContactClass::None;
    Reaction reaction = Reaction::None; ///< the reaction chosen for this class
    ReactionPhase phase = ReactionPhase::None;
    Eigen::VectorXd residual;   ///< detection residual at detection [Nm]
    Eigen::VectorXd q_detect;   ///< posture at detection [rad]
    double wrist_force = 0.0;   ///< |wrist force| at detection [N]
    double peak_residual = 0.0; ///< largest max_i |residual_i| / threshold_i from detection on [-]
    double energy_detect = kNaN; ///< kinetic energy 0.5 dq^T M(q) dq at detection (measured dq) [J]
    double energy_rest = kNaN;   ///< ... at t_detect + rest_time [J]
    double energy_max = 0.0;     ///< largest kinetic energy from detection on [J]
    double moved = 0.0;          ///< largest max_i |q_i - q_detect_i| from detection on [rad]
    double t_hold = kNaN;        ///< stamp the reaction started to hold a posture
    Eigen::VectorXd q_target;    ///< posture the reaction holds (brake / compliant) or retracts to [rad]
    /// retract: how far its plan moves the point it moves (the link only: the farthest from the link's end on) [m]
    double retract_planned = kNaN;
    /// Where and how hard: a measured contact from the wrist sensor at detection (its link, the measured force in the
    /// world frame, the point of its line of action closest to the sensor origin); a collision isolated from the
    /// residual isolation_delay after detection (ContactIsolator, spread over the ticks: t_estimate, t_estimated)
    /// when the controller has the links' geometry; link -1 otherwise.
    ContactEstimateData estimate;
    bool estimated = false;   ///< estimate was computed (false: no geometry given, or not yet)
    double t_estimate = kNaN; ///< stamp of the residual the isolation used (isolation_delay after detection)
    double t_estimated = kNaN; ///< stamp of the tick the isolation finished (its estimate applied from then on)
    bool isolating = false;    ///< (internal) an isolation is under way (begun, not finished)
    bool from_sensor = false; ///< estimate is the wrist sensor's (class Contact)
    int recrossings = 0;         ///< detections again after the residual fell below half of every threshold
    bool below_since = false;    ///< (internal) residual below all thresholds since the last crossing
    bool torque_limited = false; ///< the reaction's torque was saturated on some tick
    bool overspeed = false;      ///< some |dq_i| exceeded its velocity limit during the reaction
    bool still_moving = false;   ///< guard: energy at rest_time above the rest level
    bool guard_checked = false;  ///< the guard has run (t >= t_detect + rest_time)
    std::array<char, 256> text{}; ///< the guard's report ("" when the reaction stopped the arm)

    void resize(Eigen::Index n)
    {
      joints.setZero(n);
      residual.setZero(n);
      q_detect.setZero(n);
      q_target.setZero(n);
      clear();
    }

    void clear() noexcept
    {
      detected = false;
      t_detect = kNaN;
      joints.setZero();
      n_joints = 0;
      distal_joint = -1;
      contact_class = ContactClass::None;
      reaction = Reaction::None;
      phase = ReactionPhase::None;
      residual.setZero();
      q_detect.setZero();
      wrist_force = 0.0;
      peak_residual = 0.0;
      energy_detect = kNaN;
      energy_rest = kNaN;
      energy_max = 0.0;
      moved = 0.0;
      t_hold = kNaN;
      q_target.setZero();
      retract_planned = kNaN;
      estimate = ContactEstimateData{};
      estimated = false;
      t_estimate = kNaN;
      t_estimated = kNaN;
      isolating = false;
      from_sensor = false;
      recrossings = 0;
      below_since = false;
      torque_limited = false;
      overspeed = false;
      still_moving = false;
      guard_checked = false;
      text[0] = '\0';
    }
  };

} // namespace reflexarm
