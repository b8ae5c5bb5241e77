// The C++ tests' shared pieces: the CHECK macro and its counters (a failed check prints and counts, the test goes
// on), the exit line, and the small arm the controller tests run on.
#pragma once

#include <cstdio>

#include <Eigen/Core>

#include "pinocchio/multibody/model.hpp"
#include "pinocchio/multibody/sample-models.hpp"

inline int g_passed = 0, g_failed = 0;
#define CHECK(cond, ...)                                                                                     \
  do                                                                                                         \
  {                                                                                                          \
    if (cond)                                                                                                \
      ++g_passed;                                                                                            \
    else                                                                                                     \
    {                                                                                                        \
      ++g_failed;                                                                                            \
      std::printf("FAILED %s:%d: %s: ", __FILE__, __LINE__, #cond);                                          \
      std::printf(__VA_ARGS__);                                                                              \
      std::printf("\n");                                                                                     \
    }                                                                                                        \
  } while (0)

/// Prints "N passed, M failed"; the exit code (0 when every check passed).
inline int checksReport()
{
  std::printf("%d passed, %d failed\n", g_passed, g_failed);
  return g_failed == 0 ? 0 : 1;
}

/// Pinocchio's sample 6-joint manipulator with position, velocity and effort limits.
inline pinocchio::Model makeArm()
{
  pinocchio::Model model;
  pinocchio::buildModels::manipulator(model);
  const int n = model.nv;
  model.lowerPositionLimit = Eigen::VectorXd::Constant(n, -3.0);
  model.upperPositionLimit = Eigen::VectorXd::Constant(n, 3.0);
  model.upperVelocityLimit = Eigen::VectorXd::Constant(n, 3.0);
  model.upperEffortLimit = Eigen::VectorXd::Constant(n, 200.0);
  return model;
}
