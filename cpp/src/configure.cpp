// reflexarm::Controller::configure (checks the parameters once and sizes every buffer, not real-time), reset,
// the mode logic and the kappa switches.
#include <algorithm>
#include <cmath>
#include <limits>
#include <new>
#include <sstream>

#include "reflexarm/controller.hpp"

namespace reflexarm
{

  namespace
  {
    constexpr double kInf = std::numeric_limits<double>::infinity();

    std::string listOf(const Eigen::VectorXd & v)
    {
      std::ostringstream os;
      os.precision(17);
      os << "[";
      for (Eigen::Index i = 0; i < v.size(); ++i)
        os << (i ? ", " : "") << v[i];
      os << "]";
      return os.str();
    }

    enum class Sign
    {
      Any,
      Positive,
      NonNegative
    };

    /// value broadcast to n (size 1) and checked; allow_inf admits +inf (meaning "no bound").
    Eigen::VectorXd
    asVector(const Eigen::VectorXd & value, int n, const char * name, Sign sign, bool allow_inf = false)
    {
      Eigen::VectorXd out;
      if (value.size() == 1)
        out = Eigen::VectorXd::Constant(n, value[0]);
      else if (value.size() == n)
        out = value;
      else
      {
        std::ostringstream os;
        os << name << " must have " << n << " values (one per joint) or 1; got " << value.size();
        throw ConfigError(os.str());
      }
      for (Eigen::Index i = 0; i < n; ++i)
      {
        const double x = out[i];
        const bool finite_ok = std::isfinite(x) || (allow_inf && x == kInf);
        if (!finite_ok)
          throw ConfigError(std::string(name) + " must be finite; got " + listOf(out));
        if (sign == Sign::Positive && !(x > 0.0))
          throw ConfigError(std::string(name) + " must be positive; got " + listOf(out));
        if (sign == Sign::NonNegative && !(x >= 0.0))
          throw ConfigError(std::string(name) + " must be non-negative; got " + listOf(out));
      }
      return out;
    }

    void checkPositive(double x, const char * name)
    {
      if (!std::isfinite(x) || !(x > 0.0))
      {
        std::ostringstream os;
        os.precision(17);
        os << name << " must be a positive number; got " << x;
        throw ConfigError(os.str());
      }
    }

    int checkSwitch(int value, const char * name)
    {
      if (value != 0 && value != 1)
        throw ConfigError(std::string(name) + " must be 0 or 1; got " + std::to_string(value));
      return value;
    }

    // ------------------------------------------------------------------ configure()'s checks, in their order
    void checkModel(const pinocchio::Model & model)
    {
      if (model.nq != model.nv)
        throw ConfigError(
          "model has nq=" + std::to_string(model.nq) + " != nv=" + std::to_string(model.nv)
          + ": only fixed-base arms with 1-DoF joints are supported");
      if (model.nv == 0)
        throw ConfigError("model has no joints");
    }

    /// dt, the gains and thresholds per joint, the switches, the scalars and the friction and spring terms; q gets
    /// the per-joint values broadcast to n.
    void checkJointParams(const ControllerParams & p, int n, ControllerParams & q)
    {
      checkPositive(p.dt, "dt");
      q.stiffness = asVector(p.stiffness, n, "stiffness", Sign::Positive);
      q.damping_ratio = asVector(p.damping_ratio, n, "damping_ratio", Sign::NonNegative);
      q.observer_gain = asVector(p.observer_gain, n, "observer_gain", Sign::Positive);
      const bool use_det = p.detection_observer_gain.size() > 0;
      if (use_det)
        q.detection_observer_gain =
          asVector(p.detection_observer_gain, n, "detection_observer_gain", Sign::Positive);
      const bool has_detector = p.threshold.size() > 0;
      if (has_detector)
        q.threshold = asVector(p.threshold, n, "threshold", Sign::Positive);
      q.kappa_f = checkSwitch(p.kappa_f, "kappa_f");
      q.kappa_eps = checkSwitch(p.kappa_eps, "kappa_eps");
      q.kappa_ext = checkSwitch(p.kappa_ext, "kappa_ext");
      checkPositive(p.residual_limit, "residual_limit");
      if (!std::isfinite(p.switch_time) || p.switch_time < 0.0)
        throw ConfigError("switch_time must be a non-negative number of seconds; got " + std::to_string(p.switch_time));
      if (p.damping_update_period < 1)
        throw ConfigError(
          "damping_update_period must be a positive integer; got " + std::to_string(p.damping_update_period));
      q.friction_coulomb = asVector(p.friction_coulomb, n, "friction_coulomb", Sign::NonNegative);
      q.friction_viscous = asVector(p.friction_viscous, n, "friction_viscous", Sign::NonNegative);
      checkPositive(p.friction_velocity_band, "friction_velocity_band");
      const bool has_springs = p.spring_stiffness.size() > 0;
      if (has_springs)
      {
        q.spring_stiffness = asVector(p.spring_stiffness, n, "spring_stiffness", Sign::NonNegative);
        q.spring_reference = asVector(p.spring_reference, n, "spring_reference", Sign::Any);
      }
    }

    /// The sensor frame, the input bounds, the reactions and the observer's discretization.
    void checkBoundsAndModes(const pinocchio::Model & model, const ControllerParams & p)
    {
      if (p.sensor_frame_id >= model.frames.size())
        throw ConfigError(
          "sensor_frame_id " + std::to_string(p.sensor_frame_id) + " is not a frame of the model (it has "
          + std::to_string(model.frames.size()) + " frames)");
      const InputBounds & b = p.input_bounds;
      const double bounds[] = {b.position_margin, b.velocity_factor, b.torque_factor,
                               b.max_force,       b.max_moment,      b.gravity_tolerance,
                               b.max_acceleration, b.max_velocity,    b.max_torque};
      const char * bound_names[] = {"position_margin", "velocity_factor",  "torque_factor",
                                    "max_force",       "max_moment",       "gravity_tolerance",
                                    "max_acceleration", "max_velocity",    "max_torque"};
      for (int k = 0; k < 9; ++k)
        checkPositive(bounds[k], (std::string("InputBounds.") + bound_names[k]).c_str());
      for (const Reaction r : {p.reaction, p.contact_reaction})
        if (static_cast<int>(r) < 0 || static_cast<int>(r) >= kReactionCount)
          throw ConfigError(
            "reaction " + std::to_string(static_cast<int>(r))
            + " is not a Reaction (gravity 0, compliant 1, none 2, brake 3, retract 4)");
      const int disc = static_cast<int>(p.observer_discretization);
      if (disc != 0 && disc != 1)
        throw ConfigError(
          "observer_discretization " + std::to_string(disc) + " is not an ObserverDiscretization (euler 0, exact 1)");
    }

    void checkReactionParams(const ReactionParams & rp)
    {
      const double rvals[] = {rp.brake_time,        rp.brake_duration,     rp.retract_distance,
                              rp.max_retract_angle, rp.retract_speed,      rp.max_retract_time, rp.velocity_fraction,
                              rp.compliant_stiffness_factor, rp.rest_time, rp.rest_energy_fraction,
                              rp.rest_energy_floor, rp.energy_filter_time, rp.contact_level};
      const char * rnames[] = {"brake_time",        "brake_duration",       "retract_distance",
                               "max_retract_angle", "retract_speed",        "max_retract_time", "velocity_fraction",
                               "compliant_stiffness_factor", "rest_time",   "rest_energy_fraction",
                               "rest_energy_floor", "energy_filter_time",   "contact_level"};
      for (int k = 0; k < 13; ++k)
        checkPositive(rvals[k], (std::string("ReactionParams.") + rnames[k]).c_str());
      if (!std::isfinite(rp.position_margin) || rp.position_margin < 0.0)
        throw ConfigError("ReactionParams.position_margin must be a non-negative number of radians");
      if (!std::isfinite(rp.isolation_delay) || rp.isolation_delay < 0.0)
        throw ConfigError("ReactionParams.isolation_delay must be a non-negative number of seconds");
      if (rp.isolation_points_per_tick < 1)
        throw ConfigError(
          "ReactionParams.isolation_points_per_tick must be a positive integer; got "
          + std::to_string(rp.isolation_points_per_tick));
    }

    /// The period band, and the observer's stability at the longest integrated period (the exact form is stable at
    /// any gain). q: the gains as checkJointParams broadcast them.
    void checkObserverStability(const ControllerParams & p, const ControllerParams & q)
    {
      const bool exact = p.observer_discretization == ObserverDiscretization::Exact;
      const bool use_det = p.detection_observer_gain.size() > 0;
      const double lo = p.period_band_low, hi = p.period_band_high;
      if (!(0.0 < lo && lo <= 1.0 && 1.0 <= hi && hi < kInf))
        throw ConfigError(
          "period_band must satisfy 0 < low <= 1 <= high < inf; got (" + std::to_string(lo) + ", "
          + std::to_string(hi) + ")");
      double k_o = q.observer_gain.maxCoeff();
      if (use_det)
        k_o = std::max(k_o, q.detection_observer_gain.maxCoeff());
      if (!exact
          && (q.observer_gain.maxCoeff() * p.dt >= 1.0
              || (use_det && q.detection_observer_gain.maxCoeff() * p.dt >= 1.0)))
        throw ConfigError("observer_gain * dt must be < 1 for the discrete observer to be stable");
      if (!exact && k_o * p.dt * hi >= 1.0)
        throw ConfigError(
          "observer_gain * dt * period_band[1] must be < 1 for the observer to stay stable at the longest "
          "integrated period");
    }

    /// The torque limit, given (+inf = none) or the model's effort limits, and the torque rate limit, into q.
    void checkTorqueLimits(const pinocchio::Model & model, const ControllerParams & p, int n, ControllerParams & q)
    {
      const Eigen::VectorXd effort = model.upperEffortLimit;
      if (p.torque_limit.size() == 0)
      {
        q.torque_limit = effort;
        for (int i = 0; i < n; ++i)
          if (!(std::isfinite(effort[i]) && effort[i] > 0.0))
            q.torque_limit[i] = kInf;
      }
      else
        q.torque_limit = asVector(p.torque_limit, n, "torque_limit", Sign::Positive, true);
      if (p.torque_rate_limit.size() > 0)
        q.torque_rate_limit = asVector(p.torque_rate_limit, n, "torque_rate_limit", Sign::Positive);
    }

    /// Every check of configure() in order (throws the first ConfigError); returns p with its per-joint values
    /// broadcast to the model's joints and the torque limit resolved.
    ControllerParams checkedParams(const pinocchio::Model & model, const ControllerParams & p)
    {
      checkModel(model);
      const int n = model.nv;
      ControllerParams q = p;
      checkJointParams(p, n, q);
      checkBoundsAndModes(model, p);
      checkReactionParams(p.reaction_params);
      checkObserverStability(p, q);
      checkTorqueLimits(model, p, n, q);
      return q;
    }

    // ------------------------------------------------------------------ pinocchio::Data without indeterminate enums
    // Pinocchio's Data constructors never compute its two Eigen::LLT members (llt_JMinvJt, osim_llt), and Eigen's
    // LLT leaves m_info indeterminate until compute(): copying such a Data (its copy constructor or assignment, so a
    // Controller's) reads that enum (UBSan -fsanitize=enum: "not a valid value for type 'ComputationInfo'"). A
    // compute() on an empty matrix defines it (Success) without allocating; the LLTs stay 0x0, and every Pinocchio
    // algorithm that uses them (contact dynamics, PV; none of ours) computes them first.
    void defineLlts(pinocchio::Data & data) noexcept
    {
      data.llt_JMinvJt.compute(pinocchio::Data::MatrixXs());
      data.osim_llt.compute(pinocchio::Data::MatrixXs());
    }

    /// data = Data(model) without a copy: destroyed and constructed in place, its LLTs defined. If the constructor
    /// throws, data is left a default Data (so its owner's destructor finds an object) and the exception goes on.
    void constructData(pinocchio::Data & data, const pinocchio::Model & model)
    {
      using Data = pinocchio::Data;
      data.~Data();
      try
      {
        new (&data) Data(model);
      }
      catch (...)
      {
        new (&data) Data();
        defineLlts(data);
        throw;
      }
      defineLlts(data);
    }
  } // namespace

  Controller::Data Controller::definedData()
  {
    Data data;
    defineLlts(data);
    return data;
  }

  void Controller::configure(const Model & model, const ControllerParams & p)
  {
    configured_ = false;
    const ControllerParams q = checkedParams(model, p);
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
    threshold_ = has_detector ? q.threshold : Eigen::VectorXd::Constant(n, kInf);
    has_springs_ = has_springs && (q.spring_stiffness.array() != 0.0).any();
    spring_k_ = has_springs ? q.spring_stiffness : Eigen::VectorXd::Zero(n);
    spring_q_ = has_springs ? q.spring_reference : Eigen::VectorXd::Zero(n);
    coulomb_ = q.friction_coulomb;
    viscous_ = q.friction_viscous;
    use_det_ = use_det;
    has_detector_ = has_detector;
    inv_band_ = 1.0 / q.friction_velocity_band;
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
    v_lim_.resize(n);
    q_safe_lo_.resize(n);
    q_safe_hi_.resize(n);
    for (int i = 0; i < n; ++i)
    {
      decay_[i] = std::exp(-ko_[i] * q.dt);
      decay_det_[i] = std::exp(-ko_det_[i] * q.dt);
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
    detected_ = false;
    first_time_ = std::numeric_limits<double>::quiet_NaN();
    first_joints_.setZero();
    damping_countdown_ = 0;
    damping_next_part_ = -1;
    damping_full_ = true;
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
