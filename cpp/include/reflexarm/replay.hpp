// reflexarm::replayLog: a recorded log (t, q, dq, tau_m[, wrench]) through Controller::update in one call.
//
// The residual depends on the measurements only, so the reference handed to the controller is a hold at the
// measured position (q_d = q, dq_d = ddq_d = 0), as reflexarm.tuning.replay_residual does tick by tick from
// Python. Each row is one update() with the period measured from the stamps (period 0), in order: the result
// is the same, bit for bit, as N calls of Controller.step from Python, and the controller is left in the
// state those calls leave it in.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "reflexarm/controller.hpp"

namespace reflexarm
{

  /// A recorded log: row-major arrays of `rows` rows, owned by the caller (alive for the call).
  struct ReplayInputs
  {
    long rows = 0;
    const double * t = nullptr;      ///< N: time stamps [s]
    const double * q = nullptr;      ///< N x n [rad]
    const double * dq = nullptr;     ///< N x n [rad/s]
    const double * tau_m = nullptr;  ///< N x n: measured joint torque [Nm]
    const double * wrench = nullptr; ///< N x 6: wrist wrench [N, Nm], or nullptr: zero
    double gravity[3] = {0.0, 0.0, 0.0}; ///< measured gravity in the base frame [m/s^2], constant
  };

  /// Where the replay writes (row-major, owned by the caller; nullptr: not kept).
  struct ReplayOutputs
  {
    double * residual = nullptr;        ///< N x n: the detector's residual [Nm] (Command.residual)
    double * tau = nullptr;             ///< N x n: the command [Nm] (Command.tau)
    std::uint8_t * over = nullptr;      ///< N x n: 1 where |residual| > threshold on an accepted tick
    std::uint8_t * collision = nullptr; ///< N: Command.collision (the latched detection)
    std::int8_t * mode = nullptr;       ///< N: Command.mode (reflexarm::Mode)
    std::int32_t * status = nullptr;    ///< N: a negative fault code, else n_over + (n_saturated << kReplaySatShift)
  };

  /// update()'s status composition in ReplayOutputs::status (as reflexarm._core.SAT_SHIFT).
  constexpr int kReplaySatShift = 8;

  /// A rejected row: its index and the fault text of the command.
  struct ReplayFault
  {
    long row = 0;
    std::string text;
  };

  /// Runs every row of `in` through `ctrl.update` (command buffer `cmd`, sized by ctrl.initCommand) and writes
  /// the outputs asked for. The texts of the first `max_faults` rejected rows are appended to `faults` (the
  /// only allocation, on rejected rows only). Returns the number of rejected rows. Throws ConfigError for an
  /// unconfigured controller, a command of another size or missing inputs.
  long replayLog(Controller & ctrl, Command & cmd, const ReplayInputs & in, const ReplayOutputs & out,
                 std::vector<ReplayFault> & faults, std::size_t max_faults);

} // namespace reflexarm
