// reflexarm: a Pinocchio model to and from text (Boost serialization, as pin.Model.saveToString in
// Python). In its own translation unit: the serialization headers are costly to compile.
#pragma once

#include <string>

#include "pinocchio/multibody.hpp"

namespace reflexarm
{

  /// The model written by pinocchio's saveToString (Python: ``pin.Model.saveToString()``).
  /// Throws std::runtime_error naming the problem if the text is not a serialized model.
  pinocchio::Model modelFromString(const std::string & text);

  /// The text form of a model (readable by ``pin.Model().loadFromString`` in Python).
  std::string modelToString(const pinocchio::Model & model);

} // namespace reflexarm
