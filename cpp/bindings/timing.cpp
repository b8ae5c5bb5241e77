// reflexarm._core.time_tick_in_cpp: the tick and its four bare Pinocchio calls timed inside C++, on the same
// states, alternating which goes first, so that bench/bench_cpp_core.py prints both ratios of issue 10 in one run
// (tick from Python / calls from Python, and tick in C++ / calls in C++); and reflexarm._core.time_ticks_in_cpp:
// the bound controllers' own update() timed per tick inside C++ over one state sequence, controller after controller
// and round after round, so that bench/bench_collision_tick.py compares each tick of a controller that isolates a
// collision with the same tick of one that does not (paired, same round) without Python's call overhead.
#include <algorithm>
#include <chrono>
#include <stdexcept>
#include <tuple>
#include <string>
#include <utility>
#include <vector>

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>

#include "py_controller.hpp"

#include "pinocchio/algorithm/frames.hpp"
#include "pinocchio/algorithm/rnea.hpp"

#include "reflexarm/model_io.hpp"
#include "reflexarm/reflexarm.hpp"

namespace nb = nanobind;
using namespace nb::literals;

namespace
{
  using Rows = nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
  using Col = nb::ndarray<const double, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
  using Out = nb::ndarray<nb::numpy, double, nb::ndim<1>>;
  using Map = Eigen::Map<const Eigen::VectorXd>;
  using Ref = Eigen::Ref<const Eigen::VectorXd>;
  using Clock = std::chrono::steady_clock;

  Map row(const Rows & a, size_t i)
  {
    return Map(a.data() + i * a.shape(1), static_cast<Eigen::Index>(a.shape(1)));
  }

  Out owned(std::vector<double> && v)
  {
    auto * data = new std::vector<double>(std::move(v));
    nb::capsule owner(data, [](void * p) noexcept { delete static_cast<std::vector<double> *>(p); });
    return Out(data->data(), {data->size()}, owner);
  }

  /// The state sequence of time_ticks_in_cpp: one row per tick of each input.
  struct Sequence
  {
    const Col & t;
    const Rows &q, &dq, &tau_m, &wrench, &gravity, &q_d, &dq_d, &ddq_d;
  };

  /// One controller over the whole sequence from reset(), each update() timed into out[0 .. n_states); the number of
  /// faulted ticks. `warm`: each tick runs twice from the same state (the controller and its command copied before the
  /// first run and copied back after it, untimed) and the second run is timed: the tick with its own data in cache.
  long timeSequence(reflexarm_bindings::PyController & c, const Sequence & seq, double * out, bool warm)
  {
    c.ctrl.reset();
    long faults = 0;
    reflexarm::Controller saved;
    reflexarm::Command saved_cmd;
    for (size_t i = 0; i < seq.t.shape(0); ++i)
    {
      const Map mq = row(seq.q, i), mdq = row(seq.dq, i), mtau = row(seq.tau_m, i), mw = row(seq.wrench, i);
      const Map mg = row(seq.gravity, i), mqd = row(seq.q_d, i), mdqd = row(seq.dq_d, i), mddqd = row(seq.ddq_d, i);
      const reflexarm::State s{mq, mdq, mtau, mw, mg};
      const reflexarm::Reference r{mqd, mdqd, mddqd};
      if (warm)
      {
        saved = c.ctrl;
        saved_cmd = c.cmd;
        c.ctrl.update(seq.t.data()[i], 0.0, s, r, c.cmd);
        c.ctrl = saved;
        c.cmd = saved_cmd;
      }
      const auto c0 = Clock::now();
      faults += c.ctrl.update(seq.t.data()[i], 0.0, s, r, c.cmd) != reflexarm::FaultCode::None;
      const auto c1 = Clock::now();
      if (out)
        out[i] = std::chrono::duration<double>(c1 - c0).count();
    }
    return faults;
  }

  /// time_ticks_in_cpp: an untimed warm-up pass of each controller, then `rounds` rounds; in round k the controllers
  /// run one after the other from the (k mod count)-th on (so that none is always first after another), each the
  /// whole sequence from reset(). Times [s] as (rounds, controllers, ticks), and the number of faulted ticks.
  std::tuple<nb::ndarray<nb::numpy, double, nb::ndim<3>>, long> timeTicks(
    const nb::list & controllers, const Sequence & seq, int rounds, bool warm)
  {
    std::vector<reflexarm_bindings::PyController *> cs;
    for (nb::handle h : controllers)
      cs.push_back(&nb::cast<reflexarm_bindings::PyController &>(h));
    const size_t n_ctrl = cs.size(), n_states = seq.t.shape(0);
    for (const Rows * a : {&seq.q, &seq.dq, &seq.tau_m, &seq.wrench, &seq.gravity, &seq.q_d, &seq.dq_d, &seq.ddq_d})
      if (a->shape(0) != n_states)
        throw std::invalid_argument("time_ticks_in_cpp: every input needs one row per time stamp");
    for (auto * c : cs)
      if (seq.q.shape(1) != static_cast<size_t>(c->ctrl.nv()))
        throw std::invalid_argument("time_ticks_in_cpp: q has another number of joints than a controller");
    const size_t count = std::max(rounds, 0);
    auto * data = new std::vector<double>(count * n_ctrl * n_states);
    nb::capsule owner(data, [](void * p) noexcept { delete static_cast<std::vector<double> *>(p); });
    long faults = 0;
    for (auto * c : cs)
      timeSequence(*c, seq, nullptr, warm);
    for (size_t round = 0; round < count; ++round)
      for (size_t j = 0; j < n_ctrl; ++j)
      {
        const size_t k = (round + j) % n_ctrl;
        faults += timeSequence(*cs[k], seq, data->data() + (round * n_ctrl + k) * n_states, warm);
      }
    return {nb::ndarray<nb::numpy, double, nb::ndim<3>>(data->data(), {count, n_ctrl, n_states}, owner), faults};
  }
} // namespace

void registerTiming(nb::module_ & m)
{
  m.def(
    "time_tick_in_cpp",
    [](const std::string & model_text, const reflexarm::ControllerParams & params, const Col & t, const Rows & q,
       const Rows & dq, const Rows & tau_m, const Rows & wrench, const Rows & gravity, const Rows & q_d,
       const Rows & dq_d, const Rows & ddq_d, int rounds) {
      const pinocchio::Model model = reflexarm::modelFromString(model_text);
      reflexarm::Controller ctrl;
      ctrl.configure(model, params);
      reflexarm::Command cmd;
      ctrl.initCommand(cmd);
      pinocchio::Model model0 = model;
      model0.gravity.linear().setZero();
      pinocchio::Data d_g(model), d_c(model), d_p(model0), d_ff(model0), d_j(model);
      const bool efc = params.kappa_ext != 0; // the tick then needs the sensor frame's Jacobian as well
      Eigen::VectorXd q_buf = Eigen::VectorXd::Zero(model.nv);
      Eigen::Matrix<double, 6, Eigen::Dynamic> J = Eigen::Matrix<double, 6, Eigen::Dynamic>::Zero(6, model.nv);
      const auto frame = static_cast<pinocchio::FrameIndex>(params.sensor_frame_id);
      const Eigen::VectorXd zeros_v = Eigen::VectorXd::Zero(model.nv);
      const Ref zeros(zeros_v);
      const size_t n_states = t.shape(0);
      std::vector<double> tick_s, calls_s;
      tick_s.reserve(n_states * static_cast<size_t>(rounds));
      calls_s.reserve(n_states * static_cast<size_t>(rounds));
      long faults = 0;
      for (int round = 0; round < rounds; ++round)
      {
        ctrl.reset();
        for (size_t i = 0; i < n_states; ++i)
        {
          const Map mq = row(q, i), mdq = row(dq, i), mtau = row(tau_m, i), mw = row(wrench, i), mg = row(gravity, i);
          const Map mqd = row(q_d, i), mdqd = row(dq_d, i), mddqd = row(ddq_d, i);
          auto calls = [&]() {
            const auto c0 = Clock::now();
            const Ref rq(mq), rdq(mdq), rqd(mqd), rddqd(mddqd);
            pinocchio::computeGeneralizedGravity(model, d_g, rq);
            pinocchio::computeCoriolisMatrix(model, d_c, rq, rdq);
            pinocchio::rnea(model0, d_p, rq, zeros, rdq);
            pinocchio::rnea(model0, d_ff, rqd, zeros, rddqd);
            if (efc)
            {
              q_buf = mq;
              pinocchio::computeFrameJacobian(model, d_j, q_buf, frame, pinocchio::LOCAL, J);
            }
            calls_s.push_back(std::chrono::duration<double>(Clock::now() - c0).count());
          };
          if ((i + static_cast<size_t>(round)) % 2 == 0)
            calls();
          const reflexarm::State s{mq, mdq, mtau, mw, mg};
          const reflexarm::Reference r{mqd, mdqd, mddqd};
          const auto c0 = Clock::now();
          faults += ctrl.update(t.data()[i], 0.0, s, r, cmd) != reflexarm::FaultCode::None;
          tick_s.push_back(std::chrono::duration<double>(Clock::now() - c0).count());
          if ((i + static_cast<size_t>(round)) % 2 == 1)
            calls();
        }
      }
      return std::make_tuple(owned(std::move(tick_s)), owned(std::move(calls_s)), faults);
    },
    "model_text"_a, "params"_a, "t"_a, "q"_a, "dq"_a, "tau_m"_a, "wrench"_a, "gravity"_a, "q_d"_a, "dq_d"_a,
    "ddq_d"_a, "rounds"_a,
    "Per-call times [s] of Controller::update and of its bare Pinocchio calls (g, C, two RNEAs; with kappa_ext "
    "the sensor Jacobian too), both in C++ on the same states (one row each), alternating which goes first; and "
    "the number of faulted ticks.");
  m.def(
    "time_ticks_in_cpp",
    [](const nb::list & controllers, const Col & t, const Rows & q, const Rows & dq, const Rows & tau_m,
       const Rows & wrench, const Rows & gravity, const Rows & q_d, const Rows & dq_d, const Rows & ddq_d, int rounds,
       bool warm) {
      return timeTicks(controllers, Sequence{t, q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d}, rounds, warm);
    },
    "controllers"_a, "t"_a, "q"_a, "dq"_a, "tau_m"_a, "wrench"_a, "gravity"_a, "q_d"_a, "dq_d"_a, "ddq_d"_a,
    "rounds"_a, "warm"_a = false,
    "Per-tick times [s] of the given bound Controllers' update() (period from the time stamps) inside C++ over one "
    "state sequence (one row per tick), as an array (rounds, controllers, ticks): an untimed warm-up pass of each, "
    "then per round each controller from reset() over the whole sequence, the first one rotating round by round; "
    "and the number of faulted ticks. warm: each tick is run twice from the same state (copied before the first "
    "run, restored after it, untimed) and the second run timed, its data in cache.");
}
