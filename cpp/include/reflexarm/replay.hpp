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

  /// How replayResiduals ran a log.
  struct ResidualReplayRun
  {
    long rejected = 0;          ///< rejected rows, as replayLog's return value
    bool residual_only = false; ///< true: the residual-only path ran the whole log; false: replayLog did
    const char * reason = "";   ///< why replayLog ran instead ("" when residual_only)
  };

  /// The same log as replayLog, for what the detection needs only (residual_replay.cpp): per row the input
  /// contract, the observer(s) and the detection of update(), without the control law, the torque limits, the
  /// modal damping and the inverse dynamics. The dynamics terms (M(q) dq, C(q, dq)^T dq, g(q), J(q)^T F: see
  /// ResidualTerms) depend on the measurements only: they are computed block by block first, on `threads`
  /// threads (1 or 2; each its own pinocchio::Data), then the observers' recursion runs over the block in order.
  /// Its residual, detection flags, mode, faults and the controller's observers and clock equal replayLog's to
  /// rounding (the terms' own, ~1e-14 Nm); out.tau is not written and the status of an accepted row has no
  /// saturation count (no command). The controller's command state (the last command, the modal damping and its
  /// schedule) is not advanced: a controller that goes on to drive an arm needs reset() as after any log.
  /// replayLog runs instead, from the controller's state before the call, when the residual-only path cannot
  /// give the same result: a detection (the reaction that follows it needs the command), a detection or reaction
  /// already latched, or a joint that is not a 1-DoF revolute or prismatic one. Throws ConfigError as replayLog.
  ResidualReplayRun replayResiduals(Controller & ctrl, Command & cmd, const ReplayInputs & in, const ReplayOutputs & out,
                                    std::vector<ReplayFault> & faults, std::size_t max_faults, int threads);

} // namespace reflexarm
