// reflexarm::Controller: where and how hard a detected contact is, inside update() (the isolate -> identify stages of
// the collision pipeline): a measured contact from the wrist sensor at detection; a collision isolated from the
// detection residual (ContactIsolator, the candidate points' fit spread over the ticks). Never allocates, never throws.
#include <algorithm>

#include "pinocchio/algorithm/frames.hpp"
#include "pinocchio/algorithm/kinematics.hpp"

#include "reflexarm/controller.hpp"

namespace reflexarm
{

  // Where and how hard: the wrist sensor's measurement for a measured contact, else the isolation of the residual
  // isolation_delay after detection (when the controller has the links' geometry), spread over the ticks.
  bool Controller::awaitingIsolation() const noexcept
  {
    return has_isolator_ && !event_.estimated && event_.contact_class == ContactClass::Collision;
  }

  bool Controller::retractWaits() const noexcept
  {
    return params_.reaction_params.retract_waits_for_estimate && awaitingIsolation();
  }

  // The isolation of a collision, spread over the ticks (ContactIsolator::begin / step / finishStep / finish, the
  // same result bit for bit as one isolate()): begun on this tick from its residual and posture (kinematics and
  // candidate links only), then one part per following accepted tick (stepIsolation): the fit's units,
  // isolation_points_per_tick a tick; the choice of the link and its rank; its estimate (point, force, what is
  // determined); the estimate in on the tick after: ceil(units / points_per_tick) + 3 ticks after the beginning. A
  // retract waiting for it factorises M(q) on that tick (the modal damping's, see factorRetractMass) and is planned on
  // the next accepted tick (the solve M11^-1 J^T f and the path from that tick's q and Jacobians): no tick runs both.
  // So no tick costs much more than a step of the fit. True if it is in already (no work: nothing significant, on the
  // tick it began).
  bool Controller::beginIsolation(double t, const State & s, const Eigen::VectorXd & residual) noexcept
  {
    CollisionEvent & e = event_;
    // the joint placements and world Jacobians at s.q: computeDynamics' computeCoriolisMatrix on this tick (data_c_.oMi
    // and data_c_.J, still in cache), bit for bit what the isolator's own computeJointJacobians would give
    isolator_.begin(s.q, residual, data_c_);
    e.isolating = true;
    e.t_estimate = t; // the residual it uses
    if (isolator_.workLeft() > 0)
      return false;
    finishIsolation(t);
    return true;
  }

  bool Controller::stepIsolation(double t) noexcept
  {
    if (isolator_.workLeft() > 0)
    {
      isolator_.step(std::max(1, params_.reaction_params.isolation_points_per_tick));
      return false;
    }
    if (isolator_.finishStepsLeft() > 0)
    {
      isolator_.finishStep();
      return false;
    }
    finishIsolation(t); // a copy of the estimate the stages wrote
    return true;
  }

  void Controller::finishIsolation(double t) noexcept
  {
    CollisionEvent & e = event_;
    e.estimated = isolator_.finish(e.estimate);
    e.isolating = false;
    e.t_estimated = t;
  }

  // A contact the wrist sensor measures (class Contact): its link, the measured force in the world frame, the point of
  // its line of action nearest the sensor origin (the moment m = (p - o) x f fixes the line, not the point on it).
  void Controller::estimateContact(const State & s) noexcept
  {
    CollisionEvent & e = event_;
    ContactEstimateData & est = e.estimate;
    q_buf_ = s.q;
    pinocchio::forwardKinematics(model_, data_r_, q_buf_);
    const auto fid = static_cast<pinocchio::FrameIndex>(params_.sensor_frame_id);
    pinocchio::updateFramePlacement(model_, data_r_, fid);
    const auto & M = data_r_.oMf[fid];
    const Eigen::Vector3d f = s.wrench.head<3>(), m = s.wrench.tail<3>();
    const double f2 = f.squaredNorm(); // > contact_level^2 > 0 for this class
    est = ContactEstimateData{};
    est.link = static_cast<int>(model_.frames[fid].parentJoint) - 1;
    est.has_point = est.has_force = true;
    est.point = M.translation() + M.rotation() * (f.cross(m) / f2);
    est.force = M.rotation() * f;
    est.fit_error = 0.0;
    est.determined = Determined::PointAndForce;
    est.cause = IsolationCause::Determined;
    est.first_candidate = est.link;
    est.candidate_count = 1;
    e.estimated = e.from_sensor = true;
  }

} // namespace reflexarm
