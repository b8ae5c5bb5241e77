// reflexarm::ResidualTerms: see residual_terms.hpp.
#include "reflexarm/residual_terms.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

#include <Eigen/Geometry>

#include "pinocchio/algorithm/kinematics.hpp"

namespace reflexarm
{

  namespace
  {
    /// The joint's motion subspace in its own frame (constant for 1-DoF joints): true with revolute set and the unit
    /// axis when the joint is a pure rotation or a pure translation; false for anything else (helical, multi-DoF).
    bool jointAxis(const pinocchio::Model & model, pinocchio::Data & data, pinocchio::JointIndex i, bool & revolute,
                   Eigen::Vector3d & axis)
    {
      if (model.joints[i].nq() != 1 || model.joints[i].nv() != 1)
        return false;
      const Eigen::Matrix<double, 6, 1> s = data.joints[i].S().matrix().col(0);
      const double lin = s.head<3>().norm(), ang = s.tail<3>().norm();
      if ((lin == 0.0) == (ang == 0.0))
        return false;
      revolute = ang != 0.0;
      axis = revolute ? Eigen::Vector3d(s.tail<3>() / ang) : Eigen::Vector3d(s.head<3>() / lin);
      return true;
    }

  } // namespace

  ResidualTerms::ResidualTerms(const pinocchio::Model & model, std::size_t sensor_frame_id, bool with_wrench)
  : bodies_(static_cast<std::size_t>(model.njoints))
  , a_g_(-model.gravity.linear())
  , with_wrench_(with_wrench)
  , n_(model.nv)
  {
    pinocchio::Data data(model);
    pinocchio::forwardKinematics(model, data, pinocchio::neutral(model));
    Body & world = bodies_[0];
    world.R.setIdentity();
    world.o.setZero();
    world.v.setZero();
    world.w.setZero();
    for (pinocchio::JointIndex i = 1; i < static_cast<pinocchio::JointIndex>(model.njoints); ++i)
    {
      Body & b = bodies_[i];
      if (!jointAxis(model, data, i, b.revolute, b.axis))
        throw std::invalid_argument("ResidualTerms: joint " + model.names[i] + " is not a 1-DoF revolute or prismatic joint");
      b.parent = static_cast<int>(model.parents[i]);
      b.idx_v = model.joints[i].idx_v();
      b.R_joint = model.jointPlacements[i].rotation();
      b.p_joint = model.jointPlacements[i].translation();
      b.mass = model.inertias[i].mass();
      b.com = model.inertias[i].lever();
      b.inertia_c = model.inertias[i].inertia().matrix();
      b.armature = model.armature[b.idx_v];
      for (int k = 0; k < 3; ++k)
        if (std::abs(b.axis[k]) == 1.0)
        {
          b.aligned = k;
          b.aligned_sign = b.axis[k];
        }
    }
    const pinocchio::Frame & frame = model.frames[sensor_frame_id];
    sensor_body_ = static_cast<int>(frame.parentJoint);
    R_sensor_ = frame.placement.rotation();
    p_sensor_ = frame.placement.translation();
    for (int j = sensor_body_; j > 0; j = bodies_[static_cast<std::size_t>(j)].parent)
      bodies_[static_cast<std::size_t>(j)].carries_sensor = true;
  }

  bool ResidualTerms::supports(const pinocchio::Model & model) noexcept
  {
    try
    {
      pinocchio::Data data(model);
      pinocchio::forwardKinematics(model, data, pinocchio::neutral(model));
      bool revolute = false;
      Eigen::Vector3d axis;
      for (pinocchio::JointIndex i = 1; i < static_cast<pinocchio::JointIndex>(model.njoints); ++i)
        if (!jointAxis(model, data, i, revolute, axis))
          return false;
      return true;
    }
    catch (...)
    {
      return false;
    }
  }

  void ResidualTerms::compute(const double * q, const double * dq, const double * wrench, double * out) noexcept
  {
    using Eigen::Vector3d;
    const std::size_t nb = bodies_.size();
    for (std::size_t i = 1; i < nb; ++i) // forward: poses, velocities and each body's own momentum
    {
      Body & b = bodies_[i];
      const Body & parent = bodies_[static_cast<std::size_t>(b.parent)];
      const double qi = q[b.idx_v], dqi = dq[b.idx_v];
      const Eigen::Matrix3d R0 = parent.R * b.R_joint; // the joint's frame at q = 0
      b.o = parent.o + parent.R * b.p_joint;
      b.z = R0 * b.axis;
      Vector3d & s_lin = b.s_lin;
      Vector3d & s_ang = b.s_ang;
      if (b.revolute)
      {
        const double c = std::cos(qi), s = std::sin(qi);
        if (b.aligned >= 0) // about +-e_k: R0 Rot only mixes R0's other two columns
        {
          const int k1 = (b.aligned + 1) % 3, k2 = (b.aligned + 2) % 3;
          const double ss = b.aligned_sign * s;
          b.R.col(b.aligned) = R0.col(b.aligned);
          b.R.col(k1) = c * R0.col(k1) + ss * R0.col(k2);
          b.R.col(k2) = c * R0.col(k2) - ss * R0.col(k1);
        }
        else // Rodrigues
        {
          const Vector3d & a = b.axis;
          Eigen::Matrix3d rot = (1.0 - c) * a * a.transpose();
          rot(0, 0) += c;
          rot(1, 1) += c;
          rot(2, 2) += c;
          rot(0, 1) -= s * a.z();
          rot(1, 0) += s * a.z();
          rot(0, 2) += s * a.y();
          rot(2, 0) -= s * a.y();
          rot(1, 2) -= s * a.x();
          rot(2, 1) += s * a.x();
          b.R.noalias() = R0 * rot;
        }
        s_lin = b.o.cross(b.z);
        s_ang = b.z;
      }
      else
      {
        b.R = R0;
        s_lin = b.z;
        s_ang.setZero();
        b.o += qi * b.z; // the body's origin moves along the axis (o is then the body's origin)
      }
      b.v = parent.v + dqi * s_lin;
      b.w = parent.w + dqi * s_ang;
      const Vector3d c = b.R * b.com + b.o;
      b.h = b.mass * (b.v + b.w.cross(c));
      b.L = b.R * (b.inertia_c * (b.R.transpose() * b.w)) + c.cross(b.h);
      b.mc = b.mass * c;
      b.m_sub = b.mass;
    }
    Vector3d f_w = Vector3d::Zero(), n_w = Vector3d::Zero(); // the wrist wrench at the world origin
    if (with_wrench_)
    {
      const Body & s = bodies_[static_cast<std::size_t>(sensor_body_)];
      const Eigen::Matrix3d R = s.R * R_sensor_;
      const Vector3d p = s.o + s.R * p_sensor_;
      f_w = R * Eigen::Map<const Vector3d>(wrench);
      n_w = R * Eigen::Map<const Vector3d>(wrench + 3) + p.cross(f_w);
    }
    double *p = out, *ct = out + n_, *g = out + 2 * n_, *jt = out + 3 * n_;
    for (std::size_t i = nb - 1; i > 0; --i) // backward: subtree sums (children have larger indices), the terms
    {
      Body & b = bodies_[i];
      const int k = b.idx_v;
      const Vector3d g_lin = b.m_sub * a_g_, g_ang = b.mc.cross(a_g_);
      const Vector3d x_lin = b.w.cross(b.h), x_ang = b.w.cross(b.L) + b.v.cross(b.h); // v_k x* F_k
      p[k] = b.s_lin.dot(b.h) + b.s_ang.dot(b.L) + b.armature * dq[k];
      ct[k] = -(b.s_lin.dot(x_lin) + b.s_ang.dot(x_ang));
      g[k] = b.s_lin.dot(g_lin) + b.s_ang.dot(g_ang);
      jt[k] = b.carries_sensor && with_wrench_ ? b.s_lin.dot(f_w) + b.s_ang.dot(n_w) : 0.0;
      Body & parent = bodies_[static_cast<std::size_t>(b.parent)];
      if (b.parent > 0)
      {
        parent.h += b.h;
        parent.L += b.L;
        parent.mc += b.mc;
        parent.m_sub += b.m_sub;
      }
    }
  }

} // namespace reflexarm
