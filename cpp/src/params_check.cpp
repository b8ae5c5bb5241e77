// reflexarm::Controller::configure's parameter checks (not real-time): every ConfigError configure() throws, in
// order, and the parameters broadcast to the model's joints. See params_check.hpp.
#include "params_check.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <string>

namespace reflexarm
{

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
      q.detection_kappa_f = checkSwitch(p.detection_kappa_f, "detection_kappa_f");
      if (q.detection_kappa_f && !use_det)
        throw ConfigError("detection_kappa_f = 1 needs a detection observer (detection_observer_gain)");
      if (!std::isfinite(p.detection_friction_velocity_band) || p.detection_friction_velocity_band < 0.0)
        throw ConfigError("detection_friction_velocity_band must be a non-negative number of rad/s (0: "
                          "friction_velocity_band); got "
                          + std::to_string(p.detection_friction_velocity_band));
      if (p.detection_filter_gain.size() > 0)
        q.detection_filter_gain = asVector(p.detection_filter_gain, n, "detection_filter_gain", Sign::Positive);
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
  } // namespace

  /// Every check of configure() in order (throws the first ConfigError); returns p with its per-joint values
  /// broadcast to the model's joints and the torque limit resolved.
  ControllerParams checkedControllerParams(const pinocchio::Model & model, const ControllerParams & p)
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

} // namespace reflexarm
