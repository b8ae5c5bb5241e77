// reflexarm: fault codes of the input contract and their texts.
//
// Codes and signal ids are those of reflexarm.control.contract (FAULT_CODES, SIG_*); the Python Controller
// reports the texts written here.
#pragma once

#include <cstddef>

namespace reflexarm
{

  /// Result of Controller::update: None (0) for an accepted tick, a negative code for a fault.
  enum class FaultCode : int
  {
    None = 0,
    BadShape = -1,                ///< a signal has the wrong length (a programming error)
    NonFinite = -2,               ///< signal[index] = value is NaN/inf
    OutOfBounds = -3,             ///< signal[index] = value outside [lo, hi]
    TimeNotIncreasing = -4,       ///< time = value <= last accepted time = lo
    ModelNonFinite = -5,          ///< a dynamics term of the model is NaN/inf
    MassNotPositiveDefinite = -6, ///< the damping update's Cholesky factorization failed
    ObserverInvalid = -7,         ///< latched until reset(): detection is off
    OutputNonFinite = -8          ///< the control law gave NaN/inf (never expected); latches as -7
  };

  /// The signal a fault is about (ids as in the Python kernel).
  enum class Signal : int
  {
    Time = 0,
    Q = 1,
    Dq = 2,
    TauM = 3,
    Wrench = 4,
    Gravity = 5,
    QDesired = 6,
    DqDesired = 7,
    DdqDesired = 8,
    Model = 9,
    Period = 10 ///< the `period` argument of Controller::update
  };

  /// Details of a fault: which signal and component (-1: the whole signal), the value and the bound.
  struct FaultInfo
  {
    Signal signal = Signal::Time;
    int index = -1;
    double value = 0.0;
    double lo = 0.0;
    double hi = 0.0;
  };

  /// Short meaning of a code (reflexarm.control.contract.FAULT_CODES).
  const char * faultCodeName(FaultCode code) noexcept;

  /// Name of a signal as in the fault texts ("measurement q", "reference q_d", ...).
  const char * signalName(Signal signal) noexcept;

  /// Writes the human-readable fault text (same text as reflexarm.control.contract.describe_fault) into
  /// buf (always NUL-terminated, truncated to size). No allocation. Returns the number of characters.
  std::size_t describeFault(FaultCode code, const FaultInfo & info, char * buf, std::size_t size) noexcept;

  /// Python's repr() of a float ("0.1", "100.0", "1e-05", "inf", "nan") into buf; no allocation.
  std::size_t formatRepr(double value, char * buf, std::size_t size) noexcept;

} // namespace reflexarm
