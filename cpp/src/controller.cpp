// reflexarm::Controller::update: the tick, as the order of its steps, and the steps that carry the tick's own state
// (the dynamics terms, the clock, the commit, the command). The tick is the one of reflexarm.control.Controller.step
// (which delegates to it); tests/test_cpp_core.py checks it against an independent numpy/Pinocchio oracle.
//
// update() = commandFits -> checkPeriod -> checkInputs -> stageGravity -> dampingParts -> computeDynamics
//          -> checkModelTerms -> runDampingParts -> (accepted) commitInputs -> advanceClock -> updateObservers
//          -> detect -> controlLaw -> boundTorque -> commitTick -> react -> writeCommand;
//          any fault on the way -> reject (safe command).
// The steps live by concept: checkInputs, reject in contract.cpp; dampingParts, runDampingParts and the damping's
// commit in damping_schedule.cpp (its math in modal_damping.cpp); updateObservers, detect in observer.cpp;
// rampedEpsWeight, controlLaw, boundTorque in control_law.cpp; what react() runs after a detection in reaction.cpp
// and contact_estimate.cpp; configure, reset, the mode and the switches in configure.cpp.
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
    code = checkModelTerms();
    if (code == FaultCode::None)
      code = runDampingParts(parts);
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
    const bool started = beginEvent(t, s, n_over); // the reaction acts from the detecting tick on
    const double eps_w = rampedEpsWeight();         // after it: a compliant reaction switches kappa_eps off
    code = controlLaw(s, r, eps_w);
    if (code != FaultCode::None)
    {
      obs_invalid_ = true; // a non-finite law latches like an invalid observer: detection is off
      return reject(code, cmd);
    }
    const int n_sat = boundTorque();
    commitTick(eps_w);
    react(t, s, n_over, n_sat, started, cmd);
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

  FaultCode Controller::checkModelTerms() noexcept
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
    return FaultCode::None;
  }

  void Controller::commitInputs(const ConstVectorRef & q, const DampingParts & parts) noexcept
  {
    last_q_ = q;
    has_last_q_ = true;
    commitDamping(parts);
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

  bool Controller::beginEvent(double t, const State & s, int n_over) noexcept
  {
    if (!has_detector_)
      return false;
    filterVelocity(s);
    if (n_over == 0 || detected_)
      return false;
    detected_ = true;
    first_time_ = t;
    first_joints_ = over_;
    startReaction(t, s); // classify, record, choose and start the reaction (latched until reset())
    return true;
  }

  void Controller::react(double t, const State & s, int n_over, int n_sat, bool started, Command & cmd) noexcept
  {
    cmd.n_collided = 0;
    cmd.collided.setZero();
    if (!has_detector_)
      return;
    if (n_over > 0)
    {
      cmd.collided = over_;
      cmd.n_collided = n_over;
    }
    if (detected_ && !started)
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
