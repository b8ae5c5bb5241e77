// reflexarm: modal damping of eq. (2) by double diagonalization, allocation-free.
#pragma once

#include <Eigen/Core>

namespace reflexarm
{

  /// Buffers of computeModalDamping, sized once for n joints.
  struct ModalDampingWorkspace
  {
    explicit ModalDampingWorkspace(Eigen::Index n = 0) { resize(n); }
    void resize(Eigen::Index n);

    Eigen::MatrixXd L, B, A, LU, U;
    Eigen::VectorXd lambda;
    /// Warm start: A in the previous call's eigenvectors (W) and the rotation that diagonalizes it (V).
    Eigen::MatrixXd W, V;
    bool has_basis = false; ///< U holds the previous call's eigenvectors (M(q) changes little between calls)
  };

  /// Eigen-decomposition of a symmetric matrix W = V diag(values) V^T by cyclic Jacobi rotations
  /// (values ascending). W is overwritten; no allocation. False if it did not converge.
  bool symmetricEigen(
    Eigen::Ref<Eigen::MatrixXd> W, Eigen::Ref<Eigen::VectorXd> values, Eigen::Ref<Eigen::MatrixXd> V) noexcept;

  /// D = L U diag(2 xi_i sqrt(lambda_i)) U^T L^T with M = L L^T and L^-1 K L^-T = U diag(lambda) U^T
  /// (lambda ascending; damping_ratio[i] applies to the i-th mode).
  ///
  /// Reads the upper triangle of M only. Returns false (out untouched) if M is not finite or not positive
  /// definite. No allocation, no exception. The eigen-decomposition starts from the previous call's
  /// eigenvectors (ws.U) when there is one: in that basis L^-1 K L^-T is nearly diagonal and the Jacobi
  /// rotations converge in a sweep or two instead of ~6 (D does not depend on the start: same to round-off).
  bool computeModalDamping(
    const Eigen::Ref<const Eigen::MatrixXd> & M,
    const Eigen::Ref<const Eigen::VectorXd> & stiffness,
    const Eigen::Ref<const Eigen::VectorXd> & damping_ratio,
    ModalDampingWorkspace & ws,
    Eigen::Ref<Eigen::MatrixXd> out) noexcept;

} // namespace reflexarm
