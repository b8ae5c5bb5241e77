// reflexarm::Controller's input contract, checked before any state changes (order, bounds and fault codes of
// the contract documented in reflexarm.control.Controller), and the safe command of a rejected tick.
#include "reflexarm/controller.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "pinocchio/algorithm/rnea.hpp"

namespace reflexarm
{

  namespace
  {
    constexpr double kInf = std::numeric_limits<double>::infinity();

    FaultCode checkBox(
      const ConstVectorRef & x, const Eigen::VectorXd & lo, const Eigen::VectorXd & hi, Signal sig,
      FaultInfo & f) noexcept
    {
      for (Eigen::Index i = 0; i < x.size(); ++i)
      {
        const double v = x[i];
        if (!std::isfinite(v))
        {
          f = {sig, static_cast<int>(i), v, lo[i], hi[i]};
          return FaultCode::NonFinite;
        }
        if (v < lo[i] || v > hi[i])
        {
          f = {sig, static_cast<int>(i), v, lo[i], hi[i]};
          return FaultCode::OutOfBounds;
        }
      }
      return FaultCode::None;
    }

    FaultCode
    checkAbs(const ConstVectorRef & x, const Eigen::VectorXd & bound, Signal sig, FaultInfo & f) noexcept
    {
      for (Eigen::Index i = 0; i < x.size(); ++i)
      {
        const double v = x[i];
        if (!std::isfinite(v))
        {
          f = {sig, static_cast<int>(i), v, -bound[i], bound[i]};
          return FaultCode::NonFinite;
        }
        if (v > bound[i] || -v > bound[i])
        {
          f = {sig, static_cast<int>(i), v, -bound[i], bound[i]};
          return FaultCode::OutOfBounds;
        }
      }
      return FaultCode::None;
    }
  } // namespace

  FaultCode Controller::fault(FaultCode code, Signal s, int index, double value, double lo, double hi) noexcept
  {
    fault_ = {s, index, value, lo, hi};
    return code;
  }

  // ------------------------------------------------------------------------------------------ contract
  FaultCode Controller::checkInputs(double t, const State & s, const Reference & r) noexcept
  {
    const Eigen::Index n = n_;
    const struct
    {
      Signal sig;
      Eigen::Index length, want;
    } shapes[] = {
      {Signal::Q, s.q.size(), n},           {Signal::Dq, s.dq.size(), n},
      {Signal::TauM, s.tau_m.size(), n},    {Signal::Wrench, s.wrench.size(), 6},
      {Signal::Gravity, s.gravity.size(), 3}, {Signal::QDesired, r.q_d.size(), n},
      {Signal::DqDesired, r.dq_d.size(), n}, {Signal::DdqDesired, r.ddq_d.size(), n},
    };
    for (const auto & sh : shapes)
      if (sh.length != sh.want)
        return fault(
          FaultCode::BadShape, sh.sig, -1, static_cast<double>(sh.length), static_cast<double>(sh.want),
          static_cast<double>(sh.want));
    if (!std::isfinite(t))
      return fault(FaultCode::NonFinite, Signal::Time, -1, t, -kInf, kInf);
    if (has_t_ && !(t > last_t_))
      return fault(FaultCode::TimeNotIncreasing, Signal::Time, -1, t, last_t_, kInf);
    FaultCode code = checkBox(s.q, q_lo_, q_hi_, Signal::Q, fault_);
    if (code == FaultCode::None)
      code = checkAbs(s.dq, dq_max_, Signal::Dq, fault_);
    if (code == FaultCode::None)
      code = checkAbs(s.tau_m, tau_m_max_, Signal::TauM, fault_);
    if (code != FaultCode::None)
      return code;
    for (int k = 0; k < 6; ++k)
    {
      const double b = k < 3 ? force_max_ : moment_max_;
      const double v = s.wrench[k];
      if (!std::isfinite(v))
        return fault(FaultCode::NonFinite, Signal::Wrench, k, v, -b, b);
      if (v > b || -v > b)
        return fault(FaultCode::OutOfBounds, Signal::Wrench, k, v, -b, b);
    }
    double gn = 0.0;
    for (int k = 0; k < 3; ++k)
    {
      if (!std::isfinite(s.gravity[k]))
        return fault(FaultCode::NonFinite, Signal::Gravity, k, s.gravity[k], -kInf, kInf);
      gn += s.gravity[k] * s.gravity[k];
    }
    gn = std::sqrt(gn);
    const double lo = std::max(g_norm_ - g_tol_, 0.0);
    const double hi = g_norm_ + g_tol_;
    if (gn < lo || gn > hi)
      return fault(FaultCode::OutOfBounds, Signal::Gravity, -1, gn, lo, hi);
    code = checkBox(r.q_d, q_lo_, q_hi_, Signal::QDesired, fault_);
    if (code == FaultCode::None)
      code = checkAbs(r.dq_d, dq_max_, Signal::DqDesired, fault_);
    if (code == FaultCode::None)
      code = checkAbs(r.ddq_d, ddq_max_, Signal::DdqDesired, fault_);
    return code;
  }

  // ------------------------------------------------------------------------------------------ safe command
  FaultCode Controller::reject(FaultCode code, Command & cmd) noexcept
  {
    restoreGravity();
    cmd.fault_code = code;
    cmd.fault = code == FaultCode::ObserverInvalid ? FaultInfo{} : fault_;
    describeFault(code, cmd.fault, cmd.fault_text.data(), cmd.fault_text.size());
    cmd.mode = Mode::Fault;
    cmd.n_collided = 0;
    cmd.collided.setZero();
    cmd.residual = detectionResidual();
    // safe command: gravity compensation at the last accepted position (zero before the first)
    tau_safe_.setZero();
    if (has_last_q_)
    {
      const ConstVectorRef last_q(last_q_);
      tau_safe_ = pinocchio::computeGeneralizedGravity(model_, data_g_, last_q);
      if (has_springs_)
        for (int i = 0; i < n_; ++i)
          tau_safe_[i] = tau_safe_[i] + (last_q_[i] - spring_q_[i]) * spring_k_[i];
      if (!tau_safe_.allFinite())
        tau_safe_.setZero();
    }
    int n_sat = 0;
    for (int i = 0; i < n_; ++i)
    {
      double b = tau_safe_[i];
      if (has_prev_tau_)
        b = std::min(std::max(b, tau_prev_[i] - tau_step_[i]), tau_prev_[i] + tau_step_[i]);
      b = std::min(std::max(b, -tau_max_[i]), tau_max_[i]);
      cmd.saturated[i] = b != tau_safe_[i] ? 1 : 0;
      n_sat += cmd.saturated[i];
      cmd.tau[i] = b;
    }
    cmd.n_saturated = n_sat;
    if (code == FaultCode::BadShape) // a programming error: the Python face raises; nothing is committed
    {
      cmd.collision = has_detector_ && detected_;
      return code;
    }
    tau_prev_ = cmd.tau;
    has_prev_tau_ = true;
    // detection is off (invalid observer, or a non-finite law that latched it): never "no collision"
    const bool detection_off = code == FaultCode::ObserverInvalid || code == FaultCode::OutputNonFinite;
    cmd.collision = detection_off ? true : (has_detector_ && detected_);
    return code;
  }

} // namespace reflexarm
