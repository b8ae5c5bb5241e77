// C++ tests of the reflexarm core: no heap allocation inside update(), bounded finite commands under bad
// inputs, faults that keep the state, replay, Python-repr formatting of fault values (the modal damping and the
// law's margin: test_modal_damping.cpp).
// Exit code 0 when every check passes; prints "N passed, M failed".
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>

#include "reflexarm/model_io.hpp"
#include "reflexarm/reflexarm.hpp"
#include "reflexarm/replay.hpp"
#include "reflexarm/run_statistics.hpp"

#include "alloc_counter.hpp"
#include "checks.hpp"

namespace
{
  struct Run
  {
    long allocations = 0;
    long ticks = 0, faults = 0, non_finite = 0, beyond_limit = 0;
    bool detected = false;
  };

  // n_ticks ticks of a sine reference with noise; every 97th tick a NaN q, every 131st an implausible
  // tau_m, every 173rd a repeated time stamp; kappa switches flipped on the way. Counts allocations
  // inside update() (and setSwitches) only.
  Run runTicks(reflexarm::Controller & ctrl, int n_ticks, double push)
  {
    const int n = ctrl.nv();
    reflexarm::Command cmd;
    ctrl.initCommand(cmd);
    Eigen::VectorXd q(n), dq(n), tau_m(n), q_d(n), dq_d(n), ddq_d(n);
    Eigen::Matrix<double, 6, 1> wrench;
    Eigen::Vector3d gravity(0.0, 0.0, -9.81);
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    Run run;
    double t = 0.0;
    for (int k = 0; k < n_ticks; ++k)
    {
      t += 1e-3;
      for (int i = 0; i < n; ++i)
      {
        q_d[i] = 0.3 * std::sin(2.0 * t + i);
        dq_d[i] = 0.6 * std::cos(2.0 * t + i);
        ddq_d[i] = -1.2 * std::sin(2.0 * t + i);
        q[i] = q_d[i] + 3.4e-4 * u(rng);
        dq[i] = dq_d[i] + 5.5e-2 * u(rng);
        tau_m[i] = 10.0 * u(rng) + (k > n_ticks / 2 ? push : 0.0);
      }
      for (int i = 0; i < 6; ++i)
        wrench[i] = 2.3 * u(rng);
      double tk = t;
      if (k % 97 == 5)
        q[1] = std::nan("");
      if (k % 131 == 7)
        tau_m[0] = 1e6;
      if (k % 173 == 9)
        tk = t - 1e-3;
      reflexarm::State s{q, dq, tau_m, wrench, gravity};
      reflexarm::Reference r{q_d, dq_d, ddq_d};
      g_allocations = 0;
      g_counting = true;
      if (k == 300)
        ctrl.setSwitches(1, 1, 1);
      if (k == 600)
        ctrl.setSwitches(-1, 0, -1);
      const auto code = ctrl.update(tk, 1e-3, s, r, cmd);
      g_counting = false;
      run.allocations += g_allocations;
      ++run.ticks;
      run.faults += code != reflexarm::FaultCode::None;
      for (int i = 0; i < n; ++i)
      {
        run.non_finite += !std::isfinite(cmd.tau[i]);
        run.beyond_limit += std::abs(cmd.tau[i]) > ctrl.torqueMax()[i];
      }
    }
    run.detected = ctrl.detected();
    return run;
  }

  void testNoAllocation()
  {
    const pinocchio::Model model = makeArm();
    for (int variant = 0; variant < 3; ++variant)
    {
      reflexarm::ControllerParams p;
      p.sensor_frame_id = model.frames.size() - 1;
      p.kappa_ext = variant == 0;
      p.kappa_eps = variant != 2;
      p.kappa_f = 1;
      p.friction_coulomb = Eigen::VectorXd::Constant(1, 2.0);
      p.friction_viscous = Eigen::VectorXd::Constant(1, 1.0);
      p.damping_update_period = variant == 1 ? 1 : 10;
      if (variant == 1)
        p.detection_observer_gain = Eigen::VectorXd::Constant(1, 50.0);
      p.reaction = static_cast<reflexarm::Reaction>(variant);
      if (variant == 2)
        p.torque_rate_limit = Eigen::VectorXd::Constant(1, 2000.0);
      reflexarm::Controller ctrl;
      ctrl.configure(model, p);
      const Run run = runTicks(ctrl, 1500, 80.0);
      CHECK(run.allocations == 0, "variant %d: %ld allocations in update()", variant, run.allocations);
      CHECK(run.faults > 20, "variant %d: only %ld faults injected", variant, run.faults);
      CHECK(run.non_finite == 0, "variant %d: %ld non-finite torques", variant, run.non_finite);
      CHECK(run.beyond_limit == 0, "variant %d: %ld torques beyond the limit", variant, run.beyond_limit);
      CHECK(run.detected, "variant %d: the 80 Nm push was not detected", variant);
    }
  }

  // A sphere of m points (radius 5 cm, 10 cm along z of the joint frame) on every link.
  std::vector<reflexarm::LinkSurfaceData> sphereSurfaces(int n, int m)
  {
    std::vector<reflexarm::LinkSurfaceData> out(static_cast<size_t>(n));
    for (auto & s : out)
    {
      s.points.resize(m, 3);
      s.normals.resize(m, 3);
      for (int i = 0; i < m; ++i)
      {
        const double z = 1.0 - 2.0 * (i + 0.5) / m, r = std::sqrt(1.0 - z * z), phi = 2.399963229728653 * i;
        const Eigen::Vector3d u(r * std::cos(phi), r * std::sin(phi), z);
        s.normals.row(i) = u.transpose();
        s.points.row(i) = (Eigen::Vector3d(0.0, 0.0, 0.1) + 0.05 * u).transpose();
      }
    }
    return out;
  }

  // The collision pipeline inside update(): each reaction with the links' geometry (isolation spread over the
  // ticks), Euler and exact observers, with and without the detection residual's second stage.
  void testNoAllocationInThePipeline()
  {
    const pinocchio::Model model = makeArm();
    const reflexarm::Reaction reactions[] = {reflexarm::Reaction::Brake, reflexarm::Reaction::Retract,
                                             reflexarm::Reaction::Compliant, reflexarm::Reaction::Gravity};
    for (int variant = 0; variant < 8; ++variant)
    {
      reflexarm::ControllerParams p;
      p.sensor_frame_id = model.frames.size() - 1;
      p.kappa_ext = 1; // the wrist noise never classifies: collisions, isolated
      p.reaction = p.contact_reaction = reactions[variant % 4];
      p.observer_discretization =
        variant < 4 ? reflexarm::ObserverDiscretization::Euler : reflexarm::ObserverDiscretization::Exact;
      p.detection_observer_gain = Eigen::VectorXd::Constant(1, variant < 4 ? 50.0 : 300.0);
      if (variant % 2) // the detection residual's second stage and the detection observer's own friction model
      {
        p.detection_filter_gain = Eigen::VectorXd::Constant(1, 200.0);
        p.detection_kappa_f = 1;
        p.detection_friction_velocity_band = 0.1;
      }
      p.reaction_params.isolation_points_per_tick = 16;
      p.reaction_params.retract_waits_for_estimate = variant >= 4; // both retracts: from detection, after the estimate
      reflexarm::Controller ctrl;
      ctrl.configure(model, p);
      ctrl.setContactGeometry(sphereSurfaces(model.nv, 120), 0.25, reflexarm::IsolationParams{});
      const Run run = runTicks(ctrl, 1500, 80.0);
      const reflexarm::CollisionEvent & e = ctrl.event();
      CHECK(run.allocations == 0, "pipeline variant %d: %ld allocations in update()", variant, run.allocations);
      CHECK(run.detected && e.detected, "pipeline variant %d: the 80 Nm push was not detected", variant);
      CHECK(e.estimated, "pipeline variant %d: the collision was not isolated in the run", variant);
      // the retract's ticks (from detection, or after the estimate: M(q) factorised, then the plan) ran in the count
      if (p.reaction == reflexarm::Reaction::Retract)
        CHECK(e.phase == reflexarm::ReactionPhase::Retracting || e.phase == reflexarm::ReactionPhase::Holding,
              "pipeline variant %d: the retract was not planned after the estimate", variant);
      CHECK(run.non_finite == 0 && run.beyond_limit == 0, "pipeline variant %d: %ld non-finite, %ld beyond the limit",
            variant, run.non_finite, run.beyond_limit);
    }
  }

  // replayLog (a log through update() in one call) equals an update() loop bitwise, allocates nothing (fault texts
  // off), counts the rejected rows; RunStatistics::addRows allocates nothing and counts what it is given.
  void testReplayAndStatistics()
  {
    const pinocchio::Model model = makeArm();
    reflexarm::ControllerParams p;
    p.threshold = Eigen::VectorXd::Constant(model.nv, 4.0);
    reflexarm::Controller a, b;
    a.configure(model, p);
    b.configure(model, p);
    reflexarm::Command ca, cb;
    a.initCommand(ca);
    b.initCommand(cb);
    const int n = a.nv();
    const long N = 3000;
    std::vector<double> t(N), q(N * n), dq(N * n), tau(N * n), res(N * n);
    std::vector<std::uint8_t> over(N * n), col(N);
    std::vector<std::int8_t> mode(N);
    std::vector<std::int32_t> status(N);
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    for (long k = 0; k < N; ++k)
    {
      t[k] = 1e-3 * (k + 1);
      for (int i = 0; i < n; ++i)
      {
        q[k * n + i] = 0.3 * std::sin(2.0 * t[k] + i) + 3e-4 * u(rng);
        dq[k * n + i] = 0.6 * std::cos(2.0 * t[k] + i) + 5e-2 * u(rng);
        tau[k * n + i] = 2.0 * u(rng) + (k > 2000 && i == 1 ? 15.0 : 0.0);
      }
      if (k % 211 == 17)
        q[k * n + 2] = std::nan("");
    }
    reflexarm::ReplayInputs in;
    in.rows = N;
    in.t = t.data();
    in.q = q.data();
    in.dq = dq.data();
    in.tau_m = tau.data();
    in.gravity[2] = -9.81;
    reflexarm::ReplayOutputs out;
    out.residual = res.data();
    out.over = over.data();
    out.collision = col.data();
    out.mode = mode.data();
    out.status = status.data();
    std::vector<reflexarm::ReplayFault> faults;
    // allocations of a one-row replay (the call's own constant vectors) and of the whole log: none per row
    reflexarm::Controller one;
    one.configure(model, p);
    reflexarm::Command c1;
    one.initCommand(c1);
    reflexarm::ReplayInputs in1 = in;
    in1.rows = 1;
    g_allocations = 0;
    g_counting = true;
    reflexarm::replayLog(one, c1, in1, out, faults, 0);
    g_counting = false;
    const long per_call = g_allocations;
    g_allocations = 0;
    g_counting = true;
    const long rejected = reflexarm::replayLog(a, ca, in, out, faults, 0);
    g_counting = false;
    CHECK(g_allocations == per_call && per_call <= 2, "%ld allocations in replayLog of %ld rows, %ld of one row",
          static_cast<long>(g_allocations), N, per_call);
    long expect_rejected = 0;
    bool same = true, any_over = false;
    double first_over = std::nan("");
    const Eigen::VectorXd z = Eigen::VectorXd::Zero(n);
    const Eigen::Matrix<double, 6, 1> w = Eigen::Matrix<double, 6, 1>::Zero();
    const Eigen::Vector3d g(0.0, 0.0, -9.81);
    for (long k = 0; k < N; ++k)
    {
      const Eigen::Map<const Eigen::VectorXd> qk(&q[k * n], n), dqk(&dq[k * n], n), tk(&tau[k * n], n);
      const auto code = b.update(t[k], 0.0, {qk, dqk, tk, w, g}, {qk, z, z}, cb);
      expect_rejected += code != reflexarm::FaultCode::None ? 1 : 0;
      for (int i = 0; i < n; ++i)
        same = same && res[k * n + i] == cb.residual[i];
      same = same && (col[k] != 0) == cb.collision;
      if (status[k] > 0 && !any_over)
        first_over = t[k];
      any_over = any_over || status[k] > 0;
    }
    CHECK(same, "replayLog differs from the update() loop");
    CHECK(rejected == expect_rejected && rejected == 15, "rejected %ld, expected %ld", rejected, expect_rejected);
    CHECK(any_over && a.detected() && b.detected(), "no threshold crossing was replayed");
    reflexarm::RunStatistics st;
    st.configure(n, 0.1, 1001, reflexarm::kModeCount);
    std::vector<std::int32_t> mode32(mode.begin(), mode.end()), codes(N);
    for (long k = 0; k < N; ++k)
      codes[k] = status[k] < 0 ? status[k] : 0;
    g_allocations = 0;
    g_counting = true;
    st.addRows(N, t.data(), res.data(), res.data(), col.data(), over.data(), mode32.data(), codes.data());
    g_counting = false;
    CHECK(g_allocations == 0, "%ld allocations in RunStatistics::addRows", static_cast<long>(g_allocations));
    long hist = 0;
    for (auto c : st.counts)
      hist += static_cast<long>(c);
    CHECK(st.ticks == N && st.fault_ticks == 15 && hist == N * n, "ticks %ld faults %ld histogram %ld", st.ticks,
          st.fault_ticks, hist);
    CHECK(st.collision_events == 1 && st.first_collision_t == first_over, "events %ld first %g (expected %g)",
          st.collision_events, st.first_collision_t, first_over);
  }

  void testFaultKeepsState()
  {
    const pinocchio::Model model = makeArm();
    reflexarm::ControllerParams p;
    p.kappa_eps = 1;
    reflexarm::Controller ctrl;
    ctrl.configure(model, p);
    reflexarm::Command cmd;
    ctrl.initCommand(cmd);
    const int n = ctrl.nv();
    Eigen::VectorXd q = Eigen::VectorXd::Constant(n, 0.1), z = Eigen::VectorXd::Zero(n);
    Eigen::VectorXd tau = Eigen::VectorXd::Constant(n, 1.0);
    Eigen::Matrix<double, 6, 1> w = Eigen::Matrix<double, 6, 1>::Zero();
    Eigen::Vector3d g(0, 0, -9.81);
    for (int k = 0; k < 3; ++k)
      ctrl.update(1e-3 * (k + 1), 1e-3, {q, z, tau, w, g}, {q, z, z}, cmd);
    const Eigen::VectorXd r_before = ctrl.observer().residual;
    const Eigen::VectorXd i_before = ctrl.observer().integral;
    Eigen::VectorXd bad = q;
    bad[2] = 10.0; // beyond the joint limit + margin
    const auto code = ctrl.update(4e-3, 1e-3, {bad, z, tau, w, g}, {q, z, z}, cmd);
    CHECK(code == reflexarm::FaultCode::OutOfBounds, "code %d", static_cast<int>(code));
    CHECK(cmd.mode == reflexarm::Mode::Fault, "mode %s", reflexarm::modeName(cmd.mode));
    CHECK(ctrl.observer().residual == r_before && ctrl.observer().integral == i_before, "observer changed");
    const std::string text(cmd.fault_text.data());
    CHECK(
      text == "measurement q[2] = 10 rad outside the plausible [-3.2, 3.2] rad (joint limits +- "
              "InputBounds.position_margin)",
      "text '%s'", text.c_str());
    ctrl.observerState().integral[0] = std::nan("");
    const auto code2 = ctrl.update(5e-3, 1e-3, {q, z, tau, w, g}, {q, z, z}, cmd);
    const auto code3 = ctrl.update(6e-3, 1e-3, {q, z, tau, w, g}, {q, z, z}, cmd);
    CHECK(
      code2 == reflexarm::FaultCode::ObserverInvalid && code3 == reflexarm::FaultCode::ObserverInvalid
        && cmd.collision,
      "codes %d %d collision %d", static_cast<int>(code2), static_cast<int>(code3), cmd.collision);
    ctrl.reset();
    const auto code4 = ctrl.update(7e-3, 1e-3, {q, z, tau, w, g}, {q, z, z}, cmd);
    CHECK(code4 == reflexarm::FaultCode::None, "after reset: code %d", static_cast<int>(code4));
  }

  void testRepr()
  {
    const struct
    {
      double v;
      const char * want;
    } cases[] = {{0.1, "0.1"},     {100.0, "100.0"},     {1e-5, "1e-05"},     {0.0001, "0.0001"},
                 {1e16, "1e+16"},  {1e15, "1000000000000000.0"}, {-2.5, "-2.5"}, {1.5e200, "1.5e+200"},
                 {-0.0, "-0.0"},   {0.001, "0.001"},     {123.456, "123.456"}, {1.0 / 3.0, "0.3333333333333333"}};
    for (const auto & c : cases)
    {
      char buf[64];
      reflexarm::formatRepr(c.v, buf, sizeof(buf));
      CHECK(std::strcmp(buf, c.want) == 0, "repr(%.17g) = '%s', want '%s'", c.v, buf, c.want);
    }
  }

  void testModelText()
  {
    const pinocchio::Model model = makeArm();
    const pinocchio::Model back = reflexarm::modelFromString(reflexarm::modelToString(model));
    CHECK(back == model, "model changed through its text form");
    bool threw = false;
    try
    {
      reflexarm::modelFromString("not a model");
    }
    catch (const std::runtime_error &)
    {
      threw = true;
    }
    CHECK(threw, "garbage text was accepted");
  }
} // namespace

void testCounterCounts()
{
  // the counter must see both kinds of allocation, or a 0 above would mean nothing
  g_allocations = 0;
  g_counting = true;
  int * volatile x = new int(3);
  Eigen::VectorXd * volatile v = new Eigen::VectorXd(Eigen::VectorXd::Zero(50));
  g_counting = false;
  const long seen = g_allocations;
  delete v;
  delete x;
  CHECK(seen >= 3, "the allocation counter saw %ld of 3 allocations", seen);
}

int main()
{
  testCounterCounts();
  g_trace = std::getenv("TRACE_ALLOC") != nullptr;
  testNoAllocation();
  testNoAllocationInThePipeline();
  testFaultKeepsState();
  testReplayAndStatistics();
  testRepr();
  testModelText();
  return checksReport();
}
