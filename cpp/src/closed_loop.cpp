// reflexarm::ClosedLoop: see closed_loop.hpp. The per-tick arithmetic mirrors reflexarm/sim/_kernels.py
// (measurement, load_compensated_wrench, external_joint_torque, sum_force) and Plant._apply_forces in
// the same order of operations, so that the compiled loop and the Python loop agree to round-off.
#include "reflexarm/closed_loop.hpp"

#include <cmath>
#include <cstring>
#include <mutex>

namespace reflexarm
{

  namespace
  {
    // MuJoCo's com-based inertia (10,) times a spatial motion vector (6,): as _kernels._mul_inert.
    inline void mulInert(const mjtNum * i, const mjtNum * v, double * out) noexcept
    {
      out[0] = i[0] * v[0] + i[3] * v[1] + i[4] * v[2] - i[8] * v[4] + i[7] * v[5];
      out[1] = i[3] * v[0] + i[1] * v[1] + i[5] * v[2] + i[8] * v[3] - i[6] * v[5];
      out[2] = i[4] * v[0] + i[5] * v[1] + i[2] * v[2] - i[7] * v[3] + i[6] * v[4];
      out[3] = i[8] * v[1] - i[7] * v[2] + i[9] * v[3];
      out[4] = i[6] * v[2] - i[8] * v[0] + i[9] * v[4];
      out[5] = i[7] * v[0] - i[6] * v[1] + i[9] * v[5];
    }
    // The clock of MuJoCo's profiling timers under QuietTimers.
    mjtNum noClock() noexcept { return 0.0; }
    // mjcb_time is global: QuietTimers in several threads at once (e.g. Dask workers as threads) count
    // themselves under a lock; the first saves the callback and installs noClock, the last restores it.
    // (Without the lock a check-then-write race could leave noClock installed for good.)
    std::mutex g_quiet_mutex;
    int g_quiet_count = 0;
    mjfTime g_quiet_prev = nullptr;
  } // namespace

  QuietTimers::QuietTimers(bool on) noexcept : on_(on)
  {
    if (!on_)
      return;
    const std::lock_guard<std::mutex> lock(g_quiet_mutex);
    if (g_quiet_count++ == 0)
    {
      g_quiet_prev = mjcb_time;
      mjcb_time = &noClock;
    }
  }

  QuietTimers::~QuietTimers()
  {
    if (!on_)
      return;
    const std::lock_guard<std::mutex> lock(g_quiet_mutex);
    if (--g_quiet_count == 0 && mjcb_time == &noClock) // a callback set meanwhile by someone else stays
      mjcb_time = g_quiet_prev;
  }

  void stepSensingLast(const mjModel * m, mjData * d, int steps) noexcept
  {
    // the plant's model is the caller's; its disable flags are restored before returning (as
    // reflexarm.sim._plant_sensors.step_sensing_last does in the Python loop)
    auto * mm = const_cast<mjModel *>(m);
    const int flags = mm->opt.disableflags;
    mm->opt.disableflags = flags | mjDSBL_SENSOR;
    for (int s = 0; s < steps - 1; ++s)
      mj_step(mm, d);
    mm->opt.disableflags = flags;
    mj_step(mm, d);
  }

  void ClosedLoop::configure(const mjModel * model, mjData * data, const PlantLayout & layout,
                             const pinocchio::Model & controller_model, const ControllerParams & params)
  {
    if (model == nullptr || data == nullptr)
      throw ConfigError("ClosedLoop: the MuJoCo model and data must not be null");
    const int n = static_cast<int>(layout.qadr.size());
    if (n == 0 || static_cast<int>(layout.vadr.size()) != n)
      throw ConfigError("ClosedLoop: qadr and vadr must list the same non-zero number of joints; got "
                        + std::to_string(layout.qadr.size()) + " and " + std::to_string(layout.vadr.size()));
    if (controller_model.nv != n)
      throw ConfigError("ClosedLoop: the controller's model has " + std::to_string(controller_model.nv)
                        + " joints; the plant's arm has " + std::to_string(n));
    if (layout.substeps < 1)
      throw ConfigError("ClosedLoop: substeps must be >= 1; got " + std::to_string(layout.substeps));
    for (int b : layout.load_bodies)
      if (b < 0 || b >= model->nbody)
        throw ConfigError("ClosedLoop: load body " + std::to_string(b) + " out of range");
    for (int b : layout.arm_bodies)
      if (b < 0 || b >= model->nbody)
        throw ConfigError("ClosedLoop: arm body " + std::to_string(b) + " out of range");
    for (int i = 0; i < n; ++i)
      if (layout.qadr[i] < 0 || layout.qadr[i] >= model->nq || layout.vadr[i] < 0 || layout.vadr[i] >= model->nv)
        throw ConfigError("ClosedLoop: joint address out of range at joint " + std::to_string(i));
    m_ = model;
    d_ = data;
    lay_ = layout;
    n_ = n;
    ctrl_.configure(controller_model, params);
    ctrl_.initCommand(cmd_);
    parent_.assign(model->body_parentid, model->body_parentid + model->nbody);
    dof_body_.assign(model->dof_bodyid, model->dof_bodyid + model->nv);
    acc6_.assign(static_cast<size_t>(model->nbody) * 6, 0.0);
    meas_.setZero(3 * n + 9);
    zero_noise_.setZero(3 * n + 9);
    tau_applied_.setZero(n);
  }

  // ------------------------------------------------------------------------------------------ sensors
  void ClosedLoop::loadCompensatedWrench(double * out) noexcept
  {
    double w[6] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
    double tmp[6], tmp2[6];
    const mjtNum * cfrc = lay_.physical ? d_->cfrc_int : d_->cfrc_ext;
    for (int b : lay_.load_bodies)
    {
      if (lay_.physical)
      {
        const mjtNum * ci = d_->cinert + 10 * b;
        mulInert(ci, d_->cacc + 6 * b, tmp);
        for (int c = 0; c < 6; ++c)
          w[c] += tmp[c];
        const mjtNum * v = d_->cvel + 6 * b;
        mulInert(ci, v, tmp);
        tmp2[0] = -v[2] * tmp[1] + v[1] * tmp[2] - v[5] * tmp[4] + v[4] * tmp[5];
        tmp2[1] = v[2] * tmp[0] - v[0] * tmp[2] + v[5] * tmp[3] - v[3] * tmp[5];
        tmp2[2] = -v[1] * tmp[0] + v[0] * tmp[1] - v[4] * tmp[3] + v[3] * tmp[4];
        tmp2[3] = -v[2] * tmp[4] + v[1] * tmp[5];
        tmp2[4] = v[2] * tmp[3] - v[0] * tmp[5];
        tmp2[5] = -v[1] * tmp[3] + v[0] * tmp[4];
        for (int c = 0; c < 6; ++c)
          w[c] += tmp2[c];
      }
      else
      {
        for (int c = 0; c < 6; ++c)
          w[c] += cfrc[6 * b + c];
      }
    }
    const mjtNum * com = d_->subtree_com + 3 * lay_.com_body;
    const mjtNum * sp = d_->site_xpos + 3 * lay_.site;
    const mjtNum * sm = d_->site_xmat + 9 * lay_.site;
    const double dx = sp[0] - com[0], dy = sp[1] - com[1], dz = sp[2] - com[2];
    const double mx = w[0] - (dy * w[5] - dz * w[4]);
    const double my = w[1] - (dz * w[3] - dx * w[5]);
    const double mz = w[2] - (dx * w[4] - dy * w[3]);
    for (int k = 0; k < 3; ++k)
    {
      out[k] = sm[k] * w[3] + sm[3 + k] * w[4] + sm[6 + k] * w[5];
      out[3 + k] = sm[k] * mx + sm[3 + k] * my + sm[6 + k] * mz;
    }
    if (lay_.physical)
    {
      for (int k = 0; k < 3; ++k)
      {
        out[k] -= d_->sensordata[lay_.force_adr + k];
        out[3 + k] -= d_->sensordata[lay_.torque_adr + k];
      }
    }
  }

  void ClosedLoop::measurement(const double * noise, double * out) noexcept
  {
    const int n = n_;
    for (int i = 0; i < n; ++i)
    {
      out[i] = d_->qpos[lay_.qadr[i]] + noise[i];
      out[n + i] = d_->qvel[lay_.vadr[i]] + noise[n + i];
      out[2 * n + i] = tau_applied_[i] + noise[2 * n + i];
    }
    double * w = out + 3 * n;
    loadCompensatedWrench(w);
    for (int k = 0; k < 6; ++k)
      w[k] += noise[3 * n + k];
    for (int k = 0; k < 3; ++k)
      out[3 * n + 6 + k] = lay_.gravity[k] + noise[3 * n + 6 + k];
  }

  void ClosedLoop::externalTorque(double * out) noexcept
  {
    const auto & bodies = lay_.arm_bodies;
    for (int b : bodies)
      for (int c = 0; c < 6; ++c)
        acc6_[6 * b + c] = d_->cfrc_ext[6 * b + c];
    for (size_t k = bodies.size() - 1; k > 0; --k)
    {
      const int b = bodies[k], p = parent_[b];
      for (int c = 0; c < 6; ++c)
        acc6_[6 * p + c] += acc6_[6 * b + c];
    }
    for (int i = 0; i < n_; ++i)
    {
      const int j = lay_.vadr[i];
      const int b = dof_body_[j];
      double s = 0.0;
      for (int c = 0; c < 6; ++c)
        s += d_->cdof[6 * j + c] * acc6_[6 * b + c];
      out[i] = s;
    }
  }

  void ClosedLoop::eeContactForce(double * out) noexcept
  {
    out[0] = out[1] = out[2] = 0.0;
    for (int b : lay_.load_bodies)
      for (int c = 0; c < 3; ++c)
        out[c] += d_->cfrc_ext[6 * b + 3 + c];
  }

  // ------------------------------------------------------------------------------------------ the tick
  void ClosedLoop::sense(long k) noexcept
  {
    const int n = n_;
    const double * noise = buf_.noise != nullptr ? buf_.noise + k * (3 * n + 9) : zero_noise_.data();
    double * y = meas_.data();
    measurement(noise, y);
    const double t = d_->time;
    using Map = Eigen::Map<const Eigen::VectorXd>;
    const Map mq(y, n), mdq(y + n, n), mtau(y + 2 * n, n), mw(y + 3 * n, 6), mg(y + 3 * n + 6, 3);
    const Map qd(buf_.q_d + k * n, n), dqd(buf_.dq_d + k * n, n), ddqd(buf_.ddq_d + k * n, n);
    const State s{mq, mdq, mtau, mw, mg};
    const Reference r{qd, dqd, ddqd};
    const FaultCode code = ctrl_.update(t, 0.0, s, r, cmd_);
    // record row k
    buf_.t[k] = t;
    for (int i = 0; i < n; ++i)
    {
      buf_.q[k * n + i] = d_->qpos[lay_.qadr[i]];
      buf_.dq[k * n + i] = d_->qvel[lay_.vadr[i]];
      buf_.q_meas[k * n + i] = y[i];
      buf_.tau[k * n + i] = cmd_.tau[i];
      buf_.tau_m[k * n + i] = y[2 * n + i];
      buf_.residual[k * n + i] = cmd_.residual[i];
      buf_.collided[k * n + i] = cmd_.collided[i];
    }
    if (buf_.dq_meas != nullptr)
      for (int i = 0; i < n; ++i)
        buf_.dq_meas[k * n + i] = y[n + i];
    buf_.collision[k] = cmd_.collision ? 1 : 0;
    buf_.mode[k] = static_cast<std::int32_t>(cmd_.mode);
    buf_.fault_code[k] = static_cast<std::int32_t>(code);
    double * fi = buf_.fault_info + 5 * k;
    fi[0] = static_cast<double>(static_cast<int>(cmd_.fault.signal));
    fi[1] = cmd_.fault.index;
    fi[2] = cmd_.fault.value;
    fi[3] = cmd_.fault.lo;
    fi[4] = cmd_.fault.hi;
    for (int c = 0; c < 6; ++c)
      buf_.wrench[6 * k + c] = y[3 * n + c];
    externalTorque(buf_.tau_ext + k * n);
    eeContactForce(buf_.f_ext_ee + 3 * k);
    for (const auto & rec : qpos_records_)
      std::memcpy(rec.out + k * rec.size, d_->qpos + rec.adr, sizeof(double) * static_cast<size_t>(rec.size));
    for (const auto & rec : mocap_records_)
      std::memcpy(rec.out + 3 * k, d_->mocap_pos + 3 * rec.mocap_id, sizeof(double) * 3);
    for (const auto & push : pushes_)
    {
      std::memcpy(push.force_out + 3 * k, push.force, sizeof(double) * 3);
      std::memcpy(push.target_out + 3 * k, push.target, sizeof(double) * 3);
    }
    if (still_.spec != 0)
      watchStill(k);
  }

  // ------------------------------------------------------------------------------------------ stills
  void ClosedLoop::keepStill(int spec)
  {
    if (spec == 0)
    {
      still_ = StillStates{};
      return;
    }
    const int all = static_cast<int>(mjSTATE_INTEGRATION); // every bit of mjtState
    if (spec < 0 || (spec & ~all) != 0)
      throw ConfigError("ClosedLoop.keep_still: spec must be a mask of mjtState bits (within mjSTATE_INTEGRATION = "
                        + std::to_string(all) + "); got " + std::to_string(spec));
    if (m_ == nullptr)
      throw ConfigError("ClosedLoop.keep_still: configure the loop first");
    const int size = mj_stateSize(m_, spec);
    still_.spec = spec;
    still_.start.assign(static_cast<size_t>(size), 0.0);
    still_.peak.assign(static_cast<size_t>(size), 0.0);
    still_.start_tick = still_.peak_tick = -1;
    still_.peak2 = 0.0;
  }

  // After row k is recorded: its tau_ext row is the one StillCapture evaluates at tick k (see StillStates).
  void ClosedLoop::watchStill(long k) noexcept
  {
    if (still_.start_tick < 0)
    {
      mj_getState(m_, d_, still_.start.data(), still_.spec);
      still_.start_tick = k;
    }
    const double * tau = buf_.tau_ext + k * n_;
    double s = 0.0;
    for (int i = 0; i < n_; ++i)
      s += tau[i] * tau[i]; // rounded product, then the sum (this file is built with -ffp-contract=off)
    if (s > still_.peak2)
    {
      still_.peak2 = s;
      still_.peak_tick = k;
      mj_getState(m_, d_, still_.peak.data(), still_.spec);
    }
  }

  // As HandPush.update (reflexarm/sim/hand_push.py) and Plant.apply_external_force, operation by operation.
  void ClosedLoop::updatePush(SpringPush & push, long k) noexcept
  {
    push.applied = false;
    const double r = push.rest[k];
    if (std::isnan(r))
    {
      push.force[0] = push.force[1] = push.force[2] = 0.0;
      push.has_last = false;
      return;
    }
    const mjtNum * p = d_->site_xpos + 3 * push.site;
    const double x = push.u[0] * (p[0] - push.p0[0]) + push.u[1] * (p[1] - push.p0[1]) + push.u[2] * (p[2] - push.p0[2]);
    const double v = push.has_last ? (x - push.last_x) / push.period : 0.0;
    push.last_x = x;
    push.has_last = true;
    for (int i = 0; i < 3; ++i)
      push.target[i] = push.p0[i] + push.u[i] * r;
    double f = push.stiffness * (r - x) + push.damping * (push.rest_v[k] - v);
    f = f > 0.0 ? f : 0.0;
    for (int i = 0; i < 3; ++i)
      push.force[i] = f * push.u[i];
    if (f > 0.0)
    {
      const mjtNum * pos = d_->xpos + 3 * push.body;
      const mjtNum * R = d_->xmat + 9 * push.body;
      const double dx[3] = {p[0] - pos[0], p[1] - pos[1], p[2] - pos[2]};
      for (int i = 0; i < 3; ++i) // R^T (p - xpos)
        push.point_local[i] = R[i] * dx[0] + R[3 + i] * dx[1] + R[6 + i] * dx[2];
      push.applied = true;
    }
  }

  void ClosedLoop::applyForces() noexcept
  {
    mjtNum * xfrc = d_->xfrc_applied;
    std::memset(xfrc, 0, sizeof(mjtNum) * 6 * static_cast<size_t>(m_->nbody));
    const size_t n_list = forces_.size();
    for (size_t j = 0; j < n_list + pushes_.size(); ++j)
    {
      AppliedForce pf;
      if (j >= n_list)
      {
        const SpringPush & push = pushes_[j - n_list];
        if (!push.applied)
          continue;
        pf.body = push.body;
        for (int i = 0; i < 3; ++i)
        {
          pf.force[i] = push.force[i];
          pf.point_local[i] = push.point_local[i];
        }
      }
      const AppliedForce & f = j < n_list ? forces_[j] : pf;
      const int b = f.body;
      const mjtNum * pos = d_->xpos + 3 * b;
      const mjtNum * R = d_->xmat + 9 * b;
      const mjtNum * ci = d_->xipos + 3 * b;
      double p[3], r[3];
      for (int i = 0; i < 3; ++i)
        p[i] = pos[i] + (R[3 * i] * f.point_local[0] + R[3 * i + 1] * f.point_local[1] + R[3 * i + 2] * f.point_local[2]);
      for (int i = 0; i < 3; ++i)
        r[i] = p[i] - ci[i];
      mjtNum * x = xfrc + 6 * b;
      for (int i = 0; i < 3; ++i)
        x[i] += f.force[i];
      x[3] += r[1] * f.force[2] - r[2] * f.force[1];
      x[4] += r[2] * f.force[0] - r[0] * f.force[2];
      x[5] += r[0] * f.force[1] - r[1] * f.force[0];
    }
  }

  StepStatus ClosedLoop::act(long k) noexcept
  {
    for (const auto & plan : mocap_plans_)
    {
      const double * p = plan.pos + 3 * k;
      if (!std::isnan(p[0]))
        for (int c = 0; c < 3; ++c)
          d_->mocap_pos[3 * plan.mocap_id + c] = p[c];
    }
    for (auto & push : pushes_)
      updatePush(push, k);
    if (!forces_.empty() || !pushes_.empty())
      applyForces();
    for (int i = 0; i < n_; ++i)
    {
      tau_applied_[i] = cmd_.tau[i];
      d_->qfrc_applied[lay_.vadr[i]] = cmd_.tau[i];
    }
    const double period = lay_.substeps * m_->opt.timestep;
    const double t_end = d_->time + period;
    {
      const QuietTimers quiet(quiet_timers_);
      stepSensingLast(m_, d_, lay_.substeps);
    }
    double vv = 0.0;
    for (int i = 0; i < m_->nv; ++i)
      vv += d_->qvel[i] * d_->qvel[i];
    if (!(vv < lay_.max_speed * lay_.max_speed))
      return StepStatus::Diverged;
    if (d_->time < t_end - 0.5 * m_->opt.timestep)
      return StepStatus::TimeMismatch;
    return StepStatus::Ok;
  }

  long ClosedLoop::run(long k0, long k1, StepStatus & status) noexcept
  {
    status = StepStatus::Ok;
    for (long k = k0; k < k1; ++k)
    {
      sense(k);
      status = act(k);
      if (status != StepStatus::Ok)
        return k - k0 + 1;
    }
    return k1 - k0;
  }

} // namespace reflexarm
