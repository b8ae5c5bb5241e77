// reflexarm::Controller: the collision pipeline after the detection threshold (12): classify the contact, choose
// and run the reaction (gravity (13), brake, retract, compliant), follow the event and guard that the reaction
// brings the arm to rest. Called from update() on accepted ticks; never allocates, never throws. The event starts
// between detect() and the control law (beginEvent), so the reaction's law makes the detecting tick's torque.
//
// Reactions (the arm's own torque limits bound every one of them in boundTorque(), after this law):
//   gravity   tau = g(q)                                                         (13), for good
//   brake     tau = g(q) + C dq - M(q) dq / brake_time                          closed loop ddq = -dq / T_b,
//             for brake_duration, then hold the posture reached                  (damping injection, no spring)
//   retract   law (2) towards q_detect + dq_plan along a minimum-jerk path, then hold there; dq_plan moves the
//             contact by retract_distance along J M11^-1 J^T f: dq ~ M11^-1 J_c^T f (a contact force f gives the
//             residual r = J_c^T f; M11 M(q)'s block of the joints up to the contact's link, the later ones held)
//             is the velocity an impulse of the contact force gives those joints, the motion of least kinetic
//             energy for that displacement, with a positive component along f, away from the obstacle (De Luca et
//             al., IROS 2006, "admittance reflex")
//   compliant hold q_detect at c K (c = compliant_stiffness_factor) with the damping sqrt(c) D (the modal damping
//             of c K: same modes, frequencies scaled by sqrt(c)), kappa_eps -> 0 (the compliant mode of Fig. 3)
//   hold      law (2) with q_d = q_target, dq_d = ddq_d = 0, no disturbance compensation
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "pinocchio/algorithm/crba.hpp"
#include "pinocchio/algorithm/frames.hpp"
#include "pinocchio/algorithm/jacobian.hpp"
#include "pinocchio/algorithm/rnea.hpp"

#include "reflexarm/controller.hpp"

namespace reflexarm
{

  double Controller::kineticEnergy() const noexcept
  {
    return 0.5 * dq_f_.dot(p_f_);
  }

  // dq and p = M(q) dq low-passed (first order, energy_filter_time) on every accepted tick: the guard's energy
  // 0.5 dq_f^T p_f follows the arm's motion, not the velocity noise
  void Controller::filterVelocity(const State & s) noexcept
  {
    if (!has_filter_)
    {
      dq_f_ = s.dq;
      p_f_ = p_;
      has_filter_ = true;
      return;
    }
    const double dt = params_.dt, a = dt / (params_.reaction_params.energy_filter_time + dt);
    for (int i = 0; i < n_; ++i)
    {
      dq_f_[i] += a * (s.dq[i] - dq_f_[i]);
      p_f_[i] += a * (p_[i] - p_f_[i]);
    }
  }

  // ---------------------------------------------------------------------------------- detection -> reaction
  void Controller::startReaction(double t, const State & s) noexcept
  {
    CollisionEvent & e = event_;
    const ReactionParams & rp = params_.reaction_params;
    e.detected = true;
    e.t_detect = t;
    e.joints = over_;
    e.n_joints = 0;
    e.distal_joint = -1;
    for (int i = 0; i < n_; ++i)
      if (over_[i])
      {
        ++e.n_joints;
        e.distal_joint = i;
      }
    e.residual = detectionResidual();
    e.q_detect = s.q;
    e.q_target = s.q;
    e.wrist_force = s.wrench.head<3>().norm();
    // classify: with kappa_ext = 1 the residual already excludes what the wrist sensor measures, so a detection
    // is something the sensor does not see; with kappa_ext = 0 a detection while the sensor measures a force
    // above the contact level is taken as that end-effector contact
    e.contact_class =
      (!kappa_ext_ && e.wrist_force > rp.contact_level) ? ContactClass::Contact : ContactClass::Collision;
    e.reaction = e.contact_class == ContactClass::Contact ? params_.contact_reaction : params_.reaction;
    if (e.contact_class == ContactClass::Contact)
      estimateContact(s); // the sensor's measurement
    else if (has_isolator_ && rp.isolation_delay <= 0.0)
      beginIsolation(t, s, e.residual); // the isolation begins at once (done at once only if it has no work)
    e.energy_detect = kineticEnergy();
    e.energy_max = e.energy_detect;
    double peak = 0.0;
    for (int i = 0; i < n_; ++i)
      peak = std::max(peak, std::abs(e.residual[i]) / threshold_[i]);
    e.peak_residual = peak;
    e.below_since = false;
    t_phase_ = t;
    q_from_ = s.q;
    K_hold_ = K_;
    hold_damping_scale_ = 1.0;
    switch (e.reaction)
    {
    case Reaction::None:
      e.phase = ReactionPhase::None;
      break;
    case Reaction::Gravity:
      e.phase = ReactionPhase::Gravity;
      break;
    case Reaction::Brake:
      e.phase = ReactionPhase::Braking;
      break;
    case Reaction::Retract:
      if (retractWaits()) // brake until the collision is isolated, then retract from the estimate
        e.phase = ReactionPhase::Braking;
      else
      {
        factorRetractMass(s);
        planRetract(s);
        e.phase = ReactionPhase::Retracting;
      }
      break;
    case Reaction::Compliant:
      for (int i = 0; i < n_; ++i)
        e.q_target[i] = std::min(std::max(s.q[i], q_safe_lo_[i]), q_safe_hi_[i]);
      K_hold_ = K_ * rp.compliant_stiffness_factor;
      hold_damping_scale_ = std::sqrt(rp.compliant_stiffness_factor); // D of c K is sqrt(c) D
      e.phase = ReactionPhase::Holding;
      e.t_hold = t;
      kappa_eps_before_reaction_ = kappa_eps_;
      setSwitches(-1, 0, -1);
      break;
    }
    if (e.reaction != Reaction::None)
      reacted_ = true; // latched until reset()
    updateMode();
  }

  // The retract's joint motion dq_plan and its duration. The point that moves and the direction:
  //  * an isolated collision with an estimated point and force: that point along that force (retractFromEstimate);
  //  * a contact the wrist sensor measures (class Contact): the sensor frame, along the measured force f (the
  //    environment's force on the arm): J_s^T f;
  //  * otherwise the link, not the point: the isolated link (without isolation: the most distal link whose joint
  //    crossed its threshold), along the residual r = J_c^T f on the joints up to it (the joints after it carry no
  //    torque of a force on its link); the farthest-moving of its far end and every later point (retractMotion).
  // The joint motion d = M11^-1 J^T f of the joints up to the contact's link (M11 M(q)'s leading block; the later
  // joints stay put): the admittance reflex below. J d = J M11^-1 J^T f / |f| has a positive component along f.
  // Scaled so that the point (the farthest-moving one) moves retract_distance; bounded by max_retract_angle per
  // joint and by the joint limits (minus the reaction's margin); the duration keeps the mean speed of the point at
  // retract_speed and the minimum-jerk path's peak joint speed (1.875 x its mean) below velocity_fraction x the
  // velocity limits.
  // The Jacobians are this tick's (data_c_: computeDynamics' computeCoriolisMatrix at s.q left the joint placements
  // and world Jacobians in it, as computeJointJacobians would). M(q): the factor in llt_r_ (factorRetractMass: by the
  // caller, on this tick, or for a retract that waited for the isolation on the tick its estimate came in).
  void Controller::planRetract(const State & s) noexcept
  {
    const ReactionParams & rp = params_.reaction_params;
    CollisionEvent & e = event_;
    const RetractTarget target = retractDirection(s);
    const int last = target.last;
    // the admittance reflex of the joints up to the contact's link: d = M11^-1 J^T f, the joint velocity the contact
    // force's impulse gives those joints with the later ones held; the contact then moves along J M11^-1 J^T f, with
    // the least kinetic energy among their motions for that displacement. (d = J^T f moved the heavy proximal joints
    // as much as the light distal ones: the UR5-like arm's held-stick retract swung its base at 1.5 rad/s, 1.09 J
    // against 4.3e-5 J at detection. The full M^-1 moved the later joints too, against their own inertia coupling:
    // on Atlas' forearm push the wrist joints by up to 0.5 rad, and the pushed stick's retract kept 70 % of its
    // energy at detection 0.5 s later; 0.015 % with M11.)
    if (llt_r_.info() == Eigen::Success)
    {
      // M's leading (last + 1) block: the joints after the contact's link stay put. M11 = U11^T U11 with U11 the
      // leading block of M's factor U, so the solve needs no factor of its own.
      const auto U = llt_r_.matrixLLT().topLeftCorner(last + 1, last + 1);
      auto head = dq_plan_.head(last + 1);
      U.template triangularView<Eigen::Upper>().transpose().solveInPlace(head);
      U.template triangularView<Eigen::Upper>().solveInPlace(head);
    }
    const double norm = dq_plan_.norm();
    if (norm > 0.0)
      dq_plan_ /= norm;
    const double moved = retractMotion(target); // |J_lin d| [m/rad]
    double scale = moved > 1e-9 ? rp.retract_distance / moved : rp.max_retract_angle;
    const double largest = dq_plan_.cwiseAbs().maxCoeff();
    if (largest * scale > rp.max_retract_angle)
      scale = rp.max_retract_angle / largest;
    dq_plan_ *= scale;
    double duration = std::max(0.1, rp.retract_distance / rp.retract_speed); // [s] (0.1 s the shortest)
    for (int i = 0; i < n_; ++i)
    {
      const double goal = std::min(std::max(s.q[i] + dq_plan_[i], q_safe_lo_[i]), q_safe_hi_[i]);
      dq_plan_[i] = goal - s.q[i];
      if (std::isfinite(v_lim_[i])) // the minimum-jerk path's peak speed is 1.875 x its mean
        duration = std::max(duration, 1.875 * std::abs(dq_plan_[i]) / (rp.velocity_fraction * v_lim_[i]));
    }
    if (duration > rp.max_retract_time) // shorter and slower-bounded: both terms scale with the motion
    {
      dq_plan_ *= rp.max_retract_time / duration;
      duration = rp.max_retract_time;
    }
    e.retract_planned = retractMotion(target); // how far the contact moves [m]
    e.q_target = s.q + dq_plan_;
    retract_time_ = duration;
  }

  // M(q)'s Cholesky factor for the retract's plan: the modal damping's M_ (crba's upper triangle, which LLT<Upper>
  // reads) when it is at most kRetractMassAge accepted ticks old, so that the retract's tick runs no crba: every
  // damping_update_period ticks, 10 by default. The arm is braking or at the detecting tick's speed: at 1 kHz and
  // 2 rad/s it moved < 2e-2 rad since (tests/test_controller_oracle.py: M 28 ticks old at 0.5 rad/s moves the plan's
  // goal by 1.1e-3 rad). Older (a damping_update_period above kRetractMassAge + 1): a crba at s.q of its own, in the
  // modal damping's Data (its result is in M_ already, so its buffers are free and warm). A retract that waited for
  // the isolation factorises on the tick its estimate comes in and is planned on the next (followEvent): the factor
  // costs ~0.1 x a plain tick, the plan ~0.15 x (bench/bench_collision_tick.py).
  void Controller::factorRetractMass(const State & s) noexcept
  {
    if (massAge() <= kRetractMassAge)
    {
      llt_r_.compute(M_);
      return;
    }
    q_buf_ = s.q;
    llt_r_.compute(pinocchio::crba(model_, data_m_, q_buf_));
  }

  // The retract's direction J^T f into dq_plan_, and into J_r_ (from this tick's kinematics in data_c_) the Jacobian
  // its motion is measured with: the translational one of the point it moves when that is known (the estimate's point,
  // the sensor frame), else the link joint's (world-aligned at its origin; the sensor frame's placement updated too).
  Controller::RetractTarget Controller::retractDirection(const State & s) noexcept
  {
    CollisionEvent & e = event_;
    const bool measured = e.contact_class == ContactClass::Contact;
    // the isolated link when isolation ran (it may be more distal than the most distal crossing joint)
    const int isolated = (!measured && e.estimated && e.estimate.link >= 0) ? e.estimate.link : -1;
    // else the most distal joint whose residual at detection is significant (the isolation's first candidate link:
    // a joint below its level still carries the contact's torque), at least the most distal crossing one
    int distal = e.distal_joint;
    if (has_isolator_)
      for (int i = n_ - 1; i > distal; --i)
        if (std::abs(e.residual[i]) > isolator_.significance()[i])
        {
          distal = i;
          break;
        }
    const int last = measured ? n_ - 1 : isolated >= 0 ? isolated : distal < 0 ? n_ - 1 : distal;
    J_r_.setZero();
    dq_plan_.setZero();
    if (retractFromEstimate())
      return {last, true};
    const auto fid = static_cast<pinocchio::FrameIndex>(params_.sensor_frame_id);
    const pinocchio::SE3 & sensor = pinocchio::updateFramePlacement(model_, data_c_, fid);
    if (measured)
    {
      // the sensor measures the wrench on the arm beyond it in its own frame: rotate the force to the world
      pinocchio::getFrameJacobian(model_, data_c_, fid, pinocchio::LOCAL_WORLD_ALIGNED, J_r_);
      const Eigen::Vector3d f = sensor.rotation() * s.wrench.head<3>();
      for (int i = 0; i < n_; ++i)
        dq_plan_[i] = J_r_.col(i).head<3>().dot(f);
      return {last, true};
    }
    // the link, not the point on it: the residual r = J_c^T f on the joints up to it
    pinocchio::getJointJacobian(
      model_, data_c_, static_cast<pinocchio::JointIndex>(last + 1), pinocchio::LOCAL_WORLD_ALIGNED, J_r_);
    for (int i = 0; i <= last; ++i)
      dq_plan_[i] = e.residual[i];
    return {last, false};
  }

  // How far dq_plan_ moves the contact [m]: the known point (J_r_ of retractDirection); without one, the farthest-
  // moving of the link's far end and every point after it (the later joints' origins and the sensor frame). The
  // contact is on that link or, when the isolation erred towards the base (a later link whose joints carry little of
  // the force), on a later one; the link's far end alone can sit near the axis the retract turns about (the UR5-like
  // arm's upper arm stands on its base axis in the held-stick scene: scaled to its elbow, the forearm swept 19 cm).
  // The joints after the link do not move, so every one of those points moves with the link's frame: v + w x (p - o)
  // from the link joint's twist (v, w) at its origin o (J_r_ of retractDirection).
  double Controller::retractMotion(const RetractTarget & target) const noexcept
  {
    const int last = target.last;
    if (target.point_known)
      return pointMotion(last);
    Eigen::Matrix<double, 6, 1> twist = Eigen::Matrix<double, 6, 1>::Zero();
    for (int i = 0; i <= last; ++i)
      twist += J_r_.col(i) * dq_plan_[i];
    const Eigen::Vector3d v = twist.head<3>(), w = twist.tail<3>();
    const Eigen::Vector3d o = data_c_.oMi[static_cast<std::size_t>(last + 1)].translation();
    const Eigen::Vector3d sensor = data_c_.oMf[static_cast<std::size_t>(params_.sensor_frame_id)].translation();
    double moved = (v + w.cross(sensor - o)).norm();
    for (int id = last + 2; id < model_.njoints; ++id) // joint i's origin (Pinocchio's id i + 1) ends link i - 1
      moved = std::max(moved, (v + w.cross(data_c_.oMi[static_cast<std::size_t>(id)].translation() - o)).norm());
    return moved;
  }

  // |J_lin dq_plan| over the joints 0..last (those that move the point) [m]
  double Controller::pointMotion(int last) const noexcept
  {
    double moved = 0.0;
    for (int k = 0; k < 3; ++k)
    {
      double v = 0.0;
      for (int i = 0; i <= last; ++i)
        v += J_r_(k, i) * dq_plan_[i];
      moved += v * v;
    }
    return std::sqrt(moved);
  }

  // The limits every reaction keeps (added to its law, (13) included): a joint outside its range (minus the
  // reaction's margin) is pulled back with the controller's stiffness; a joint faster than its velocity limit is
  // braked in proportion to the excess, with the brake's damping M(q) / brake_time (its row of M dq).
  double Controller::limitTorque(const State & s, int i) const noexcept
  {
    double tau = 0.0;
    if (s.q[i] < q_safe_lo_[i])
      tau += K_[i] * (q_safe_lo_[i] - s.q[i]);
    else if (s.q[i] > q_safe_hi_[i])
      tau += K_[i] * (q_safe_hi_[i] - s.q[i]);
    const double speed = std::abs(s.dq[i]);
    if (speed > v_lim_[i])
      tau -= p_[i] / params_.reaction_params.brake_time * (1.0 - v_lim_[i] / speed);
    return tau;
  }

  // The retract of an isolated collision: the estimated point along the estimated force, d = J_p^T f / |f|
  // (J_p J_p^T f has a positive component along f); the translational Jacobian of the point (world-aligned) is
  // J_v + J_w x (p - o) of its link's joint. False if the estimate gives no point and force.
  bool Controller::retractFromEstimate() noexcept
  {
    const ContactEstimateData & est = event_.estimate;
    if (!event_.estimated || event_.from_sensor || est.link < 0 || !est.has_point || !est.has_force)
      return false;
    const double f_norm = est.force.norm();
    if (!(f_norm > 0.0))
      return false;
    const auto jid = static_cast<pinocchio::JointIndex>(est.link + 1);
    pinocchio::getJointJacobian(model_, data_c_, jid, pinocchio::LOCAL_WORLD_ALIGNED, J_r_); // this tick's (q)
    const Eigen::Vector3d arm = est.point - data_c_.oMi[jid].translation();
    for (int i = 0; i < n_; ++i)
    {
      const Eigen::Vector3d v = J_r_.col(i).head<3>() + J_r_.col(i).tail<3>().cross(arm);
      J_r_.col(i).head<3>() = v;
      dq_plan_[i] = v.dot(est.force) / f_norm;
    }
    return true;
  }

  // ---------------------------------------------------------------------------------- the reaction's law
  bool Controller::reactionLaw(const State & s, int i, double & tau) const noexcept
  {
    if (!reacted_)
      return false;
    const ReactionPhase phase = event_.phase;
    if (phase != ReactionPhase::Braking && phase != ReactionPhase::Retracting && phase != ReactionPhase::Holding)
      return false;
    const Eigen::MatrixXd & C = data_c_.C;
    double c_dq = 0.0;
    for (int j = 0; j < n_; ++j)
      c_dq += C(i, j) * s.dq[j];
    if (phase == ReactionPhase::Braking)
    {
      tau = g_[i] + c_dq - p_[i] / params_.reaction_params.brake_time;
      return true;
    }
    double d_e = 0.0, q_d = event_.q_target[i], ff = 0.0;
    if (phase == ReactionPhase::Retracting) // law (2) along the path of retractReference()
    {
      q_d = qd_r_[i];
      ff = ff_r_[i];
      for (int j = 0; j < n_; ++j)
        d_e += D_(i, j) * (dqd_r_[j] - s.dq[j]);
    }
    else
    {
      for (int j = 0; j < n_; ++j)
        d_e += D_(i, j) * (-s.dq[j]);
      d_e *= hold_damping_scale_;
    }
    tau = K_hold_[i] * (q_d - s.q[i]) + d_e + g_[i] + c_dq + ff
          + static_cast<double>(kappa_f_) * frictionTorque(i, s.dq[i]);
    return true;
  }

  // The retract's reference this tick: the minimum-jerk path q_from + dq_plan s(tau), tau = (t - t0) / T, and the
  // feed-forward M(q_d) ddq_d of law (2)
  void Controller::retractReference() noexcept
  {
    const double tau_s = std::min(std::max((last_t_ - t_phase_) / retract_time_, 0.0), 1.0);
    const double t2 = tau_s * tau_s, t3 = t2 * tau_s, T = retract_time_;
    const double pos = t3 * (10.0 - 15.0 * tau_s + 6.0 * t2);             // s
    const double vel = 30.0 * t2 * (1.0 - 2.0 * tau_s + t2) / T;           // ds/dt [1/s]
    const double acc = 60.0 * tau_s * (1.0 - 3.0 * tau_s + 2.0 * t2) / (T * T); // d2s/dt2 [1/s^2]
    for (int i = 0; i < n_; ++i)
    {
      qd_r_[i] = q_from_[i] + dq_plan_[i] * pos;
      dqd_r_[i] = dq_plan_[i] * vel;
      ddqd_r_[i] = dq_plan_[i] * acc;
    }
    const ConstVectorRef zeros(zeros_);
    ff_r_ = pinocchio::rnea(model0_, data_ff_, ConstVectorRef(qd_r_), zeros, ConstVectorRef(ddqd_r_));
  }

  // ---------------------------------------------------------------------------------- after detection
  void Controller::advanceReaction(double t, const State & s) noexcept
  {
    CollisionEvent & e = event_;
    const ReactionParams & rp = params_.reaction_params;
    bool hold = false;
    if (e.phase == ReactionPhase::Braking && e.reaction == Reaction::Brake && t - t_phase_ >= rp.brake_duration)
    {
      for (int i = 0; i < n_; ++i) // hold where the brake stopped the arm
        e.q_target[i] = std::min(std::max(s.q[i], q_safe_lo_[i]), q_safe_hi_[i]);
      hold = true;
    }
    else if (e.phase == ReactionPhase::Retracting && t - t_phase_ >= retract_time_)
      hold = true; // q_target is the retract's goal
    if (hold)
    {
      e.phase = ReactionPhase::Holding;
      e.t_hold = t;
      t_phase_ = t;
      updateMode();
    }
  }

  void Controller::followEvent(double t, const State & s, int n_over, int n_sat) noexcept
  {
    CollisionEvent & e = event_;
    const ReactionParams & rp = params_.reaction_params;
    bool isolated = false; // the isolation's estimate came in on this tick
    if (e.isolating)
      isolated = stepIsolation(t);
    else if (awaitingIsolation() && t - e.t_detect >= rp.isolation_delay - 1e-12)
      // the residual isolation_delay after detection: grown from the threshold towards the contact's J^T f
      isolated = beginIsolation(t, s, detectionResidual());
    if (isolated)
    {
      // the brake so far; the retract from the estimate: M(q)'s factor now, the plan on the next accepted tick (no
      // tick runs both the estimate's last step and the plan)
      if (reacted_ && e.reaction == Reaction::Retract && rp.retract_waits_for_estimate)
      {
        factorRetractMass(s);
        retract_due_ = true;
      }
    }
    else if (retract_due_) // the retract from the estimate: its plan on this tick's q, M(q)'s factor of the tick before
    {
      retract_due_ = false;
      planRetract(s);
      e.phase = ReactionPhase::Retracting;
      t_phase_ = t;
      q_from_ = s.q;
      updateMode();
    }
    else if (reacted_)
      advanceReaction(t, s);
    const Eigen::VectorXd & r = detectionResidual();
    double peak = e.peak_residual, moved = e.moved;
    for (int i = 0; i < n_; ++i)
    {
      peak = std::max(peak, std::abs(r[i]) / threshold_[i]);
      moved = std::max(moved, std::abs(s.q[i] - e.q_detect[i]));
      if (reacted_ && std::abs(s.dq[i]) > v_lim_[i])
        e.overspeed = true;
    }
    e.peak_residual = peak;
    e.moved = moved;
    bool quiet = true; // hysteresis: a new contact needs the residual below half of every threshold first
    for (int i = 0; i < n_ && quiet; ++i)
      quiet = std::abs(r[i]) < 0.5 * threshold_[i];
    if (quiet)
      e.below_since = true;
    else if (e.below_since && n_over > 0)
    {
      ++e.recrossings; // the residual crossed again after falling below half of every threshold: a new contact
      e.below_since = false;
    }
    if (reacted_ && n_sat > 0 && e.phase != ReactionPhase::Gravity)
      e.torque_limited = true;
    const double energy = kineticEnergy();
    e.energy_max = std::max(e.energy_max, energy);
    if (!e.guard_checked && t - e.t_detect >= rp.rest_time)
    {
      e.guard_checked = true;
      e.energy_rest = energy;
      const double rest_level = std::max(rp.rest_energy_fraction * e.energy_detect, rp.rest_energy_floor);
      if (e.reaction != Reaction::None && energy > rest_level)
      {
        e.still_moving = true;
        std::snprintf(
          e.text.data(), e.text.size(),
          "reaction %s left the arm moving: kinetic energy %.3g J %.3g s after detection (%.3g J at detection; "
          "rest level %.3g J)%s",
          reactionName(e.reaction), energy, t - e.t_detect, e.energy_detect, rest_level,
          e.torque_limited ? "; its torque was saturated" : "");
      }
    }
  }

} // namespace reflexarm
