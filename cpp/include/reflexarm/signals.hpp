// reflexarm: what crosses the control boundary each tick (State and Reference in, Command out).
#pragma once

#include <array>
#include <cstdint>

#include <Eigen/Core>

#include "reflexarm/fault.hpp"

namespace reflexarm
{

  using ConstVectorRef = Eigen::Ref<const Eigen::VectorXd>;

  /// Measured state of the arm (views: build it each tick from your own buffers, no copy is made).
  ///
  /// q [rad], dq [rad/s], tau_m measured motor torque [Nm] (n each); wrench: load-compensated wrist
  /// wrench (f, m) in the sensor frame [N, Nm] (6); gravity: gravity vector in the base frame [m/s^2] (3).
  struct State
  {
    ConstVectorRef q;
    ConstVectorRef dq;
    ConstVectorRef tau_m;
    ConstVectorRef wrench;
    ConstVectorRef gravity;
  };

  /// Desired joint trajectory sample: q_d [rad], dq_d [rad/s], ddq_d [rad/s^2] (views, n each).
  struct Reference
  {
    ConstVectorRef q_d;
    ConstVectorRef dq_d;
    ConstVectorRef ddq_d;
  };

  /// Control modes (names as reflexarm.control.MODES).
  enum class Mode : int
  {
    Compliant = 0,          ///< kappa_eps = 0: closed loop (3)
    PreciseStiff = 1,       ///< kappa_eps = 1, kappa_ext = 0: closed loop (10)
    PreciseEeCompliant = 2, ///< kappa_eps = kappa_ext = 1: closed loop (11)
    GravityCompensation = 3,///< reaction (13)
    Fault = 4,              ///< unusable input or invalid observer: safe command
    Braking = 5,            ///< reaction "brake": damping injection until the arm rests
    Retracting = 6,         ///< reaction "retract": moving the contact away
    Holding = 7             ///< after brake / retract / compliant: holding a posture (impedance, no compensation)
  };
  constexpr int kModeCount = 8;

  const char * modeName(Mode mode) noexcept;

  /// What Controller::update writes. Size it once with Controller::initCommand (or resize(n)).
  struct Command
  {
    Eigen::VectorXd tau;      ///< commanded torque [Nm], always finite and within the torque limit
    Eigen::VectorXd residual; ///< residual the detector looks at, before the cut-off [Nm]
    bool collision = false;   ///< collision detected (latched until reset); true on an invalid observer
    /// 1 where |residual| exceeded the threshold this tick (accepted ticks only).
    Eigen::Matrix<std::uint8_t, Eigen::Dynamic, 1> collided;
    int n_collided = 0;
    /// 1 where the torque was limited this tick (saturation or rate limit).
    Eigen::Matrix<std::uint8_t, Eigen::Dynamic, 1> saturated;
    int n_saturated = 0;
    Mode mode = Mode::Compliant;
    FaultCode fault_code = FaultCode::None;
    FaultInfo fault;
    std::array<char, 256> fault_text{}; ///< empty string when fault_code is None

    void resize(Eigen::Index n)
    {
      tau.setZero(n);
      residual.setZero(n);
      collided.setZero(n);
      saturated.setZero(n);
    }
  };

} // namespace reflexarm
