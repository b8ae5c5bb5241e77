#include "reflexarm/modal_damping.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

namespace reflexarm
{

  void ModalDampingWorkspace::resize(Eigen::Index n)
  {
    L.setZero(n, n);
    B.setZero(n, n);
    A.setZero(n, n);
    LU.setZero(n, n);
    lambda.setZero(n);
    U.setZero(n, n);
    W.setZero(n, n);
    V.setZero(n, n);
    has_basis = false;
  }

  bool symmetricEigen(Eigen::Ref<Eigen::MatrixXd> W, Eigen::Ref<Eigen::VectorXd> values,
                      Eigen::Ref<Eigen::MatrixXd> V) noexcept
  {
    // cyclic Jacobi rotations W <- J^T W J, V <- V J until every off-diagonal entry is negligible
    // against its diagonal pair (relative criterion); then sort ascending. In place, no allocation.
    // (Eigen's SelfAdjointEigenSolver allocates a workspace in compute() for dynamic sizes.)
    const Eigen::Index n = W.rows();
    constexpr double eps = std::numeric_limits<double>::epsilon();
    V.setIdentity();
    bool converged = false;
    for (int sweep = 0; sweep < 60 && !converged; ++sweep)
    {
      converged = true;
      for (Eigen::Index p = 0; p < n; ++p)
        for (Eigen::Index q = p + 1; q < n; ++q)
        {
          const double wpq = W(p, q);
          if (std::abs(wpq) <= eps * std::sqrt(std::abs(W(p, p) * W(q, q))) || wpq == 0.0)
            continue;
          converged = false;
          const double theta = (W(q, q) - W(p, p)) / (2.0 * wpq);
          const double t = (theta >= 0.0 ? 1.0 : -1.0) / (std::abs(theta) + std::sqrt(theta * theta + 1.0));
          const double c = 1.0 / std::sqrt(t * t + 1.0);
          const double s = t * c;
          for (Eigen::Index k = 0; k < n; ++k)
          {
            const double a = W(k, p), b = W(k, q);
            W(k, p) = c * a - s * b;
            W(k, q) = s * a + c * b;
          }
          for (Eigen::Index k = 0; k < n; ++k)
          {
            const double a = W(p, k), b = W(q, k);
            W(p, k) = c * a - s * b;
            W(q, k) = s * a + c * b;
          }
          W(p, q) = 0.0;
          W(q, p) = 0.0;
          for (Eigen::Index k = 0; k < n; ++k)
          {
            const double a = V(k, p), b = V(k, q);
            V(k, p) = c * a - s * b;
            V(k, q) = s * a + c * b;
          }
        }
    }
    if (!converged)
      return false;
    for (Eigen::Index i = 0; i < n; ++i)
      values[i] = W(i, i);
    for (Eigen::Index i = 0; i < n; ++i) // selection sort, ascending, columns of V along
    {
      Eigen::Index k = i;
      for (Eigen::Index j = i + 1; j < n; ++j)
        if (values[j] < values[k])
          k = j;
      if (k != i)
      {
        std::swap(values[i], values[k]);
        V.col(i).swap(V.col(k));
      }
    }
    return true;
  }

  namespace
  {
    /// lambda, U of A = U diag(lambda) U^T starting from the previous eigenvectors U0 = ws.U: W = U0^T A U0 is
    /// nearly diagonal, W = V diag(lambda) V^T by Jacobi rotations, U = U0 V. False (ws.U untouched) if there
    /// is no previous basis or the rotations did not converge.
    bool eigenFromPreviousBasis(ModalDampingWorkspace & ws) noexcept
    {
      if (!ws.has_basis)
        return false;
      const Eigen::Index n = ws.A.rows();
      const Eigen::MatrixXd & A = ws.A;
      Eigen::MatrixXd & U = ws.U;
      Eigen::MatrixXd & AU = ws.LU; // scratch until the end of computeModalDamping
      for (Eigen::Index i = 0; i < n; ++i)
        for (Eigen::Index j = 0; j < n; ++j)
        {
          double s = 0.0;
          for (Eigen::Index m = 0; m < n; ++m)
            s += A(i, m) * U(m, j);
          AU(i, j) = s;
        }
      for (Eigen::Index i = 0; i < n; ++i)
        for (Eigen::Index j = 0; j <= i; ++j)
        {
          double s = 0.0, t = 0.0;
          for (Eigen::Index m = 0; m < n; ++m)
          {
            s += U(m, i) * AU(m, j);
            t += U(m, j) * AU(m, i);
          }
          ws.W(i, j) = ws.W(j, i) = 0.5 * (s + t); // symmetric to round-off
        }
      if (!ws.W.allFinite() || !symmetricEigen(ws.W, ws.lambda, ws.V))
        return false;
      for (Eigen::Index i = 0; i < n; ++i) // U <- U0 V, through AU as scratch
        for (Eigen::Index j = 0; j < n; ++j)
        {
          double s = 0.0;
          for (Eigen::Index m = 0; m < n; ++m)
            s += U(i, m) * ws.V(m, j);
          AU(i, j) = s;
        }
      U = AU;
      // re-orthonormalize (modified Gram-Schmidt): the products U0 V would otherwise let round-off build up
      // over the many thousand updates of a long run
      for (Eigen::Index j = 0; j < n; ++j)
      {
        for (Eigen::Index i = 0; i < j; ++i)
          U.col(j) -= U.col(i).dot(U.col(j)) * U.col(i);
        U.col(j).normalize();
      }
      return true;
    }
  } // namespace

  bool computeModalDamping(
    const Eigen::Ref<const Eigen::MatrixXd> & M,
    const Eigen::Ref<const Eigen::VectorXd> & stiffness,
    const Eigen::Ref<const Eigen::VectorXd> & damping_ratio,
    ModalDampingWorkspace & ws,
    Eigen::Ref<Eigen::MatrixXd> out) noexcept
  {
    const Eigen::Index n = M.rows();
    for (Eigen::Index i = 0; i < n; ++i)
      for (Eigen::Index j = i; j < n; ++j)
        if (!std::isfinite(M(i, j)))
          return false;
    Eigen::MatrixXd & L = ws.L;
    L.setZero();
    for (Eigen::Index j = 0; j < n; ++j)
    {
      double s = M(j, j);
      for (Eigen::Index m = 0; m < j; ++m)
        s -= L(j, m) * L(j, m);
      if (!(s > 0.0))
        return false;
      L(j, j) = std::sqrt(s);
      for (Eigen::Index i = j + 1; i < n; ++i)
      {
        double t = M(j, i); // = M(i, j), upper triangle
        for (Eigen::Index m = 0; m < j; ++m)
          t -= L(i, m) * L(j, m);
        L(i, j) = t / L(j, j);
      }
    }
    Eigen::MatrixXd & B = ws.B; // B = L^-1 sqrt(K), lower triangular
    B.setZero();
    for (Eigen::Index j = 0; j < n; ++j)
    {
      B(j, j) = std::sqrt(stiffness[j]) / L(j, j);
      for (Eigen::Index i = j + 1; i < n; ++i)
      {
        double s = 0.0;
        for (Eigen::Index m = j; m < i; ++m)
          s += L(i, m) * B(m, j);
        B(i, j) = -s / L(i, i);
      }
    }
    Eigen::MatrixXd & A = ws.A;
    for (Eigen::Index i = 0; i < n; ++i)
      for (Eigen::Index j = 0; j <= i; ++j)
      {
        double s = 0.0;
        for (Eigen::Index m = 0; m <= j; ++m)
          s += B(i, m) * B(j, m);
        A(i, j) = s;
        A(j, i) = s;
      }
    for (Eigen::Index i = 0; i < n; ++i)
      for (Eigen::Index j = 0; j < n; ++j)
        if (!std::isfinite(A(i, j)))
          return false;
    Eigen::VectorXd & lam = ws.lambda;
    if (!eigenFromPreviousBasis(ws))
    {
      ws.has_basis = false;
      if (!symmetricEigen(A, lam, ws.U)) // cold start; A is overwritten
        return false;
    }
    ws.has_basis = true;
    const Eigen::MatrixXd & U = ws.U;
    Eigen::MatrixXd & LU = ws.LU;
    for (Eigen::Index i = 0; i < n; ++i)
      for (Eigen::Index j = 0; j < n; ++j)
      {
        double s = 0.0;
        for (Eigen::Index m = 0; m <= i; ++m)
          s += L(i, m) * U(m, j);
        LU(i, j) = s;
      }
    for (Eigen::Index j = 0; j < n; ++j)
      lam[j] = 2.0 * damping_ratio[j] * std::sqrt(std::max(lam[j], 0.0));
    for (Eigen::Index i = 0; i < n; ++i)
      for (Eigen::Index j = 0; j <= i; ++j)
      {
        double s = 0.0;
        for (Eigen::Index m = 0; m < n; ++m)
          s += LU(i, m) * lam[m] * LU(j, m);
        out(i, j) = s;
        out(j, i) = s;
      }
    return true;
  }

} // namespace reflexarm
