// reflexarm::ContactIsolator, private: the constants of reflexarm.control.collision.identify shared by the isolator's
// translation units (isolation.cpp: configure, begin/step/finish, the choice and the estimate; isolation_fit.cpp:
// the constrained fit of the candidate points, the rank of a link's Jacobian, the wrench fit of a link without
// geometry).
#pragma once

#include <limits>

#include <Eigen/Core>

namespace reflexarm
{
  namespace isolation_detail
  {
    // the constants of identify.py
    constexpr double kRankTolerance = 1e-6;
    constexpr double kInteriorCondition = 1e-9;
    constexpr double kFacetCondition = 1e-10;
    constexpr double kEdgeFloor = 1e-14;
    constexpr double kForceAgreement = 0.10;
    constexpr double kDirectionAgreementDeg = 10.0;
    constexpr double kInf = std::numeric_limits<double>::infinity();
    constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
    constexpr double kTiny = std::numeric_limits<double>::min(); // np.finfo(float).tiny

    inline bool allFinite(const Eigen::Ref<const Eigen::MatrixXd> & a)
    {
      return a.allFinite();
    }

    inline double sign(double x)
    {
      return x > 0.0 ? 1.0 : (x < 0.0 ? -1.0 : 0.0);
    }
  } // namespace isolation_detail
} // namespace reflexarm
