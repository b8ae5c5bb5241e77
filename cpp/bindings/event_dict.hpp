// reflexarm bindings: the collision event record of a Controller as a Python dict (shared by _core and
// _closed_loop).
#pragma once

#include <string>

#include <nanobind/eigen/dense.h>
#include <nanobind/nanobind.h>
#include <nanobind/stl/string.h>

#include "reflexarm/controller.hpp"
#include "estimate_dict.hpp"

namespace reflexarm_bindings
{
  namespace nb = nanobind;

  /// The collision event record as a dict (copies; NaN where not known).
  inline nb::dict eventDict(const reflexarm::Controller & ctrl)
  {
    const reflexarm::CollisionEvent & e = ctrl.event();
    nb::dict d;
    d["detected"] = e.detected;
    d["t_detect"] = e.t_detect;
    d["joints"] = Eigen::VectorXi(e.joints.cast<int>());
    d["distal_joint"] = e.distal_joint;
    d["contact_class"] = std::string(reflexarm::contactClassName(e.contact_class));
    d["reaction"] = std::string(e.detected ? reflexarm::reactionName(e.reaction) : "none");
    d["phase"] = std::string(reflexarm::reactionPhaseName(e.phase));
    d["residual"] = Eigen::VectorXd(e.residual);
    d["q_detect"] = Eigen::VectorXd(e.q_detect);
    d["q_target"] = Eigen::VectorXd(e.q_target);
    d["retract_planned"] = e.retract_planned;
    d["estimate"] = e.estimated ? nb::object(estimateDict(e.estimate)) : nb::none();
    d["estimate_from_sensor"] = e.from_sensor;
    d["t_estimate"] = e.t_estimate;
    d["t_estimated"] = e.t_estimated;
    d["wrist_force"] = e.wrist_force;
    d["peak_residual"] = e.peak_residual;
    d["energy_detect"] = e.energy_detect;
    d["energy_rest"] = e.energy_rest;
    d["energy_max"] = e.energy_max;
    d["moved"] = e.moved;
    d["t_hold"] = e.t_hold;
    d["recrossings"] = e.recrossings;
    d["torque_limited"] = e.torque_limited;
    d["overspeed"] = e.overspeed;
    d["still_moving"] = e.still_moving;
    d["guard_checked"] = e.guard_checked;
    d["text"] = std::string(e.text.data());
    return d;
  }

} // namespace reflexarm_bindings
