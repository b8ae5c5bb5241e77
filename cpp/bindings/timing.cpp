// reflexarm._core.time_tick_in_cpp: the tick and its four bare Pinocchio calls timed inside C++, on the same
// states, alternating which goes first, so that bench/bench_cpp_core.py prints both ratios of issue 10 in one run
// (tick from Python / calls from Python, and tick in C++ / calls in C++).
#include <chrono>
#include <string>
#include <utility>
#include <vector>

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/tuple.h>

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
}
