// C++ tests of the modal damping of (2): against Eigen's generalized eigensolver, in parts as the controller spreads
// it over ticks, and the law's margin at the rate (Controller::lawModeShare) from the damping in use.
// Exit code 0 when every check passes; prints "N passed, M failed".
#include <algorithm>
#include <cmath>

#include <Eigen/Eigenvalues>

#include "pinocchio/algorithm/crba.hpp"

#include "reflexarm/reflexarm.hpp"

#include "checks.hpp"

namespace
{
  void testModalDamping()
  {
    const pinocchio::Model model = makeArm();
    pinocchio::Data data(model);
    const int n = model.nv;
    Eigen::VectorXd q = Eigen::VectorXd::LinSpaced(n, -0.5, 0.7);
    pinocchio::crba(model, data, q);
    Eigen::MatrixXd M = data.M;
    M.triangularView<Eigen::StrictlyLower>() = M.transpose();
    Eigen::VectorXd K = Eigen::VectorXd::LinSpaced(n, 100.0, 400.0), xi = Eigen::VectorXd::Constant(n, 0.7);
    reflexarm::ModalDampingWorkspace ws(n);
    Eigen::MatrixXd D(n, n);
    CHECK(reflexarm::computeModalDamping(data.M, K, xi, ws, D), "factorization failed");
    // generalized eigenproblem K v = lambda M v with V^T M V = I: V^T D V = diag(2 xi sqrt(lambda))
    Eigen::GeneralizedSelfAdjointEigenSolver<Eigen::MatrixXd> ges(Eigen::MatrixXd(K.asDiagonal()), M);
    const Eigen::MatrixXd modal = ges.eigenvectors().transpose() * D * ges.eigenvectors();
    Eigen::MatrixXd want = Eigen::MatrixXd::Zero(n, n);
    for (int i = 0; i < n; ++i)
      want(i, i) = 2.0 * 0.7 * std::sqrt(ges.eigenvalues()[i]);
    const double err = (modal - want).cwiseAbs().maxCoeff();
    // 1e-9: both are double-precision eigen decompositions of a well-conditioned 6x6 problem (entries ~10)
    CHECK(err < 1e-9, "modal damping off by %g", err);
    Eigen::MatrixXd bad = data.M;
    bad(0, 0) = -1.0;
    CHECK(!reflexarm::computeModalDamping(bad, K, xi, ws, D), "accepted a non-positive-definite M");
  }

  void testModalDampingInParts()
  {
    // the parts run one after the other (as the controller spreads them over ticks) give the same D as the whole
    // computation, to the bit, along a motion (warm starts from the previous basis) and after a cold start
    const pinocchio::Model model = makeArm();
    pinocchio::Data data(model);
    const int n = model.nv;
    Eigen::VectorXd K = Eigen::VectorXd::LinSpaced(n, 100.0, 400.0), xi = Eigen::VectorXd::Constant(n, 0.7);
    reflexarm::ModalDampingWorkspace whole(n), parts(n);
    Eigen::MatrixXd D_whole(n, n), D_parts(n, n);
    int max_sweeps = 0;
    for (int k = 0; k < 50; ++k)
    {
      const Eigen::VectorXd q = Eigen::VectorXd::LinSpaced(n, -0.5, 0.7).array() + 0.02 * k;
      pinocchio::crba(model, data, q);
      CHECK(reflexarm::computeModalDamping(data.M, K, xi, whole, D_whole), "whole computation failed at %d", k);
      CHECK(reflexarm::modalFactorize(data.M, K, parts), "factorize failed at %d", k);
      CHECK(reflexarm::modalProject(parts), "project failed at %d", k);
      reflexarm::modalSweep(parts, 1);
      reflexarm::modalSweep(parts, 1);
      CHECK(reflexarm::modalFinish(parts), "finish failed at %d", k);
      reflexarm::modalAssemble(xi, parts, D_parts);
      CHECK(D_parts == D_whole, "parts differ from the whole computation at %d by %g", k,
            (D_parts - D_whole).cwiseAbs().maxCoeff());
      CHECK(parts.cold == (k == 0), "cold start at %d: %d", k, static_cast<int>(parts.cold));
      if (k > 0)
        max_sweeps = std::max(max_sweeps, parts.sweeps);
    }
    // warm starts converge in a few sweeps (0.02 rad per step here; ~6 from scratch), so the controller's
    // two single-sweep parts leave little to its finishing part
    CHECK(max_sweeps >= 1 && max_sweeps <= 6, "warm-started decompositions took up to %d sweeps", max_sweeps);
  }

  void testLawModeShare()
  {
    // the law's margin at the posture of the damping in use, against Eigen's generalized eigen-solver on crba's M
    // (the controller's comes from its own Cholesky + Jacobi rotations); NaN before the first damping and after reset
    const pinocchio::Model model = makeArm();
    reflexarm::ControllerParams p;
    reflexarm::Controller ctrl;
    ctrl.configure(model, p);
    CHECK(std::isnan(ctrl.lawModeShare()), "before the first damping: %g", ctrl.lawModeShare());
    reflexarm::Command cmd;
    ctrl.initCommand(cmd);
    const int n = ctrl.nv();
    const Eigen::VectorXd q = Eigen::VectorXd::LinSpaced(n, -0.3, 0.4), z = Eigen::VectorXd::Zero(n);
    const Eigen::Matrix<double, 6, 1> w = Eigen::Matrix<double, 6, 1>::Zero();
    const Eigen::Vector3d g(0, 0, -9.81);
    ctrl.update(1e-3, 1e-3, {q, z, z, w, g}, {q, z, z}, cmd);
    pinocchio::Data data(model);
    pinocchio::crba(model, data, q);
    Eigen::MatrixXd M = data.M;
    M.triangularView<Eigen::StrictlyLower>() = M.transpose();
    const Eigen::MatrixXd K = Eigen::VectorXd::Constant(n, 300.0).asDiagonal();
    const Eigen::GeneralizedSelfAdjointEigenSolver<Eigen::MatrixXd> es(K, M, Eigen::EigenvaluesOnly);
    const double want = std::sqrt(es.eigenvalues().maxCoeff()) * 1e-3 / std::min(1.0 / 0.7, 4.0 * 0.7);
    const double got = ctrl.lawModeShare();
    CHECK(std::abs(got - want) <= 1e-9 * want, "law mode share %.17g, Eigen's generalized solver %.17g", got, want);
    ctrl.reset();
    CHECK(std::isnan(ctrl.lawModeShare()), "after reset: %g", ctrl.lawModeShare());
  }

} // namespace

int main()
{
  testModalDamping();
  testModalDampingInParts();
  testLawModeShare();
  return checksReport();
}
