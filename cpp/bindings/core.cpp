// reflexarm._core: the C++ controller from Python (nanobind).
//
// The model crosses the language boundary as text (pin.Model.saveToString() in Python, Boost
// serialization): the Python `pin.Model` is a Boost.Python object that nanobind cannot take directly.
// Inputs are float64 C-contiguous vectors (anything else raises TypeError instead of being copied
// silently: the caller converts once). update() returns the compiled kernel's status encoding (negative fault code, else
// n_over + (n_saturated << 8)); the command lives in buffers sized once, read through numpy views.
#include <cmath>
#include <string>

#include <nanobind/eigen/dense.h>
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>

#include "reflexarm/model_io.hpp"
#include "reflexarm/reflexarm.hpp"

namespace nb = nanobind;
using namespace nb::literals;

namespace
{
  using In = nb::ndarray<const double, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
  using Map = Eigen::Map<const Eigen::VectorXd>;
  template<typename T>
  using View = nb::ndarray<nb::numpy, const T, nb::ndim<1>>;
  using MatView = nb::ndarray<nb::numpy, const double, nb::ndim<2>>;
  using WritableView = nb::ndarray<nb::numpy, double, nb::ndim<1>>;
  constexpr int kSatShift = 8; // as reflexarm.control._kernels.SAT_SHIFT

  struct PyController
  {
    reflexarm::Controller ctrl;
    reflexarm::Command cmd;
  };

  Map asMap(const In & a)
  {
    return Map(a.data(), static_cast<Eigen::Index>(a.shape(0)));
  }

  reflexarm::Reaction reactionFromName(const std::string & name)
  {
    if (name == "gravity")
      return reflexarm::Reaction::Gravity;
    if (name == "compliant")
      return reflexarm::Reaction::Compliant;
    if (name == "none")
      return reflexarm::Reaction::None;
    throw reflexarm::ConfigError("unknown reaction '" + name + "'; choose one of: gravity, compliant, none");
  }

  int tick(PyController & c, double t, double period, const In & q, const In & dq, const In & tau_m,
           const In & wrench, const In & gravity, const In & q_d, const In & dq_d, const In & ddq_d)
  {
    const Map mq = asMap(q), mdq = asMap(dq), mtau = asMap(tau_m), mw = asMap(wrench), mg = asMap(gravity);
    const Map mqd = asMap(q_d), mdqd = asMap(dq_d), mddqd = asMap(ddq_d);
    const reflexarm::State s{mq, mdq, mtau, mw, mg};
    const reflexarm::Reference r{mqd, mdqd, mddqd};
    const auto code = c.ctrl.update(t, period, s, r, c.cmd);
    if (code != reflexarm::FaultCode::None)
      return static_cast<int>(code);
    return c.cmd.n_collided + (c.cmd.n_saturated << kSatShift);
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
  m.attr("SAT_SHIFT") = kSatShift;

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
    .def_rw("threshold", &P::threshold)
    .def_prop_rw(
      "reaction", [](const P & p) { return std::string(reflexarm::reactionName(p.reaction)); },
      [](P & p, const std::string & name) { p.reaction = reactionFromName(name); })
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
      [](PyController & c, double t, const In & q, const In & dq, const In & tau_m, const In & wrench,
         const In & gravity, const In & q_d, const In & dq_d, const In & ddq_d) {
        return tick(c, t, 0.0, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d);
      },
      "t"_a.noconvert(), "q"_a.noconvert(), "dq"_a.noconvert(), "tau_m"_a.noconvert(), "wrench"_a.noconvert(),
      "gravity"_a.noconvert(), "q_d"_a.noconvert(), "dq_d"_a.noconvert(), "ddq_d"_a.noconvert(),
      "One tick, the period measured from the time stamps (t must be a float); returns a negative fault code, "
      "else n_collided + (n_saturated << SAT_SHIFT).")
    .def(
      "update_with_period",
      [](PyController & c, double t, double period, const In & q, const In & dq, const In & tau_m,
         const In & wrench, const In & gravity, const In & q_d, const In & dq_d, const In & ddq_d) {
        return tick(c, t, period, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d);
      },
      "t"_a, "period"_a, "q"_a.noconvert(), "dq"_a.noconvert(), "tau_m"_a.noconvert(), "wrench"_a.noconvert(),
      "gravity"_a.noconvert(), "q_d"_a.noconvert(), "dq_d"_a.noconvert(), "ddq_d"_a.noconvert(),
      "One tick with ros2_control's measured period [s] (0: from the time stamps); returns as update().")
    .def("reset", [](PyController & c) { c.ctrl.reset(); })
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
      "(signal id, component, value, lo, hi) of the last fault (ids as reflexarm.control._kernels.SIG_*)")
    // ---------------------------------------------------------------- controller state
    .def_prop_ro("mode", [](const PyController & c) { return std::string(reflexarm::modeName(c.ctrl.mode())); })
    .def_prop_ro("kappa_f", [](const PyController & c) { return c.ctrl.kappaF(); })
    .def_prop_ro("kappa_eps", [](const PyController & c) { return c.ctrl.kappaEps(); })
    .def_prop_ro("kappa_ext", [](const PyController & c) { return c.ctrl.kappaExt(); })
    .def_prop_ro("eps_weight", [](const PyController & c) { return c.ctrl.epsWeight(); })
    .def_prop_ro("reacted", [](const PyController & c) { return c.ctrl.reacted(); })
    .def_prop_ro("detected", [](const PyController & c) { return c.ctrl.detected(); })
    .def_prop_ro("first_time", [](const PyController & c) { return c.ctrl.firstDetectionTime(); })
    .def_prop_ro("first_joints", [](nb::handle_t<PyController> h) {
      auto & c = nb::cast<PyController &>(h);
      const auto & j = c.ctrl.firstDetectionJoints();
      return view<std::uint8_t>(h, j.data(), j.size());
    })
    .def_prop_ro("observer_invalid", [](const PyController & c) { return c.ctrl.observerInvalid(); })
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
