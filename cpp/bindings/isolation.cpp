// reflexarm._core.ContactIsolator: reflexarm::ContactIsolator from Python (nanobind).
//
// Configured from the model text (pin.Model.saveToString(), as reflexarm._core.Controller) and the collision
// surfaces as float64 C-contiguous (m, 3) arrays per joint; isolate(q, residual) takes float64 C-contiguous
// (n,) vectors (anything else raises TypeError instead of being copied silently: noconvert) and returns a dict.
// The Python face is reflexarm.control.collision.isolate_core.CoreContactIsolator.
#include <string>
#include <vector>

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include "reflexarm/isolation.hpp"
#include "reflexarm/model_io.hpp"
#include "estimate_dict.hpp"

namespace nb = nanobind;
using namespace nb::literals;

namespace
{
  using reflexarm_bindings::Rows3;
  using reflexarm_bindings::estimateDict;
  using reflexarm_bindings::surfacesFrom;
  using Vec = nb::ndarray<const double, nb::shape<-1>, nb::c_contig, nb::device::cpu>;
  using Map = Eigen::Map<const Eigen::VectorXd>;

  struct PyIsolator
  {
    reflexarm::ContactIsolator iso;
    reflexarm::ContactEstimateData out;
  };

  Map view(const Vec & a)
  {
    return Map(a.data(), static_cast<Eigen::Index>(a.shape(0)));
  }

} // namespace

void bindIsolation(nb::module_ & m)
{
  nb::class_<PyIsolator>(
    m, "ContactIsolator",
    "Collision isolation and identification from the joint residual (reflexarm::ContactIsolator); the Python "
    "face is reflexarm.control.collision.isolate_core.CoreContactIsolator.")
    .def(
      "__init__",
      [](PyIsolator * self, const std::string & model_text, const std::vector<Rows3> & points,
         const std::vector<Rows3> & normals, const Vec & significance, double fit_tolerance,
         double relative_tolerance, double friction_coefficient, int cone_edges) {
        const std::vector<reflexarm::LinkSurfaceData> surfaces = surfacesFrom(points, normals);
        reflexarm::IsolationParams params;
        params.significance = view(significance);
        params.fit_tolerance = fit_tolerance;
        params.relative_tolerance = relative_tolerance;
        params.friction_coefficient = friction_coefficient;
        params.cone_edges = cone_edges;
        new (self) PyIsolator();
        self->iso.configure(reflexarm::modelFromString(model_text), surfaces, params);
      },
      "model_text"_a, "points"_a, "normals"_a, "significance"_a, "fit_tolerance"_a, "relative_tolerance"_a,
      "friction_coefficient"_a, "cone_edges"_a,
      "Configure from a Pinocchio model as text (pin.Model.saveToString()), per joint (m, 3) surface points and "
      "outward normals in the joint frame, and the parameters of the Python ContactIsolator.")
    .def_prop_ro("nv", [](const PyIsolator & s) { return s.iso.nv(); })
    .def(
      "isolate",
      [](PyIsolator & s, const Vec & q, const Vec & residual) {
        if (!s.iso.isolate(view(q), view(residual), s.out))
          throw nb::value_error(
            ("q and residual must be finite vectors of size " + std::to_string(s.iso.nv())).c_str());
        return estimateDict(s.out);
      },
      "q"_a.noconvert(), "residual"_a.noconvert(),
      "Contact from the residual at q (float64 C-contiguous (n,) vectors): a dict of link, point, force, "
      "fit_error, determined (0 point_and_force, 1 force_only, 2 link_only, 3 none), cause and the numbers of "
      "the reason.")
    .def(
      "isolate_only",
      [](PyIsolator & s, const Vec & q, const Vec & residual) {
        return s.iso.isolate(view(q), view(residual), s.out);
      },
      "q"_a.noconvert(), "residual"_a.noconvert(), "The C++ call alone, no result dict (for bench/): returns whether the input was valid.")
    .def(
      "isolate_in_steps",
      [](PyIsolator & s, const Vec & q, const Vec & residual, int point_budget) {
        if (point_budget < 1)
          throw nb::value_error(("point_budget must be >= 1; got " + std::to_string(point_budget)).c_str());
        s.iso.begin(view(q), view(residual));
        int steps = 0;
        for (bool done = s.iso.workTotal() == 0; !done; ++steps)
          done = s.iso.step(point_budget);
        const int work = s.iso.workTotal(); // after an early stop: the work done
        if (!s.iso.finish(s.out))
          throw nb::value_error(
            ("q and residual must be finite vectors of size " + std::to_string(s.iso.nv())).c_str());
        nb::dict d = estimateDict(s.out);
        d["work"] = work;
        d["steps"] = steps;
        d["pruned"] = s.iso.prunedPoints();
        return d;
      },
      "q"_a.noconvert(), "residual"_a.noconvert(), "point_budget"_a,
      "The same isolation spread over calls as the real-time tick does it (begin, step(point_budget) until done, "
      "finish): isolate()'s dict (bit for bit the same values) plus work (units: ceil(m / 16) + m per "
      "candidate link examined with m points, pass 1 tracing 16 points a unit and pass 2 fitting one; 1 per link "
      "examined without geometry; links_examined: the fit stops once the links fitted settle the choice), steps (ceil(work / point_budget)) and pruned (pass-2 points whose constrained fit the lower "
      "bound skipped).");
}
