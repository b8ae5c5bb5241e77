// reflexarm::Controller: the modal damping D of (2) scheduled over the ticks. The math (factorize, project, sweep,
// finish, assemble) is modal_damping.cpp's; this file decides which parts a tick runs, runs them on this tick's
// M(q) and puts the new D in use once the last part is done.
//
// The modal damping of a new M(q) is computed in four parts: 0 factorize (crba, M = L L^T, A = L^-1 K L^-T; it
// needs this tick's M(q)), 1 project A on the previous eigenvectors + one Jacobi sweep, 2 one more sweep, 3 the
// sweeps left (usually one or two), the new eigenvectors and D. They are spread over min(4,
// damping_update_period) consecutive accepted ticks (the last one runs all parts left) so that no tick carries
// the whole cost (~2x a plain tick) and most ticks carry none: part 0 on the tick the countdown reaches 0, the
// new D used from the tick of the last part on. The first tick after configure() / reset() runs all parts at
// once (there is no D for this posture yet). In gravity compensation (13) D is not used and nothing is computed.
#include <algorithm>
#include <cmath>

#include "reflexarm/controller.hpp"

namespace reflexarm
{

  namespace
  {
    // The largest omega dt / min(1/xi, 4 xi) over the modes (the Jury bound of the mode sampled with a hold; see
    // reflexarm.control.law_stability), omega^2 = lambda; modes with xi <= 0 not counted.
    double lawShare(const Eigen::VectorXd & lambda, const Eigen::VectorXd & xi, double dt) noexcept
    {
      double share = 0.0;
      for (Eigen::Index i = 0; i < lambda.size(); ++i)
        if (xi[i] > 0.0)
          share = std::max(share, std::sqrt(std::max(lambda[i], 0.0)) * dt / std::min(1.0 / xi[i], 4.0 * xi[i]));
      return share;
    }
  } // namespace

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

  // Before the tick is accepted: its parts work on the candidate D_new_ only (D_ is replaced in commitDamping).
  FaultCode Controller::runDampingParts(const DampingParts & parts) noexcept
  {
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

  // On an accepted tick: which parts ran, where the computation goes on, the new D in use after its last part.
  // (The countdown to the next computation is stepped in commitTick.)
  void Controller::commitDamping(const DampingParts & parts) noexcept
  {
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
      law_share_ = lawShare(modal_.lambda, xi_, params_.dt);
    }
    else if (parts.first >= 0)
      damping_next_part_ = parts.last + 1;
    else if (gravity_mode_)
      damping_next_part_ = -1;
  }

} // namespace reflexarm
