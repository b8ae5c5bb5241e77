// reflexarm::ContactIsolator, private: the constants of reflexarm.control.collision.identify shared by the isolator's
// translation units (isolation.cpp: configure, begin/step/finish, the choice and the estimate; isolation_fit.cpp:
// the constrained fit of the candidate points, the rank of a link's Jacobian, the wrench fit of a link without
// geometry).
#pragma once

#include <cmath>
#include <limits>

#include <Eigen/Core>
#include <Eigen/Eigenvalues>

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
    /// Eigenvalues of the symmetric tridiagonal (diag, sub) below x: the negative pivots of its LDL^T - x I
    /// (Sturm count, backward stable).
    template <typename Diag, typename Sub>
    inline int eigenvaluesBelow(const Diag & diag, const Sub & sub, double x)
    {
      int count = 0;
      double q = diag[0] - x;
      for (Eigen::Index i = 0;; ++i)
      {
        if (q == 0.0)
          q = -std::numeric_limits<double>::epsilon() * (std::abs(x) + std::numeric_limits<double>::min());
        count += q < 0.0;
        if (i + 1 >= diag.size())
          return count;
        q = diag[i + 1] - x - sub[i] * sub[i] / q;
      }
    }

    /// Householder tridiagonalisation of the symmetric N x N matrix a (both triangles; overwritten): its diagonal and
    /// subdiagonal, a matrix with the same eigenvalues (Golub and Van Loan, Matrix Computations, 4th ed., 8.3.1).
    template <int N>
    void tridiagonalize(
      Eigen::Matrix<double, N, N> & a, Eigen::Matrix<double, N, 1> & diag, Eigen::Matrix<double, N - 1, 1> & sub) noexcept
    {
      for (int k = 0; k + 2 < N; ++k)
      {
        diag[k] = a(k, k);
        const double x0 = a(k + 1, k);
        double tail2 = 0.0;
        for (int i = k + 2; i < N; ++i)
          tail2 += a(i, k) * a(i, k);
        if (tail2 == 0.0) // the column is tridiagonal already
        {
          sub[k] = x0;
          continue;
        }
        const double norm = std::sqrt(x0 * x0 + tail2);
        const double alpha = x0 > 0.0 ? -norm : norm; // the sign that avoids cancellation in v0
        double v[N], p[N];
        v[k + 1] = x0 - alpha;
        for (int i = k + 2; i < N; ++i)
          v[i] = a(i, k);
        const double beta = 2.0 / (v[k + 1] * v[k + 1] + tail2); // H = I - beta v v^T
        double vp = 0.0;
        for (int i = k + 1; i < N; ++i)
        {
          double s = 0.0;
          for (int j = k + 1; j < N; ++j)
            s += a(i, j) * v[j];
          p[i] = beta * s;
          vp += v[i] * p[i];
        }
        const double c = 0.5 * beta * vp;
        for (int i = k + 1; i < N; ++i)
          p[i] -= c * v[i]; // w = p - c v: H A H = A - v w^T - w v^T on the trailing block
        for (int i = k + 1; i < N; ++i)
          for (int j = k + 1; j < N; ++j)
            a(i, j) -= v[i] * p[j] + p[i] * v[j];
        sub[k] = alpha;
      }
      diag[N - 2] = a(N - 2, N - 2);
      diag[N - 1] = a(N - 1, N - 1);
      sub[N - 2] = a(N - 1, N - 2);
    }

    /// The rank of the symmetric positive semidefinite N x N matrix g: its eigenvalues above tol2 x the largest.
    /// The largest lies in [trace / N, trace], so if no eigenvalue lies between tol2 times those two (Sturm counts on
    /// g's tridiagonal form, scaled by its largest entry), the count is the rank; otherwise -1 (undecided: the caller
    /// computes the eigenvalues). 0 for a zero matrix.
    template <int N>
    int psdRank(const Eigen::Matrix<double, N, N> & g, double tol2) noexcept
    {
      const double scale = g.cwiseAbs().maxCoeff();
      if (!(scale > 0.0))
        return 0;
      Eigen::Matrix<double, N, N> a = g / scale;
      Eigen::Matrix<double, N, 1> diag;
      Eigen::Matrix<double, N - 1, 1> sub;
      tridiagonalize<N>(a, diag, sub);
      const double trace = diag.sum();
      if (!(trace > 0.0))
        return 0;
      const int below_lo = eigenvaluesBelow(diag, sub, tol2 * trace / N * (1.0 - 1e-9));
      const int below_hi = eigenvaluesBelow(diag, sub, tol2 * trace * (1.0 + 1e-9));
      return below_lo == below_hi ? N - below_lo : -1;
    }

    /// psdRank, decided: when psdRank leaves it undecided, from the eigenvalues (fixed size: no allocation).
    template <int N>
    int psdRankExact(const Eigen::Matrix<double, N, N> & g, double tol2) noexcept
    {
      const int rank = psdRank<N>(g, tol2);
      if (rank >= 0)
        return rank;
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, N, N>> eig(g, Eigen::EigenvaluesOnly);
      const auto & w = eig.eigenvalues(); // ascending
      if (!(w[N - 1] > 0.0))
        return 0;
      int count = 0;
      for (int i = 0; i < N; ++i)
        count += w[i] > tol2 * w[N - 1];
      return count;
    }
  } // namespace isolation_detail
} // namespace reflexarm
