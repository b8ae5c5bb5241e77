// reflexarm::Controller::update and friends. The tick follows reflexarm.control.Controller.step and its
// compiled kernel (reflexarm/control/_kernels.py) statement by statement, so both give the same numbers.
#include "reflexarm/controller.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "pinocchio/algorithm/crba.hpp"
#include "pinocchio/algorithm/frames.hpp"
#include "pinocchio/algorithm/rnea.hpp"

namespace reflexarm
{

  // ------------------------------------------------------------------------------------------ reset & mode
  void Controller::reset() noexcept
  {
    if (!configured_)
      return;
    if (reacted_ && params_.reaction == Reaction::Compliant)
      kappa_eps_ = kappa_eps_before_reaction_;
    reacted_ = false;
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
    started_ = false;
    has_t_ = false;
    last_t_ = 0.0;
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
    gravity_mode_ = reacted_ && params_.reaction == Reaction::Gravity;
    if (gravity_mode_)
      mode_ = Mode::GravityCompensation;
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

  // ------------------------------------------------------------------------------------------ the tick
  FaultCode Controller::update(
    double t, double /*period*/, const State & s, const Reference & r, Command & cmd) noexcept
  {
    if (!configured_ || cmd.tau.size() != n_ || cmd.residual.size() != n_ || cmd.collided.size() != n_
        || cmd.saturated.size() != n_)
    {
      cmd.fault_code = FaultCode::BadShape;
      cmd.mode = Mode::Fault;
      cmd.fault = {Signal::Model, -1, static_cast<double>(cmd.tau.size()), static_cast<double>(n_), static_cast<double>(n_)};
      std::snprintf(
        cmd.fault_text.data(), cmd.fault_text.size(),
        configured_ ? "command not sized for this controller: call initCommand() once"
                    : "controller not configured: call configure() first");
      return FaultCode::BadShape;
    }
    FaultCode code = checkInputs(t, s, r);
    if (code != FaultCode::None)
      return reject(code, cmd);
    const int n = n_;
    // gravity of the measurement (a candidate until the tick is accepted)
    auto gm = model_.gravity.linear(); // a view into the model
    if (s.gravity[0] != gm[0] || s.gravity[1] != gm[1] || s.gravity[2] != gm[2])
    {
      gm = s.gravity;
      gravity_staged_ = true;
    }
    // dynamics terms (argument types as in libpinocchio_default's explicit instantiations: Eigen::Ref vectors,
    // a VectorXd for the frame Jacobian; other types would compile the algorithms in this file again)
    const ConstVectorRef zeros(zeros_);
    g_ = pinocchio::computeGeneralizedGravity(model_, data_g_, s.q);
    if (has_springs_) // joint springs of the robot file: g_hat(q) includes K_s (q - q_s)
      for (int i = 0; i < n; ++i)
        g_[i] = g_[i] + (s.q[i] - spring_q_[i]) * spring_k_[i];
    const Eigen::MatrixXd & C = pinocchio::computeCoriolisMatrix(model_, data_c_, s.q, s.dq);
    p_ = pinocchio::rnea(model0_, data_p_, s.q, zeros, s.dq);     // M(q) dq
    ff_ = pinocchio::rnea(model0_, data_ff_, r.q_d, zeros, r.ddq_d); // M(q_d) ddq_d
    const bool kappa_ext = kappa_ext_ != 0;
    if (kappa_ext)
    {
      q_buf_ = s.q;
      J_.setZero();
      pinocchio::computeFrameJacobian(
        model_, data_j_, q_buf_, static_cast<pinocchio::FrameIndex>(params_.sensor_frame_id), pinocchio::LOCAL, J_);
    }
    double eps_w = eps_weight_;
    if (eps_weight_ != static_cast<double>(kappa_eps_)) // bumpless kappa_eps ramp
    {
      const double inc = params_.dt / params_.switch_time;
      eps_w = kappa_eps_ > eps_weight_ ? std::min(eps_weight_ + inc, 1.0) : std::max(eps_weight_ - inc, 0.0);
    }
    const bool update_damping = damping_countdown_ == 0 && !gravity_mode_;
    if (update_damping)
      M_ = pinocchio::crba(model_, data_m_, s.q); // upper triangle
    // model terms finite
    double acc = 0.0;
    for (int i = 0; i < n; ++i)
    {
      acc += g_[i] + p_[i] + ff_[i];
      for (int j = 0; j < n; ++j)
        acc += C(i, j);
      if (kappa_ext)
        for (int k = 0; k < 6; ++k)
          acc += J_(k, i);
    }
    if (!std::isfinite(acc))
      return reject(fault(FaultCode::ModelNonFinite, Signal::Model, -1, acc, 0.0, 0.0), cmd);
    if (update_damping && !computeModalDamping(M_, K_, xi_, modal_, D_new_))
      return reject(fault(FaultCode::MassNotPositiveDefinite, Signal::Model, -1, 0.0, 0.0, 0.0), cmd);
    // ---------------------------------------------------------------- accepted: commit from here on
    last_q_ = s.q;
    has_last_q_ = true;
    if (update_damping)
      D_ = D_new_;
    double h = params_.dt; // integrated period: measured, clipped to the band
    if (has_t_)
    {
      const double measured = t - last_t_;
      h = std::min(std::max(measured, period_lo_), period_hi_);
      if (timing_.n_periods == 0)
      {
        timing_.min_period = measured;
        timing_.max_period = measured;
      }
      else
      {
        timing_.min_period = std::min(timing_.min_period, measured);
        timing_.max_period = std::max(timing_.max_period, measured);
      }
      timing_.n_periods += 1;
      timing_.sum_period += measured;
      if (h != measured)
        timing_.clipped += 1;
    }
    has_t_ = true;
    last_t_ = t;
    if (obs_invalid_)
      return reject(FaultCode::ObserverInvalid, cmd);
    const bool integrate = started_;
    if (!integrate) // p(0): the integral of (4) starts here
    {
      obs_.integral.setZero();
      obs_.residual.setZero();
      obs_.p0 = p_;
      obs_det_.integral.setZero();
      obs_det_.residual.setZero();
      obs_det_.p0 = p_;
      started_ = true;
    }
    const double kappa_f = static_cast<double>(kappa_f_);
    const double limit = limit_;
    int n_over = 0, n_sat = 0;
    double obs_acc = 0.0;
    for (int i = 0; i < n; ++i)
    {
      double ct_dq = 0.0, c_dq = 0.0; // C^T dq for (5), C dq for (2)
      for (int j = 0; j < n; ++j)
      {
        ct_dq += C(j, i) * s.dq[j];
        c_dq += C(i, j) * s.dq[j];
      }
      double sg = s.dq[i] * inv_band_; // smooth sign of the friction model
      if (sg > 1.0)
        sg = 1.0;
      else if (sg < -1.0)
        sg = -1.0;
      const double tau_f = coulomb_[i] * sg + viscous_[i] * s.dq[i];
      double alpha = kappa_f * tau_f; // (6)
      if (kappa_ext)
      {
        double jt_f = 0.0;
        for (int k = 0; k < 6; ++k)
          jt_f += J_(k, i) * s.wrench[k];
        alpha -= jt_f;
      }
      const double base = s.tau_m[i] - (g_[i] - ct_dq) - alpha;
      if (integrate) // momentum observer (4), explicit Euler over the integrated period
      {
        obs_.integral[i] += h * (base + obs_.residual[i]);
        obs_.residual[i] = ko_[i] * (p_[i] - obs_.p0[i] - obs_.integral[i]);
        if (use_det_)
        {
          obs_det_.integral[i] += h * (base + obs_det_.residual[i]);
          obs_det_.residual[i] = ko_det_[i] * (p_[i] - obs_det_.p0[i] - obs_det_.integral[i]);
        }
      }
      obs_acc += obs_.integral[i] + obs_.residual[i] + obs_det_.integral[i] + obs_det_.residual[i];
      const double r_det = use_det_ ? obs_det_.residual[i] : obs_.residual[i];
      if (r_det > threshold_[i] || -r_det > threshold_[i]) // detection (12)
      {
        over_[i] = 1;
        ++n_over;
      }
      else
        over_[i] = 0;
      double tau;
      if (gravity_mode_) // reaction (13)
        tau = g_[i];
      else // control law (2)
      {
        double d_e = 0.0;
        for (int j = 0; j < n; ++j)
          d_e += D_(i, j) * (r.dq_d[j] - s.dq[j]);
        tau = K_[i] * (r.q_d[i] - s.q[i]) + d_e + g_[i] + c_dq + ff_[i] + kappa_f * tau_f;
        if (eps_w != 0.0)
        {
          double res = obs_.residual[i];
          if (res > limit)
            res = limit;
          else if (res < -limit)
            res = -limit;
          tau -= eps_w * res;
        }
      }
      if (!std::isfinite(tau)) // the observers are part-way updated: they latch as invalid either way
      {
        obs_invalid_ = true;
        if (!std::isfinite(obs_acc))
          return reject(FaultCode::ObserverInvalid, cmd);
        return reject(fault(FaultCode::OutputNonFinite, Signal::Model, i, tau, 0.0, 0.0), cmd);
      }
      std::uint8_t sat = 0; // bounded torque: rate limit, then saturation
      if (has_prev_tau_)
      {
        const double step = tau_step_[i];
        const double prev = tau_prev_[i];
        if (tau > prev + step)
        {
          tau = prev + step;
          sat = 1;
        }
        else if (tau < prev - step)
        {
          tau = prev - step;
          sat = 1;
        }
      }
      const double tmax = tau_max_[i];
      if (tau > tmax)
      {
        tau = tmax;
        sat = 1;
      }
      else if (tau < -tmax)
      {
        tau = -tmax;
        sat = 1;
      }
      sat_[i] = sat;
      n_sat += sat;
      tau_new_[i] = tau;
    }
    if (!std::isfinite(obs_acc))
    {
      obs_invalid_ = true;
      return reject(FaultCode::ObserverInvalid, cmd);
    }
    tau_prev_ = tau_new_;
    has_prev_tau_ = true;
    // commit what the Python step commits for an accepted tick
    gravity_staged_ = false;
    gravity_ = gm;
    eps_weight_ = eps_w;
    if (!gravity_mode_)
      damping_countdown_ = (damping_countdown_ ? damping_countdown_ : params_.damping_update_period) - 1;
    // detection (12) and the latched reaction
    cmd.n_collided = 0;
    cmd.collided.setZero();
    if (has_detector_ && n_over > 0)
    {
      cmd.collided = over_;
      cmd.n_collided = n_over;
      if (!detected_)
      {
        detected_ = true;
        first_time_ = t;
        first_joints_ = over_;
      }
      if (!reacted_ && params_.reaction != Reaction::None)
      {
        reacted_ = true;
        if (params_.reaction == Reaction::Compliant)
        {
          kappa_eps_before_reaction_ = kappa_eps_;
          setSwitches(-1, 0, -1);
        }
        updateMode();
      }
    }
    cmd.tau = tau_prev_;
    cmd.residual = detectionResidual();
    cmd.collision = has_detector_ && detected_;
    if (n_sat > 0)
      cmd.saturated = sat_;
    else
      cmd.saturated.setZero();
    cmd.n_saturated = n_sat;
    cmd.mode = mode_;
    cmd.fault_code = FaultCode::None;
    cmd.fault = FaultInfo{};
    cmd.fault_text[0] = '\0';
    return FaultCode::None;
  }

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
      const auto & g = pinocchio::computeGeneralizedGravity(model_, data_g_, last_q);
      tau_safe_ = g;
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
