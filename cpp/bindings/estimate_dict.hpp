// reflexarm bindings: contact estimates (reflexarm::ContactEstimateData) as Python dicts and collision surfaces
// from numpy arrays (shared by the isolator, the controller's event and the closed loop).
#pragma once

#include <string>
#include <vector>

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/vector.h>

#include "reflexarm/isolation.hpp"

namespace reflexarm_bindings
{
  namespace nb = nanobind;

  using Rows3 = nb::ndarray<const double, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu>;

  inline nb::object vector3(const Eigen::Vector3d & v)
  {
    using Out3 = nb::ndarray<nb::numpy, double, nb::shape<3>>;
    auto * data = new double[3]{v[0], v[1], v[2]};
    nb::capsule owner(data, [](void * p) noexcept { delete[] static_cast<double *>(p); });
    return nb::cast(Out3(data, {3}, owner));
  }

  /// One LinkSurfaceData per joint from (m, 3) float64 C-contiguous points and normals.
  inline std::vector<reflexarm::LinkSurfaceData>
  surfacesFrom(const std::vector<Rows3> & points, const std::vector<Rows3> & normals)
  {
    if (points.size() != normals.size())
      throw reflexarm::ConfigError(
        "points and normals: one array per joint each; got " + std::to_string(points.size()) + " and "
        + std::to_string(normals.size()));
    using R = reflexarm::LinkSurfaceData::Rows3;
    std::vector<reflexarm::LinkSurfaceData> surfaces(points.size());
    for (size_t i = 0; i < points.size(); ++i)
    {
      surfaces[i].points = Eigen::Map<const R>(points[i].data(), static_cast<Eigen::Index>(points[i].shape(0)), 3);
      surfaces[i].normals = Eigen::Map<const R>(normals[i].data(), static_cast<Eigen::Index>(normals[i].shape(0)), 3);
    }
    return surfaces;
  }

  /// IsolationParams from the Python ContactIsolator's keyword arguments (the significance is set by the caller).
  inline reflexarm::IsolationParams
  isolationParams(double fit_tolerance, double relative_tolerance, double friction_coefficient, int cone_edges)
  {
    reflexarm::IsolationParams p;
    p.fit_tolerance = fit_tolerance;
    p.relative_tolerance = relative_tolerance;
    p.friction_coefficient = friction_coefficient;
    p.cone_edges = cone_edges;
    return p;
  }

  /// The estimate as the dict reflexarm.control.collision.isolate_core reads.
  inline nb::dict estimateDict(const reflexarm::ContactEstimateData & e)
  {
    nb::dict d;
    d["link"] = e.link;
    d["point"] = e.has_point ? vector3(e.point) : nb::none();
    d["force"] = e.has_force ? vector3(e.force) : nb::none();
    d["best_point"] = vector3(e.point);
    d["best_force"] = vector3(e.force);
    d["fit_error"] = e.fit_error;
    d["determined"] = static_cast<int>(e.determined);
    d["cause"] = static_cast<int>(e.cause);
    d["first_candidate"] = e.first_candidate;
    d["candidate_count"] = e.candidate_count;
    d["consistent_points"] = e.consistent_points;
    d["point_spread"] = e.point_spread;
    d["links_examined"] = e.links_examined;
    d["best_fit"] = e.best_fit;
    d["tolerance"] = e.tolerance;
    d["link_rank"] = e.link_rank;
    d["force_rank"] = e.force_rank;
    d["force_variation"] = e.force_variation;
    d["direction_variation_deg"] = e.direction_variation_deg;
    d["max_significance_ratio"] = e.max_significance_ratio;
    return d;
  }

} // namespace reflexarm_bindings
