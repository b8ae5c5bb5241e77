// reflexarm, private: the parameter checks of Controller::configure (params_check.cpp).
#pragma once

#include "reflexarm/controller.hpp"

namespace reflexarm
{
  /// Every check of configure() in order (throws the first ConfigError); returns p with its per-joint values
  /// broadcast to the model's joints and the torque limit resolved.
  ControllerParams checkedControllerParams(const pinocchio::Model & model, const ControllerParams & p);
  /// Throws ConfigError "<name> must be a positive number; got <x>" unless x is finite and > 0.
  void checkPositive(double x, const char * name);
} // namespace reflexarm
