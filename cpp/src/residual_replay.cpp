// reflexarm::replayResiduals: a recorded log through update()'s input contract, observers and detection only (see
// replay.hpp). Per block of rows: the dynamics terms of every row (ResidualTerms, on one or two threads), then the
// rows in order through the steps of update() that the residual depends on, run by the controller's own members:
//
//   checkInputs -> stageGravity -> (the terms' finiteness, as checkModelTerms) -> commitInputs' last q -> advanceClock
//   -> the observers (updateObservers' loop on the precomputed terms) -> observersFinite -> detect;
//   any fault on the way -> reject (the safe command, as update()).
//
// Left out, as they never change the residual: the modal damping (computeDynamics' crba and its parts), the
// feed-forward M(q_d) ddq_d (zero for the hold), the control law and the torque limits, react() (without a
// detection it only low-passes dq for the reaction's energy guard, done here too). A detection hands the whole log
// to replayLog from the state before the call: the reaction it starts needs the command.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <optional>
#include <thread>

#include "reflexarm/replay.hpp"
#include "reflexarm/residual_terms.hpp"

namespace reflexarm
{

  /// Rows whose terms are computed before the observers run over them (4 n doubles each).
  constexpr long kResidualBlock = 8192;
  /// The main thread's share of a block's terms on two threads: it also runs the observers, measured at ~0.75 of the
  /// terms' cost per row on the Atlas arm (terms 0.54 us, the rest 0.4 us): (1 - 0.75) / 2 ~ 1/8 balances the two.
  constexpr double kMainShare = 1.0 / 8.0;

  /// Joins a thread when it goes out of scope.
  struct Joined
  {
    std::thread & thread;
    ~Joined() { thread.join(); }
  };

  struct ResidualReplay
  {
    /// The terms of rows [first, last) of `in` into terms (4 n doubles a row, from row `first`).
    static void computeTerms(ResidualTerms & rt, const ReplayInputs & in, int n, long first, long last, double * terms)
    {
      for (long k = first; k < last; ++k)
        rt.compute(in.q + k * n, in.dq + k * n, in.wrench != nullptr ? in.wrench + 6 * k : nullptr,
                   terms + (k - first) * 4 * n);
    }

    /// updateObservers' loop with C^T dq and J^T F given (p_ and g_ hold the row's p and g).
    static void stepObservers(Controller & c, const State & s, const double * ct, const double * jt, double h)
    {
      if (!c.started_)
      {
        c.startObservers();
        return;
      }
      const bool exact = c.params_.observer_discretization == ObserverDiscretization::Exact;
      const bool nominal = h == c.params_.dt;
      for (int i = 0; i < c.n_; ++i)
        c.stepObserverJoint(i, s.dq[i], s.tau_m[i] - (c.g_[i] - ct[i]), jt[i], h, exact, nominal);
    }

    /// One row (terms: its 4 n doubles). Returns the fault code; sets `detected` on a detection (nothing written).
    static FaultCode row(Controller & c, Command & cmd, const State & s, const Reference & r, double t,
                         const double * terms, bool & detected)
    {
      const int n = c.n_;
      c.damping_updated_ = false;
      c.damping_parts_run_ = 0;
      FaultCode code = c.checkInputs(t, s, r);
      if (code != FaultCode::None)
        return c.reject(code, cmd);
      c.stageGravity(s.gravity);
      const double *ct = terms + n, *jt = terms + 3 * n;
      double acc = 0.0; // checkModelTerms on the terms the observer uses
      for (int i = 0; i < n; ++i)
      {
        c.p_[i] = terms[i];
        c.g_[i] = terms[2 * n + i];
        if (c.has_springs_)
          c.g_[i] = c.g_[i] + (s.q[i] - c.spring_q_[i]) * c.spring_k_[i];
        acc += c.g_[i] + c.p_[i] + ct[i];
        if (c.kappa_ext_)
          acc += jt[i];
      }
      if (!std::isfinite(acc))
        return c.reject(c.fault(FaultCode::ModelNonFinite, Signal::Model, -1, acc, 0.0, 0.0), cmd);
      // accepted: commit from here on
      c.last_q_ = s.q;
      c.has_last_q_ = true;
      const double h = c.advanceClock(t, 0.0);
      if (c.obs_invalid_)
        return c.reject(FaultCode::ObserverInvalid, cmd);
      stepObservers(c, s, ct, jt, h);
      if (!c.observersFinite())
      {
        c.obs_invalid_ = true;
        return c.reject(FaultCode::ObserverInvalid, cmd);
      }
      if (c.detect() > 0 && c.has_detector_)
      {
        detected = true;
        return FaultCode::None;
      }
      c.eps_weight_ = c.rampedEpsWeight();
      c.gravity_staged_ = false;
      c.gravity_ = c.model_.gravity.linear();
      if (c.has_detector_)
        c.filterVelocity(s);
      return FaultCode::None;
    }

    static const char * unsupported(const Controller & c, const ReplayOutputs & out)
    {
      if (out.tau != nullptr)
        return "the commanded torque is asked for";
      if (c.detected_ || c.reacted_)
        return "a detection is latched in the controller";
      if (!ResidualTerms::supports(c.model_))
        return "a joint is not a 1-DoF revolute or prismatic joint";
      return nullptr;
    }

    /// Rows [first, last) through the observers in order (terms: theirs, from row first). False on a detection.
    static bool rows(Controller & c, Command & cmd, const ReplayInputs & in, const ReplayOutputs & out, long first,
                     long last, const double * terms, std::vector<ReplayFault> & faults, std::size_t max_faults,
                     long & rejected)
    {
      using Map = Eigen::Map<const Eigen::VectorXd>;
      const int n = c.n_;
      const Eigen::VectorXd & zeros_n = c.zeros_;
      const Eigen::Matrix<double, 6, 1> zero_wrench = Eigen::Matrix<double, 6, 1>::Zero();
      const Map gravity(in.gravity, 3);
      for (long k = first; k < last; ++k)
      {
        const Map q(in.q + k * n, n), dq(in.dq + k * n, n), tau_m(in.tau_m + k * n, n);
        const Map wrench(in.wrench != nullptr ? in.wrench + 6 * k : zero_wrench.data(), 6);
        const State s{q, dq, tau_m, wrench, gravity};
        const Reference r{q, zeros_n, zeros_n};
        bool detected = false;
        const FaultCode code = row(c, cmd, s, r, in.t[k], terms + (k - first) * 4 * n, detected);
        if (detected)
          return false;
        const bool accepted = code == FaultCode::None;
        const Eigen::VectorXd & residual = accepted ? c.detectionResidual() : cmd.residual;
        if (out.residual != nullptr)
          std::memcpy(out.residual + k * n, residual.data(), sizeof(double) * static_cast<size_t>(n));
        if (out.over != nullptr)
          std::memset(out.over + k * n, 0, static_cast<size_t>(n)); // no joint over: else a detection above
        if (out.collision != nullptr)
          out.collision[k] = accepted ? 0 : (cmd.collision ? 1 : 0);
        if (out.mode != nullptr)
          out.mode[k] = static_cast<std::int8_t>(accepted ? static_cast<int>(c.mode_) : static_cast<int>(Mode::Fault));
        if (out.status != nullptr)
          out.status[k] = accepted ? 0 : static_cast<std::int32_t>(code);
        if (!accepted)
        {
          ++rejected;
          if (faults.size() < max_faults)
            faults.push_back(ReplayFault{k, std::string(cmd.fault_text.data())});
        }
      }
      return true;
    }

    /// The whole log; false (the controller then half-way) on a detection. On two threads the blocks are a
    /// pipeline: while the main thread runs block b's observers and the first kMainShare of block b+1's terms,
    /// the helper computes the rest of block b+1's terms.
    static bool run(Controller & c, Command & cmd, const ReplayInputs & in, const ReplayOutputs & out,
                    std::vector<ReplayFault> & faults, std::size_t max_faults, int threads, long & rejected)
    {
      const int n = c.n_;
      pinocchio::Model model = c.model_; // the terms' gravity is the log's (as stageGravity makes it)
      model.gravity.linear() = Eigen::Map<const Eigen::Vector3d>(in.gravity);
      const bool efc = c.kappa_ext_ != 0 && in.wrench != nullptr;
      ResidualTerms main_terms(model, c.params_.sensor_frame_id, efc);
      std::optional<ResidualTerms> other_terms;
      if (threads > 1)
        other_terms.emplace(model, c.params_.sensor_frame_id, efc);
      const long block = std::min(in.rows, kResidualBlock);
      std::vector<double> buffers[2];
      for (auto & b : buffers)
        b.resize(static_cast<std::size_t>(block * 4 * n));
      rejected = 0;
      computeTerms(main_terms, in, n, 0, block, buffers[0].data());
      for (long first = 0, b = 0; first < in.rows; first += block, b ^= 1)
      {
        const long last = std::min(first + block, in.rows), next_last = std::min(last + block, in.rows);
        double * next = buffers[b ^ 1].data();
        bool whole = true;
        if (other_terms && next_last > last)
        {
          const long split = last + static_cast<long>(kMainShare * static_cast<double>(next_last - last));
          std::thread helper(computeTerms, std::ref(*other_terms), std::cref(in), n, split, next_last,
                             next + (split - last) * 4 * n);
          const Joined joined{helper}; // also when a fault text's allocation throws
          computeTerms(main_terms, in, n, last, split, next);
          whole = rows(c, cmd, in, out, first, last, buffers[b].data(), faults, max_faults, rejected);
        }
        else
        {
          whole = rows(c, cmd, in, out, first, last, buffers[b].data(), faults, max_faults, rejected);
          if (whole && next_last > last)
            computeTerms(main_terms, in, n, last, next_last, next);
        }
        if (!whole)
          return false;
      }
      return true;
    }
  };

  ResidualReplayRun replayResiduals(Controller & ctrl, Command & cmd, const ReplayInputs & in, const ReplayOutputs & out,
                                    std::vector<ReplayFault> & faults, std::size_t max_faults, int threads)
  {
    if (!ctrl.isConfigured())
      throw ConfigError("replayResiduals: the controller is not configured");
    const int n = ctrl.nv();
    if (cmd.tau.size() != n || cmd.residual.size() != n)
      throw ConfigError("replayResiduals: the command is not sized for this controller (call initCommand)");
    if (in.rows < 0 || (in.rows > 0 && (in.t == nullptr || in.q == nullptr || in.dq == nullptr || in.tau_m == nullptr)))
      throw ConfigError("replayResiduals: t, q, dq and tau_m are needed");
    if (threads < 1 || threads > 2)
      throw ConfigError("replayResiduals: threads must be 1 or 2; got " + std::to_string(threads));
    ResidualReplayRun result;
    result.reason = ResidualReplay::unsupported(ctrl, out);
    if (result.reason == nullptr)
    {
      // a detection needs the log from the start on the full path: keep the state to start it from (a detector
      // only; without one there is no detection)
      std::optional<Controller> before;
      std::optional<Command> cmd_before;
      if (ctrl.hasDetector())
      {
        before.emplace(ctrl);
        cmd_before.emplace(cmd);
      }
      const std::size_t n_faults = faults.size();
      if (ResidualReplay::run(ctrl, cmd, in, out, faults, max_faults, threads, result.rejected))
      {
        result.residual_only = true;
        result.reason = "";
        return result;
      }
      ctrl = *before;
      cmd = *cmd_before;
      faults.resize(n_faults);
      result.reason = "a detection (the reaction it starts needs the command)";
    }
    result.rejected = replayLog(ctrl, cmd, in, out, faults, max_faults);
    return result;
  }

} // namespace reflexarm
