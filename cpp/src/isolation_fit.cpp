// reflexarm::ContactIsolator: the fit of the candidate points, in ranges so that step() can spread it over the ticks;
// the rank of a link's Jacobian (the choice) and the wrench fit of a link without geometry.
//
// Everything per point is in the link's joint frame, where the points, the pyramid's generators and its facet
// normals are stored: with u_c, v_c the rows of W J^T rotated into that frame (linkTerms, once per link), row c of
// W J_p^T at the point p is a_c(p) = u_c + v_c x p, so that
//   A(p) = sum a_c a_c^T = P + M + M^T + [p]x S [p]x^T,   M = Q [p]x (row i of M: Q_i x p),
//   b(p) = sum (W r)_c a_c = ur + vr x p,
// P = sum u u^T, Q = sum u v^T, S = sum v v^T, ur = sum (W r)_c u_c, vr = sum (W r)_c v_c: A and b of a point in a
// fixed number of flops whatever the number of joints, and no rotation per point (A, b, the force and the error
// are those of identify.py's world frame rotated by R^T: the same numbers up to round-off; the choice and the
// estimate rotate only the best point and force back). Pass 1 (traceRange) needs only the trace of A (the edges'
// floor needs the link's largest trace), a few flops a point. Pass 2 (fitRange): A and b, the lower bound below,
// then unless it rules the point out the least squares min |W (J_p^T f - r)| with f in the friction pyramid, solved
// exactly over its interior, facets, edges and apex (the port of reflexarm.control.collision.identify), and the
// fit error |W (J_p^T f - r)| computed directly from the rows a_c: sum_c (u_c . f + v_c . (p x f) - (W r)_c)^2. Not
// from the expansion f^T A f - 2 f^T b + |W r|^2: that cancels to eps |W r|^2 / e^2 relative (e ~ 1e-8 |W r| for
// an exact fit, worse with an ill-conditioned A and a large f), the direct sum keeps identify.py's round-off, so
// that the best point, its ties and the consistent set (errors <= best + tolerance) are decided as in Python.
//
// Exact pruning: the unconstrained minimum |W r|^2 - b^T A^-1 b is a lower bound of the constrained error^2. A point
// whose bound exceeds (the link's best so far + tolerance)^2 can be neither the link's best point nor in its
// consistent set (errors <= best + tolerance): its constrained fit is skipped, its error set to +inf. The bound is
// used only where A is well conditioned (det A > kPruneCondition (tr A / 3)^3, its round-off then ~1e-9 |W r|^2)
// and with a margin of kPruneMargin |W r|^2, so that round-off never skips a point that would count.
#include <algorithm>
#include <cmath>
#include <limits>

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
    const Eigen::VectorXd & r = weighted_residual_;
    P_.setZero();
    Q_.setZero();
    S_.setZero();
    ur_.setZero();
    vr_.setZero();
    for (int c = 0; c < n_; ++c) // columns outside the link's support are zero: rows u_c = v_c = 0
    {
      const Eigen::Vector3d u = Rt * J.col(c).head<3>() * weights_[c];
      const Eigen::Vector3d v = Rt * J.col(c).tail<3>() * weights_[c];
      uv_.row(c).head<3>() = u.transpose();
      uv_.row(c).tail<3>() = v.transpose();
      P_ += u * u.transpose();
      Q_ += u * v.transpose();
      S_ += v * v.transpose();
      ur_ += r[c] * u;
      vr_ += r[c] * v;
    }
  }

  void ContactIsolator::traceRange(int link, Eigen::Index begin, Eigen::Index end) noexcept
  {
    LinkBuffers & L = links_[static_cast<size_t>(link)];
    const LinkGeometry & G = geometry(link);
    if (begin == 0)
      linkTerms(link);
    // trace A(p) = tr P + 2 tr(Q [p]x) + |p|^2 tr S - p^T S p, tr(Q [p]x) = t . p
    const Eigen::Vector3d t(Q_(1, 2) - Q_(2, 1), Q_(2, 0) - Q_(0, 2), Q_(0, 1) - Q_(1, 0));
    const double trP = P_.trace(), trS = S_.trace();
    double max_trace = L.max_trace;
    for (Eigen::Index i = begin; i < end; ++i)
    {
      const Eigen::Vector3d p = row3(G.points_local.row(i));
      max_trace = std::max(max_trace, trP + 2.0 * t.dot(p) + p.squaredNorm() * trS - p.dot(S_ * p));
    }
    L.max_trace = max_trace;
  }

  void ContactIsolator::fitRange(int link, Eigen::Index begin, Eigen::Index end) noexcept
  {
    if (K_ == kDefaultConeEdges)
      fitRangeK<kDefaultConeEdges>(link, begin, end);
    else
      fitRangeK<0>(link, begin, end);
  }

  // KC > 0: the pyramid's K = KC edges known at compile time (the default 8): the per-edge values live in local arrays
  // and the loops over the edges unroll; KC = 0: K_ edges, the members' buffers. The same operations in the same
  // order either way (the same numbers bit for bit).
  template <int KC>
  void ContactIsolator::fitRangeK(int link, Eigen::Index begin, Eigen::Index end) noexcept
  {
    constexpr int KS = KC > 0 ? KC : 1;
    double h_local[KS], gg_local[KS], g12_local[KS], x1_local[KS], x2_local[KS], t_local[KS];
    Eigen::Matrix<double, KS, 3, Eigen::RowMajor> ad_local;
    double * const hk = KC > 0 ? h_local : h_.data();
    double * const gg = KC > 0 ? gg_local : gg_.data();
    double * const g12 = KC > 0 ? g12_local : g12_.data();
    double * const x1 = KC > 0 ? x1_local : x1_.data();
    double * const x2 = KC > 0 ? x2_local : x2_.data();
    double * const tk = KC > 0 ? t_local : t_.data();
    Eigen::Map<Rows3> ad(KC > 0 ? ad_local.data() : ad_.data(), KC > 0 ? KC : K_, 3);
    LinkBuffers & L = links_[static_cast<size_t>(link)];
    const LinkGeometry & G = geometry(link);
    const Eigen::VectorXd & r = weighted_residual_;
    const int K = KC > 0 ? KC : K_;
    const double floor = L.floor;
    int best = L.best;
    double best_error = L.best_error;
    for (Eigen::Index i = begin; i < end; ++i)
    {
      const Eigen::Vector3d p = row3(G.points_local.row(i));
      // A = P + M + M^T + [p]x S [p]x^T (M = Q [p]x), b = ur + vr x p
      Eigen::Matrix3d M, N;
      for (int a = 0; a < 3; ++a)
      {
        M.row(a) = Q_.row(a).cross(p.transpose());    // (Q [p]x)_a = Q_a x p
        N.row(a) = p.cross(S_.col(a)).transpose();    // N = S [p]x^T (row a: p x S_a, S symmetric)
      }
      Eigen::Matrix3d A;
      for (int a = 0; a < 3; ++a)
      {
        const Eigen::Vector3d na = p.cross(N.col(a)); // column (= row) a of [p]x S [p]x^T = [p]x N
        for (int bb = a; bb < 3; ++bb)
          A(a, bb) = A(bb, a) = P_(a, bb) + M(a, bb) + M(bb, a) + na[bb];
      }
      const Eigen::Vector3d b = ur_ + vr_.cross(p);
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
      const double tr3 = (A(0, 0) + A(1, 1) + A(2, 2)) / 3.0;
      const double tr3_cubed = tr3 * tr3 * tr3;
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
      const auto D = G.generators.middleRows(i * K, K);
      for (int k = 0; k < K; ++k)
      {
        const Eigen::Vector3d dk = row3(D.row(k));
        const Eigen::Vector3d Adk = A * dk;
        ad.row(k) = Adk.transpose();
        hk[k] = dk.dot(b);
        gg[k] = dk.dot(Adk);
      }
      for (int k = 0; k < K; ++k) // G[k, k+1] = d_k . A d_k+1
        g12[k] = D.row(k).dot(ad.row(k + 1 < K ? k + 1 : 0));
      // edges: f = t d_k, t = max(h_k, 0) / gg_k >= 0 (divided only where h_k > 0: else t = 0 as well)
      for (int k = 0; k < K; ++k)
        tk[k] = gg[k] > floor && hk[k] > 0.0 ? hk[k] / gg[k] : 0.0;
      // the best feasible candidate: first maximum over [interior, facets, edges, apex], as np.argmax
      int choice = 0;
      double top = -kInf;
      if (well)
      {
        bool inside = true;
        const auto C = G.facet_normals.middleRows(i * K, K);
        for (int k = 0; k < K; ++k)
          inside = inside && (C.row(k).dot(f_int.transpose()) >= 0.0);
        if (inside)
          top = f_int.dot(b);
      }
      for (int k = 0; k < K; ++k)
      {
        const int l = k + 1 < K ? k + 1 : 0; // (k + 1) mod K without an integer division
        const double det = gg[k] * gg[l] - g12[k] * g12[k];
        const double n1 = gg[l] * hk[k] - g12[k] * hk[l], n2 = gg[k] * hk[l] - g12[k] * hk[k];
        // feasible: solvable (det > 0) and x = n / det >= 0, i.e. n >= 0: divided only then (~2 of the K facets)
        if (!(gg[k] > floor && gg[l] > floor && det > kFacetCondition * gg[k] * gg[l] && n1 >= 0.0 && n2 >= 0.0))
          continue;
        x1[k] = n1 / det;
        x2[k] = n2 / det;
        const double red = x1[k] * hk[k] + x2[k] * hk[l];
        if (red > top)
        {
          top = red;
          choice = 1 + k;
        }
      }
      for (int k = 0; k < K; ++k)
      {
        const double red = tk[k] * hk[k];
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
        f = x1[k] * row3(D.row(k)) + x2[k] * row3(D.row(k + 1 < K ? k + 1 : 0));
      }
      else if (choice <= 2 * K)
      {
        const int k = choice - 1 - K;
        f = tk[k] * row3(D.row(k));
      }
      L.forces.row(i) = f.transpose();
      // error |W (J_p^T f - r)|: row c of W J_p^T . f = u_c . f + (v_c x p) . f = u_c . f + v_c . (p x f)
      const Eigen::Vector3d g = p.cross(f);
      double e2 = 0.0;
      for (int c = 0; c < n_; ++c)
      {
        const double e = uv_.row(c).head<3>().dot(f.transpose()) + uv_.row(c).tail<3>().dot(g.transpose()) - r[c];
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

  // ---------------------------------------------------------------- the choice's rank and a link without geometry

  int ContactIsolator::linkRank(int link) noexcept
  {
    const Jac & J = links_[static_cast<size_t>(link)].jacobian;
    Eigen::Matrix<double, 6, 6> G;
    for (int i = 0; i < 6; ++i)
      for (int j = i; j < 6; ++j)
      {
        double s = 0.0;
        for (int c = 0; c <= link; ++c)
          s += J(i, c) * J(j, c);
        G(i, j) = G(j, i) = s;
      }
    // the rank: eigenvalues of G (squared singular values of J[:, :link+1]) above kRankTolerance^2 x the largest, by
    // Sturm counts on G's tridiagonal form; only when an eigenvalue lies within a factor 6 of the threshold, the
    // eigenvalues themselves (psdRankExact)
    return psdRankExact<6>(G, kRankTolerance * kRankTolerance);
  }

  double ContactIsolator::wrenchError(int link) noexcept
  {
    // |r - J^T w*| for the best wrench at the link origin: r minus its projection on the range of (J W)^T
    const Jac & J = links_[static_cast<size_t>(link)].jacobian;
    for (int c = 0; c < n_; ++c)
      for (int i = 0; i < 6; ++i)
        wrench_b_(c, i) = J(i, c) * weights_[c];
    wrench_svd_.compute(wrench_b_);
    const auto & s = wrench_svd_.singularValues();
    const auto & U = wrench_svd_.matrixU();
    const double cutoff = std::numeric_limits<double>::epsilon() * std::max(n_, 6) * (s.size() ? s[0] : 0.0);
    wrench_r_ = weighted_residual_;
    for (Eigen::Index k = 0; k < s.size(); ++k)
      if (s[k] > cutoff)
        wrench_r_ -= U.col(k) * U.col(k).dot(weighted_residual_);
    return wrench_r_.norm();
  }

} // namespace reflexarm
