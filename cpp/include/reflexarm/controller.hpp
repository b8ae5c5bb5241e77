// reflexarm::Controller: joint impedance control (2) with modal damping, momentum observer (4)-(6),
// disturbance compensation (9)-(11) with an output cut-off, collision detection (12) and reaction (13).
//
// Shaped like a ros2_control controller: configure() allocates everything (on_configure), reset()
// restarts the observers (on_activate), update() runs one tick (update) without heap allocation and
// without exceptions. The math and the input contract are those of reflexarm.control.Controller.step.
#pragma once

#include <cstdint>
#include <limits>

#include <Eigen/Cholesky>
#include <Eigen/Core>

#include "pinocchio/multibody.hpp"

#include "reflexarm/collision_event.hpp"
#include "reflexarm/defined_data.hpp"
#include "reflexarm/fault.hpp"
#include "reflexarm/modal_damping.hpp"
#include "reflexarm/params.hpp"
#include "reflexarm/signals.hpp"

namespace reflexarm
{

  /// Statistics of the measured control periods since the last reset (accepted ticks only).
  struct TimingStats
  {
    long n_periods = 0;
    double sum_period = 0.0; ///< [s]
    double min_period = 0.0; ///< [s] (meaningful when n_periods > 0)
    double max_period = 0.0; ///< [s]
    long clipped = 0;        ///< periods integrated at the band's edge instead
    double band_low = 0.0;   ///< [s]
    double band_high = 0.0;  ///< [s]
  };

  /// State of one momentum observer (4): integral, p(0), residual tau_eps_hat.
  struct ObserverState
  {
    Eigen::VectorXd integral, p0, residual;
    void resize(Eigen::Index n)
    {
      integral.setZero(n);
      p0.setZero(n);
      residual.setZero(n);
    }
  };

  class Controller
  {
  public:
    using Model = pinocchio::Model;
    using Data = pinocchio::Data;

    /// Copies the model, checks the parameters and sizes every buffer. Throws ConfigError.
    void configure(const Model & model, const ControllerParams & params);
    bool isConfigured() const noexcept { return configured_; }

    /// Clears the observers, the latched collision, reaction and observer fault, the clock and its
    /// statistics; the next update() re-initialises. After a "compliant" reaction the kappa_eps active
    /// before it is restored. Keeps the last command (the rate limit goes on); everything else is as after
    /// configure(), so a run after reset() equals a fresh controller's bitwise (without a torque rate limit).
    void reset() noexcept;

    /// One control tick. `time` is the measurement's time stamp [s] (strictly increasing over accepted ticks).
    /// `period` [s] is ros2_control's measured time since the previous update() call: the observer integrates
    /// the sum of the periods given since the last accepted tick (rejected calls included), clipped to the
    /// period band. `period = 0` measures that time from the stamps instead (time - last accepted time),
    /// which is what the Python Controller does; both agree when the stamps advance by the periods. A
    /// negative or non-finite period is a fault (Signal::Period). Writes `command` (sized by initCommand)
    /// and returns its fault code (None for an accepted tick). Never allocates, never throws.
    FaultCode update(
      double time, double period, const State & state, const Reference & reference, Command & command) noexcept;

    /// Gives the controller the collision surfaces of its links (one per joint, in the joint frame; zero rows: a
    /// link without geometry): a detected collision the wrist sensor does not measure is then isolated and
    /// identified inside update(), with the residual components above significance_share x the
    /// threshold counting (ContactIsolator), spread over the ticks from isolation_delay after detection on
    /// (ReactionParams::isolation_points_per_tick). Call after configure() (allocates; throws ConfigError).
    void setContactGeometry(
      const std::vector<LinkSurfaceData> & surfaces, double significance_share, const IsolationParams & params);
    bool hasContactGeometry() const noexcept { return has_isolator_; }

    /// Sizes a Command for this controller (call once, outside the loop).
    void initCommand(Command & command) const;

    /// Flips kappa_f / kappa_eps / kappa_ext (-1: unchanged); kappa_eps is ramped over switch_time.
    void setSwitches(int kappa_f = -1, int kappa_eps = -1, int kappa_ext = -1) noexcept;

    // ---------------------------------------------------------------- facts
    int nv() const noexcept { return n_; }
    const ControllerParams & params() const noexcept { return params_; }
    const Model & model() const noexcept { return model_; }
    Mode mode() const noexcept { return mode_; }
    int kappaF() const noexcept { return kappa_f_; }
    int kappaEps() const noexcept { return kappa_eps_; }
    int kappaExt() const noexcept { return kappa_ext_; }
    double epsWeight() const noexcept { return eps_weight_; } ///< ramped kappa_eps applied now
    bool reacted() const noexcept { return reacted_; }
    /// The record of the collision detected since the last reset() (event().detected false before one).
    const CollisionEvent & event() const noexcept { return event_; }
    bool detected() const noexcept { return detected_; }
    bool hasDetector() const noexcept { return has_detector_; }
    double firstDetectionTime() const noexcept { return first_time_; } ///< NaN before a detection
    const Eigen::Matrix<std::uint8_t, Eigen::Dynamic, 1> & firstDetectionJoints() const noexcept
    {
      return first_joints_;
    }
    bool observerInvalid() const noexcept { return obs_invalid_; }
    const TimingStats & timing() const noexcept { return timing_; }
    const Eigen::MatrixXd & damping() const noexcept { return D_; }
    /// True if the last update() put a new damping matrix in use (every damping_update_period accepted ticks;
    /// computed from M(q) of the tick min(kDampingParts, damping_update_period) - 1 accepted ticks earlier).
    bool dampingUpdated() const noexcept { return damping_updated_; }
    /// Which parts of the modal damping the last update() ran, as bits (bit k: part k): 0 factorize (crba,
    /// Cholesky), 1 project on the previous eigenvectors + a Jacobi sweep, 2 a sweep, 3 the sweeps left, the
    /// eigenvectors and D; 0 if none.
    int dampingPartsRun() const noexcept { return damping_parts_run_; }
    /// The impedance law sampled at the nominal dt: the largest omega_i dt / its limit min(1/xi_i, 4 xi_i) over the
    /// modes of the damping in use (omega_i^2 the eigenvalues of L^-1 K L^-T at the M(q) it came from; a mode with
    /// xi_i = 0 is not counted). >= 1: the held torque grows every tick (a link too light for its stiffness at this
    /// rate; reflexarm.control.law_stability says which and what would do). NaN before the first damping.
    double lawModeShare() const noexcept { return law_share_; }
    /// Parts of one computation of the modal damping, run on as many consecutive accepted ticks (at most).
    static constexpr int kDampingParts = 4;
    /// The retract plans with the modal damping's M(q) (crba of its part 0) when that is at most this many accepted
    /// ticks old (the default damping_update_period is 10: always), else with a crba of its own.
    static constexpr int kRetractMassAge = 10;
    /// The residual the detector looks at: the detection observer's if there is one (else the observer's),
    /// through the second stage (detection_filter_gain) if there is one.
    const Eigen::VectorXd & detectionResidual() const noexcept
    {
      return det_stage_ ? r_f_ : (use_det_ ? obs_det_.residual : obs_.residual);
    }
    bool hasDetectionFilter() const noexcept { return det_stage_; } ///< detection_filter_gain given
    const ObserverState & observer() const noexcept { return obs_; }
    const ObserverState & detectionObserver() const noexcept { return obs_det_; }
    /// Mutable observer states, for diagnostics and tests (e.g. to exercise the invalid-observer latch).
    ObserverState & observerState() noexcept { return obs_; }
    ObserverState & detectionObserverState() noexcept { return obs_det_; }
    const Eigen::VectorXd & lastCommand() const noexcept { return tau_prev_; }
    const Eigen::Vector3d & gravity() const noexcept { return gravity_; } ///< last accepted
    // plausibility bounds per joint
    const Eigen::VectorXd & positionLow() const noexcept { return q_lo_; }
    const Eigen::VectorXd & positionHigh() const noexcept { return q_hi_; }
    const Eigen::VectorXd & velocityMax() const noexcept { return dq_max_; }
    const Eigen::VectorXd & accelerationMax() const noexcept { return ddq_max_; }
    const Eigen::VectorXd & motorTorqueMax() const noexcept { return tau_m_max_; }
    const Eigen::VectorXd & torqueMax() const noexcept { return tau_max_; }
    const Eigen::VectorXd & torqueStep() const noexcept { return tau_step_; }

  private:
    FaultCode fault(FaultCode code, Signal s, int index, double value, double lo, double hi) noexcept;
    FaultCode checkInputs(double t, const State & s, const Reference & r) noexcept;
    FaultCode reject(FaultCode code, Command & cmd) noexcept;
    void updateMode() noexcept;
    void restoreGravity() noexcept;
    // the steps of configure() after its checks, in order (configure.cpp)
    void setModel(const Model & model);
    void setJointParams(const Model & model, const ControllerParams & q);
    void setInputBounds(const Model & model, const ControllerParams & q);
    void setObserverAndReactionBounds(const Model & model, const ControllerParams & q);
    void sizeReaction(const ControllerParams & q);
    void sizeBuffers(const ControllerParams & q);
    // the steps of update(), in order (controller.cpp unless noted)
    bool commandFits(const Command & cmd) const noexcept;
    FaultCode notReady(Command & cmd) const noexcept;
    FaultCode checkPeriod(double period) noexcept;
    void stageGravity(const ConstVectorRef & gravity) noexcept;
    /// The parts of the modal damping a tick runs: first..last of 0..kDampingParts-1 (first = -1: none), in a
    /// computation spread over `span` ticks.
    struct DampingParts
    {
      int first = -1, last = -1, span = 1;
    };
    DampingParts dampingParts() const noexcept; // damping_schedule.cpp
    void computeDynamics(const State & s, const Reference & r, bool factorize) noexcept;
    FaultCode checkModelTerms() noexcept;
    FaultCode runDampingParts(const DampingParts & parts) noexcept; // damping_schedule.cpp
    void commitInputs(const ConstVectorRef & q, const DampingParts & parts) noexcept;
    void commitDamping(const DampingParts & parts) noexcept; // damping_schedule.cpp
    double advanceClock(double t, double period) noexcept;
    // the momentum observers and the detection (observer.cpp)
    void updateObservers(const State & s, double h) noexcept;
    /// The first accepted tick: p(0), where the integral of (4) starts; every residual 0.
    void startObservers() noexcept;
    void stepExact(ObserverState & o, int i, double k, double decay, double base, double h) noexcept;
    /// Joint i of both observers over the period h: head = tau_m - (g - C^T dq), jt = (J^T F)_i (used with
    /// kappa_ext); the friction of (6) per observer (kappa_f; the detection observer's own with detection_kappa_f);
    /// then the detection residual's second stage (detection_filter_gain).
    void stepObserverJoint(int i, double dq, double head, double jt, double h, bool exact, bool nominal) noexcept;
    bool observersFinite() const noexcept;
    int detect() noexcept;
    // the control law and the torque limits (control_law.cpp)
    double rampedEpsWeight() const noexcept;
    FaultCode controlLaw(const State & s, const Reference & r, double eps_w) noexcept;
    int boundTorque() noexcept;
    void commitTick(double eps_w) noexcept;
    /// Before the law: low-pass dq for the guard; on the first detection start the event and its reaction, so
    /// that the reaction's law already makes this tick's torque. True when the event started on this tick.
    bool beginEvent(double t, const State & s, int n_over) noexcept;
    /// After the law: the command's detection fields; follow a running event (not on the tick it started).
    void react(double t, const State & s, int n_over, int n_sat, bool started, Command & cmd) noexcept;
    void writeCommand(int n_sat, Command & cmd) const noexcept;
    // the collision pipeline after detection (reaction.cpp)
    void startReaction(double t, const State & s) noexcept;
    void planRetract(const State & s) noexcept;
    void factorRetractMass(const State & s) noexcept;
    // Accepted ticks since M_'s crba, after commitTick: the damping's part 0 runs when the countdown is 0, and
    // commitTick then sets it to damping_update_period - 1. (Not in gravity compensation (13), where the countdown
    // stands still; no retract runs then.)
    int massAge() const noexcept { return params_.damping_update_period - 1 - damping_countdown_; }
    /// What the retract moves: the last joint that moves the contact, and whether J_r_ is the contact point's own
    /// Jacobian (else the link joint's: the contact is somewhere from that link on).
    struct RetractTarget
    {
      int last;
      bool point_known;
    };
    RetractTarget retractDirection(const State & s) noexcept;
    double pointMotion(int last) const noexcept;
    double retractMotion(const RetractTarget & target) const noexcept;
    void estimateContact(const State & s) noexcept;
    bool beginIsolation(double t, const State & s, const Eigen::VectorXd & residual) noexcept;
    bool stepIsolation(double t) noexcept;
    void finishIsolation(double t) noexcept;
    bool awaitingIsolation() const noexcept;
    /// a retract of this event brakes until the isolation's estimate is in (retract_waits_for_estimate)
    bool retractWaits() const noexcept;
    bool retractFromEstimate() noexcept;
    void followEvent(double t, const State & s, int n_over, int n_sat) noexcept;
    void advanceReaction(double t, const State & s) noexcept;
    void retractReference() noexcept;
    double limitTorque(const State & s, int i) const noexcept;
    bool reactionLaw(const State & s, int i, double & tau) const noexcept;
    double kineticEnergy() const noexcept;
    void filterVelocity(const State & s) noexcept;
    /// tau_f of joint i: coulomb * clip(dq / velocity_band, -1, 1) + viscous * dq
    double frictionTorque(int i, double dq) const noexcept { return frictionTorque(i, dq, inv_band_); }
    double frictionTorque(int i, double dq, double inv_band) const noexcept
    {
      double sg = dq * inv_band;
      if (sg > 1.0)
        sg = 1.0;
      else if (sg < -1.0)
        sg = -1.0;
      return coulomb_[i] * sg + viscous_[i] * dq;
    }

    bool configured_ = false;
    int n_ = 0;
    ControllerParams params_;
    Model model_, model0_; // model0_: zero gravity, for M(q) x as RNEA(q, 0, x)
    Data data_g_ = definedData(), data_c_ = definedData(), data_j_ = definedData(), data_m_ = definedData(),
         data_p_ = definedData(), data_ff_ = definedData(), data_r_ = definedData();
    // parameters per joint
    Eigen::VectorXd K_, xi_, ko_, ko_det_, threshold_, coulomb_, viscous_, spring_k_, spring_q_;
    bool has_springs_ = false;
    Eigen::VectorXd q_lo_, q_hi_, dq_max_, ddq_max_, tau_m_max_, tau_max_, tau_step_;
    Eigen::VectorXd decay_, decay_det_; // exact observer: e^{-K_o dt} per joint at the nominal period
    Eigen::VectorXd kf_, decay_f_;       // the detection residual's second stage: K_f, e^{-K_f dt}
    bool det_stage_ = false;              // detection_filter_gain given
    Eigen::VectorXd v_lim_, q_safe_lo_, q_safe_hi_; // velocity limits (+inf: none), reaction posture bounds
    // the reaction under way (reaction.cpp)
    CollisionEvent event_;
    Eigen::VectorXd K_hold_, q_from_, dq_plan_, qd_r_, dqd_r_, ddqd_r_, ff_r_;
    Eigen::VectorXd dq_f_, p_f_; // low-passed dq and M(q) dq for the guard's kinetic energy
    bool has_filter_ = false;
    Eigen::Matrix<double, 6, Eigen::Dynamic> J_r_;
    using RetractLlt = Eigen::LLT<Eigen::MatrixXd, Eigen::Upper>;
    // M(q)'s Cholesky factor for the retract's plan, sized once in configure (no allocation)
    RetractLlt llt_r_ = definedLlt<RetractLlt>(0);
    bool retract_due_ = false; // llt_r_ holds M(q)'s factor of the tick the isolation came in: the plan is due
    ContactIsolator isolator_;
    bool has_isolator_ = false;
    double t_phase_ = 0.0, retract_time_ = 0.0, hold_damping_scale_ = 1.0;
    double inv_band_ = 0.0, limit_ = 0.0, period_lo_ = 0.0, period_hi_ = 0.0;
    double inv_band_det_ = 0.0; // the detection observer's friction band (detection_kappa_f)
    bool det_friction_ = false; // detection_kappa_f: the detection observer subtracts friction whatever kappa_f
    double g_norm_ = 0.0, g_tol_ = 0.0, force_max_ = 0.0, moment_max_ = 0.0;
    bool use_det_ = false, has_detector_ = false;
    // buffers
    Eigen::VectorXd zeros_, g_, p_, ff_, tau_new_, last_q_, tau_prev_, tau_safe_, q_buf_;
    Eigen::Matrix<double, 6, Eigen::Dynamic> J_;
    Eigen::MatrixXd M_, D_, D_new_;
    ModalDampingWorkspace modal_;
    Eigen::Matrix<std::uint8_t, Eigen::Dynamic, 1> over_, sat_, first_joints_;
    // state
    ObserverState obs_, obs_det_;
    Eigen::VectorXd r_f_; // the detection residual after the second stage (detection_filter_gain)
    Eigen::Vector3d gravity_ = Eigen::Vector3d::Zero(); // last accepted
    bool gravity_staged_ = false;
    bool started_ = false, has_t_ = false, has_last_q_ = false, obs_invalid_ = false, has_prev_tau_ = false;
    double last_t_ = 0.0;
    double elapsed_ = 0.0; // sum of the `period`s given since the last accepted tick [s]
    TimingStats timing_;
    int kappa_f_ = 0, kappa_eps_ = 0, kappa_ext_ = 0, kappa_eps_before_reaction_ = 0;
    double eps_weight_ = 0.0;
    bool reacted_ = false, gravity_mode_ = false, detected_ = false;
    double first_time_ = 0.0;
    int damping_countdown_ = 0;
    int damping_next_part_ = -1; // the part the next accepted tick runs of a computation under way (-1: none)
    int damping_span_ = 1;       // ticks of the computation under way
    bool damping_full_ = true;   // the next computation runs whole in its first tick (after configure/reset)
    bool damping_updated_ = false;
    int damping_parts_run_ = 0;
    double law_share_ = std::numeric_limits<double>::quiet_NaN(); ///< lawModeShare()
    Mode mode_ = Mode::Compliant;
    FaultInfo fault_;

    // the residual-only replay (residual_replay.cpp) runs update()'s contract, observers and detection without the law
    friend struct ResidualReplay;
  };

} // namespace reflexarm
