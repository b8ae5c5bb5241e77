// reflexarm::ContactIsolator: the fit of the candidate points, in ranges so that step() can spread it over the ticks.
// Per link, once (linkTerms): the 3x3 terms P, Q, S of its weighted Jacobian in its joint frame (row c of W J_p^T at
// the point p is u_c + v_c x p), so that pass 1 has the trace of A = J_p W W J_p^T of a point in closed form, a few
// flops (traceRange: the edges' floor needs the link's largest trace). Pass 2 per point (fitRange): A and
// b = J_p W W r as identify.py forms them (world frame, sums of products of W J_p^T), the lower bound below, then
// unless it rules the point out the least squares min |W (J_p^T f - r)| with f in the friction pyramid, solved
// exactly over its interior, facets, edges and apex: the port of reflexarm.control.collision.identify, in its order
// of operations.
//
// Exact pruning: the unconstrained minimum |W r|^2 - b^T A^-1 b is a lower bound of the constrained error^2. A point
// whose bound exceeds (the link's best so far + tolerance)^2 can be neither the link's best point nor in its
// consistent set (errors <= best + tolerance): its constrained fit is skipped, its error set to +inf. The bound is
// used only where A is well conditioned (det A > kPruneCondition (tr A / 3)^3, its round-off then ~1e-9 |W r|^2)
// and with a margin of kPruneMargin |W r|^2, so that round-off never skips a point that would count.
#include <algorithm>
#include <cmath>

#include "reflexarm/isolation.hpp"

#include "isolation_detail.hpp"

namespace reflexarm
{
  using namespace isolation_detail;

  namespace
  {
    constexpr double kPruneCondition = 1e-6;
    constexpr double kPruneMargin = 1e-6;

    inline Eigen::Vector3d row3(const Eigen::Ref<const Eigen::Matrix<double, 1, 3>> & r)
    {
      return r.transpose();
    }
  } // namespace

  void ContactIsolator::linkTerms(int link) noexcept
  {
    const LinkBuffers & L = links_[static_cast<size_t>(link)];
    const Eigen::Matrix3d Rt = L.rotation.transpose();
    const Jac & J = L.jacobian;
    P_.setZero();
    Q_.setZero();
    S_.setZero();
    for (int c = 0; c < n_; ++c)
    {
      const Eigen::Vector3d u = Rt * J.col(c).head<3>() * weights_[c];
      const Eigen::Vector3d v = Rt * J.col(c).tail<3>() * weights_[c];
      P_ += u * u.transpose();
      Q_ += u * v.transpose();
      S_ += v * v.transpose();
    }
  }

  void ContactIsolator::traceRange(int link, Eigen::Index begin, Eigen::Index end) noexcept
  {
    LinkBuffers & L = links_[static_cast<size_t>(link)];
    if (begin == 0)
      linkTerms(link);
    // trace A(p) = tr P + 2 tr(Q [p]x) + |p|^2 tr S - p^T S p, tr(Q [p]x) = t . p
    const Eigen::Vector3d t(Q_(1, 2) - Q_(2, 1), Q_(2, 0) - Q_(0, 2), Q_(0, 1) - Q_(1, 0));
    const double trP = P_.trace(), trS = S_.trace();
    double max_trace = L.max_trace;
    for (Eigen::Index i = begin; i < end; ++i)
    {
      const Eigen::Vector3d p = row3(L.points_local.row(i));
      max_trace = std::max(max_trace, trP + 2.0 * t.dot(p) + p.squaredNorm() * trS - p.dot(S_ * p));
    }
    L.max_trace = max_trace;
  }

  // J_p^T W of the point at d = p - o: row c is (J_v,c + J_w,c x d) w_c
  void ContactIsolator::pointJacobianT(const Jac & J, const Eigen::Vector3d & d) noexcept
  {
    for (int c = 0; c < n_; ++c)
    {
      const Eigen::Vector3d jv = J.col(c).head<3>(), jw = J.col(c).tail<3>();
      jpt_.row(c) = ((jv + jw.cross(d)) * weights_[c]).transpose();
    }
  }

  void ContactIsolator::fitRange(int link, Eigen::Index begin, Eigen::Index end) noexcept
  {
    LinkBuffers & L = links_[static_cast<size_t>(link)];
    const Eigen::Matrix3d & R = L.rotation;
    const Jac & J = L.jacobian;
    const Eigen::VectorXd & r = weighted_residual_;

    // pass 2: A and b, the lower bound, then unless it rules the point out the constrained fit (interior, facets,
    // edges, apex) and its error
    const Eigen::Vector3d & o = L.origin;
    const int K = K_;
    const double floor = L.floor;
    int best = L.best;
    double best_error = L.best_error;
    for (Eigen::Index i = begin; i < end; ++i)
    {
      const Eigen::Vector3d d = R * L.points_local.row(i).transpose(); // p - o
      L.points.row(i) = (d + o).transpose();
      pointJacobianT(J, d);
      Eigen::Matrix3d A;
      Eigen::Vector3d b;
      for (int a = 0; a < 3; ++a)
      {
        for (int bb = 0; bb < 3; ++bb)
        {
          double s = 0.0;
          for (int c = 0; c < n_; ++c)
            s += jpt_(c, a) * jpt_(c, bb);
          A(a, bb) = s;
        }
        double s = 0.0;
        for (int c = 0; c < n_; ++c)
          s += jpt_(c, a) * r[c];
        b[a] = s;
      }
      // interior: the unconstrained solve, if inside the pyramid
      Eigen::Matrix3d adj;
      adj(0, 0) = A(1, 1) * A(2, 2) - A(1, 2) * A(2, 1);
      adj(0, 1) = A(0, 2) * A(2, 1) - A(0, 1) * A(2, 2);
      adj(0, 2) = A(0, 1) * A(1, 2) - A(0, 2) * A(1, 1);
      adj(1, 0) = A(1, 2) * A(2, 0) - A(1, 0) * A(2, 2);
      adj(1, 1) = A(0, 0) * A(2, 2) - A(0, 2) * A(2, 0);
      adj(1, 2) = A(0, 2) * A(1, 0) - A(0, 0) * A(1, 2);
      adj(2, 0) = A(1, 0) * A(2, 1) - A(1, 1) * A(2, 0);
      adj(2, 1) = A(0, 1) * A(2, 0) - A(0, 0) * A(2, 1);
      adj(2, 2) = A(0, 0) * A(1, 1) - A(0, 1) * A(1, 0);
      const double detA = A(0, 0) * adj(0, 0) + A(0, 1) * adj(1, 0) + A(0, 2) * adj(2, 0);
      const double tr = A(0, 0) + A(1, 1) + A(2, 2);
      const double tr3 = tr / 3.0;
      const double tr3_cubed = std::pow(tr3, 3.0);
      const bool well = detA > kInteriorCondition * tr3_cubed;
      Eigen::Vector3d f_int = adj * b;
      f_int /= well ? detA : 1.0;
      if (detA > kPruneCondition * tr3_cubed && best_error < kInf) // the lower bound decides
      {
        const double limit = best_error + tolerance_;
        if (wr2_ - f_int.dot(b) > limit * limit + kPruneMargin * wr2_)
        {
          L.errors[i] = kInf;
          ++pruned_;
          continue;
        }
      }
      for (int k = 0; k < K; ++k)
      {
        d_world_.row(k) = (R * L.generators.row(i * K + k).transpose()).transpose();
        c_world_.row(k) = (R * L.facet_normals.row(i * K + k).transpose()).transpose();
      }
      for (int k = 0; k < K; ++k)
      {
        const Eigen::Vector3d dk = d_world_.row(k).transpose();
        const Eigen::Vector3d Adk = A * dk;
        h_[k] = dk.dot(b);
        gg_[k] = dk.dot(Adk);
      }
      for (int k = 0; k < K; ++k)
      {
        const Eigen::Vector3d dl = d_world_.row((k + 1) % K).transpose();
        g12_[k] = d_world_.row(k).dot((A * dl).transpose());
      }
      // edges: f = t d_k, t >= 0
      for (int k = 0; k < K; ++k)
        t_[k] = gg_[k] > floor ? std::max(h_[k], 0.0) / gg_[k] : 0.0;
      bool inside = true;
      for (int k = 0; k < K; ++k)
        inside = inside && (c_world_.row(k).dot(f_int.transpose()) >= 0.0);
      // the best feasible candidate: first maximum over [interior, facets, edges, apex], as np.argmax
      int choice = 0;
      double top = (well && inside) ? f_int.dot(b) : -kInf;
      for (int k = 0; k < K; ++k)
      {
        const int l = (k + 1) % K;
        const double det = gg_[k] * gg_[l] - g12_[k] * g12_[k];
        bool ok = gg_[k] > floor && gg_[l] > floor && det > kFacetCondition * gg_[k] * gg_[l];
        const double safe = ok ? det : 1.0;
        x1_[k] = (gg_[l] * h_[k] - g12_[k] * h_[l]) / safe;
        x2_[k] = (gg_[k] * h_[l] - g12_[k] * h_[k]) / safe;
        ok = ok && x1_[k] >= 0.0 && x2_[k] >= 0.0;
        const double red = ok ? x1_[k] * h_[k] + x2_[k] * h_[l] : -kInf;
        if (red > top)
        {
          top = red;
          choice = 1 + k;
        }
      }
      for (int k = 0; k < K; ++k)
      {
        const double red = t_[k] * h_[k];
        if (red > top)
        {
          top = red;
          choice = 1 + K + k;
        }
      }
      if (0.0 > top)
        choice = 1 + 2 * K;
      Eigen::Vector3d f = Eigen::Vector3d::Zero();
      if (choice == 0)
        f = f_int;
      else if (choice <= K)
      {
        const int k = choice - 1;
        f = x1_[k] * d_world_.row(k).transpose() + x2_[k] * d_world_.row((k + 1) % K).transpose();
      }
      else if (choice <= 2 * K)
      {
        const int k = choice - 1 - K;
        f = t_[k] * d_world_.row(k).transpose();
      }
      L.forces.row(i) = f.transpose();
      // error |W (J_p^T f - r)|
      double e2 = 0.0;
      for (int c = 0; c < n_; ++c)
      {
        const double e = jpt_.row(c).dot(f.transpose()) - r[c];
        e2 += e * e;
      }
      L.errors[i] = std::sqrt(e2);
      if (L.errors[i] < best_error)
      {
        best_error = L.errors[i];
        best = static_cast<int>(i);
      }
    }
    L.best = best;
    L.best_error = best_error;
  }

} // namespace reflexarm
