// reflexarm::ResidualTerms: the dynamics terms of the momentum observer (4)-(6) from a measured (q, dq) only, in one
// forward pass and one backward pass over the tree (no Coriolis matrix, no inverse dynamics), every spatial quantity in
// the world frame at the world origin (Featherstone's / Pinocchio's Force-Motion algebra, written out for 1-DoF
// revolute and prismatic joints):
//
//   p = M(q) dq      p_k  = S_k . F_k + armature_k dq_k,   F_k = sum over the subtree of k of I_i v_i (momenta)
//   C(q, dq)^T dq    ct_k = -S_k . (v_k x* F_k)            (= dT/dq_k, T the kinetic energy; C^T dq = Mdot dq - C dq)
//   g(q)             g_k  = S_k . sum over the subtree of I_i a_g  = z_k . ((sum m_i c_i - m_k o_k) x a_g) (revolute)
//   J(q)^T F         jt_k = S_k . (the wrist wrench in the world frame), k an ancestor of the sensor frame
//
// S_k = (o_k x z_k, z_k) for a revolute joint about the unit axis z_k through o_k, (z_k, 0) for a prismatic one;
// v_k = v_parent + S_k dq_k; a_g = -gravity. In the world frame the subtree sums need no transformation, which is what
// makes this pass cheaper than the same formulas in each joint's frame (0.54 against 1.04 us a sample on the Atlas arm,
// bench/replay_terms_timing.cpp). They equal Pinocchio's rnea(q, 0, dq), computeCoriolisMatrix(q, dq)^T dq,
// computeGeneralizedGravity(q) and computeFrameJacobian(LOCAL)^T F to rounding (tests/test_replay.py against the full
// path; the timing bench prints the largest difference to each).
// One ResidualTerms per thread: all its state is its own; the Model is only read in the constructor.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "pinocchio/multibody.hpp"

namespace reflexarm
{

  class ResidualTerms
  {
  public:
    /// `model` (its gravity is the one of g) and the sensor frame of J^T F (with_wrench).
    ResidualTerms(const pinocchio::Model & model, std::size_t sensor_frame_id, bool with_wrench);

    /// True when every joint is a 1-DoF revolute or prismatic joint (the only ones these formulas are written for).
    static bool supports(const pinocchio::Model & model) noexcept;

    /// The terms of one sample into out[0..n) = p, out[n..2n) = C^T dq, out[2n..3n) = g, out[3n..4n) = J^T F
    /// (zero without with_wrench). `wrench` (6: force, moment in the sensor frame) is read only with_wrench.
    void compute(const double * q, const double * dq, const double * wrench, double * out) noexcept;

  private:
    /// One joint and the body it moves: constants from the model, then this sample's world-frame quantities.
    struct Body
    {
      int parent = 0;              ///< index into bodies_ (0: the world)
      int idx_v = 0;               ///< the joint's column in q, dq
      bool revolute = true;        ///< else prismatic
      bool carries_sensor = false; ///< the sensor frame is on this body or below it
      Eigen::Matrix3d R_joint;     ///< placement of the joint in its parent's frame
      Eigen::Vector3d p_joint;
      Eigen::Vector3d axis;        ///< unit axis in the joint's own frame
      int aligned = -1;            ///< k when axis = +-e_k (the rotation then touches two columns), else -1
      double aligned_sign = 1.0;
      double mass = 0.0, armature = 0.0;
      Eigen::Vector3d com;         ///< in the body's frame
      Eigen::Matrix3d inertia_c;   ///< rotational inertia about the COM, in the body's frame
      // this sample, world frame
      Eigen::Matrix3d R;
      Eigen::Vector3d o, z;        ///< joint origin and axis
      Eigen::Vector3d s_lin, s_ang; ///< S_k: (o x z, z) revolute, (z, 0) prismatic
      Eigen::Vector3d v, w;        ///< spatial velocity (linear at the world origin, angular)
      Eigen::Vector3d h, L;        ///< subtree momentum (linear, angular about the world origin)
      Eigen::Vector3d mc;          ///< subtree sum of m_i c_i
      double m_sub = 0.0;          ///< subtree mass
    };
    std::vector<Body> bodies_; ///< [0] the world, then the model's joints in order (parents first)
    Eigen::Vector3d a_g_;      ///< -gravity
    int sensor_body_ = 0;
    Eigen::Matrix3d R_sensor_; ///< the sensor frame in its body's frame
    Eigen::Vector3d p_sensor_;
    bool with_wrench_ = false;
    int n_ = 0;
  };

} // namespace reflexarm
