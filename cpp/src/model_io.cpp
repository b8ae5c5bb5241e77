#include "reflexarm/model_io.hpp"

#include <stdexcept>

#include "pinocchio/serialization.hpp"

namespace reflexarm
{

  pinocchio::Model modelFromString(const std::string & text)
  {
    pinocchio::Model model;
    try
    {
      model.loadFromString(text);
    }
    catch (const std::exception & e)
    {
      throw std::runtime_error(
        std::string("cannot read a Pinocchio model from the given text (expected the output of "
                    "pin.Model.saveToString()): ")
        + e.what());
    }
    return model;
  }

  std::string modelToString(const pinocchio::Model & model)
  {
    return model.saveToString();
  }

} // namespace reflexarm
