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
    modal_gain.setZero(n);
    U.setZero(n, n);
    W.setZero(n, n);
    V.setZero(n, n);
    has_basis = false;
    converged = false;
    cold = false;
    sweeps = 0;
  }

  bool jacobiSweep(Eigen::Ref<Eigen::MatrixXd> W, Eigen::Ref<Eigen::MatrixXd> V) noexcept
  {
    // one cyclic sweep of Jacobi rotations W <- J^T W J, V <- V J over every off-diagonal entry that is not
    // negligible against its diagonal pair (relative criterion). In place, no allocation.
    // (Eigen's SelfAdjointEigenSolver allocates a workspace in compute() for dynamic sizes.)
    const Eigen::Index n = W.rows();
    constexpr double eps = std::numeric_limits<double>::epsilon();
    bool rotated = false;
    for (Eigen::Index p = 0; p < n; ++p)
      for (Eigen::Index q = p + 1; q < n; ++q)
      {
        const double wpq = W(p, q);
        if (std::abs(wpq) <= eps * std::sqrt(std::abs(W(p, p) * W(q, q))) || wpq == 0.0)
          continue;
        rotated = true;
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
    return rotated;
  }

  namespace
  {
    /// values = diag(W) ascending, the columns of V along.
    void sortEigen(const Eigen::Ref<const Eigen::MatrixXd> & W, Eigen::Ref<Eigen::VectorXd> values,
                   Eigen::Ref<Eigen::MatrixXd> V) noexcept
    {
      const Eigen::Index n = W.rows();
      for (Eigen::Index i = 0; i < n; ++i)
        values[i] = W(i, i);
      for (Eigen::Index i = 0; i < n; ++i) // selection sort
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
    }
  } // namespace

  bool symmetricEigen(Eigen::Ref<Eigen::MatrixXd> W, Eigen::Ref<Eigen::VectorXd> values,
                      Eigen::Ref<Eigen::MatrixXd> V) noexcept
  {
    V.setIdentity();
    for (int sweep = 0; sweep < kMaxJacobiSweeps; ++sweep)
      if (!jacobiSweep(W, V))
      {
        sortEigen(W, values, V);
        return true;
      }
    return false;
  }

  bool modalFactorize(
    const Eigen::Ref<const Eigen::MatrixXd> & M, const Eigen::Ref<const Eigen::VectorXd> & stiffness,
    ModalDampingWorkspace & ws) noexcept
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
    return true;
  }

  bool modalProject(ModalDampingWorkspace & ws) noexcept
  {
    ws.sweeps = 0;
    ws.converged = false;
    if (!ws.has_basis) // cold start: the whole decomposition of A here (A is overwritten)
    {
      if (!symmetricEigen(ws.A, ws.lambda, ws.U))
        return false;
      ws.has_basis = true;
      ws.converged = true;
      ws.cold = true;
      return true;
    }
    // warm start from the previous eigenvectors U0 = ws.U: W = U0^T A U0 is nearly diagonal
    ws.cold = false;
    const Eigen::Index n = ws.A.rows();
    const Eigen::MatrixXd & A = ws.A;
    const Eigen::MatrixXd & U = ws.U;
    Eigen::MatrixXd & AU = ws.LU; // scratch (LU is written by modalAssemble only)
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
    ws.V.setIdentity();
    return ws.W.allFinite();
  }

  void modalSweep(ModalDampingWorkspace & ws, int max_sweeps) noexcept
  {
    for (int k = 0; k < max_sweeps && !ws.converged && ws.sweeps < kMaxJacobiSweeps; ++k)
    {
      ws.converged = !jacobiSweep(ws.W, ws.V);
      ws.sweeps += 1;
    }
  }

  bool modalFinish(ModalDampingWorkspace & ws) noexcept
  {
    if (ws.cold)
      return true;
    modalSweep(ws, kMaxJacobiSweeps);
    if (!ws.converged)
    {
      ws.has_basis = false; // the next computation starts cold
      return false;
    }
    const Eigen::Index n = ws.A.rows();
    sortEigen(ws.W, ws.lambda, ws.V);
    Eigen::MatrixXd & U = ws.U;
    Eigen::MatrixXd & AU = ws.LU;
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

  bool modalDecompose(ModalDampingWorkspace & ws) noexcept
  {
    if (!modalProject(ws))
    {
      ws.has_basis = false; // the previous basis gave a non-finite W: start cold
      if (!modalProject(ws))
        return false;
    }
    if (modalFinish(ws))
      return true;
    return modalProject(ws) && modalFinish(ws); // not converged from the previous basis: once more, cold
  }

  void modalAssemble(
    const Eigen::Ref<const Eigen::VectorXd> & damping_ratio, ModalDampingWorkspace & ws,
    Eigen::Ref<Eigen::MatrixXd> out) noexcept
  {
    const Eigen::Index n = ws.L.rows();
    const Eigen::MatrixXd & L = ws.L;
    const Eigen::MatrixXd & U = ws.U;
    Eigen::MatrixXd & LU = ws.LU;
    Eigen::VectorXd & c = ws.modal_gain;
    for (Eigen::Index i = 0; i < n; ++i)
      for (Eigen::Index j = 0; j < n; ++j)
      {
        double s = 0.0;
        for (Eigen::Index m = 0; m <= i; ++m)
          s += L(i, m) * U(m, j);
        LU(i, j) = s;
      }
    for (Eigen::Index j = 0; j < n; ++j)
      c[j] = 2.0 * damping_ratio[j] * std::sqrt(std::max(ws.lambda[j], 0.0));
    for (Eigen::Index i = 0; i < n; ++i)
      for (Eigen::Index j = 0; j <= i; ++j)
      {
        double s = 0.0;
        for (Eigen::Index m = 0; m < n; ++m)
          s += LU(i, m) * c[m] * LU(j, m);
        out(i, j) = s;
        out(j, i) = s;
      }
  }

  bool computeModalDamping(
    const Eigen::Ref<const Eigen::MatrixXd> & M,
    const Eigen::Ref<const Eigen::VectorXd> & stiffness,
    const Eigen::Ref<const Eigen::VectorXd> & damping_ratio,
    ModalDampingWorkspace & ws,
    Eigen::Ref<Eigen::MatrixXd> out) noexcept
  {
    if (!modalFactorize(M, stiffness, ws) || !modalDecompose(ws))
      return false;
    modalAssemble(damping_ratio, ws, out);
    return true;
  }

} // namespace reflexarm
