// reflexarm::ResidualTerms: the dynamics terms of the momentum observer (4)-(6) from a measured (q, dq) only, in one
// forward-kinematics pass and one backward pass over the tree (no Coriolis matrix, no inverse dynamics):
//
//   p = M(q) dq      p_k  = S_k . F_k + armature_k dq_k,   F_k = sum over the subtree of k of I_i v_i (momenta)
//   C(q, dq)^T dq    ct_k = -S_k . (v_k x* F_k)            (= dT/dq_k, T the kinetic energy; C^T dq = Mdot dq - C dq)
//   g(q)             g_k  = S_k . sum over the subtree of I_i a_g    (a_g = -gravity, in the body's frame)
//   J(q)^T F         jt_k = S_k . (the wrist wrench moved to joint k's frame), k an ancestor of the sensor frame
//
// in each joint's frame (Pinocchio's Force/Motion algebra; S_k the joint's motion subspace, constant in its frame).
// They equal Pinocchio's rnea(q, 0, dq), computeCoriolisMatrix(q, dq)^T dq, computeGeneralizedGravity(q) and
// computeFrameJacobian(LOCAL)^T F to rounding (measured: p to the bit, the others within 3e-14 on the Atlas arm).
// One ResidualTerms per thread: its Data is its own, the Model is shared read-only.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "pinocchio/multibody.hpp"

namespace reflexarm
{

  class ResidualTerms
  {
  public:
    /// `model` (outlives this object; its gravity is the one of g) and the sensor frame of J^T F (with_wrench).
    ResidualTerms(const pinocchio::Model & model, std::size_t sensor_frame_id, bool with_wrench);

    /// True when every joint has one degree of freedom (the only ones these formulas are written for).
    static bool supports(const pinocchio::Model & model) noexcept;

    /// The terms of one sample into out[0..n) = p, out[n..2n) = C^T dq, out[2n..3n) = g, out[3n..4n) = J^T F
    /// (zero without with_wrench). `wrench` (6: force, moment in the sensor frame) is read only with_wrench.
    void compute(const double * q, const double * dq, const double * wrench, double * out) noexcept;

  private:
    const pinocchio::Model & model_;
    pinocchio::Data data_;
    std::vector<pinocchio::Force> momentum_, gravity_, wrench_;
    Eigen::Matrix<double, 6, Eigen::Dynamic> S_;
    Eigen::VectorXd q_, dq_;
    pinocchio::JointIndex sensor_joint_ = 0;
    pinocchio::SE3 sensor_placement_;
    bool with_wrench_ = false;
  };

} // namespace reflexarm
