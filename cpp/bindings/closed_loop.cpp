// reflexarm._closed_loop.ClosedLoop: the compiled closed loop from Python (nanobind), driven by
// reflexarm.sim.compiled_loop. A module of its own rather than a part of reflexarm._core: _core (the
// controller a real robot runs) stays free of MuJoCo. It takes reflexarm._core.ControllerParams (import
// reflexarm._core first): nanobind shares bound types between modules built with the same nanobind.
//
// The MuJoCo model and data cross as the addresses of the Python Plant's MjModel/MjData (mujoco's
// `_address`): the same libmujoco is mapped once in the process, and the Python objects outlive the loop
// (the Python wrapper keeps them). Every array is checked for dtype, C order and row count once, when it is
// handed over; the loop then writes through raw pointers.
#include <algorithm>
#include <cstdint>
#include <string>
#include <tuple>
#include <vector>

#include <nanobind/eigen/dense.h>
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include "reflexarm/closed_loop.hpp"
#include "reflexarm/model_io.hpp"
#include "event_dict.hpp"

namespace nb = nanobind;
using namespace nb::literals;

namespace
{
  template<typename T>
  using Arr = nb::ndarray<T, nb::c_contig, nb::device::cpu>;
  using IntArr = nb::ndarray<const std::int64_t, nb::ndim<1>, nb::c_contig, nb::device::cpu>;

  std::vector<int> ints(const IntArr & a)
  {
    std::vector<int> out(a.shape(0));
    for (size_t i = 0; i < a.shape(0); ++i)
      out[i] = static_cast<int>(a.data()[i]);
    return out;
  }

  /// Checks an array of `rows` x `cols` (cols 0: one dimension) and returns its data pointer.
  template<typename T>
  T * rowsOf(const Arr<T> & a, long rows, long cols, const char * name)
  {
    const bool ok = cols == 0 ? (a.ndim() == 1 && static_cast<long>(a.shape(0)) == rows)
                              : (a.ndim() == 2 && static_cast<long>(a.shape(0)) == rows
                                 && static_cast<long>(a.shape(1)) == cols);
    if (!ok)
    {
      std::string shape;
      for (size_t i = 0; i < a.ndim(); ++i)
        shape += (i ? ", " : "") + std::to_string(a.shape(i));
      throw reflexarm::ConfigError(std::string("ClosedLoop: ") + name + " must have shape (" + std::to_string(rows)
                                   + (cols ? ", " + std::to_string(cols) : std::string(",")) + "); got (" + shape + ")");
    }
    return a.data();
  }

  struct PyLoop
  {
    reflexarm::ClosedLoop loop;
    long rows = 0;
  };
} // namespace

void bindRunStatistics(nb::module_ & m); // run_statistics.cpp: reflexarm::RunStatistics

NB_MODULE(_closed_loop, m)
{
  bindRunStatistics(m);
  m.doc() = "reflexarm's compiled closed loop: MuJoCo plant, sensors, the C++ controller, recording";
  using reflexarm::StepStatus;
  m.attr("STEP_OK") = static_cast<int>(StepStatus::Ok);
  m.attr("STEP_DIVERGED") = static_cast<int>(StepStatus::Diverged);
  m.attr("STEP_TIME_MISMATCH") = static_cast<int>(StepStatus::TimeMismatch);

  m.def(
    "replay_torques",
    [](std::uintptr_t model_address, std::uintptr_t data_address, const Arr<const double> & tau, const IntArr & vadr,
       int substeps, bool quiet_timers) {
      const auto * mm = reinterpret_cast<const mjModel *>(model_address);
      auto * dd = reinterpret_cast<mjData *>(data_address);
      const std::vector<int> adr = ints(vadr);
      const long n = static_cast<long>(adr.size());
      const long N = tau.ndim() == 2 ? static_cast<long>(tau.shape(0)) : -1;
      const double * t = rowsOf(tau, N, n, "tau");
      nb::gil_scoped_release release;
      for (long k = 0; k < N; ++k)
      {
        for (long i = 0; i < n; ++i)
          dd->qfrc_applied[adr[i]] = t[k * n + i];
        const reflexarm::QuietTimers quiet(quiet_timers); // as ClosedLoop::act
        reflexarm::stepSensingLast(mm, dd, substeps);     // as both loops step
      }
    },
    "model_address"_a, "data_address"_a, "tau"_a, "vadr"_a, "substeps"_a, "quiet_timers"_a = false,
    "MuJoCo stepping alone (the benchmark's baseline): each row of tau held for `substeps` physics steps; "
    "quiet_timers: MuJoCo's profiling timers read a clock of 0 meanwhile (reflexarm::QuietTimers).");

  nb::class_<PyLoop>(m, "ClosedLoop")
    .def(
      "__init__",
      [](PyLoop * self, std::uintptr_t model_address, std::uintptr_t data_address, const std::string & model_text,
         const reflexarm::ControllerParams & params, const IntArr & qadr, const IntArr & vadr,
         const IntArr & load_bodies, const IntArr & arm_bodies, int force_adr, int torque_adr, int com_body, int site,
         bool physical, int substeps, double max_speed, std::tuple<double, double, double> gravity) {
        new (self) PyLoop();
        reflexarm::PlantLayout lay;
        lay.qadr = ints(qadr);
        lay.vadr = ints(vadr);
        lay.load_bodies = ints(load_bodies);
        lay.arm_bodies = ints(arm_bodies);
        lay.force_adr = force_adr;
        lay.torque_adr = torque_adr;
        lay.com_body = com_body;
        lay.site = site;
        lay.physical = physical;
        lay.substeps = substeps;
        lay.max_speed = max_speed;
        lay.gravity[0] = std::get<0>(gravity);
        lay.gravity[1] = std::get<1>(gravity);
        lay.gravity[2] = std::get<2>(gravity);
        self->loop.configure(reinterpret_cast<const mjModel *>(model_address),
                             reinterpret_cast<mjData *>(data_address), lay, reflexarm::modelFromString(model_text),
                             params);
      },
      "model_address"_a, "data_address"_a, "model_text"_a, "params"_a, "qadr"_a, "vadr"_a, "load_bodies"_a,
      "arm_bodies"_a, "force_adr"_a, "torque_adr"_a, "com_body"_a, "site"_a, "physical"_a, "substeps"_a,
      "max_speed"_a, "gravity"_a,
      "The plant (MjModel/MjData addresses, kept alive by the caller), its layout and the controller.")
    .def(
      "set_buffers",
      [](PyLoop & self, nb::object noise, const Arr<const double> & q_d, const Arr<const double> & dq_d,
         const Arr<const double> & ddq_d, const Arr<double> & t, const Arr<double> & q, const Arr<double> & dq,
         const Arr<double> & q_meas, const Arr<double> & tau, const Arr<double> & tau_m, const Arr<double> & residual,
         const Arr<double> & wrench, const Arr<double> & tau_ext, const Arr<double> & f_ext_ee,
         const Arr<std::uint8_t> & collision, const Arr<std::uint8_t> & collided, const Arr<std::int32_t> & mode,
         const Arr<std::int32_t> & fault_code, const Arr<double> & fault_info) {
        const long N = static_cast<long>(t.shape(0)), n = self.loop.nv();
        reflexarm::RunBuffers b;
        b.rows = N;
        if (!noise.is_none())
          b.noise = rowsOf(nb::cast<Arr<const double>>(noise), N, self.loop.measurementSize(), "noise");
        b.q_d = rowsOf(q_d, N, n, "q_d");
        b.dq_d = rowsOf(dq_d, N, n, "dq_d");
        b.ddq_d = rowsOf(ddq_d, N, n, "ddq_d");
        b.t = rowsOf(t, N, 0, "t");
        b.q = rowsOf(q, N, n, "q");
        b.dq = rowsOf(dq, N, n, "dq");
        b.q_meas = rowsOf(q_meas, N, n, "q_meas");
        b.tau = rowsOf(tau, N, n, "tau");
        b.tau_m = rowsOf(tau_m, N, n, "tau_m");
        b.residual = rowsOf(residual, N, n, "residual");
        b.wrench = rowsOf(wrench, N, 6, "wrench");
        b.tau_ext = rowsOf(tau_ext, N, n, "tau_ext");
        b.f_ext_ee = rowsOf(f_ext_ee, N, 3, "f_ext_ee");
        b.collision = rowsOf(collision, N, 0, "collision");
        b.collided = rowsOf(collided, N, n, "collided");
        b.mode = rowsOf(mode, N, 0, "mode");
        b.fault_code = rowsOf(fault_code, N, 0, "fault_code");
        b.fault_info = rowsOf(fault_info, N, 5, "fault_info");
        self.loop.setBuffers(b);
        self.rows = N;
      },
      "noise"_a.none(), "q_d"_a, "dq_d"_a, "ddq_d"_a, "t"_a, "q"_a, "dq"_a, "q_meas"_a, "tau"_a, "tau_m"_a,
      "residual"_a, "wrench"_a, "tau_ext"_a, "f_ext_ee"_a, "collision"_a, "collided"_a, "mode"_a, "fault_code"_a,
      "fault_info"_a, "The run's arrays (N rows each; the caller keeps them alive until the run ends).")
    .def(
      "set_forces",
      [](PyLoop & self, const Arr<const double> & forces) {
        const long F = forces.ndim() == 2 ? static_cast<long>(forces.shape(0)) : -1;
        const double * f = rowsOf(forces, F, 7, "forces");
        std::vector<reflexarm::AppliedForce> out(static_cast<size_t>(F));
        for (long i = 0; i < F; ++i)
        {
          out[i].body = static_cast<int>(f[7 * i]);
          for (int c = 0; c < 3; ++c)
          {
            out[i].force[c] = f[7 * i + 1 + c];
            out[i].point_local[c] = f[7 * i + 4 + c];
          }
        }
        self.loop.setForces(out);
      },
      "forces"_a, "Applied forces, one row (body, force (3) [N, world], point in the body frame (3) [m]) each.")
    .def(
      "set_scene_data",
      [](PyLoop & self, const std::vector<std::tuple<int, Arr<const double>>> & mocap_plans,
         const std::vector<std::tuple<int, int, Arr<double>>> & qpos_records,
         const std::vector<std::tuple<int, Arr<double>>> & mocap_records) {
        const long N = self.rows;
        std::vector<reflexarm::MocapPlan> plans;
        for (const auto & [id, arr] : mocap_plans)
          plans.push_back({id, rowsOf(arr, N, 3, "mocap plan")});
        std::vector<reflexarm::QposRecord> qrec;
        for (const auto & [adr, size, arr] : qpos_records)
          qrec.push_back({adr, size, rowsOf(arr, N, size, "qpos record")});
        std::vector<reflexarm::MocapRecord> mrec;
        for (const auto & [id, arr] : mocap_records)
          mrec.push_back({id, rowsOf(arr, N, 3, "mocap record")});
        self.loop.setMocapPlans(plans);
        self.loop.setRecords(qrec, mrec);
      },
      "mocap_plans"_a, "qpos_records"_a, "mocap_records"_a,
      "Scene data (call after set_buffers): (mocap id, N x 3 positions, NaN: unchanged) played before each "
      "tick's physics; (qpos address, size, N x size) and (mocap id, N x 3) recorded every tick.")
    .def(
      "run",
      [](PyLoop & self, long k0, long k1) {
        if (k0 < 0 || k1 > self.rows || k0 > k1)
          throw reflexarm::ConfigError("ClosedLoop.run: need 0 <= k0 <= k1 <= " + std::to_string(self.rows)
                                       + "; got " + std::to_string(k0) + ", " + std::to_string(k1));
        StepStatus status;
        long done;
        {
          nb::gil_scoped_release release;
          done = self.loop.run(k0, k1, status);
        }
        return std::make_tuple(done, static_cast<int>(status));
      },
      "k0"_a, "k1"_a, "Ticks [k0, k1); returns (ticks done, status); a failed step ends the call after its tick.")
    .def(
      "sense",
      [](PyLoop & self, long k) {
        if (k < 0 || k >= self.rows)
          throw reflexarm::ConfigError("ClosedLoop.sense: tick " + std::to_string(k) + " out of range");
        self.loop.sense(k);
      },
      "k"_a)
    .def(
      "act",
      [](PyLoop & self, long k) {
        if (k < 0 || k >= self.rows)
          throw reflexarm::ConfigError("ClosedLoop.act: tick " + std::to_string(k) + " out of range");
        return static_cast<int>(self.loop.act(k));
      },
      "k"_a)
    .def(
      "set_push",
      [](PyLoop & self, int body, int site, std::tuple<double, double, double> u, std::tuple<double, double, double> p0,
         double stiffness, double damping, double period, const Arr<const double> & rest,
         const Arr<const double> & rest_v, const Arr<double> & force_out, const Arr<double> & target_out,
         double last_x, bool has_last, bool applied, std::tuple<double, double, double> force,
         std::tuple<double, double, double> target, std::tuple<double, double, double> point_local) {
        const long N = self.rows;
        reflexarm::SpringPush push;
        push.body = body;
        push.site = site;
        const auto put = [](double * out, const std::tuple<double, double, double> & v) {
          out[0] = std::get<0>(v);
          out[1] = std::get<1>(v);
          out[2] = std::get<2>(v);
        };
        put(push.u, u);
        put(push.p0, p0);
        push.stiffness = stiffness;
        push.damping = damping;
        push.period = period;
        push.rest = rowsOf(rest, N, 0, "rest");
        push.rest_v = rowsOf(rest_v, N, 0, "rest_v");
        push.force_out = rowsOf(force_out, N, 3, "force_out");
        push.target_out = rowsOf(target_out, N, 3, "target_out");
        push.last_x = last_x;
        push.has_last = has_last;
        push.applied = applied;
        put(push.force, force);
        put(push.target, target);
        put(push.point_local, point_local);
        std::vector<reflexarm::SpringPush> pushes = self.loop.pushes();
        pushes.push_back(push);
        self.loop.setPushes(pushes);
      },
      "body"_a, "site"_a, "u"_a, "p0"_a, "stiffness"_a, "damping"_a, "period"_a, "rest"_a, "rest_v"_a,
      "force_out"_a, "target_out"_a, "last_x"_a, "has_last"_a, "applied"_a, "force"_a, "target"_a, "point_local"_a,
      "Adds a spring-damper push (reflexarm::SpringPush; rest NaN: off) with its state; arrays of N rows.")
    .def("clear_pushes", [](PyLoop & self) { self.loop.setPushes({}); })
    .def(
      "push_state",
      [](PyLoop & self, size_t i) {
        const auto & p = self.loop.pushes().at(i);
        const auto v3 = [](const double * a) { return std::make_tuple(a[0], a[1], a[2]); };
        return std::make_tuple(p.last_x, p.has_last, p.applied, v3(p.force), v3(p.target), v3(p.point_local));
      },
      "i"_a, "(last_x, has_last, applied, force, target, point_local) of push i now.")
    .def(
      "record_measured_velocity",
      [](PyLoop & self, nb::object dq_meas) {
        if (dq_meas.is_none())
        {
          self.loop.setMeasuredVelocityBuffer(nullptr);
          return;
        }
        Arr<double> a;
        if (!nb::try_cast(dq_meas, a, false))
          throw reflexarm::ConfigError("ClosedLoop: dq_meas must be a writable C-contiguous float64 array");
        self.loop.setMeasuredVelocityBuffer(rowsOf(a, self.rows, self.loop.nv(), "dq_meas"));
      },
      "dq_meas"_a.none(),
      "Record the measured (noisy) velocity of each tick into dq_meas (rows x n, the rows of set_buffers; call "
      "after it, which stops the recording; None: stop).")
    .def(
      "keep_still", [](PyLoop & self, int spec) { self.loop.keepStill(spec); }, "spec"_a,
      "Keep MuJoCo's state (mj_getState with the mjtState mask `spec`; 0: stop) at the first tick sensed and at "
      "the tick of the largest sum of tau_ext_i^2 (strictly larger than any before; reflexarm::StillStates).")
    .def(
      "still_states",
      [](PyLoop & self) {
        const auto & s = self.loop.still();
        const auto arr = [](const std::vector<double> & v) {
          auto * data = new double[v.size()];
          std::copy(v.begin(), v.end(), data);
          nb::capsule owner(data, [](void * p) noexcept { delete[] static_cast<double *>(p); });
          return nb::ndarray<nb::numpy, double, nb::ndim<1>>(data, {v.size()}, owner);
        };
        return std::make_tuple(s.spec, s.start_tick, arr(s.start), s.peak_tick, arr(s.peak), s.peak2);
      },
      nb::rv_policy::move, "(spec, start tick, start state, peak tick (-1: none), peak state, peak sum of tau_ext_i^2), copied.")
    .def("reset_controller", [](PyLoop & self) { self.loop.controller().reset(); })
    .def(
      "set_contact_geometry",
      [](PyLoop & self, const std::vector<reflexarm_bindings::Rows3> & points,
         const std::vector<reflexarm_bindings::Rows3> & normals, double significance_share, double fit_tolerance,
         double relative_tolerance, double friction_coefficient, int cone_edges) {
        self.loop.controller().setContactGeometry(
          reflexarm_bindings::surfacesFrom(points, normals), significance_share,
          reflexarm_bindings::isolationParams(fit_tolerance, relative_tolerance, friction_coefficient, cone_edges));
      },
      "points"_a, "normals"_a, "significance_share"_a, "fit_tolerance"_a, "relative_tolerance"_a,
      "friction_coefficient"_a, "cone_edges"_a, "As reflexarm._core.Controller.set_contact_geometry.")
    .def_prop_rw(
      "quiet_timers", [](PyLoop & self) { return self.loop.quietTimers(); },
      [](PyLoop & self, bool on) { self.loop.setQuietTimers(on); },
      "Step the physics with MuJoCo's profiling timers on a clock of 0 (reflexarm::QuietTimers; default False).")
    .def(
      "set_applied_torque",
      [](PyLoop & self, const Arr<const double> & tau) {
        const double * p = rowsOf(tau, self.loop.nv(), 0, "tau");
        for (int i = 0; i < self.loop.nv(); ++i)
          self.loop.appliedTorque()[i] = p[i];
      },
      "tau"_a)
    .def_prop_ro("applied_torque", [](PyLoop & self) { return Eigen::VectorXd(self.loop.appliedTorque()); })
    .def_prop_ro("first_time", [](PyLoop & self) { return self.loop.controller().firstDetectionTime(); })
    .def_prop_ro("detected", [](PyLoop & self) { return self.loop.controller().detected(); })
    .def_prop_ro("reacted", [](PyLoop & self) { return self.loop.controller().reacted(); })
    .def_prop_ro("event", [](PyLoop & self) { return reflexarm_bindings::eventDict(self.loop.controller()); })
    .def_prop_ro("mode", [](PyLoop & self) {
      return std::string(reflexarm::modeName(self.loop.controller().mode()));
    });
}
