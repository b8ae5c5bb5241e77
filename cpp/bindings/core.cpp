// reflexarm._core: the C++ controller from Python (nanobind).
//
// The model crosses the language boundary as text (pin.Model.saveToString() in Python, Boost
// serialization): the Python `pin.Model` is a Boost.Python object that nanobind cannot take directly.
// Inputs are float64 C-contiguous vectors read in place (tick_io.hpp: plain numpy arrays from their fields,
// other objects through the buffer protocol; anything else raises TypeError instead of being copied silently:
// the caller converts once). update() returns a status (negative fault code, else n_over + (n_saturated << 8));
// the command lives in buffers sized once, read through numpy views. step_signals(measurement, reference) is
// Controller.step's fast path: the Measurement and Reference tuples read here, the plain Command built here.
#include <cmath>
#include <cstring>
#include <initializer_list>
#include <string>

#include <nanobind/eigen/dense.h>
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>

#include "reflexarm/model_io.hpp"
#include "reflexarm/reflexarm.hpp"
#include "event_dict.hpp"
#include "py_controller.hpp"
#include "replay.hpp"
#include "tick_io.hpp"

namespace nb = nanobind;
using namespace nb::literals;

void registerTiming(nb::module_ & m); // timing.cpp: time_tick_in_cpp (bench_cpp_core.py), time_ticks_in_cpp
void bindIsolation(nb::module_ & m);  // isolation.cpp: ContactIsolator

namespace
{
  using reflexarm_bindings::Map;
  using reflexarm_bindings::PyController;
  using reflexarm_bindings::newArrayCopy;
  using reflexarm_bindings::readFloat;
  using reflexarm_bindings::TickInputs;
  template<typename T>
  using View = nb::ndarray<nb::numpy, const T, nb::ndim<1>>;
  using MatView = nb::ndarray<nb::numpy, const double, nb::ndim<2>>;
  using WritableView = nb::ndarray<nb::numpy, double, nb::ndim<1>>;
  constexpr int kSatShift = 8; // status = n_collided + (n_saturated << kSatShift)


  reflexarm::Reaction reactionFromName(const std::string & name)
  {
    if (name == "gravity")
      return reflexarm::Reaction::Gravity;
    if (name == "compliant")
      return reflexarm::Reaction::Compliant;
    if (name == "none")
      return reflexarm::Reaction::None;
    if (name == "brake")
      return reflexarm::Reaction::Brake;
    if (name == "retract")
      return reflexarm::Reaction::Retract;
    throw reflexarm::ConfigError(
      "unknown reaction '" + name + "'; choose one of: gravity, brake, retract, compliant, none");
  }

  reflexarm::ObserverDiscretization discretizationFromName(const std::string & name)
  {
    if (name == "euler")
      return reflexarm::ObserverDiscretization::Euler;
    if (name == "exact")
      return reflexarm::ObserverDiscretization::Exact;
    throw reflexarm::ConfigError("unknown observer_discretization '" + name + "'; choose one of: euler, exact");
  }



  /// One tick on inputs already read; returns a negative fault code, else n_collided + (n_saturated << kSatShift).
  int tick(PyController & c, double t, double period, const TickInputs & in)
  {
    const Map mq = in[0], mdq = in[1], mtau = in[2], mw = in[3], mg = in[4], mqd = in[5], mdqd = in[6],
              mddqd = in[7];
    const reflexarm::State s{mq, mdq, mtau, mw, mg};
    const reflexarm::Reference r{mqd, mdqd, mddqd};
    const auto code = c.ctrl.update(t, period, s, r, c.cmd);
    if (code != reflexarm::FaultCode::None)
      return static_cast<int>(code);
    return c.cmd.n_collided + (c.cmd.n_saturated << kSatShift);
  }

  /// One tick on eight vectors given one by one: C-contiguous float64 vectors, else TypeError (the Python
  /// Controller then converts once).
  int tick(PyController & c, double t, double period, nb::handle q, nb::handle dq, nb::handle tau_m,
           nb::handle wrench, nb::handle gravity, nb::handle q_d, nb::handle dq_d, nb::handle ddq_d)
  {
    PyObject * const objects[TickInputs::kCount] = {q.ptr(),       dq.ptr(),      tau_m.ptr(), wrench.ptr(),
                                                    gravity.ptr(), q_d.ptr(),     dq_d.ptr(),  ddq_d.ptr()};
    TickInputs in;
    if (!in.read(objects))
      throw nb::type_error("tick inputs must be C-contiguous float64 vectors");
    return tick(c, t, period, in);
  }

  /// The Command of a plain tick (accepted, no threshold crossing, nothing bounded), tau and residual in new
  /// arrays of their own.
  nb::object plainCommand(PyController & c)
  {
    nb::object tau = nb::steal(newArrayCopy(c.cmd.tau));
    if (!tau.is_valid())
      throw nb::python_error();
    nb::object residual = nb::steal(newArrayCopy(c.cmd.residual));
    if (!residual.is_valid())
      throw nb::python_error();
    // a Command is a tuple subclass: allocate it with its 8 items directly (what tuple.__new__ does)
    // (no Python allocation between tp_alloc and the last item: the half-filled tuple is never seen)
    auto * type = reinterpret_cast<PyTypeObject *>(c.command_type.ptr());
    PyObject * out = type->tp_alloc(type, 8);
    if (!out)
      throw nb::python_error();
    PyTuple_SET_ITEM(out, 0, tau.release().ptr());
    PyTuple_SET_ITEM(out, 1, residual.release().ptr());
    PyTuple_SET_ITEM(out, 2, nb::bool_(c.cmd.collision).release().ptr()); // Py_True/Py_False
    PyTuple_SET_ITEM(out, 3, c.empty_tuple.inc_ref().ptr());
    PyTuple_SET_ITEM(out, 4, c.mode_names[static_cast<int>(c.cmd.mode)].inc_ref().ptr());
    PyTuple_SET_ITEM(out, 5, c.empty_str.inc_ref().ptr());
    PyTuple_SET_ITEM(out, 6, c.empty_tuple.inc_ref().ptr());
    PyTuple_SET_ITEM(out, 7, c.zero.inc_ref().ptr());
    return nb::steal(out);
  }

  /// step(measurement, reference): the tick straight from a Measurement (t, q, dq, tau_m, wrench, gravity) and
  /// a Reference (q_d, dq_d, ddq_d), both tuples (NamedTuples are tuple subclasses), t a float or numpy.float64
  /// and the vectors readable by TickInputs. Returns the Command of a plain tick, the status int of update()
  /// otherwise, and None without touching the controller when the inputs are not of these types (the Python
  /// Controller then unpacks, converts or raises as for any other input).
  nb::object stepSignals(PyController & c, nb::handle measurement, nb::handle reference)
  {
    PyObject * m = measurement.ptr();
    PyObject * r = reference.ptr();
    double t = 0.0;
    if (!PyTuple_Check(m) || PyTuple_GET_SIZE(m) != 6 || !PyTuple_Check(r) || PyTuple_GET_SIZE(r) != 3
        || !readFloat(PyTuple_GET_ITEM(m, 0), t) || !c.command_type.is_valid())
      return nb::none();
    PyObject * const objects[TickInputs::kCount] = {
      PyTuple_GET_ITEM(m, 1), PyTuple_GET_ITEM(m, 2), PyTuple_GET_ITEM(m, 3), PyTuple_GET_ITEM(m, 4),
      PyTuple_GET_ITEM(m, 5), PyTuple_GET_ITEM(r, 0), PyTuple_GET_ITEM(r, 1), PyTuple_GET_ITEM(r, 2)};
    TickInputs in;
    if (!in.read(objects))
      return nb::none();
    const int status = tick(c, t, 0.0, in);
    if (status != 0)
      return nb::int_(status);
    return plainCommand(c);
  }

  template<typename T>
  View<T> view(nb::handle owner, const T * data, Eigen::Index n)
  {
    return View<T>(data, {static_cast<size_t>(n)}, owner);
  }
} // namespace

NB_MODULE(_core, m)
{
  m.doc() = "reflexarm's real-time core (C++): the control tick of eqs. (2), (4)-(6), (9)-(13)";
  reflexarm_bindings::importNumpy();
  registerTiming(m);
  bindIsolation(m);
  m.attr("SAT_SHIFT") = kSatShift;

  using RP = reflexarm::ReactionParams;
  nb::class_<RP>(m, "ReactionParams")
    .def(nb::init<>())
    .def_rw("brake_time", &RP::brake_time)
    .def_rw("brake_duration", &RP::brake_duration)
    .def_rw("retract_distance", &RP::retract_distance)
    .def_rw("max_retract_angle", &RP::max_retract_angle)
    .def_rw("retract_speed", &RP::retract_speed)
    .def_rw("max_retract_time", &RP::max_retract_time)
    .def_rw("energy_filter_time", &RP::energy_filter_time)
    .def_rw("velocity_fraction", &RP::velocity_fraction)
    .def_rw("compliant_stiffness_factor", &RP::compliant_stiffness_factor)
    .def_rw("rest_time", &RP::rest_time)
    .def_rw("rest_energy_fraction", &RP::rest_energy_fraction)
    .def_rw("rest_energy_floor", &RP::rest_energy_floor)
    .def_rw("contact_level", &RP::contact_level)
    .def_rw("position_margin", &RP::position_margin)
    .def_rw("isolation_delay", &RP::isolation_delay)
    .def_rw("isolation_points_per_tick", &RP::isolation_points_per_tick)
    .def_rw("retract_waits_for_estimate", &RP::retract_waits_for_estimate);

  nb::class_<reflexarm::InputBounds>(m, "InputBounds")
    .def(nb::init<>())
    .def_rw("position_margin", &reflexarm::InputBounds::position_margin)
    .def_rw("velocity_factor", &reflexarm::InputBounds::velocity_factor)
    .def_rw("torque_factor", &reflexarm::InputBounds::torque_factor)
    .def_rw("max_force", &reflexarm::InputBounds::max_force)
    .def_rw("max_moment", &reflexarm::InputBounds::max_moment)
    .def_rw("gravity_tolerance", &reflexarm::InputBounds::gravity_tolerance)
    .def_rw("max_acceleration", &reflexarm::InputBounds::max_acceleration)
    .def_rw("max_velocity", &reflexarm::InputBounds::max_velocity)
    .def_rw("max_torque", &reflexarm::InputBounds::max_torque);

  using P = reflexarm::ControllerParams;
  nb::class_<P>(m, "ControllerParams")
    .def(nb::init<>())
    .def_rw("stiffness", &P::stiffness)
    .def_rw("damping_ratio", &P::damping_ratio)
    .def_rw("observer_gain", &P::observer_gain)
    .def_rw("detection_observer_gain", &P::detection_observer_gain)
    .def_rw("detection_kappa_f", &P::detection_kappa_f)
    .def_rw("detection_friction_velocity_band", &P::detection_friction_velocity_band)
    .def_rw("detection_filter_gain", &P::detection_filter_gain)
    .def_rw("threshold", &P::threshold)
    .def_prop_rw(
      "reaction", [](const P & p) { return std::string(reflexarm::reactionName(p.reaction)); },
      [](P & p, const std::string & name) { p.reaction = reactionFromName(name); })
    .def_prop_rw(
      "contact_reaction", [](const P & p) { return std::string(reflexarm::reactionName(p.contact_reaction)); },
      [](P & p, const std::string & name) { p.contact_reaction = reactionFromName(name); })
    .def_prop_rw(
      "observer_discretization",
      [](const P & p) {
        return std::string(p.observer_discretization == reflexarm::ObserverDiscretization::Exact ? "exact" : "euler");
      },
      [](P & p, const std::string & name) { p.observer_discretization = discretizationFromName(name); })
    .def_rw("reaction_params", &P::reaction_params)
    .def_rw("kappa_f", &P::kappa_f)
    .def_rw("kappa_eps", &P::kappa_eps)
    .def_rw("kappa_ext", &P::kappa_ext)
    .def_rw("residual_limit", &P::residual_limit)
    .def_rw("switch_time", &P::switch_time)
    .def_rw("dt", &P::dt)
    .def_rw("damping_update_period", &P::damping_update_period)
    .def_rw("friction_coulomb", &P::friction_coulomb)
    .def_rw("friction_viscous", &P::friction_viscous)
    .def_rw("friction_velocity_band", &P::friction_velocity_band)
    .def_rw("spring_stiffness", &P::spring_stiffness)
    .def_rw("spring_reference", &P::spring_reference)
    .def_rw("sensor_frame_id", &P::sensor_frame_id)
    .def_rw("torque_limit", &P::torque_limit)
    .def_rw("torque_rate_limit", &P::torque_rate_limit)
    .def_rw("input_bounds", &P::input_bounds)
    .def_rw("period_band_low", &P::period_band_low)
    .def_rw("period_band_high", &P::period_band_high);

  nb::class_<PyController>(m, "Controller")
    .def(
      "__init__",
      [](PyController * self, const std::string & model_text, const P & params) {
        new (self) PyController();
        self->ctrl.configure(reflexarm::modelFromString(model_text), params);
        self->ctrl.initCommand(self->cmd);
      },
      "model_text"_a, "params"_a,
      "Configure from a Pinocchio model given as text (pin.Model.saveToString()) and the parameters.")
    .def(
      "update",
      [](PyController & c, double t, nb::handle q, nb::handle dq, nb::handle tau_m, nb::handle wrench,
         nb::handle gravity, nb::handle q_d, nb::handle dq_d, nb::handle ddq_d) {
        return tick(c, t, 0.0, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d);
      },
      "t"_a.noconvert(), "q"_a, "dq"_a, "tau_m"_a, "wrench"_a, "gravity"_a, "q_d"_a, "dq_d"_a, "ddq_d"_a,
      "One tick, the period measured from the time stamps (t must be a float); returns a negative fault code, "
      "else n_collided + (n_saturated << SAT_SHIFT).")
    .def(
      "update_with_period",
      [](PyController & c, double t, double period, nb::handle q, nb::handle dq, nb::handle tau_m,
         nb::handle wrench, nb::handle gravity, nb::handle q_d, nb::handle dq_d, nb::handle ddq_d) {
        return tick(c, t, period, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d);
      },
      "t"_a, "period"_a, "q"_a, "dq"_a, "tau_m"_a, "wrench"_a, "gravity"_a, "q_d"_a, "dq_d"_a, "ddq_d"_a,
      "One tick with ros2_control's measured period [s] (0: from the time stamps); returns as update().")
    .def(
      "set_command_type",
      [](nb::handle_t<PyController> h, nb::object type) {
        auto & c = nb::cast<PyController &>(h);
        c.command_type = type;
        c.empty_tuple = nb::steal(PyTuple_New(0));
        c.empty_str = nb::str("");
        c.zero = nb::int_(0);
        for (int m = 0; m < reflexarm::kModeCount; ++m)
          c.mode_names[m] = nb::str(reflexarm::modeName(static_cast<reflexarm::Mode>(m)));
      },
      "command_type"_a, "The tuple subclass step() returns (reflexarm.signals.Command).")
    .def(
      "step",
      [](PyController & c, double t, nb::handle q, nb::handle dq, nb::handle tau_m, nb::handle wrench,
         nb::handle gravity, nb::handle q_d, nb::handle dq_d, nb::handle ddq_d) -> nb::object {
        const int status = tick(c, t, 0.0, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d);
        if (status != 0 || !c.command_type.is_valid())
          return nb::int_(status);
        return plainCommand(c);
      },
      "t"_a.noconvert(), "q"_a, "dq"_a, "tau_m"_a, "wrench"_a, "gravity"_a, "q_d"_a, "dq_d"_a, "ddq_d"_a,
      "One tick as update(); returns the Command (of set_command_type) of an accepted tick without events, "
      "else the status int of update().")
    .def("step_signals", &stepSignals, "measurement"_a, "reference"_a,
         "One tick from a Measurement and a Reference: the Command of an accepted tick without events, else the "
         "status int of update(); None (nothing done) for inputs other than tuples of a float time and "
         "C-contiguous float64 vectors.")
    .def("reset", [](PyController & c) {
      c.ctrl.reset();
      c.cmd.fault_code = reflexarm::FaultCode::None; // the last command's fault text is cleared as well
      c.cmd.fault_text[0] = '\0';
    })
    .def(
      "replay",
      [](PyController & c, const reflexarm_bindings::ReplayCol & t, const reflexarm_bindings::ReplayRows & q,
         const reflexarm_bindings::ReplayRows & dq, const reflexarm_bindings::ReplayRows & tau_m, nb::handle wrench,
         const reflexarm_bindings::ReplayCol & gravity, nb::handle residual, nb::handle tau, nb::handle over,
         nb::handle collision, nb::handle mode, nb::handle status, size_t max_faults, bool residual_only,
         int threads) {
        return reflexarm_bindings::replay(c.ctrl, c.cmd, t, q, dq, tau_m, wrench, gravity, residual, tau, over,
                                          collision, mode, status, max_faults, residual_only, threads);
      },
      "t"_a, "q"_a, "dq"_a, "tau_m"_a, "wrench"_a.none(), "gravity"_a, "residual"_a, "tau"_a.none(), "over"_a.none(),
      "collision"_a.none(), "mode"_a.none(), "status"_a.none(), "max_faults"_a = 16, "residual_only"_a = false,
      "threads"_a = 1,
      "A whole log through update() (reflexarm::replayLog; reference: a hold at the measured q) into the given "
      "output arrays, or with residual_only through its contract, observers and detection only "
      "(reflexarm::replayResiduals, on `threads` threads: 1 or 2); returns (rejected rows, [(row, fault text)] of "
      "the first max_faults, whether the residual-only path ran, why not).")
    .def(
      "copy_state_from",
      [](PyController & self, const PyController & other) {
        if (other.ctrl.nv() != self.ctrl.nv())
          throw reflexarm::ConfigError("copy_state_from: the controllers have different numbers of joints");
        self.ctrl = other.ctrl; // every buffer keeps its size: the numpy views into self stay valid
        self.cmd = other.cmd;
      },
      "other"_a, "Make this controller's whole state (model, parameters, observers, event, command) a copy of other's.")
    .def(
      "set_contact_geometry",
      [](PyController & c, const std::vector<reflexarm_bindings::Rows3> & points,
         const std::vector<reflexarm_bindings::Rows3> & normals, double significance_share, double fit_tolerance,
         double relative_tolerance, double friction_coefficient, int cone_edges) {
        c.ctrl.setContactGeometry(
          reflexarm_bindings::surfacesFrom(points, normals), significance_share,
          reflexarm_bindings::isolationParams(fit_tolerance, relative_tolerance, friction_coefficient, cone_edges));
      },
      "points"_a, "normals"_a, "significance_share"_a, "fit_tolerance"_a, "relative_tolerance"_a,
      "friction_coefficient"_a, "cone_edges"_a,
      "The links' collision surfaces (per joint (m, 3) points and outward normals in the joint frame): detected "
      "collisions are then isolated in update().")
    .def(
      "set_switches",
      [](PyController & c, int kappa_f, int kappa_eps, int kappa_ext) {
        for (int v : {kappa_f, kappa_eps, kappa_ext})
          if (v != -1 && v != 0 && v != 1)
            throw reflexarm::ConfigError("kappa switches must be 0 or 1 (-1: unchanged); got " + std::to_string(v));
        c.ctrl.setSwitches(kappa_f, kappa_eps, kappa_ext);
      },
      "kappa_f"_a = -1, "kappa_eps"_a = -1, "kappa_ext"_a = -1)
    // ---------------------------------------------------------------- the last command (views)
    .def_prop_ro("n", [](const PyController & c) { return c.ctrl.nv(); })
    .def_prop_ro("tau", [](nb::handle_t<PyController> h) {
      auto & c = nb::cast<PyController &>(h);
      return view<double>(h, c.cmd.tau.data(), c.cmd.tau.size());
    })
    .def_prop_ro("residual", [](nb::handle_t<PyController> h) {
      auto & c = nb::cast<PyController &>(h);
      return view<double>(h, c.cmd.residual.data(), c.cmd.residual.size());
    })
    .def_prop_ro("collided", [](nb::handle_t<PyController> h) {
      auto & c = nb::cast<PyController &>(h);
      return view<std::uint8_t>(h, c.cmd.collided.data(), c.cmd.collided.size());
    })
    .def_prop_ro("saturated", [](nb::handle_t<PyController> h) {
      auto & c = nb::cast<PyController &>(h);
      return view<std::uint8_t>(h, c.cmd.saturated.data(), c.cmd.saturated.size());
    })
    .def_prop_ro("collision", [](const PyController & c) { return c.cmd.collision; })
    .def_prop_ro("command_mode", [](const PyController & c) { return std::string(reflexarm::modeName(c.cmd.mode)); })
    .def_prop_ro("fault", [](const PyController & c) { return std::string(c.cmd.fault_text.data()); })
    .def_prop_ro("fault_code", [](const PyController & c) { return static_cast<int>(c.cmd.fault_code); })
    .def_prop_ro(
      "fault_info",
      [](const PyController & c) {
        const auto & f = c.cmd.fault;
        return std::make_tuple(static_cast<int>(f.signal), f.index, f.value, f.lo, f.hi);
      },
      "(signal id, component, value, lo, hi) of the last fault (ids as reflexarm.control.contract.SIG_*)")
    // ---------------------------------------------------------------- controller state
    .def_prop_ro("mode", [](const PyController & c) { return std::string(reflexarm::modeName(c.ctrl.mode())); })
    .def_prop_ro("kappa_f", [](const PyController & c) { return c.ctrl.kappaF(); })
    .def_prop_ro("kappa_eps", [](const PyController & c) { return c.ctrl.kappaEps(); })
    .def_prop_ro("kappa_ext", [](const PyController & c) { return c.ctrl.kappaExt(); })
    .def_prop_ro("eps_weight", [](const PyController & c) { return c.ctrl.epsWeight(); })
    .def_prop_ro("reacted", [](const PyController & c) { return c.ctrl.reacted(); })
    .def_prop_ro("event", [](const PyController & c) { return reflexarm_bindings::eventDict(c.ctrl); },
                 "The collision event record since the last reset (a dict of copies).")
    .def_prop_ro("detected", [](const PyController & c) { return c.ctrl.detected(); })
    .def_prop_ro("first_time", [](const PyController & c) { return c.ctrl.firstDetectionTime(); })
    .def_prop_ro("first_joints", [](nb::handle_t<PyController> h) {
      auto & c = nb::cast<PyController &>(h);
      const auto & j = c.ctrl.firstDetectionJoints();
      return view<std::uint8_t>(h, j.data(), j.size());
    })
    .def_prop_ro("observer_invalid", [](const PyController & c) { return c.ctrl.observerInvalid(); })
    .def_prop_ro(
      "damping_parts_run", [](const PyController & c) { return c.ctrl.dampingPartsRun(); },
      "Which parts of the modal damping computation the last tick ran, as bits (0: none); for benches.")
    .def_prop_ro(
      "law_mode_share", [](const PyController & c) { return c.ctrl.lawModeShare(); },
      "The law sampled at dt: largest omega dt / its stability limit over the modes of the damping in use (>= 1 "
      "unstable; NaN before the first damping)")
    .def_prop_ro("timing", [](const PyController & c) {
      const auto & s = c.ctrl.timing();
      return std::make_tuple(s.n_periods, s.sum_period, s.min_period, s.max_period, s.clipped, s.band_low, s.band_high);
    }, "(n_periods, sum, min, max, clipped, band_low, band_high) of the measured periods [s]")
    .def_prop_ro("observer_residual", [](nb::handle_t<PyController> h) {
      auto & c = nb::cast<PyController &>(h);
      return view<double>(h, c.ctrl.observer().residual.data(), c.ctrl.nv());
    })
    .def_prop_ro("detection_residual", [](nb::handle_t<PyController> h) {
      auto & c = nb::cast<PyController &>(h);
      return view<double>(h, c.ctrl.detectionResidual().data(), c.ctrl.nv());
    })
    .def_prop_ro("damping", [](nb::handle_t<PyController> h) {
      auto & c = nb::cast<PyController &>(h);
      const size_t n = static_cast<size_t>(c.ctrl.nv());
      // column-major Eigen storage; D is symmetric, so the row-major reading is the same matrix
      return MatView(c.ctrl.damping().data(), {n, n}, h);
    })
    .def_prop_ro("gravity", [](const PyController & c) { return Eigen::Vector3d(c.ctrl.gravity()); })
    .def_prop_ro(
      "bounds",
      [](const PyController & c) {
        return std::make_tuple(
          Eigen::VectorXd(c.ctrl.positionLow()), Eigen::VectorXd(c.ctrl.positionHigh()),
          Eigen::VectorXd(c.ctrl.velocityMax()), Eigen::VectorXd(c.ctrl.accelerationMax()),
          Eigen::VectorXd(c.ctrl.motorTorqueMax()), Eigen::VectorXd(c.ctrl.torqueMax()),
          Eigen::VectorXd(c.ctrl.torqueStep()));
      },
      "(q_lo, q_hi, dq_max, ddq_max, tau_m_max, tau_max, tau_step) per joint")
    .def(
      "_set_observer_integral",
      [](PyController & c, int joint, double value) { c.ctrl.observerState().integral[joint] = value; },
      "joint"_a, "value"_a, "Test hook: overwrite one entry of the observer's integral (e.g. with NaN).")
    .def_prop_ro(
      "observer_arrays",
      [](nb::handle_t<PyController> h) {
        auto & c = nb::cast<PyController &>(h);
        const size_t n = static_cast<size_t>(c.ctrl.nv());
        auto w = [&](Eigen::VectorXd & v) { return WritableView(v.data(), {n}, h); };
        auto & o = c.ctrl.observerState();
        auto & d = c.ctrl.detectionObserverState();
        return std::make_tuple(w(o.integral), w(o.p0), w(o.residual), w(d.integral), w(d.p0), w(d.residual));
      },
      "Writable views of both observers' states: (integral, p0, residual) of the compensation observer, then "
      "of the detection observer (zeros when there is none). For diagnostics and tests.");

  m.def(
    "modal_damping",
    [](const Eigen::MatrixXd & M, const Eigen::VectorXd & stiffness,
       const Eigen::VectorXd & damping_ratio) -> nb::object {
      const Eigen::Index n = M.rows();
      if (M.cols() != n || stiffness.size() != n || damping_ratio.size() != n)
        throw reflexarm::ConfigError(
          "modal_damping: M must be n x n and stiffness, damping_ratio of size n; got M " + std::to_string(M.rows())
          + " x " + std::to_string(M.cols()) + ", stiffness " + std::to_string(stiffness.size())
          + ", damping_ratio " + std::to_string(damping_ratio.size()));
      reflexarm::ModalDampingWorkspace ws(n);
      Eigen::MatrixXd out = Eigen::MatrixXd::Zero(n, n);
      if (!reflexarm::computeModalDamping(M, stiffness, damping_ratio, ws, out))
        return nb::none();
      return nb::cast(out);
    },
    "M"_a, "stiffness"_a, "damping_ratio"_a,
    "D of eq. (2) by double diagonalization (reads the upper triangle of M); None if M is not finite or not "
    "positive definite.");

  m.def(
    "describe_fault",
    [](int code, int signal, int index, double value, double lo, double hi) {
      char buf[256];
      reflexarm::describeFault(
        static_cast<reflexarm::FaultCode>(code),
        reflexarm::FaultInfo{static_cast<reflexarm::Signal>(signal), index, value, lo, hi}, buf, sizeof(buf));
      return std::string(buf);
    },
    "code"_a, "signal"_a, "index"_a, "value"_a, "lo"_a, "hi"_a, "The fault text of the C++ core.");
  m.def("format_repr", [](double v) {
    char buf[64];
    reflexarm::formatRepr(v, buf, sizeof(buf));
    return std::string(buf);
  });
}
