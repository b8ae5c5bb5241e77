// reflexarm::Controller: the momentum observers (4)-(6) and the residual's detection (12). Two observers share the
// dynamics terms of the tick: the compensation's (gains K_o, its residual feeds (9)-(11) in the law) and, when the
// detector has gains of its own, the detection observer (K_o,det). The detection observer subtracts the law's
// friction (kappa_f) or, with detection_kappa_f, its own (the model's, in a velocity band of its own). Each is
// stepped by explicit Euler over the integrated period or by the exact (zero-order-hold) discretization, stable at
// any gain. With detection_filter_gain the detector's residual goes through a second first-order stage (its exact
// form), which makes it a second-order filter of the external torque.
#include <cmath>

#include "reflexarm/controller.hpp"

namespace reflexarm
{

  void Controller::updateObservers(const State & s, double h) noexcept
  {
    if (!started_)
    {
      startObservers();
      return;
    }
    const Eigen::MatrixXd & C = data_c_.C;
    const bool exact = params_.observer_discretization == ObserverDiscretization::Exact;
    const bool nominal = h == params_.dt; // the decay at the nominal period is computed once in configure()
    for (int i = 0; i < n_; ++i)
    {
      double ct_dq = 0.0; // C^T dq of gamma (5)
      for (int j = 0; j < n_; ++j)
        ct_dq += C(j, i) * s.dq[j];
      double jt_f = 0.0;
      if (kappa_ext_)
        for (int k = 0; k < 6; ++k)
          jt_f += J_(k, i) * s.wrench[k];
      stepObserverJoint(i, s.dq[i], s.tau_m[i] - (g_[i] - ct_dq), jt_f, h, exact, nominal);
    }
  }

  void Controller::startObservers() noexcept
  {
    obs_.integral.setZero();
    obs_.residual.setZero();
    obs_.p0 = p_;
    obs_det_.integral.setZero();
    obs_det_.residual.setZero();
    obs_det_.p0 = p_;
    r_f_.setZero();
    started_ = true;
  }

  void Controller::stepObserverJoint(int i, double dq, double head, double jt, double h, bool exact,
                                     bool nominal) noexcept
  {
    double alpha = static_cast<double>(kappa_f_) * frictionTorque(i, dq); // (6)
    if (kappa_ext_)
      alpha -= jt;
    const double base = head - alpha;
    if (exact)
      stepExact(obs_, i, ko_[i], nominal ? decay_[i] : std::exp(-ko_[i] * h), base, h);
    else
    { // momentum observer (4), explicit Euler over the integrated period
      obs_.integral[i] += h * (base + obs_.residual[i]);
      obs_.residual[i] = ko_[i] * (p_[i] - obs_.p0[i] - obs_.integral[i]);
    }
    if (use_det_)
    {
      double base_det = base;
      if (det_friction_) // detection_kappa_f: the detection observer's own friction model
      {
        double alpha_det = frictionTorque(i, dq, inv_band_det_);
        if (kappa_ext_)
          alpha_det -= jt;
        base_det = head - alpha_det;
      }
      if (exact)
        stepExact(obs_det_, i, ko_det_[i], nominal ? decay_det_[i] : std::exp(-ko_det_[i] * h), base_det, h);
      else
      {
        obs_det_.integral[i] += h * (base_det + obs_det_.residual[i]);
        obs_det_.residual[i] = ko_det_[i] * (p_[i] - obs_det_.p0[i] - obs_det_.integral[i]);
      }
    }
    if (det_stage_) // the second stage, r_f = b r_f + (1 - b) r over the period h (exact at any K_f)
    {
      const double b = nominal ? decay_f_[i] : std::exp(-kf_[i] * h);
      const double r = use_det_ ? obs_det_.residual[i] : obs_.residual[i];
      r_f_[i] = b * r_f_[i] + (1.0 - b) * r;
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
      acc += obs_.integral[i] + obs_.residual[i] + obs_det_.integral[i] + obs_det_.residual[i] + r_f_[i];
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

} // namespace reflexarm
