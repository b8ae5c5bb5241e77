// reflexarm::ResidualTerms: see residual_terms.hpp.
#include "reflexarm/residual_terms.hpp"

#include "pinocchio/algorithm/kinematics.hpp"

namespace reflexarm
{

  ResidualTerms::ResidualTerms(const pinocchio::Model & model, std::size_t sensor_frame_id, bool with_wrench)
  : model_(model)
  , data_(model)
  , momentum_(static_cast<std::size_t>(model.njoints))
  , gravity_(static_cast<std::size_t>(model.njoints))
  , wrench_(static_cast<std::size_t>(model.njoints))
  , S_(6, model.nv)
  , q_(Eigen::VectorXd::Zero(model.nq))
  , dq_(Eigen::VectorXd::Zero(model.nv))
  , with_wrench_(with_wrench)
  {
    pinocchio::forwardKinematics(model_, data_, q_); // S_k of every joint (constant in its own frame)
    S_.setZero();
    for (pinocchio::JointIndex i = 1; i < static_cast<pinocchio::JointIndex>(model_.njoints); ++i)
      S_.col(model_.joints[i].idx_v()) = data_.joints[i].S().matrix().col(0);
    const pinocchio::Frame & frame = model_.frames[sensor_frame_id];
    sensor_joint_ = frame.parentJoint;
    sensor_placement_ = frame.placement;
  }

  bool ResidualTerms::supports(const pinocchio::Model & model) noexcept
  {
    for (pinocchio::JointIndex i = 1; i < static_cast<pinocchio::JointIndex>(model.njoints); ++i)
      if (model.joints[i].nq() != 1 || model.joints[i].nv() != 1)
        return false;
    return true;
  }

  void ResidualTerms::compute(const double * q, const double * dq, const double * wrench, double * out) noexcept
  {
    using pinocchio::Force;
    using pinocchio::JointIndex;
    const int n = model_.nv;
    const JointIndex nj = static_cast<JointIndex>(model_.njoints);
    q_ = Eigen::Map<const Eigen::VectorXd>(q, n);
    dq_ = Eigen::Map<const Eigen::VectorXd>(dq, n);
    pinocchio::forwardKinematics(model_, data_, q_, dq_); // liMi, oMi, v (each in its joint's frame)
    const Eigen::Vector3d a_g = -model_.gravity.linear();  // rnea's base acceleration for gravity
    for (JointIndex i = 1; i < nj; ++i)
    {
      momentum_[i] = model_.inertias[i] * data_.v[i];
      const pinocchio::Motion a(data_.oMi[i].rotation().transpose() * a_g, Eigen::Vector3d::Zero());
      gravity_[i] = model_.inertias[i] * a;
      wrench_[i].setZero();
    }
    if (with_wrench_)
      wrench_[sensor_joint_] = sensor_placement_.act(Force(Eigen::Map<const Eigen::Matrix<double, 6, 1>>(wrench)));
    double *p = out, *ct = out + n, *g = out + 2 * n, *jt = out + 3 * n;
    for (JointIndex i = nj - 1; i > 0; --i)
    {
      const int k = model_.joints[i].idx_v();
      const auto s = S_.col(k);
      p[k] = s.dot(momentum_[i].toVector()) + model_.armature[k] * dq[k];
      ct[k] = -s.dot(data_.v[i].cross(momentum_[i]).toVector());
      g[k] = s.dot(gravity_[i].toVector());
      jt[k] = with_wrench_ ? s.dot(wrench_[i].toVector()) : 0.0;
      const JointIndex parent = model_.parents[i];
      if (parent > 0)
      {
        const pinocchio::SE3 & X = data_.liMi[i];
        momentum_[parent] += X.act(momentum_[i]);
        gravity_[parent] += X.act(gravity_[i]);
        if (with_wrench_)
          wrench_[parent] += X.act(wrench_[i]);
      }
    }
  }

} // namespace reflexarm
