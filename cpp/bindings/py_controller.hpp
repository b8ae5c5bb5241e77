// reflexarm._core.Controller's C++ object: the controller, its command and step()'s constant Python objects. In a
// header of its own so that another translation unit of the module (timing.cpp: time_ticks_in_cpp) can take the
// bound controllers themselves (nb::cast<PyController &>), geometry and settings as Python configured them.
#pragma once

#include <nanobind/nanobind.h>

#include "reflexarm/reflexarm.hpp"

namespace reflexarm_bindings
{
  struct PyController
  {
    reflexarm::Controller ctrl;
    reflexarm::Command cmd;
    // step(): the Python Command type and the constant parts of a plain command, made once
    nanobind::object command_type, empty_tuple, empty_str, zero;
    nanobind::object mode_names[reflexarm::kModeCount];
  };
} // namespace reflexarm_bindings
