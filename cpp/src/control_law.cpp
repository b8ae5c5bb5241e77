// reflexarm::Controller: the torque of an accepted tick. The joint impedance law (2) with the feed-forward
// M(q_d) ddq_d, the friction compensation (kappa_f) and the disturbance compensation (9)-(11) with its output
// cut-off, ramped over switch_time when kappa_eps flips; while a reaction runs, its law instead (gravity (13) here,
// brake / retract / hold in reaction.cpp). Then the arm's torque limits: the rate limit and the saturation.
#include <algorithm>
#include <cmath>

#include "reflexarm/controller.hpp"

namespace reflexarm
{

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

} // namespace reflexarm
