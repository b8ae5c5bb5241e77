// reflexarm::ClosedLoop: the simulated closed loop in C++ (MuJoCo plant + sensors + Controller + recording).
//
// The plant is a compiled MuJoCo model and its data, both owned by the caller (in Python: the Plant's
// MjModel/MjData, passed by address); the scene is defined by the caller too and acts through data this
// class plays: per-tick mocap positions and forces applied at points fixed on bodies. Sensor noise and the
// reference are sampled by the caller into arrays (so a run equals the Python loop's, tick by tick).
//
// One tick k = sense(k) then act(k):
//   sense: measurement (q, dq, tau_m, load-compensated wrist wrench, gravity, each plus noise row k),
//          Controller::update with reference row k, recording of row k;
//   act:   mocap positions of row k, applied forces refreshed at the bodies' poses, the command as joint
//          torque, `substeps` physics steps, the divergence check.
// The arithmetic of the measurement, the true external torque and the contact force follows
// reflexarm/sim/_kernels.py operation by operation, so that both loops give the same numbers.
#pragma once

#include <cstdint>
#include <vector>

#include <mujoco/mujoco.h>

#include "reflexarm/controller.hpp"

namespace reflexarm
{

  /// Where the arm and its sensors are in the MuJoCo model (indices as the Python Plant computes them).
  struct PlantLayout
  {
    std::vector<int> qadr, vadr;  ///< qpos / qvel address of each arm joint (n each, controller's order)
    std::vector<int> load_bodies; ///< bodies beyond the wrist sensor (its subtree, sorted)
    std::vector<int> arm_bodies;  ///< subtree of the first arm body (sorted, parents first)
    int force_adr = 0, torque_adr = 0; ///< sensordata addresses of the wrist force/torque sensors
    int com_body = 0;  ///< body whose subtree_com is the com-based reference point
    int site = 0;      ///< wrist sensor site
    bool physical = true; ///< the sensor body is welded (load compensation) rather than an ideal sensor
    int substeps = 2;
    double max_speed = 1e3; ///< a larger velocity norm is a divergence [rad/s or m/s]
    double gravity[3] = {0.0, 0.0, 0.0}; ///< true gravity in the world (base) frame [m/s^2]
  };

  /// A force [N] fixed in the world, applied at a point fixed on a body (as Plant.apply_external_force).
  struct AppliedForce
  {
    int body = 0;
    double force[3] = {0.0, 0.0, 0.0};
    double point_local[3] = {0.0, 0.0, 0.0};
  };

  /// The arrays of one run (N rows; row-major, owned by the caller, alive for the run).
  struct RunBuffers
  {
    long rows = 0;
    // inputs
    const double * noise = nullptr; ///< N x (3n + 9), or nullptr: no noise
    const double * q_d = nullptr;   ///< N x n
    const double * dq_d = nullptr;  ///< N x n
    const double * ddq_d = nullptr; ///< N x n
    // outputs
    double *t = nullptr, *q = nullptr, *dq = nullptr, *q_meas = nullptr, *tau = nullptr, *tau_m = nullptr;
    double *residual = nullptr, *wrench = nullptr, *tau_ext = nullptr, *f_ext_ee = nullptr;
    std::uint8_t *collision = nullptr, *collided = nullptr; ///< N, N x n
    std::int32_t *mode = nullptr, *fault_code = nullptr;    ///< N each
    double * fault_info = nullptr; ///< N x 5: signal, component, value, lo, hi
    double * dq_meas = nullptr;    ///< N x n: measured (noisy) velocity, or nullptr: not recorded
  };

  /// Per-tick positions of one mocap body (N x 3; a NaN row leaves the body where it is).
  struct MocapPlan
  {
    int mocap_id = 0;
    const double * pos = nullptr;
  };

  /// A qpos slice recorded every tick (N x size), e.g. a free body's pose.
  struct QposRecord
  {
    int adr = 0, size = 0;
    double * out = nullptr;
  };

  /// A mocap position recorded every tick (N x 3).
  struct MocapRecord
  {
    int mocap_id = 0;
    double * out = nullptr;
  };

  /// A spring-damper "hand" pushing a site along a fixed world direction u from a start point p0 (as
  /// reflexarm.sim.HandPush): each tick with a rest travel r, x = u.(p - p0), v = (x - x_last) / period (0 on
  /// the first tick of a push), force = max(0, k (r - x) + c (r_v - v)) u at the site, fixed on its body.
  struct SpringPush
  {
    int body = 0, site = 0;
    double u[3] = {0.0, 0.0, 0.0}, p0[3] = {0.0, 0.0, 0.0};
    double stiffness = 0.0, damping = 0.0, period = 1e-3;
    const double * rest = nullptr;   ///< N: rest travel [m] per tick, NaN: the hand is off
    const double * rest_v = nullptr; ///< N: its speed [m/s]
    double * force_out = nullptr;    ///< N x 3: force recorded with row k (the one applied over tick k - 1)
    double * target_out = nullptr;   ///< N x 3: rest point recorded with row k
    // state (read back by the caller after a run)
    double last_x = 0.0;
    bool has_last = false;
    bool applied = false; ///< a force is applied now (force, point_local)
    double force[3] = {0.0, 0.0, 0.0}, target[3] = {0.0, 0.0, 0.0}, point_local[3] = {0.0, 0.0, 0.0};
  };

  /// MuJoCo states kept for a still of the run (reflexarm.sim.video.StillCapture), as mj_getState gives them
  /// for `spec` (a mjtState bit mask): at the first tick sensed and at the tick of the largest true external
  /// joint torque. Both are taken in sense(k), after the measurement and the recording of row k and before
  /// act(k) (where the Python loop calls its callbacks). The criterion is StillCapture's: the squared norm
  /// tau_ext . tau_ext summed over the joints in their order, left to right (no fused multiply-add); a tick
  /// is the new peak when that sum is strictly larger than the largest so far, which starts at 0: ties keep
  /// the earlier tick, and without any external torque no peak is taken (peak_tick stays -1).
  /// The buffers are sized by ClosedLoop::keepStill (before the run): nothing is allocated in the loop.
  struct StillStates
  {
    int spec = 0;            ///< mjtState mask; 0: no still is kept
    std::vector<double> start, peak; ///< mj_stateSize(spec) each
    long start_tick = -1, peak_tick = -1;
    double peak2 = 0.0;      ///< largest sum of tau_ext_i^2 so far [Nm^2]
  };

  /// Outcome of ClosedLoop::act / run.
  enum class StepStatus : int
  {
    Ok = 0,
    Diverged = 1,     ///< non-finite or too fast state after the step
    TimeMismatch = 2  ///< MuJoCo's clock did not advance by one control period
  };

  /// `steps` physics steps with the sensors (and the post-constraint pass they trigger) evaluated on the last
  /// one only: they feed nothing in the dynamics, and the loop reads them after the last step, so the state
  /// and the readings are the same to the bit. The model's disable flags are restored.
  void stepSensingLast(const mjModel * m, mjData * d, int steps) noexcept;

  /// While alive and `on`, MuJoCo's profiling timers (mjData.timer) read a clock that returns 0 instead of
  /// mjcb_time (restored at the end). Without a callback MuJoCo times nothing, but the Python mujoco package
  /// installs one that reads the system clock at every start and end of a timer, dozens of times per step
  /// (measured on the demo plant: 0.7-1.2 us of a 12-15 us step, 1.4-1.8 us per tick of the compiled loop);
  /// the timers feed nothing in the dynamics, so the state is the same to the bit and mjData.timer still
  /// counts the steps, with no duration. Callers turn it on only when nobody asked for the timings (Python:
  /// mujoco.get_mjcb_time() is None). mjcb_time is global: QuietTimers alive in several threads at once share
  /// one count under a lock (the first installs the clock of 0, the last restores the callback); other threads'
  /// plants stepped meanwhile read no durations either.
  class QuietTimers
  {
  public:
    explicit QuietTimers(bool on) noexcept;
    ~QuietTimers();
    QuietTimers(const QuietTimers &) = delete;
    QuietTimers & operator=(const QuietTimers &) = delete;

  private:
    bool on_ = false;
  };

  class ClosedLoop
  {
  public:
    /// `model`/`data`: the plant (not owned; they must outlive this object). Configures the controller
    /// (throws ConfigError) and sizes every buffer.
    void configure(const mjModel * model, mjData * data, const PlantLayout & layout,
                   const pinocchio::Model & controller_model, const ControllerParams & params);

    Controller & controller() noexcept { return ctrl_; }
    const Command & command() const noexcept { return cmd_; }
    int nv() const noexcept { return n_; }
    int measurementSize() const noexcept { return 3 * n_ + 9; }

    void setBuffers(const RunBuffers & buffers) { buf_ = buffers; }
    /// Record the measured velocity into `dq_meas` (N x n rows of the buffers set last; nullptr: stop).
    void setMeasuredVelocityBuffer(double * dq_meas) noexcept { buf_.dq_meas = dq_meas; }
    void setForces(const std::vector<AppliedForce> & forces) { forces_ = forces; }
    void setMocapPlans(const std::vector<MocapPlan> & plans) { mocap_plans_ = plans; }
    void setPushes(const std::vector<SpringPush> & pushes) { pushes_ = pushes; }
    const std::vector<SpringPush> & pushes() const noexcept { return pushes_; }
    void setRecords(const std::vector<QposRecord> & qpos, const std::vector<MocapRecord> & mocap)
    {
      qpos_records_ = qpos;
      mocap_records_ = mocap;
    }
    /// Keep the states of a still (StillStates) with mj_getState's `spec` from the next tick sensed on;
    /// `spec` 0 stops keeping them. Throws ConfigError for a spec MuJoCo does not know.
    void keepStill(int spec);
    const StillStates & still() const noexcept { return still_; }
    /// Step the physics under QuietTimers (default off).
    void setQuietTimers(bool on) noexcept { quiet_timers_ = on; }
    bool quietTimers() const noexcept { return quiet_timers_; }
    /// Motor torque currently applied (the tau_m of the next measurement, before noise).
    Eigen::VectorXd & appliedTorque() noexcept { return tau_applied_; }

    /// Measure, control and record row k.
    void sense(long k) noexcept;
    /// Play the scene data of row k, apply the last command, step the physics.
    StepStatus act(long k) noexcept;
    /// Ticks [k0, k1): sense + act each. Returns the number of completed ticks (k1 - k0 unless a step
    /// failed: then the failing tick is recorded and counted, and `status` says why).
    long run(long k0, long k1, StepStatus & status) noexcept;

    // the plant's per-tick quantities (exposed for tests)
    void measurement(const double * noise, double * out) noexcept;
    void externalTorque(double * out) noexcept;
    void eeContactForce(double * out) noexcept;

  private:
    void loadCompensatedWrench(double * out) noexcept;
    void applyForces() noexcept;
    void updatePush(SpringPush & push, long k) noexcept;
    void watchStill(long k) noexcept;

    const mjModel * m_ = nullptr;
    mjData * d_ = nullptr;
    PlantLayout lay_;
    int n_ = 0;
    Controller ctrl_;
    Command cmd_;
    RunBuffers buf_;
    std::vector<AppliedForce> forces_;
    std::vector<MocapPlan> mocap_plans_;
    std::vector<SpringPush> pushes_;
    std::vector<QposRecord> qpos_records_;
    std::vector<MocapRecord> mocap_records_;
    StillStates still_;
    bool quiet_timers_ = false;
    std::vector<int> parent_, dof_body_;
    std::vector<double> acc6_; // nbody x 6
    Eigen::VectorXd meas_, tau_applied_, zero_noise_;
  };

} // namespace reflexarm
