// reflexarm in a periodic 1 kHz C++ loop against a MuJoCo plant (the robot's own MJCF file).
//
// What a ros2_control controller would do, in one file: configure() once (on_configure), reset() when
// the loop starts (on_activate), update() every period (update). The plant is MuJoCo through its C API
// (two 0.5 ms steps per tick, joint friction of the file); a 60 N push on the hand from t = 1.5 s is
// detected and answered by gravity compensation (13). Prints the median/p99/max time of update() (all ticks,
// and split by the part of the modal damping each tick ran, if any) and fails if update() allocated on the heap.
//
//   realtime_loop [robot.xml] [seconds] [options]
//     --busy        no wait between ticks (and time the bare Pinocchio calls for the ratio update()/calls)
//     --spin        wait for the next period by spinning on the clock instead of sleeping
//     --pin CPU     run on this CPU only (sched_setaffinity)
//     --mlock       lock the process's memory (mlockall), no page faults in the loop
//     --fifo PRIO   real-time scheduling (SCHED_FIFO, needs the privilege)
//     --warmup N    N untimed ticks on the initial state before the loop (then reset(), as on_activate)
//     --dump FILE   write every tick's update() time (CSV: tick, us, damping parts) for a closer look
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <cstring>
#include <new>
#include <string>
#include <vector>

#include <sched.h>
#include <sys/mman.h>

#include <mujoco/mujoco.h>

#include "pinocchio/algorithm/frames.hpp"
#include "pinocchio/algorithm/rnea.hpp"

#include "reflexarm/reflexarm.hpp"

pinocchio::Model loadModel(const std::string & path); // load_model.cpp

// ------------------------------------------------------------------ allocation counter (operator new, malloc)
static std::atomic<long> g_allocations{0};
static std::atomic<bool> g_counting{false};
extern "C" void * __libc_malloc(std::size_t);
void * operator new(std::size_t size)
{
  if (g_counting.load(std::memory_order_relaxed))
    g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void * p = __libc_malloc(size ? size : 1))
    return p;
  throw std::bad_alloc();
}
void * operator new[](std::size_t size) { return operator new(size); }
void operator delete(void * p) noexcept { std::free(p); }
void operator delete[](void * p) noexcept { std::free(p); }
void operator delete(void * p, std::size_t) noexcept { std::free(p); }
void operator delete[](void * p, std::size_t) noexcept { std::free(p); }
extern "C" void * malloc(std::size_t size)
{
  if (g_counting.load(std::memory_order_relaxed))
    g_allocations.fetch_add(1, std::memory_order_relaxed);
  return __libc_malloc(size);
}

static double nowSeconds()
{
  timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

struct Options
{
  std::string path = REFLEXARM_DEFAULT_ROBOT;
  double seconds = 3.0;
  bool busy = false, spin = false, mlock = false;
  int pin = -1, fifo = 0;
  long warmup = 0;
  std::string dump;
};

static Options parseOptions(int argc, char ** argv)
{
  Options o;
  int positional = 0;
  for (int i = 1; i < argc; ++i)
  {
    const std::string a = argv[i];
    const bool has_value = i + 1 < argc;
    if (a == "--busy")
      o.busy = true;
    else if (a == "--spin")
      o.spin = true;
    else if (a == "--mlock")
      o.mlock = true;
    else if (a == "--pin" && has_value)
      o.pin = std::atoi(argv[++i]);
    else if (a == "--fifo" && has_value)
      o.fifo = std::atoi(argv[++i]);
    else if (a == "--dump" && has_value)
      o.dump = argv[++i];
    else if (a == "--warmup" && has_value)
      o.warmup = std::atol(argv[++i]);
    else if (positional == 0 && a.rfind("--", 0) != 0)
    {
      if (!a.empty())
        o.path = a;
      ++positional;
    }
    else if (positional == 1 && a.rfind("--", 0) != 0)
    {
      o.seconds = std::atof(a.c_str());
      ++positional;
    }
    else
    {
      std::fprintf(stderr, "unknown argument '%s'\n", a.c_str());
      std::exit(2);
    }
  }
  return o;
}

/// The settings of a real-time thread that the options ask for; prints what each did.
static void applyRealTimeSettings(const Options & o)
{
  if (o.pin >= 0)
  {
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(o.pin, &set);
    const int rc = sched_setaffinity(0, sizeof(set), &set);
    std::printf("pinned to CPU %d: %s\n", o.pin, rc == 0 ? "yes" : std::strerror(errno));
  }
  if (o.mlock)
  {
    const int rc = mlockall(MCL_CURRENT | MCL_FUTURE);
    std::printf("mlockall: %s\n", rc == 0 ? "yes" : std::strerror(errno));
  }
  if (o.fifo > 0)
  {
    sched_param sp{};
    sp.sched_priority = o.fifo;
    const int rc = sched_setscheduler(0, SCHED_FIFO, &sp);
    std::printf("SCHED_FIFO priority %d: %s\n", o.fifo, rc == 0 ? "yes" : std::strerror(errno));
  }
}

struct Stats
{
  double median = 0.0, p99 = 0.0, max = 0.0; // [us]
  std::size_t count = 0;
};

static Stats stats(std::vector<double> v)
{
  Stats s;
  s.count = v.size();
  if (v.empty())
    return s;
  std::sort(v.begin(), v.end());
  auto at = [&](double p) {
    return 1e6 * v[std::min(v.size() - 1, static_cast<std::size_t>(p * static_cast<double>(v.size())))];
  };
  s.median = at(0.5);
  s.p99 = at(0.99);
  s.max = 1e6 * v.back();
  return s;
}

int main(int argc, char ** argv)
{
  const Options opt = parseOptions(argc, argv);
  const std::string & path = opt.path;
  const double seconds = opt.seconds;
  const bool busy = opt.busy;
  constexpr double dt = 1e-3;
  applyRealTimeSettings(opt);

  // ---------------------------------------------------------------- the controller (on_configure)
  const pinocchio::Model model = loadModel(path);
  const int n = model.nv;
  reflexarm::ControllerParams params;
  params.stiffness = Eigen::VectorXd::Constant(1, 300.0);
  params.kappa_f = 1;
  params.kappa_eps = 1;
  params.friction_coulomb = model.upperDryFrictionLimit; // the file's friction (a real arm: its identified friction)
  params.friction_viscous = model.damping;
  params.sensor_frame_id = model.existFrame("wrist_ft") ? model.getFrameId("wrist_ft") : model.frames.size() - 1;
  reflexarm::Controller controller;
  controller.configure(model, params);
  reflexarm::Command command;
  controller.initCommand(command);

  // ---------------------------------------------------------------- the plant
  char error[1000] = "";
  mjModel * m = mj_loadXML(path.c_str(), nullptr, error, sizeof(error));
  if (!m)
  {
    std::fprintf(stderr, "MuJoCo cannot load %s: %s\n", path.c_str(), error);
    return 2;
  }
  if (m->nv != n)
  {
    std::fprintf(stderr, "MuJoCo has %d DoF, Pinocchio %d\n", m->nv, n);
    return 2;
  }
  mjData * d = mj_makeData(m);
  const int substeps = std::max(1, static_cast<int>(std::lround(dt / m->opt.timestep)));
  Eigen::VectorXd q0(n);
  for (int i = 0; i < n; ++i) // a pose inside the joint ranges
    q0[i] = std::clamp(0.0, model.lowerPositionLimit[i] + 0.4, model.upperPositionLimit[i] - 0.4);
  for (int i = 0; i < n; ++i)
    d->qpos[i] = q0[i];
  mj_forward(m, d);
  int hand = mj_name2id(m, mjOBJ_BODY, "l_hand");
  if (hand < 0)
    hand = m->nbody - 1;

  // ---------------------------------------------------------------- buffers of the loop (sized once)
  Eigen::VectorXd q(n), dq(n), tau_m = Eigen::VectorXd::Zero(n), q_d(n), dq_d(n), ddq_d(n);
  Eigen::Matrix<double, 6, 1> wrench = Eigen::Matrix<double, 6, 1>::Zero();
  Eigen::Vector3d gravity(m->opt.gravity[0], m->opt.gravity[1], m->opt.gravity[2]);
  const long ticks = static_cast<long>(seconds / dt);
  std::vector<double> durations(static_cast<std::size_t>(ticks)), floor_durations;
  std::vector<unsigned char> parts_of(static_cast<std::size_t>(ticks));
  constexpr int kParts = reflexarm::Controller::kDampingParts;
  std::vector<double> by_parts[1 << kParts]; // tick durations by the parts of the modal damping the tick ran (bits)
  for (auto & v : by_parts)
    v.reserve(static_cast<std::size_t>(ticks));
  // --busy also times the tick's bare Pinocchio calls (g, C, two RNEAs) on the same state, alternating
  // which goes first, for the ratio update() / floor inside C++
  pinocchio::Model model0 = model;
  model0.gravity.linear().setZero();
  pinocchio::Data d_g(model), d_c(model), d_p(model0), d_ff(model0);
  const Eigen::VectorXd zeros = Eigen::VectorXd::Zero(n);
  auto floor_calls = [&]() {
    const double f0 = nowSeconds();
    pinocchio::computeGeneralizedGravity(model, d_g, q);
    pinocchio::computeCoriolisMatrix(model, d_c, q, dq);
    pinocchio::rnea(model0, d_p, q, zeros, dq);
    pinocchio::rnea(model0, d_ff, q_d, zeros, ddq_d);
    floor_durations.push_back(nowSeconds() - f0);
  };
  if (busy)
    floor_durations.reserve(static_cast<std::size_t>(ticks));
  long allocations = 0, late = 0, faults = 0;

  if (opt.warmup > 0) // untimed ticks on the initial state: caches, branch predictors, page tables
  {
    Eigen::VectorXd z = Eigen::VectorXd::Zero(n);
    for (long k = 0; k < opt.warmup; ++k)
      controller.update(static_cast<double>(k + 1) * dt, dt, {q0, z, z, wrench, gravity}, {q0, z, z}, command);
  }
  controller.reset(); // on_activate
  timespec next;
  clock_gettime(CLOCK_MONOTONIC, &next);
  for (long k = 0; k < ticks; ++k)
  {
    const double t = static_cast<double>(k + 1) * dt;
    for (int i = 0; i < n; ++i)
    {
      const double w = 2.0 * M_PI * 0.5;
      q_d[i] = q0[i] + 0.2 * std::sin(w * t);
      dq_d[i] = 0.2 * w * std::cos(w * t);
      ddq_d[i] = -0.2 * w * w * std::sin(w * t);
      q[i] = d->qpos[i];
      dq[i] = d->qvel[i];
    }
    const reflexarm::State state{q, dq, tau_m, wrench, gravity};
    const reflexarm::Reference reference{q_d, dq_d, ddq_d};
    if (busy && k % 2 == 0)
      floor_calls();
    g_allocations.store(0, std::memory_order_relaxed);
    g_counting.store(true, std::memory_order_relaxed);
    const double t0 = nowSeconds();
    const reflexarm::FaultCode code = controller.update(t, dt, state, reference, command);
    const double t1 = nowSeconds();
    g_counting.store(false, std::memory_order_relaxed);
    allocations += g_allocations.load(std::memory_order_relaxed);
    durations[static_cast<std::size_t>(k)] = t1 - t0;
    by_parts[controller.dampingPartsRun()].push_back(t1 - t0);
    parts_of[static_cast<std::size_t>(k)] = static_cast<unsigned char>(controller.dampingPartsRun());
    faults += code != reflexarm::FaultCode::None;
    if (k == 0 && !(controller.lawModeShare() < 1.0)) // the law's margin at this rate, before its torque is applied
    {
      std::fprintf(stderr, "the impedance law is unstable at dt = %g s (lawModeShare %.3g >= 1): a link too light for "
                   "its stiffness; lower it (reflexarm robots FILE says which) or run faster\n", dt,
                   controller.lawModeShare());
      return 1;
    }
    if (busy && k % 2 == 1)
      floor_calls();
    // actuate: the motors deliver the command (the measured motor torque of the next tick)
    tau_m = command.tau;
    for (int i = 0; i < n; ++i)
      d->qfrc_applied[i] = command.tau[i];
    for (int a = 0; a < 6; ++a)
      d->xfrc_applied[6 * hand + a] = 0.0;
    if (t >= 1.5 && t < 2.0)
      d->xfrc_applied[6 * hand + 0] = 60.0; // a push on the hand [N]
    for (int s = 0; s < substeps; ++s)
      mj_step(m, d);
    // sleep until the next period (absolute deadline: no drift)
    next.tv_nsec += 1000000;
    if (next.tv_nsec >= 1000000000)
    {
      next.tv_nsec -= 1000000000;
      next.tv_sec += 1;
    }
    timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    if (busy)
      continue;
    if (now.tv_sec > next.tv_sec || (now.tv_sec == next.tv_sec && now.tv_nsec > next.tv_nsec))
      ++late;
    else if (opt.spin)
      while (now.tv_sec < next.tv_sec || (now.tv_sec == next.tv_sec && now.tv_nsec < next.tv_nsec))
        clock_gettime(CLOCK_MONOTONIC, &now);
    else
      clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, nullptr);
  }

  if (!opt.dump.empty())
  {
    if (std::FILE * f = std::fopen(opt.dump.c_str(), "w"))
    {
      std::fprintf(f, "tick,update_us,damping_parts\n");
      for (long k = 0; k < ticks; ++k)
        std::fprintf(f, "%ld,%.3f,%d\n", k, 1e6 * durations[static_cast<std::size_t>(k)],
                     static_cast<int>(parts_of[static_cast<std::size_t>(k)]));
      std::fclose(f);
    }
    else
      std::fprintf(stderr, "cannot write %s: %s\n", opt.dump.c_str(), std::strerror(errno));
  }
  const Stats all = stats(durations);
  std::printf("robot: %s (%d joints), %ld ticks at 1 kHz, %d MuJoCo step(s) of %.4g s per tick, wait: %s\n",
              path.c_str(), n, ticks, substeps, m->opt.timestep, busy ? "none (--busy)" : opt.spin ? "spin" : "sleep");
  std::printf("update(): median %.2f us, p99 %.2f us, max %.2f us (p99/median %.2f)\n", all.median, all.p99, all.max,
              all.p99 / all.median);
  // the modal damping is computed in parts on consecutive ticks (Controller::kDampingParts)
  const char * part_names[kParts] = {"factorize M(q)", "project + 1 sweep", "1 sweep", "finish eigenvectors + D"};
  for (int b = 0; b < (1 << kParts); ++b)
    if (!by_parts[b].empty())
    {
      std::string what;
      for (int k = 0; k < kParts; ++k)
        if (b & (1 << k))
          what += std::string(what.empty() ? "" : ", ") + part_names[k];
      const Stats st = stats(by_parts[b]);
      std::printf("  ticks with %s (%zu): median %.2f us, p99 %.2f us\n", b ? what.c_str() : "no damping work",
                  st.count, st.median, st.p99);
    }
  std::printf("late periods: %ld, faults: %ld, collision detected at t = %.3f s, mode %s\n", late, faults,
              controller.firstDetectionTime(), reflexarm::modeName(controller.mode()));
  if (busy)
  {
    std::sort(floor_durations.begin(), floor_durations.end());
    const double floor_median = 1e6 * floor_durations[floor_durations.size() / 2];
    std::printf("bare Pinocchio calls (g, C, 2 x RNEA): median %.2f us; update()/calls %.2f\n", floor_median,
                all.median / floor_median);
  }
  std::printf("heap allocations inside update(): %ld\n", allocations);
  mj_deleteData(d);
  mj_deleteModel(m);
  if (allocations != 0)
  {
    std::fprintf(stderr, "FAILED: update() allocated %ld times\n", allocations);
    return 1;
  }
  if (!controller.detected())
  {
    std::fprintf(stderr, "FAILED: the push was not detected\n");
    return 1;
  }
  return 0;
}
