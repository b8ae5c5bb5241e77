// reflexarm::replayLog: see replay.hpp.
#include "reflexarm/replay.hpp"

#include <cstring>

namespace reflexarm
{

  long replayLog(Controller & ctrl, Command & cmd, const ReplayInputs & in, const ReplayOutputs & out,
                 std::vector<ReplayFault> & faults, std::size_t max_faults)
  {
    if (!ctrl.isConfigured())
      throw ConfigError("replayLog: the controller is not configured");
    const int n = ctrl.nv();
    if (cmd.tau.size() != n || cmd.residual.size() != n)
      throw ConfigError("replayLog: the command is not sized for this controller (call initCommand)");
    if (in.rows < 0 || (in.rows > 0 && (in.t == nullptr || in.q == nullptr || in.dq == nullptr || in.tau_m == nullptr)))
      throw ConfigError("replayLog: t, q, dq and tau_m are needed");
    using Map = Eigen::Map<const Eigen::VectorXd>;
    const Eigen::VectorXd zeros_n = Eigen::VectorXd::Zero(n), zero_wrench = Eigen::VectorXd::Zero(6);
    const Map gravity(in.gravity, 3);
    long rejected = 0;
    for (long k = 0; k < in.rows; ++k)
    {
      const Map q(in.q + k * n, n), dq(in.dq + k * n, n), tau_m(in.tau_m + k * n, n);
      const Map wrench(in.wrench != nullptr ? in.wrench + 6 * k : zero_wrench.data(), 6);
      const State s{q, dq, tau_m, wrench, gravity};
      const Reference r{q, zeros_n, zeros_n};
      const FaultCode code = ctrl.update(in.t[k], 0.0, s, r, cmd);
      const bool accepted = code == FaultCode::None;
      if (out.residual != nullptr)
        std::memcpy(out.residual + k * n, cmd.residual.data(), sizeof(double) * static_cast<size_t>(n));
      if (out.tau != nullptr)
        std::memcpy(out.tau + k * n, cmd.tau.data(), sizeof(double) * static_cast<size_t>(n));
      if (out.over != nullptr)
      {
        std::uint8_t * o = out.over + k * n;
        for (int i = 0; i < n; ++i)
          o[i] = accepted && cmd.n_collided > 0 ? cmd.collided[i] : 0;
      }
      if (out.collision != nullptr)
        out.collision[k] = cmd.collision ? 1 : 0;
      if (out.mode != nullptr)
        out.mode[k] = static_cast<std::int8_t>(accepted ? static_cast<int>(cmd.mode) : static_cast<int>(Mode::Fault));
      if (out.status != nullptr)
        out.status[k] = accepted ? cmd.n_collided + (cmd.n_saturated << kReplaySatShift) : static_cast<std::int32_t>(code);
      if (!accepted)
      {
        ++rejected;
        if (faults.size() < max_faults)
          faults.push_back(ReplayFault{k, std::string(cmd.fault_text.data())});
      }
    }
    return rejected;
  }

} // namespace reflexarm
