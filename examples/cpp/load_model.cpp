// The controller's model from the robot's MJCF file (Pinocchio's parser, in its own translation unit).
#include <string>

#include "pinocchio/parsers/mjcf.hpp"

pinocchio::Model loadModel(const std::string & path)
{
  pinocchio::Model model;
  pinocchio::mjcf::buildModel(path, model);
  return model;
}
