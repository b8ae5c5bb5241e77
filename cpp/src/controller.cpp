// reflexarm::Controller::update and its steps. The tick is the one of reflexarm.control.Controller.step (which
// delegates to it); tests/test_cpp_core.py checks it against an independent numpy/Pinocchio oracle.
//
// update() = commandFits -> checkPeriod -> checkInputs -> stageGravity -> computeDynamics -> checkModelTerms
//          -> (accepted) commitInputs -> advanceClock -> updateObservers -> detect -> controlLaw
//          -> boundTorque -> commitTick -> react -> writeCommand;  any fault on the way -> reject (safe command).
#include "reflexarm/controller.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "pinocchio/algorithm/crba.hpp"
#include "pinocchio/algorithm/frames.hpp"
#include "pinocchio/algorithm/rnea.hpp"

namespace reflexarm
{

  // ------------------------------------------------------------------------------------------ the tick
  FaultCode Controller::update(
    double t, double period, const State & s, const Reference & r, Command & cmd) noexcept
  {
    damping_updated_ = false;
    damping_parts_run_ = 0;
    if (!commandFits(cmd))
      return notReady(cmd);
    FaultCode code = checkPeriod(period);
    if (code != FaultCode::None)
      return reject(code, cmd);
    if (period > 0.0)
      elapsed_ += period; // time since the last accepted tick, rejected calls included (ros2_control)
    code = checkInputs(t, s, r);
    if (code != FaultCode::None)
      return reject(code, cmd);
    stageGravity(s.gravity);
    const DampingParts parts = dampingParts();
    computeDynamics(s, r, parts.first == 0);
    code = checkModelTerms(parts);
    if (code != FaultCode::None)
      return reject(code, cmd);
    // ---------------------------------------------------------------- accepted: commit from here on
    commitInputs(s.q, parts);
    const double h = advanceClock(t, period);
    if (obs_invalid_)
      return reject(FaultCode::ObserverInvalid, cmd);
    updateObservers(s, h);
    if (!observersFinite())
    {
      obs_invalid_ = true;
      return reject(FaultCode::ObserverInvalid, cmd);
    }
    const int n_over = detect();
    const double eps_w = rampedEpsWeight();
    code = controlLaw(s, r, eps_w);
    if (code != FaultCode::None)
    {
      obs_invalid_ = true; // a non-finite law latches like an invalid observer: detection is off
      return reject(code, cmd);
    }
    const int n_sat = boundTorque();
    commitTick(eps_w);
    react(t, s, n_over, n_sat, cmd);
    writeCommand(n_sat, cmd);
    return FaultCode::None;
  }

  bool Controller::commandFits(const Command & cmd) const noexcept
  {
    return configured_ && cmd.tau.size() == n_ && cmd.residual.size() == n_ && cmd.collided.size() == n_
           && cmd.saturated.size() == n_;
  }

  FaultCode Controller::notReady(Command & cmd) const noexcept
  {
    cmd.fault_code = FaultCode::BadShape;
    cmd.mode = Mode::Fault;
    const double size = static_cast<double>(cmd.tau.size()), n = static_cast<double>(n_);
    cmd.fault = {Signal::Model, -1, size, n, n};
    std::snprintf(
      cmd.fault_text.data(), cmd.fault_text.size(), "%s",
      configured_ ? "command not sized for this controller: call initCommand() once"
                  : "controller not configured: call configure() first");
    return FaultCode::BadShape;
  }

  FaultCode Controller::checkPeriod(double period) noexcept
  {
    constexpr double kInf = std::numeric_limits<double>::infinity();
    if (!std::isfinite(period))
      return fault(FaultCode::NonFinite, Signal::Period, -1, period, 0.0, kInf);
    if (period < 0.0)
      return fault(FaultCode::OutOfBounds, Signal::Period, -1, period, 0.0, kInf);
    return FaultCode::None;
  }

  void Controller::stageGravity(const ConstVectorRef & gravity) noexcept
  {
    auto gm = model_.gravity.linear(); // a view into the model; a candidate until the tick is accepted
    if (gravity[0] != gm[0] || gravity[1] != gm[1] || gravity[2] != gm[2])
    {
      gm = gravity;
      gravity_staged_ = true;
    }
  }

  // argument types as in libpinocchio_default's explicit instantiations (Eigen::Ref vectors, a VectorXd for
  // the frame Jacobian): other types would compile the algorithms in this file again
  void Controller::computeDynamics(const State & s, const Reference & r, bool factorize) noexcept
  {
    const ConstVectorRef zeros(zeros_);
    g_ = pinocchio::computeGeneralizedGravity(model_, data_g_, s.q);
    if (has_springs_) // joint springs of the robot file: g_hat(q) includes K_s (q - q_s)
      for (int i = 0; i < n_; ++i)
        g_[i] = g_[i] + (s.q[i] - spring_q_[i]) * spring_k_[i];
    pinocchio::computeCoriolisMatrix(model_, data_c_, s.q, s.dq);      // C(q, dq) in data_c_.C
    p_ = pinocchio::rnea(model0_, data_p_, s.q, zeros, s.dq);       // M(q) dq
    ff_ = pinocchio::rnea(model0_, data_ff_, r.q_d, zeros, r.ddq_d); // M(q_d) ddq_d
    if (kappa_ext_)
    {
      q_buf_ = s.q;
      J_.setZero();
      pinocchio::computeFrameJacobian(
        model_, data_j_, q_buf_, static_cast<pinocchio::FrameIndex>(params_.sensor_frame_id), pinocchio::LOCAL, J_);
    }
    if (factorize)
      M_ = pinocchio::crba(model_, data_m_, s.q); // upper triangle
  }

  // The modal damping of a new M(q) is computed in four parts: 0 factorize (crba, M = L L^T, A = L^-1 K L^-T; it
  // needs this tick's M(q)), 1 project A on the previous eigenvectors + one Jacobi sweep, 2 one more sweep, 3 the
  // sweeps left (usually one or two), the new eigenvectors and D. They are spread over min(4,
  // damping_update_period) consecutive accepted ticks (the last one runs all parts left) so that no tick carries
  // the whole cost (~2x a plain tick) and most ticks carry none: part 0 on the tick the countdown reaches 0, the
  // new D used from the tick of the last part on. The first tick after configure()
  // / reset() runs all three at once (there is no D for this posture yet). In gravity compensation (13) D is
  // not used and nothing is computed.
  Controller::DampingParts Controller::dampingParts() const noexcept
  {
    DampingParts p;
    if (gravity_mode_)
      return p;
    if (damping_countdown_ == 0) // a new M(q): start (again)
    {
      p.first = 0;
      p.span = damping_full_ ? 1 : std::min(kDampingParts, params_.damping_update_period);
    }
    else if (damping_next_part_ > 0) // a computation under way
    {
      p.first = damping_next_part_;
      p.span = damping_span_;
    }
    else
      return p;
    p.last = p.first == p.span - 1 ? kDampingParts - 1 : p.first;
    return p;
  }

  FaultCode Controller::checkModelTerms(const DampingParts & parts) noexcept
  {
    const Eigen::MatrixXd & C = data_c_.C;
    double acc = 0.0;
    for (int i = 0; i < n_; ++i)
    {
      acc += g_[i] + p_[i] + ff_[i];
      for (int j = 0; j < n_; ++j)
        acc += C(i, j);
      if (kappa_ext_)
        for (int k = 0; k < 6; ++k)
          acc += J_(k, i);
    }
    if (!std::isfinite(acc))
      return fault(FaultCode::ModelNonFinite, Signal::Model, -1, acc, 0.0, 0.0);
    bool ok = true;
    for (int part = parts.first; ok && part >= 0 && part <= parts.last; ++part)
      switch (part)
      {
      case 0:
        ok = modalFactorize(M_, K_, modal_);
        break;
      case 1: // a non-finite W from the previous basis: start cold
        ok = modalProject(modal_);
        if (!ok)
        {
          modal_.has_basis = false;
          ok = modalProject(modal_);
        }
        if (ok)
          modalSweep(modal_, 1);
        break;
      case 2:
        modalSweep(modal_, 1);
        break;
      default: // not converged from the previous basis (never seen): once more, cold
        ok = modalFinish(modal_) || (modalProject(modal_) && modalFinish(modal_));
        if (ok)
          modalAssemble(xi_, modal_, D_new_);
      }
    if (!ok)
    {
      // M(q) of this tick not positive definite (part 0; the next accepted tick tries its own), or, never seen,
      // the rotations of a later part did not converge: start again from the next tick's M(q)
      damping_next_part_ = -1;
      damping_countdown_ = 0;
      return fault(FaultCode::MassNotPositiveDefinite, Signal::Model, -1, 0.0, 0.0, 0.0);
    }
    return FaultCode::None;
  }

  void Controller::commitInputs(const ConstVectorRef & q, const DampingParts & parts) noexcept
  {
    last_q_ = q;
    has_last_q_ = true;
    damping_parts_run_ = 0;
    for (int part = parts.first; part >= 0 && part <= parts.last; ++part)
      damping_parts_run_ |= 1 << part;
    damping_updated_ = parts.last == kDampingParts - 1;
    if (parts.first == 0)
    {
      damping_full_ = false;
      damping_span_ = parts.span;
    }
    if (damping_updated_)
    {
      D_ = D_new_;
      damping_next_part_ = -1;
    }
    else if (parts.first >= 0)
      damping_next_part_ = parts.last + 1;
    else if (gravity_mode_)
      damping_next_part_ = -1;
  }

  double Controller::advanceClock(double t, double period) noexcept
  {
    // the measured period since the last accepted tick: the sum of the `period`s given since then (when the
    // caller gives them, ros2_control), else the difference of the time stamps; integrated clipped to the band
    double h = params_.dt;
    if (has_t_)
    {
      const double measured = period > 0.0 ? elapsed_ : t - last_t_;
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
    elapsed_ = 0.0;
    return h;
  }

  void Controller::updateObservers(const State & s, double h) noexcept
  {
    if (!started_) // p(0): the integral of (4) starts here
    {
      obs_.integral.setZero();
      obs_.residual.setZero();
      obs_.p0 = p_;
      obs_det_.integral.setZero();
      obs_det_.residual.setZero();
      obs_det_.p0 = p_;
      started_ = true;
      return;
    }
    const Eigen::MatrixXd & C = data_c_.C;
    const double kappa_f = static_cast<double>(kappa_f_);
    const bool exact = params_.observer_discretization == ObserverDiscretization::Exact;
    const bool nominal = h == params_.dt; // the decay at the nominal period is computed once in configure()
    for (int i = 0; i < n_; ++i)
    {
      double ct_dq = 0.0; // C^T dq of gamma (5)
      for (int j = 0; j < n_; ++j)
        ct_dq += C(j, i) * s.dq[j];
      double alpha = kappa_f * frictionTorque(i, s.dq[i]); // (6)
      if (kappa_ext_)
      {
        double jt_f = 0.0;
        for (int k = 0; k < 6; ++k)
          jt_f += J_(k, i) * s.wrench[k];
        alpha -= jt_f;
      }
      const double base = s.tau_m[i] - (g_[i] - ct_dq) - alpha;
      if (exact)
      {
        stepExact(obs_, i, ko_[i], nominal ? decay_[i] : std::exp(-ko_[i] * h), base, h);
        if (use_det_)
          stepExact(obs_det_, i, ko_det_[i], nominal ? decay_det_[i] : std::exp(-ko_det_[i] * h), base, h);
        continue;
      }
      // momentum observer (4), explicit Euler over the integrated period
      obs_.integral[i] += h * (base + obs_.residual[i]);
      obs_.residual[i] = ko_[i] * (p_[i] - obs_.p0[i] - obs_.integral[i]);
      if (use_det_)
      {
        obs_det_.integral[i] += h * (base + obs_det_.residual[i]);
        obs_det_.residual[i] = ko_det_[i] * (p_[i] - obs_det_.p0[i] - obs_det_.integral[i]);
      }
    }
  }

  // The observer (4) is the first-order filter dr/dt = K_o (tau_ext - r) of the external torque; over a period h the
  // momentum's increment gives the mean tau_ext = (p_k - p_{k-1}) / h - beta, beta = tau_m - g + C^T dq - alpha, and
  // the filter's exact (zero-order-hold) form is r_k = e^{-K_o h} r_{k-1} + (1 - e^{-K_o h}) tau_ext: stable at any
  // gain. p_{k-1} is not stored: by (4), p_{k-1} = p0 + integral + r_{k-1} / K_o; the integral is kept so that (4)
  // holds after the step (integral = p_k - p0 - r_k / K_o), so both forms share one state.
  void Controller::stepExact(ObserverState & o, int i, double k, double decay, double base, double h) noexcept
  {
    const double p_prev = o.p0[i] + o.integral[i] + o.residual[i] / k;
    const double ext = (p_[i] - p_prev) / h - base;
    o.residual[i] = decay * o.residual[i] + (1.0 - decay) * ext;
    o.integral[i] = p_[i] - o.p0[i] - o.residual[i] / k;
  }

  bool Controller::observersFinite() const noexcept
  {
    double acc = 0.0;
    for (int i = 0; i < n_; ++i)
      acc += obs_.integral[i] + obs_.residual[i] + obs_det_.integral[i] + obs_det_.residual[i];
    return std::isfinite(acc);
  }

  int Controller::detect() noexcept
  {
    const Eigen::VectorXd & r = detectionResidual();
    int n_over = 0;
    for (int i = 0; i < n_; ++i) // (12); thresholds are +inf without a detector
    {
      over_[i] = (r[i] > threshold_[i] || -r[i] > threshold_[i]) ? 1 : 0;
      n_over += over_[i];
    }
    return n_over;
  }

  double Controller::rampedEpsWeight() const noexcept
  {
    if (eps_weight_ == static_cast<double>(kappa_eps_))
      return eps_weight_;
    const double inc = params_.dt / params_.switch_time; // bumpless kappa_eps ramp
    return kappa_eps_ > eps_weight_ ? std::min(eps_weight_ + inc, 1.0) : std::max(eps_weight_ - inc, 0.0);
  }

  FaultCode Controller::controlLaw(const State & s, const Reference & r, double eps_w) noexcept
  {
    const Eigen::MatrixXd & C = data_c_.C;
    const double kappa_f = static_cast<double>(kappa_f_);
    if (reacted_ && event_.phase == ReactionPhase::Retracting)
      retractReference();
    for (int i = 0; i < n_; ++i)
    {
      double tau;
      if (gravity_mode_) // reaction (13), within the joint and velocity limits
        tau = g_[i] + limitTorque(s, i);
      else if (reactionLaw(s, i, tau)) // brake / retract / hold (reaction.cpp), within the limits
        tau += limitTorque(s, i);
      else // control law (2)
      {
        double c_dq = 0.0, d_e = 0.0;
        for (int j = 0; j < n_; ++j)
        {
          c_dq += C(i, j) * s.dq[j];
          d_e += D_(i, j) * (r.dq_d[j] - s.dq[j]);
        }
        tau = K_[i] * (r.q_d[i] - s.q[i]) + d_e + g_[i] + c_dq + ff_[i] + kappa_f * frictionTorque(i, s.dq[i]);
        if (eps_w != 0.0) // disturbance compensation with the output cut-off
          tau -= eps_w * std::min(std::max(obs_.residual[i], -limit_), limit_);
      }
      if (!std::isfinite(tau))
        return fault(FaultCode::OutputNonFinite, Signal::Model, i, tau, 0.0, 0.0);
      tau_new_[i] = tau;
    }
    return FaultCode::None;
  }

  int Controller::boundTorque() noexcept
  {
    int n_sat = 0; // rate limit, then saturation
    for (int i = 0; i < n_; ++i)
    {
      const double want = tau_new_[i];
      double tau = want;
      if (has_prev_tau_)
        tau = std::min(std::max(tau, tau_prev_[i] - tau_step_[i]), tau_prev_[i] + tau_step_[i]);
      tau = std::min(std::max(tau, -tau_max_[i]), tau_max_[i]);
      sat_[i] = tau != want ? 1 : 0;
      n_sat += sat_[i];
      tau_new_[i] = tau;
    }
    return n_sat;
  }

  void Controller::commitTick(double eps_w) noexcept
  {
    tau_prev_ = tau_new_;
    has_prev_tau_ = true;
    gravity_staged_ = false;
    gravity_ = model_.gravity.linear();
    eps_weight_ = eps_w;
    if (!gravity_mode_)
      damping_countdown_ = (damping_countdown_ ? damping_countdown_ : params_.damping_update_period) - 1;
  }

  void Controller::react(double t, const State & s, int n_over, int n_sat, Command & cmd) noexcept
  {
    cmd.n_collided = 0;
    cmd.collided.setZero();
    if (!has_detector_)
      return;
    filterVelocity(s);
    if (n_over > 0)
    {
      cmd.collided = over_;
      cmd.n_collided = n_over;
      if (!detected_)
      {
        detected_ = true;
        first_time_ = t;
        first_joints_ = over_;
        startReaction(t, s); // classify, record, choose and start the reaction (latched until reset())
        return;
      }
    }
    if (detected_)
      followEvent(t, s, n_over, n_sat);
  }

  void Controller::writeCommand(int n_sat, Command & cmd) const noexcept
  {
    cmd.tau = tau_prev_;
    cmd.residual = detectionResidual();
    cmd.collision = has_detector_ && detected_;
    cmd.saturated = sat_;
    cmd.n_saturated = n_sat;
    cmd.mode = mode_;
    cmd.fault_code = FaultCode::None;
    cmd.fault = FaultInfo{};
    cmd.fault_text[0] = '\0';
  }

} // namespace reflexarm
