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
    Eigen::VectorXd lambda, modal_gain;
    /// Warm start: A in the previous call's eigenvectors (W) and the rotation that diagonalizes it (V).
    Eigen::MatrixXd W, V;
    bool has_basis = false; ///< U holds the previous call's eigenvectors (M(q) changes little between calls)
    bool converged = false; ///< the Jacobi sweeps on W found nothing left to rotate
    bool cold = false;      ///< this decomposition started without a previous basis (done whole in modalProject)
    int sweeps = 0;         ///< Jacobi sweeps of this decomposition so far (warm start)
  };

  /// Most Jacobi sweeps of one decomposition before it counts as not converged.
  constexpr int kMaxJacobiSweeps = 60;

  /// One cyclic sweep of Jacobi rotations on the symmetric W (W <- J^T W J, V <- V J); true if it rotated
  /// anything (false: every off-diagonal entry is negligible against its diagonal pair: converged).
  bool jacobiSweep(Eigen::Ref<Eigen::MatrixXd> W, Eigen::Ref<Eigen::MatrixXd> V) noexcept;

  /// Eigen-decomposition of a symmetric matrix W = V diag(values) V^T by cyclic Jacobi rotations
  /// (values ascending). W is overwritten; no allocation. False if it did not converge.
  bool symmetricEigen(
    Eigen::Ref<Eigen::MatrixXd> W, Eigen::Ref<Eigen::VectorXd> values, Eigen::Ref<Eigen::MatrixXd> V) noexcept;

  /// The parts of computeModalDamping, for a computation spread over several ticks (each part only reads what
  /// the previous one left in `ws`; together they give the same D as computeModalDamping, to the bit):
  /// - modalFactorize: M = L L^T and A = L^-1 K L^-T (false if M is not finite or not positive definite, or A
  ///   not finite);
  /// - modalDecompose: A = U diag(lambda) U^T, whole; or in steps: modalProject (W = U0^T A U0 in the previous
  ///   eigenvectors U0, nearly diagonal; without a previous basis the whole decomposition, cold; false if not
  ///   finite), modalSweep (up to `max_sweeps` Jacobi sweeps on W), modalFinish (the sweeps left until
  ///   converged, then U = U0 V; false if not converged after kMaxJacobiSweeps: then call modalProject again,
  ///   which starts cold);
  /// - modalAssemble: D = L U diag(2 xi_i sqrt(lambda_i)) U^T L^T into `out`.
  bool modalFactorize(
    const Eigen::Ref<const Eigen::MatrixXd> & M, const Eigen::Ref<const Eigen::VectorXd> & stiffness,
    ModalDampingWorkspace & ws) noexcept;
  bool modalDecompose(ModalDampingWorkspace & ws) noexcept;
  bool modalProject(ModalDampingWorkspace & ws) noexcept;
  void modalSweep(ModalDampingWorkspace & ws, int max_sweeps) noexcept;
  bool modalFinish(ModalDampingWorkspace & ws) noexcept;
  void modalAssemble(
    const Eigen::Ref<const Eigen::VectorXd> & damping_ratio, ModalDampingWorkspace & ws,
    Eigen::Ref<Eigen::MatrixXd> out) noexcept;

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
