#include "reflexarm/fault.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include "reflexarm/collision_event.hpp"
#include "reflexarm/params.hpp"
#include "reflexarm/signals.hpp"

namespace reflexarm
{

  const char * reactionName(Reaction r) noexcept
  {
    switch (r)
    {
    case Reaction::Gravity:
      return "gravity";
    case Reaction::Compliant:
      return "compliant";
    case Reaction::None:
      return "none";
    case Reaction::Brake:
      return "brake";
    case Reaction::Retract:
      return "retract";
    }
    return "?";
  }

  const char * contactClassName(ContactClass c) noexcept
  {
    switch (c)
    {
    case ContactClass::None:
      return "none";
    case ContactClass::Contact:
      return "contact";
    case ContactClass::Collision:
      return "collision";
    }
    return "?";
  }

  const char * reactionPhaseName(ReactionPhase p) noexcept
  {
    switch (p)
    {
    case ReactionPhase::None:
      return "none";
    case ReactionPhase::Gravity:
      return "gravity";
    case ReactionPhase::Braking:
      return "braking";
    case ReactionPhase::Retracting:
      return "retracting";
    case ReactionPhase::Holding:
      return "holding";
    }
    return "?";
  }

  const char * modeName(Mode mode) noexcept
  {
    switch (mode)
    {
    case Mode::Compliant:
      return "compliant";
    case Mode::PreciseStiff:
      return "precise_stiff";
    case Mode::PreciseEeCompliant:
      return "precise_ee_compliant";
    case Mode::GravityCompensation:
      return "gravity_compensation";
    case Mode::Fault:
      return "fault";
    case Mode::Braking:
      return "braking";
    case Mode::Retracting:
      return "retracting";
    case Mode::Holding:
      return "holding";
    }
    return "?";
  }

  const char * faultCodeName(FaultCode code) noexcept
  {
    switch (code)
    {
    case FaultCode::None:
      return "none";
    case FaultCode::BadShape:
      return "signal of the wrong shape";
    case FaultCode::NonFinite:
      return "non-finite signal";
    case FaultCode::OutOfBounds:
      return "signal beyond its plausibility bound";
    case FaultCode::TimeNotIncreasing:
      return "time stamp repeated or going backwards";
    case FaultCode::ModelNonFinite:
      return "non-finite dynamics terms of the model";
    case FaultCode::MassNotPositiveDefinite:
      return "mass matrix not positive definite";
    case FaultCode::ObserverInvalid:
      return "observer state invalid (latched until reset)";
    case FaultCode::OutputNonFinite:
      return "non-finite control law (latched until reset, as an invalid observer)";
    }
    return "?";
  }

  const char * signalName(Signal signal) noexcept
  {
    switch (signal)
    {
    case Signal::Time:
      return "measurement t";
    case Signal::Q:
      return "measurement q";
    case Signal::Dq:
      return "measurement dq";
    case Signal::TauM:
      return "measurement tau_m";
    case Signal::Wrench:
      return "measurement wrench";
    case Signal::Gravity:
      return "measurement gravity";
    case Signal::QDesired:
      return "reference q_d";
    case Signal::DqDesired:
      return "reference dq_d";
    case Signal::DdqDesired:
      return "reference ddq_d";
    case Signal::Model:
      return "model";
    case Signal::Period:
      return "update period";
    }
    return "input";
  }

  namespace
  {
    const char * signalUnit(Signal signal) noexcept
    {
      switch (signal)
      {
      case Signal::Time:
      case Signal::Period:
        return "s";
      case Signal::Q:
      case Signal::QDesired:
        return "rad";
      case Signal::Dq:
      case Signal::DqDesired:
        return "rad/s";
      case Signal::TauM:
        return "Nm";
      case Signal::Wrench:
        return "N or Nm";
      case Signal::Gravity:
        return "m/s^2";
      case Signal::DdqDesired:
        return "rad/s^2";
      case Signal::Model:
        return "";
      }
      return "";
    }

    // which InputBounds field sets the bound of each signal (named in the fault text)
    const char * boundName(Signal signal) noexcept
    {
      switch (signal)
      {
      case Signal::Q:
      case Signal::QDesired:
        return "joint limits +- InputBounds.position_margin";
      case Signal::Dq:
      case Signal::DqDesired:
        return "InputBounds.velocity_factor x velocity limit";
      case Signal::TauM:
        return "InputBounds.torque_factor x torque limit";
      case Signal::DdqDesired:
        return "InputBounds.max_acceleration";
      case Signal::Gravity:
        return "model gravity +- InputBounds.gravity_tolerance";
      case Signal::Period:
        return "a period >= 0; 0: measured from the time stamps";
      default:
        return "bound";
      }
    }

    // Python's format(value, ".6g")
    void formatG6(double value, char * buf, std::size_t size) noexcept
    {
      if (std::isnan(value))
        std::snprintf(buf, size, "nan");
      else
        std::snprintf(buf, size, "%.6g", value);
    }
  } // namespace

  std::size_t formatRepr(double value, char * buf, std::size_t size) noexcept
  {
    if (size == 0)
      return 0;
    if (std::isnan(value))
      return static_cast<std::size_t>(std::snprintf(buf, size, "nan"));
    if (std::isinf(value))
      return static_cast<std::size_t>(std::snprintf(buf, size, value > 0 ? "inf" : "-inf"));
    char sci[64];
    auto res = std::to_chars(sci, sci + sizeof(sci) - 1, value, std::chars_format::scientific);
    *res.ptr = '\0';
    // sci = [-]d[.ddd]e(+|-)XX: shortest round-trip digits and the decimal exponent
    const char * p = sci;
    bool negative = false;
    if (*p == '-')
    {
      negative = true;
      ++p;
    }
    char digits[32];
    std::size_t nd = 0;
    for (; *p != 'e' && *p != '\0'; ++p)
      if (*p != '.' && nd < sizeof(digits))
        digits[nd++] = *p;
    const int exponent = (*p == 'e') ? std::atoi(p + 1) : 0;
    const int decpt = exponent + 1; // value = 0.d1d2... x 10^decpt
    if (decpt <= -4 || decpt > 16)  // Python's repr switches to the exponent form here
      return static_cast<std::size_t>(std::snprintf(buf, size, "%s", sci));
    char out[64];
    std::size_t k = 0;
    if (negative)
      out[k++] = '-';
    if (decpt <= 0)
    {
      out[k++] = '0';
      out[k++] = '.';
      for (int i = 0; i < -decpt; ++i)
        out[k++] = '0';
      for (std::size_t i = 0; i < nd; ++i)
        out[k++] = digits[i];
    }
    else
    {
      for (int i = 0; i < decpt; ++i)
        out[k++] = static_cast<std::size_t>(i) < nd ? digits[i] : '0';
      out[k++] = '.';
      if (static_cast<std::size_t>(decpt) < nd)
        for (std::size_t i = static_cast<std::size_t>(decpt); i < nd; ++i)
          out[k++] = digits[i];
      else
        out[k++] = '0';
    }
    out[k] = '\0';
    return static_cast<std::size_t>(std::snprintf(buf, size, "%s", out));
  }

  std::size_t describeFault(FaultCode code, const FaultInfo & info, char * buf, std::size_t size) noexcept
  {
    if (size == 0)
      return 0;
    const char * name = signalName(info.signal);
    char where[64];
    if (info.index >= 0)
      std::snprintf(where, sizeof(where), "%s[%d]", name, info.index);
    else
      std::snprintf(where, sizeof(where), "%s", name);
    char v[48], lo[48], hi[48];
    int written = 0;
    switch (code)
    {
    case FaultCode::None:
      buf[0] = '\0';
      return 0;
    case FaultCode::BadShape:
      written = std::snprintf(
        buf, size, "%s must be a real vector of shape (%d,); got shape (%d,)", name, static_cast<int>(info.hi),
        static_cast<int>(info.value));
      break;
    case FaultCode::NonFinite:
      formatRepr(info.value, v, sizeof(v));
      written = std::snprintf(buf, size, "non-finite %s = %s", where, v);
      break;
    case FaultCode::OutOfBounds:
    {
      const char * unit = signalUnit(info.signal);
      const char * bound = boundName(info.signal);
      if (info.signal == Signal::Wrench)
      {
        bound = info.index < 3 ? "InputBounds.max_force" : "InputBounds.max_moment";
        unit = info.index < 3 ? "N" : "Nm";
      }
      else if (info.signal == Signal::Gravity)
        std::snprintf(where, sizeof(where), "|%s|", name);
      formatG6(info.value, v, sizeof(v));
      formatG6(info.lo, lo, sizeof(lo));
      formatG6(info.hi, hi, sizeof(hi));
      written = std::snprintf(
        buf, size, "%s = %s %s outside the plausible [%s, %s] %s (%s)", where, v, unit, lo, hi, unit, bound);
      break;
    }
    case FaultCode::TimeNotIncreasing:
      formatRepr(info.value, v, sizeof(v));
      formatRepr(info.lo, lo, sizeof(lo));
      written = std::snprintf(
        buf, size,
        "measurement t = %s s does not advance past the last accepted t = %s s (repeated or backwards time "
        "stamp)",
        v, lo);
      break;
    case FaultCode::ModelNonFinite:
      written = std::snprintf(
        buf, size, "non-finite model terms (gravity, Coriolis, momentum or feed-forward) at this state");
      break;
    case FaultCode::MassNotPositiveDefinite:
      written =
        std::snprintf(buf, size, "mass matrix of the model not positive definite at this q; damping not updated");
      break;
    case FaultCode::ObserverInvalid:
      written =
        std::snprintf(buf, size, "observer state invalid (non-finite): collision detection is off until reset()");
      break;
    case FaultCode::OutputNonFinite:
      written = std::snprintf(buf, size, "non-finite control law on joint %d: collision detection is off until reset()", info.index);
      break;
    default:
      written = std::snprintf(buf, size, "fault %d", static_cast<int>(code));
    }
    if (written < 0)
    {
      buf[0] = '\0';
      return 0;
    }
    return std::min(static_cast<std::size_t>(written), size - 1);
  }

} // namespace reflexarm
