// reflexarm::Controller::configure (checks the parameters once, params_check.cpp, and sizes every buffer, not
// real-time), reset, the mode logic and the kappa switches.
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "params_check.hpp"
#include "reflexarm/controller.hpp"

namespace reflexarm
{

  namespace
  {
    constexpr double kInf = std::numeric_limits<double>::infinity();
  } // namespace

  void Controller::configure(const Model & model, const ControllerParams & p)
  {
    configured_ = false;
    const ControllerParams q = checkedControllerParams(model, p);
    // ---------------------------------------------------------------- everything checked: allocate
    params_ = q;
    n_ = model.nv;
    setModel(model);
    setJointParams(model, q);
    setInputBounds(model, q);
    setObserverAndReactionBounds(model, q);
    sizeReaction(q);
    sizeBuffers(q);
    configured_ = true;
    reset();
  }

  void Controller::setModel(const Model & model)
  {
    model_ = model;
    model0_ = model;
    model0_.gravity.linear().setZero();
    constructData(data_g_, model_);
    constructData(data_c_, model_);
    constructData(data_j_, model_);
    constructData(data_m_, model_);
    constructData(data_p_, model0_);
    constructData(data_ff_, model0_);
    constructData(data_r_, model_);
  }

  void Controller::setJointParams(const Model & model, const ControllerParams & q)
  {
    const int n = n_;
    const bool use_det = q.detection_observer_gain.size() > 0;
    const bool has_detector = q.threshold.size() > 0;
    const bool has_springs = q.spring_stiffness.size() > 0;
    K_ = q.stiffness;
    xi_ = q.damping_ratio;
    ko_ = q.observer_gain;
    ko_det_ = use_det ? q.detection_observer_gain : Eigen::VectorXd::Zero(n);
    det_stage_ = q.detection_filter_gain.size() > 0;
    kf_ = det_stage_ ? q.detection_filter_gain : Eigen::VectorXd::Zero(n);
    threshold_ = has_detector ? q.threshold : Eigen::VectorXd::Constant(n, kInf);
    has_springs_ = has_springs && (q.spring_stiffness.array() != 0.0).any();
    spring_k_ = has_springs ? q.spring_stiffness : Eigen::VectorXd::Zero(n);
    spring_q_ = has_springs ? q.spring_reference : Eigen::VectorXd::Zero(n);
    coulomb_ = q.friction_coulomb;
    viscous_ = q.friction_viscous;
    use_det_ = use_det;
    has_detector_ = has_detector;
    inv_band_ = 1.0 / q.friction_velocity_band;
    det_friction_ = use_det && q.detection_kappa_f == 1;
    inv_band_det_ = 1.0 / (q.detection_friction_velocity_band > 0.0 ? q.detection_friction_velocity_band
                                                                      : q.friction_velocity_band);
    limit_ = q.residual_limit;
    period_lo_ = q.period_band_low * q.dt;
    period_hi_ = q.period_band_high * q.dt;
    timing_.band_low = period_lo_;
    timing_.band_high = period_hi_;
    gravity_ = model.gravity.linear();
    g_norm_ = gravity_.norm();
    g_tol_ = q.input_bounds.gravity_tolerance;
    force_max_ = q.input_bounds.max_force;
    moment_max_ = q.input_bounds.max_moment;
  }

  void Controller::setInputBounds(const Model & model, const ControllerParams & q)
  {
    const int n = n_;
    const InputBounds & b = q.input_bounds;
    const Eigen::VectorXd & effort = model.upperEffortLimit;
    q_lo_.resize(n);
    q_hi_.resize(n);
    dq_max_.resize(n);
    tau_m_max_.resize(n);
    for (int i = 0; i < n; ++i)
    {
      const double lower = model.lowerPositionLimit[i], upper = model.upperPositionLimit[i];
      q_lo_[i] = std::isfinite(lower) ? lower - b.position_margin : -kInf;
      q_hi_[i] = std::isfinite(upper) ? upper + b.position_margin : kInf;
      const double vel = model.upperVelocityLimit[i];
      dq_max_[i] = (std::isfinite(vel) && vel > 0.0) ? b.velocity_factor * vel : b.max_velocity;
      // tau_m is judged against the saturation, or the model's effort limit when saturation is off
      const double ref = std::isfinite(q.torque_limit[i]) ? q.torque_limit[i] : effort[i];
      tau_m_max_[i] = (std::isfinite(ref) && ref > 0.0) ? b.torque_factor * ref : b.max_torque;
    }
    ddq_max_ = Eigen::VectorXd::Constant(n, b.max_acceleration);
  }

  void Controller::setObserverAndReactionBounds(const Model & model, const ControllerParams & q)
  {
    const int n = n_;
    const ReactionParams & rp = q.reaction_params;
    decay_.resize(n);
    decay_det_.resize(n);
    decay_f_.resize(n);
    v_lim_.resize(n);
    q_safe_lo_.resize(n);
    q_safe_hi_.resize(n);
    for (int i = 0; i < n; ++i)
    {
      decay_[i] = std::exp(-ko_[i] * q.dt);
      decay_det_[i] = std::exp(-ko_det_[i] * q.dt);
      decay_f_[i] = std::exp(-kf_[i] * q.dt);
      const double vel = model.upperVelocityLimit[i];
      v_lim_[i] = (std::isfinite(vel) && vel > 0.0) ? vel : kInf;
      const double lower = model.lowerPositionLimit[i], upper = model.upperPositionLimit[i];
      const double margin = std::isfinite(lower) && std::isfinite(upper)
                              ? std::min(rp.position_margin, 0.25 * (upper - lower))
                              : rp.position_margin;
      q_safe_lo_[i] = std::isfinite(lower) ? lower + margin : -kInf;
      q_safe_hi_[i] = std::isfinite(upper) ? upper - margin : kInf;
    }
  }

  void Controller::sizeReaction(const ControllerParams & q)
  {
    const int n = n_;
    event_.resize(n);
    K_hold_ = K_;
    q_from_.setZero(n);
    dq_plan_.setZero(n);
    qd_r_.setZero(n);
    dqd_r_.setZero(n);
    ddqd_r_.setZero(n);
    ff_r_.setZero(n);
    dq_f_.setZero(n);
    p_f_.setZero(n);
    J_r_.setZero(6, n);
    llt_r_ = definedLlt<RetractLlt>(n);
    t_phase_ = 0.0;
    retract_time_ = 0.1;
    tau_max_ = q.torque_limit;
    tau_step_ = q.torque_rate_limit.size() > 0 ? Eigen::VectorXd(q.torque_rate_limit * q.dt)
                                                : Eigen::VectorXd::Constant(n, kInf);
  }

  void Controller::sizeBuffers(const ControllerParams & q)
  {
    const int n = n_;
    zeros_.setZero(n);
    g_.setZero(n);
    p_.setZero(n);
    ff_.setZero(n);
    tau_new_.setZero(n);
    last_q_.setZero(n);
    tau_prev_.setZero(n);
    tau_safe_.setZero(n);
    q_buf_.setZero(n);
    J_.setZero(6, n);
    M_.setZero(n, n);
    D_.setZero(n, n);
    D_new_.setZero(n, n);
    modal_.resize(n);
    over_.setZero(n);
    sat_.setZero(n);
    first_joints_.setZero(n);
    obs_.resize(n);
    obs_det_.resize(n);
    r_f_.setZero(n);
    gravity_staged_ = false;
    has_last_q_ = false;
    has_prev_tau_ = false;
    kappa_f_ = q.kappa_f;
    kappa_eps_ = q.kappa_eps;
    kappa_ext_ = q.kappa_ext;
    kappa_eps_before_reaction_ = kappa_eps_;
    reacted_ = false;
  }

  // ------------------------------------------------------------------------------------------ reset & mode
  void Controller::reset() noexcept
  {
    if (!configured_)
      return;
    if (reacted_ && event_.reaction == Reaction::Compliant)
      kappa_eps_ = kappa_eps_before_reaction_;
    reacted_ = false;
    retract_due_ = false;
    event_.clear();
    dq_f_.setZero();
    p_f_.setZero();
    has_filter_ = false;
    obs_.integral.setZero();
    obs_.p0.setZero();
    obs_.residual.setZero();
    obs_det_.integral.setZero();
    obs_det_.p0.setZero();
    obs_det_.residual.setZero();
    r_f_.setZero();
    detected_ = false;
    first_time_ = std::numeric_limits<double>::quiet_NaN();
    first_joints_.setZero();
    damping_countdown_ = 0;
    damping_next_part_ = -1;
    damping_full_ = true;
    law_share_ = std::numeric_limits<double>::quiet_NaN();
    modal_.has_basis = false; // the first damping after a reset starts cold, as after configure(): bitwise the same
    started_ = false;
    has_t_ = false;
    last_t_ = 0.0;
    elapsed_ = 0.0;
    obs_invalid_ = false;
    timing_.n_periods = 0;
    timing_.sum_period = 0.0;
    timing_.min_period = 0.0;
    timing_.max_period = 0.0;
    timing_.clipped = 0;
    eps_weight_ = static_cast<double>(kappa_eps_);
    updateMode();
  }

  void Controller::updateMode() noexcept
  {
    gravity_mode_ = reacted_ && event_.reaction == Reaction::Gravity;
    if (gravity_mode_)
      mode_ = Mode::GravityCompensation;
    else if (reacted_ && event_.phase == ReactionPhase::Braking)
      mode_ = Mode::Braking;
    else if (reacted_ && event_.phase == ReactionPhase::Retracting)
      mode_ = Mode::Retracting;
    else if (reacted_ && event_.phase == ReactionPhase::Holding && event_.reaction != Reaction::Compliant)
      mode_ = Mode::Holding;
    else if (!kappa_eps_)
      mode_ = Mode::Compliant;
    else
      mode_ = kappa_ext_ ? Mode::PreciseEeCompliant : Mode::PreciseStiff;
  }

  void Controller::setSwitches(int kappa_f, int kappa_eps, int kappa_ext) noexcept
  {
    if (kappa_f == 0 || kappa_f == 1)
      kappa_f_ = kappa_f;
    if (kappa_eps == 0 || kappa_eps == 1)
    {
      kappa_eps_ = kappa_eps;
      if (params_.switch_time == 0.0)
        eps_weight_ = static_cast<double>(kappa_eps_);
    }
    if (kappa_ext == 0 || kappa_ext == 1)
      kappa_ext_ = kappa_ext;
    updateMode();
  }

  void Controller::setContactGeometry(
    const std::vector<LinkSurfaceData> & surfaces, double significance_share, const IsolationParams & params)
  {
    if (!configured_)
      throw ConfigError("setContactGeometry: configure() the controller first");
    if (!has_detector_)
      throw ConfigError("setContactGeometry: the controller has no detector (threshold) to isolate detections of");
    checkPositive(significance_share, "significance_share");
    if (significance_share > 1.0)
      throw ConfigError("significance_share must be in (0, 1]; got " + std::to_string(significance_share));
    IsolationParams p = params;
    p.significance = threshold_ * significance_share;
    has_isolator_ = false;
    isolator_.configure(model_, surfaces, p); // throws ConfigError on bad surfaces
    has_isolator_ = true;
  }

  void Controller::initCommand(Command & command) const
  {
    command.resize(n_);
    command.fault_text[0] = '\0';
    command.mode = mode_;
  }

  void Controller::restoreGravity() noexcept
  {
    if (gravity_staged_)
    {
      model_.gravity.linear() = gravity_;
      gravity_staged_ = false;
    }
  }

} // namespace reflexarm
