// reflexarm::ContactIsolator: the C++ port of reflexarm.control.collision.isolate / identify (see isolation.hpp).
// Each step follows the Python (vectorised) code, with its decisions (argmin, argmax, the tolerance tests) in the same
// order, so that the two agree to round-off (the fit itself in each link's joint frame: isolation_fit.cpp).
#include "reflexarm/isolation.hpp"

#include "isolation_detail.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <utility>

#include "pinocchio/algorithm/jacobian.hpp"

namespace reflexarm
{
  using namespace isolation_detail;

  namespace
  {
    /// estimateLink: the relative band of joint-frame distances within which the world distance is formed
    constexpr double kSpreadTies = 1e-9;
  } // namespace

  void ContactIsolator::configure(
    const pinocchio::Model & model, const std::vector<LinkSurfaceData> & surfaces, const IsolationParams & params)
  {
    const int n = static_cast<int>(model.nv);
    if (model.nq != model.nv || model.njoints != model.nv + 1)
      throw ConfigError(
        "ContactIsolator needs a fixed-base arm with one degree of freedom per joint (nq == nv == njoints - 1); got nq "
        + std::to_string(model.nq) + ", nv " + std::to_string(model.nv) + ", njoints "
        + std::to_string(model.njoints));
    if (static_cast<int>(surfaces.size()) != n)
      throw ConfigError(
        "surfaces: one per joint expected (" + std::to_string(n) + "); got " + std::to_string(surfaces.size()));
    const Eigen::Index ns = params.significance.size();
    if (ns != 1 && ns != n)
      throw ConfigError(
        "significance: size 1 or " + std::to_string(n) + " expected; got " + std::to_string(ns));
    if (!params.significance.allFinite() || (params.significance.array() <= 0.0).any())
      throw ConfigError("significance must be finite and > 0 [Nm]");
    const auto nonNegative = [](const char * name, double v) {
      if (!std::isfinite(v) || v < 0.0)
        throw ConfigError(std::string(name) + " must be a finite number >= 0; got " + std::to_string(v));
    };
    nonNegative("fit_tolerance", params.fit_tolerance);
    nonNegative("relative_tolerance", params.relative_tolerance);
    nonNegative("friction_coefficient", params.friction_coefficient);
    if (params.cone_edges < 3)
      throw ConfigError("cone_edges must be an integer >= 3; got " + std::to_string(params.cone_edges));

    model_ = model;
    constructData(data_, model_); // in place, its LLTs defined (defined_data.hpp)
    n_ = 0; // until the surfaces are in: an isolator whose configure() threw isolates nothing (begin() refuses)
    K_ = params.cone_edges;
    params_ = params;
    significance_ = ns == 1 ? Eigen::VectorXd::Constant(n, params.significance[0]) : params.significance;
    weights_ = significance_.minCoeff() / significance_.array();
    residual_.resize(n);
    wrench_r_.resize(n);
    weighted_residual_.resize(n);
    h_.resize(K_);
    gg_.resize(K_);
    g12_.resize(K_);
    x1_.resize(K_);
    x2_.resize(K_);
    t_.resize(K_);
    ad_.resize(K_, 3);
    uv_.setZero(n, 6);
    wrench_b_.resize(n, 6);
    wrench_svd_ = Eigen::JacobiSVD<Eigen::MatrixXd>(n, 6, Eigen::ComputeThinU);

    const double mu = params.friction_coefficient;
    links_.assign(static_cast<size_t>(n), LinkBuffers());
    auto geometry = std::make_shared<std::vector<LinkGeometry>>(static_cast<size_t>(n));
    for (int link = 0; link < n; ++link)
    {
      const LinkSurfaceData & s = surfaces[static_cast<size_t>(link)];
      const Eigen::Index m = s.points.rows();
      if (s.normals.rows() != m)
        throw ConfigError(
          "surface of joint " + std::to_string(link) + ": " + std::to_string(m) + " points but "
          + std::to_string(s.normals.rows()) + " normals");
      if (!allFinite(s.points) || !allFinite(s.normals))
        throw ConfigError("surface of joint " + std::to_string(link) + ": non-finite point or normal");
      if (m > 0 && (s.normals.rowwise().norm().array() - 1.0).abs().maxCoeff() > 1e-6)
        throw ConfigError("surface of joint " + std::to_string(link) + ": normals must be unit vectors");
      LinkBuffers & L = links_[static_cast<size_t>(link)];
      LinkGeometry & G = (*geometry)[static_cast<size_t>(link)];
      G.points_local = s.points;
      G.generators.resize(m * K_, 3);
      G.facet_normals.resize(m * K_, 3);
      L.forces.resize(m, 3);
      L.errors.resize(m);
      L.jacobian = Jac::Zero(6, n);
      for (Eigen::Index i = 0; i < m; ++i)
      {
        const Eigen::Vector3d nout = s.normals.row(i).transpose();
        // _tangent_basis: a fixed rule
        const Eigen::Vector3d helper =
          std::abs(nout[0]) < 0.9 ? Eigen::Vector3d(1.0, 0.0, 0.0) : Eigen::Vector3d(0.0, 1.0, 0.0);
        Eigen::Vector3d t1 = nout.cross(helper);
        t1 /= t1.norm();
        const Eigen::Vector3d t2 = nout.cross(t1);
        for (int k = 0; k < K_; ++k)
        {
          const double a = 2.0 * M_PI * k / K_;
          const double ca = std::cos(a), sa = std::sin(a);
          Eigen::Vector3d d;
          for (int j = 0; j < 3; ++j)
            d[j] = -nout[j] + mu * (ca * t1[j] + sa * t2[j]);
          d /= d.norm();
          G.generators.row(i * K_ + k) = d.transpose();
        }
        for (int k = 0; k < K_; ++k)
        {
          const Eigen::Vector3d dk = G.generators.row(i * K_ + k).transpose();
          const Eigen::Vector3d dl = G.generators.row(i * K_ + (k + 1) % K_).transpose();
          Eigen::Vector3d c = dk.cross(dl); // normal of the facet spanned by edges k, k+1
          c *= sign(c.dot(-nout));          // oriented into the pyramid
          G.facet_normals.row(i * K_ + k) = c.transpose();
        }
      }
    }
    geometry_ = std::move(geometry);
    n_ = n;
  }

  void ContactIsolator::estimateLink(int link, double tolerance, ContactEstimateData & out) noexcept
  {
    LinkBuffers & L = links_[static_cast<size_t>(link)];
    out.link = link;
    out.has_point = out.has_force = false; // out.link_rank: chooseLink()'s
    if (L.best < 0)
    {
      out.point.setZero();
      out.force.setZero();
      out.fit_error = L.best_error;
      out.determined = Determined::LinkOnly;
      out.cause = IsolationCause::NoGeometry;
      out.consistent_points = 0;
      out.point_spread = kNaN;
      out.force_rank = 0;
      return;
    }
    const int best = L.best;
    // the fit is in the link's joint frame (isolation_fit.cpp): the best point and force rotated into the world
    const Rows3 & points = geometry(link).points_local;
    const Eigen::Vector3d pl = points.row(best).transpose(), fl = L.forces.row(best).transpose();
    const Eigen::Vector3d d = L.rotation * pl; // p - o
    const Eigen::Vector3d pb = d + L.origin;
    const Eigen::Vector3d fb = L.rotation * fl;
    const Jac & J = L.jacobian;
    double e2 = 0.0;
    Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
    for (int c = 0; c < n_; ++c)
    {
      const Eigen::Vector3d jv = J.col(c).head<3>(), jw = J.col(c).tail<3>();
      const Eigen::Vector3d jp = jv + jw.cross(d);
      const double e = jp.dot(fb) - residual_[c];
      e2 += e * e;
      A += jp * jp.transpose();
    }
    out.point = pb;
    out.force = fb;
    out.fit_error = std::sqrt(e2);
    // the consistent set, in the joint frame (magnitudes, angles and distances do not depend on it); the largest
    // distance from the best point formed from the world points as identify.py forms them (R p + o), so that a
    // distance on the candidate grid (e.g. exactly 5.25 cm) rounds as in Python where the reason prints it: for the
    // points within a relative kSpreadTies of the largest joint-frame distance so far only: they include every point
    // where the world distance can be largest (the two frames' squared distances differ by round-off, ~1e-16 |p|^2)
    const double limit = L.errors[best] + tolerance;
    int count = 0;
    double far2 = 0.0, spread2 = 0.0, max_rel = 0.0, min_cos = kInf;
    const double ref = fl.norm();
    for (Eigen::Index i = 0; i < L.errors.size(); ++i)
    {
      if (!(L.errors[i] <= limit))
        continue;
      ++count;
      const double d2 = (points.row(i).transpose() - pl).squaredNorm();
      if (d2 >= far2 * (1.0 - kSpreadTies))
      {
        far2 = std::max(far2, d2);
        const Eigen::Vector3d pi = L.rotation * points.row(i).transpose() + L.origin;
        spread2 = std::max(spread2, (pi - pb).squaredNorm());
      }
      const Eigen::Vector3d fi = L.forces.row(i).transpose();
      const double mag = fi.norm();
      min_cos = std::min(min_cos, fi.dot(fl) / std::max(mag * ref, kTiny));
      max_rel = std::max(max_rel, std::abs(mag - ref));
    }
    out.consistent_points = count;
    out.point_spread = std::sqrt(spread2); // the largest distance (sqrt is monotonic)
    out.force_variation = max_rel / std::max(ref, kTiny);
    out.direction_variation_deg = std::acos(std::clamp(min_cos, -1.0, 1.0)) * (180.0 / M_PI);
    // rank of J_p J_p^T at the best point (eigenvalues: squared singular values), by Sturm counts; only when an
    // eigenvalue lies within a factor 3 of the threshold, the eigenvalues themselves (psdRankExact)
    const int force_rank = psdRankExact<3>(A, kRankTolerance * kRankTolerance);
    out.force_rank = force_rank;
    if (force_rank < 3)
    {
      out.determined = Determined::LinkOnly;
      out.cause = IsolationCause::ForceRankDeficient;
      return;
    }
    if (out.link_rank >= 5)
    {
      out.determined = Determined::PointAndForce;
      out.cause = IsolationCause::Determined;
      out.has_point = out.has_force = true;
      return;
    }
    if (out.force_variation <= kForceAgreement && out.direction_variation_deg <= kDirectionAgreementDeg)
    {
      out.determined = Determined::ForceOnly;
      out.cause = IsolationCause::Determined;
      out.has_force = true;
      return;
    }
    out.determined = Determined::LinkOnly;
    out.cause = IsolationCause::ForcesDisagree;
  }

  bool ContactIsolator::isolate(
    const Eigen::Ref<const Eigen::VectorXd> & q,
    const Eigen::Ref<const Eigen::VectorXd> & residual,
    ContactEstimateData & out) noexcept
  {
    begin(q, residual);
    step(std::numeric_limits<int>::max());
    return finish(out);
  }

  void ContactIsolator::cancel() noexcept
  {
    active_ = valid_ = false;
    first_ = -1;
    ratio_ = 0.0;
    work_total_ = work_done_ = 0;
    pruned_ = 0;
    cur_link_ = 0;
    cur_pass_ = 1;
    cur_point_ = 0;
    stage_ = 0;
  }

  bool ContactIsolator::begin(
    const Eigen::Ref<const Eigen::VectorXd> & q, const Eigen::Ref<const Eigen::VectorXd> & residual) noexcept
  {
    return beginWith(q, residual, nullptr);
  }

  bool ContactIsolator::begin(
    const Eigen::Ref<const Eigen::VectorXd> & q,
    const Eigen::Ref<const Eigen::VectorXd> & residual,
    const pinocchio::Data & kin) noexcept
  {
    return beginWith(q, residual, &kin);
  }

  bool ContactIsolator::beginWith(
    const Eigen::Ref<const Eigen::VectorXd> & q,
    const Eigen::Ref<const Eigen::VectorXd> & residual,
    const pinocchio::Data * kin) noexcept
  {
    cancel();
    active_ = true;
    if (n_ == 0 || q.size() != n_ || residual.size() != n_ || !q.allFinite() || !residual.allFinite())
      return false;
    if (kin && (kin->J.cols() != n_ || static_cast<int>(kin->oMi.size()) != n_ + 1))
      return false;
    valid_ = true;
    residual_ = residual;
    int last = -1;
    double ratio = 0.0;
    for (int j = 0; j < n_; ++j)
    {
      const double a = std::abs(residual[j]);
      if (a > significance_[j])
        last = j;
      ratio = std::max(ratio, a / significance_[j]);
    }
    ratio_ = ratio;
    first_ = last;
    if (last < 0)
      return true;
    weighted_residual_ = weights_.cwiseProduct(residual);
    wr2_ = weighted_residual_.squaredNorm();
    tolerance_ = params_.fit_tolerance + params_.relative_tolerance * weighted_residual_.norm();

    if (!kin)
      pinocchio::computeJointJacobians(model_, data_, q);
    const pinocchio::Data & data = kin ? *kin : data_;
    for (int link = last; link < n_; ++link)
    {
      LinkBuffers & L = links_[static_cast<size_t>(link)];
      const auto jid = static_cast<pinocchio::JointIndex>(link + 1);
      L.rotation = data.oMi[jid].rotation();
      L.origin = data.oMi[jid].translation();
      L.jacobian.setZero();
      pinocchio::getJointJacobian(model_, data, jid, pinocchio::LOCAL_WORLD_ALIGNED, L.jacobian);
      L.max_trace = -kInf;
      L.floor = 0.0;
      L.best = 0;
      L.best_error = kInf;
      const Eigen::Index m = geometry(link).points_local.rows();
      work_total_ += m > 0 ? static_cast<int>((m + kTracePoints - 1) / kTracePoints + m) : 1;
    }
    cur_link_ = last;
    return true;
  }

  bool ContactIsolator::step(int point_budget) noexcept
  {
    long budget = std::max(point_budget, 1);
    while (work_done_ < work_total_ && budget > 0)
    {
      const int link = cur_link_;
      LinkBuffers & L = links_[static_cast<size_t>(link)];
      const Eigen::Index m = geometry(link).points_local.rows();
      if (m == 0) // no geometry: the best wrench at the link origin (one unit)
      {
        L.best = -1;
        L.best_error = wrenchError(link);
        ++work_done_;
        --budget;
        ++cur_link_;
        if (settled())
        {
          work_total_ = work_done_; // the later links need no fit: the work ends here
          break;
        }
        continue;
      }
      if (cur_pass_ == 1) // kTracePoints points a unit, the link's last unit the rest
      {
        const long units = std::min<long>((m - cur_point_ + kTracePoints - 1) / kTracePoints, budget);
        const Eigen::Index end = std::min<Eigen::Index>(m, cur_point_ + units * kTracePoints);
        traceRange(link, cur_point_, end);
        work_done_ += static_cast<int>(units);
        budget -= units;
        cur_point_ = end;
      }
      else // one unit a point
      {
        const Eigen::Index end = std::min<Eigen::Index>(m, cur_point_ + budget);
        fitRange(link, cur_point_, end);
        work_done_ += static_cast<int>(end - cur_point_);
        budget -= end - cur_point_;
        cur_point_ = end;
      }
      if (cur_point_ < m)
        continue;
      cur_point_ = 0;
      if (cur_pass_ == 1) // the edges' floor from the largest trace of the link's points
      {
        L.floor = kEdgeFloor * std::max(L.max_trace, kTiny);
        cur_pass_ = 2;
      }
      else
      {
        L.best_error = L.errors[L.best];
        cur_pass_ = 1;
        ++cur_link_;
        if (settled())
        {
          work_total_ = work_done_;
          break;
        }
      }
    }
    return work_done_ >= work_total_;
  }

  // After a candidate link's fit: the links examined so far, first_ .. cur_link_ - 1, with m the best of their fits.
  // The choice is the first candidate within the tolerance of the best of ALL candidates, best <= m. The first examined
  // link j within m + tol of m is the only one that can still be chosen among them (an earlier one is above
  // m + tol >= best + tol), and if its fit is within tol itself it is chosen whatever the links after it hold (then
  // b_j <= tol <= best + tol, as best >= 0), and the estimate is not NoSingleContact (best <= b_j <= tol). So the
  // links after it need no fit: step() ends the work there (work_total_ becomes the work done) with the estimate the
  // exhaustive fit gives; only best_fit is then the best over the links examined.
  bool ContactIsolator::settled() const noexcept
  {
    double m = kInf;
    for (int link = first_; link < cur_link_; ++link)
      m = std::min(m, links_[static_cast<size_t>(link)].best_error);
    for (int link = first_; link < cur_link_; ++link)
    {
      const double b = links_[static_cast<size_t>(link)].best_error;
      if (b <= m + tolerance_)
        return b <= tolerance_;
    }
    return false;
  }

  // finish()'s stage 1: the most proximal candidate link within the tolerance of the best fit, and the rank of its
  // Jacobian (the estimate's fields other than those of estimateLink)
  void ContactIsolator::chooseLink() noexcept
  {
    ContactEstimateData & out = estimate_;
    out = ContactEstimateData();
    out.fit_error = kNaN;
    out.point_spread = kNaN;
    out.max_significance_ratio = ratio_;
    const int last = first_;
    out.first_candidate = last;
    out.candidate_count = n_ - last;
    out.links_examined = cur_link_ - last;
    const double tol = tolerance_;
    double best = kInf;
    for (int link = last; link < n_; ++link)
      best = std::min(best, links_[static_cast<size_t>(link)].best_error);
    int chosen = last;
    for (int link = last; link < n_; ++link)
      if (links_[static_cast<size_t>(link)].best_error <= best + tol)
      {
        chosen = link;
        break;
      }
    out.best_fit = best;
    out.tolerance = tol;
    out.link = chosen;
    out.link_rank = linkRank(chosen);
  }

  bool ContactIsolator::finishStep() noexcept
  {
    if (finishStepsLeft() == 0)
      return true;
    if (work_done_ < work_total_)
      return false; // the fit first
    if (stage_ == 0)
      chooseLink();
    else // stage 2: the chosen link's estimate
    {
      ContactEstimateData & out = estimate_;
      estimateLink(out.link, tolerance_, out);
      if (!(out.best_fit <= tolerance_))
      {
        out.determined = Determined::LinkOnly;
        out.cause = IsolationCause::NoSingleContact;
        out.has_point = out.has_force = false;
      }
    }
    ++stage_;
    return stage_ == kFinishSteps;
  }

  bool ContactIsolator::finish(ContactEstimateData & out) noexcept
  {
    out = ContactEstimateData();
    out.fit_error = kNaN;
    out.point_spread = kNaN;
    if (!valid_)
    {
      cancel();
      return false;
    }
    step(std::numeric_limits<int>::max()); // the work left, if any
    while (!finishStep()) // ... and the stages left
    {
    }
    active_ = false;
    if (first_ < 0)
    {
      out.max_significance_ratio = ratio_;
      out.determined = Determined::None;
      out.cause = IsolationCause::NoSignificantJoint;
      return true;
    }
    out = estimate_;
    return true;
  }

} // namespace reflexarm
