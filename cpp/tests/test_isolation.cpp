// C++ tests of reflexarm::ContactIsolator: no heap allocation inside isolate() nor begin/step/finish, the stepped
// isolation bitwise equal to isolate() for any budget, a contact at a candidate point of
// a distal link recovered exactly (link, point, force), bad input refused (isolate returns false, configure throws
// ConfigError). The agreement with the Python ContactIsolator is tests/test_isolation_core.py.
// Exit code 0 when every check passes; prints "N passed, M failed".
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>

#include "pinocchio/algorithm/jacobian.hpp"
#include "pinocchio/algorithm/rnea.hpp"
#include "pinocchio/multibody/sample-models.hpp"

#include <Eigen/QR>

#include "reflexarm/isolation.hpp"

#include "../src/isolation_detail.hpp" // the rank helpers (private to the isolator)

#include "alloc_counter.hpp"

#include "checks.hpp"

namespace
{
  using reflexarm::LinkSurfaceData;

  /// A sphere of radius 5 cm, 0.1 m along z of every joint frame (Fibonacci points, outward normals).
  std::vector<LinkSurfaceData> spheres(int n, int m)
  {
    std::vector<LinkSurfaceData> out(static_cast<size_t>(n));
    const Eigen::Vector3d centre(0.0, 0.0, 0.1);
    for (auto & s : out)
    {
      s.points.resize(m, 3);
      s.normals.resize(m, 3);
      for (int i = 0; i < m; ++i)
      {
        const double z = 1.0 - 2.0 * (i + 0.5) / m, r = std::sqrt(1.0 - z * z), phi = 2.399963229728653 * i;
        const Eigen::Vector3d u(r * std::cos(phi), r * std::sin(phi), z);
        s.normals.row(i) = u.transpose();
        s.points.row(i) = (centre + 0.05 * u).transpose();
      }
    }
    return out;
  }

  /// Points of the candidate links (the most distal joint with |r_j| > significance and every later one): the
  /// constrained fits of pass 2, pruned or not.
  long candidatePoints(const std::vector<LinkSurfaceData> & surfaces, const Eigen::VectorXd & r, double significance)
  {
    long points = 0;
    int last = -1;
    for (Eigen::Index j = 0; j < r.size(); ++j)
      if (std::abs(r[j]) > significance)
        last = static_cast<int>(j);
    for (int j = std::max(last, 0); last >= 0 && j < static_cast<int>(surfaces.size()); ++j)
      points += surfaces[static_cast<size_t>(j)].points.rows();
    return points;
  }

  reflexarm::IsolationParams params()
  {
    reflexarm::IsolationParams p;
    p.significance = Eigen::VectorXd::Constant(1, 1e-6);
    return p;
  }

  void testExactContactAndNoAllocation()
  {
    pinocchio::Model model;
    pinocchio::buildModels::manipulator(model);
    const int n = static_cast<int>(model.nv);
    const auto surfaces = spheres(n, 300);
    reflexarm::ContactIsolator iso;
    iso.configure(model, surfaces, params());
    pinocchio::Data data(model);
    reflexarm::ContactEstimateData out;
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> u(-1.5, 1.5);
    std::uniform_int_distribution<int> pick(0, 299);
    Eigen::VectorXd q(n), r(n), bad(n + 1);
    bad.setZero();
    Eigen::Matrix<double, 6, Eigen::Dynamic> J(6, n);
    long allocations = 0, exact = 0, trials = 0, pruned = 0, points = 0;
    for (int k = 0; k < 40; ++k)
    {
      for (int j = 0; j < n; ++j)
        q[j] = u(rng);
      const int link = n - 1 - (k % 2); // the two distal links: rank >= 5
      const int i = pick(rng);
      pinocchio::computeJointJacobians(model, data, q);
      J.setZero();
      pinocchio::getJointJacobian(model, data, link + 1, pinocchio::LOCAL_WORLD_ALIGNED, J);
      const auto & M = data.oMi[static_cast<size_t>(link + 1)];
      const Eigen::Vector3d p = M.act(Eigen::Vector3d(surfaces[link].points.row(i).transpose()));
      const Eigen::Vector3d nrm = M.rotation() * surfaces[link].normals.row(i).transpose();
      const Eigen::Vector3d f = -40.0 * nrm + 5.0 * nrm.unitOrthogonal(); // inside the cone (mu 0.5)
      for (int c = 0; c < n; ++c)
        r[c] = (J.col(c).head<3>() + J.col(c).tail<3>().cross(p - M.translation())).dot(f);
      g_counting = true;
      const bool ok = iso.isolate(q, r, out);
      const bool refused = !iso.isolate(bad, r, out);
      g_counting = false;
      allocations += g_allocations.exchange(0);
      CHECK(ok && refused, "contact %d: isolate %d, refused wrong size %d", k, ok, refused);
      iso.isolate(q, r, out);
      pruned += iso.prunedPoints();
      points += candidatePoints(surfaces, r, 1e-6);
      ++trials;
      const bool same = out.link == link && out.determined == reflexarm::Determined::PointAndForce
                        && (out.point - p).norm() < 1e-9 && (out.force - f).norm() < 1e-6 && out.fit_error < 1e-9;
      exact += same;
      if (!same)
        std::printf("contact %d on link %d: got link %d, determined %d, |dp| %.3g, |df| %.3g, fit %.3g\n", k, link,
                    out.link, static_cast<int>(out.determined), (out.point - p).norm(), (out.force - f).norm(),
                    out.fit_error);
    }
    CHECK(allocations == 0, "%ld heap allocations inside isolate()", allocations);
    CHECK(exact >= trials - 2, "%ld of %ld exact contacts recovered (link, point, force)", exact, trials);
    // the exact pruning (isolation_fit.cpp) skipped constrained fits and the recovery above stayed exact; that
    // it changes no result is tests/test_isolation_core.py (the Python isolator fits every point)
    CHECK(pruned > 0 && pruned < points, "%ld of %ld candidate points pruned", pruned, points);
  }

  bool sameBits(double a, double b)
  {
    return std::memcmp(&a, &b, sizeof a) == 0;
  }

  bool sameBits(const Eigen::Vector3d & a, const Eigen::Vector3d & b)
  {
    return sameBits(a[0], b[0]) && sameBits(a[1], b[1]) && sameBits(a[2], b[2]);
  }

  /// Every field of two estimates equal bit for bit (NaN of the same bits included).
  bool sameEstimate(const reflexarm::ContactEstimateData & a, const reflexarm::ContactEstimateData & b)
  {
    return a.link == b.link && a.has_point == b.has_point && a.has_force == b.has_force && sameBits(a.point, b.point)
           && sameBits(a.force, b.force) && sameBits(a.fit_error, b.fit_error) && a.determined == b.determined
           && a.cause == b.cause && a.first_candidate == b.first_candidate && a.candidate_count == b.candidate_count
           && a.consistent_points == b.consistent_points && sameBits(a.point_spread, b.point_spread)
           && sameBits(a.best_fit, b.best_fit) && sameBits(a.tolerance, b.tolerance) && a.link_rank == b.link_rank
           && a.force_rank == b.force_rank && sameBits(a.force_variation, b.force_variation)
           && sameBits(a.direction_variation_deg, b.direction_variation_deg)
           && sameBits(a.max_significance_ratio, b.max_significance_ratio);
  }

  /// begin / step(budget)... / finish: bit for bit isolate()'s result, in ceil(work / budget) steps of at most
  /// budget units each, without a heap allocation; links without geometry (one unit) among the candidates; a
  /// cancel() or a new begin() in the middle leaves nothing behind.
  void testSteppedEqualsOneShot()
  {
    pinocchio::Model model;
    pinocchio::buildModels::manipulator(model);
    const int n = static_cast<int>(model.nv);
    auto surfaces = spheres(n, 97);
    surfaces[static_cast<size_t>(n - 2)].points.resize(0, 3); // a link without geometry among the candidates
    surfaces[static_cast<size_t>(n - 2)].normals.resize(0, 3);
    auto p = params();
    p.significance = Eigen::VectorXd::Constant(1, 0.5);
    reflexarm::ContactIsolator iso, stepped;
    iso.configure(model, surfaces, p);
    stepped.configure(model, surfaces, p);
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-1.5, 1.5), f(-30.0, 30.0);
    Eigen::VectorXd q(n), r(n), q2(n), r2(n);
    reflexarm::ContactEstimateData one, spread;
    long allocations = 0, equal = 0, trials = 0, steps_right = 0, bounded = 0;
    const int budgets[] = {1, 7, 16, 32, 97, 194, 1000};
    for (int k = 0; k < 60; ++k)
    {
      for (int j = 0; j < n; ++j)
      {
        q[j] = u(rng);
        r[j] = f(rng) / (1 + (k % 4) * j); // some contacts with few significant joints, some with many
        q2[j] = u(rng);
        r2[j] = f(rng);
      }
      iso.isolate(q, r, one);
      for (const int budget : budgets)
      {
        g_counting = true;
        if (k % 5 == 0) // an isolation dropped half-way first: nothing of it stays
        {
          stepped.begin(q2, r2);
          stepped.step(budget);
          stepped.cancel();
        }
        else if (k % 5 == 1) // ... or replaced by a new begin()
        {
          stepped.begin(q2, r2);
          stepped.step(budget);
        }
        stepped.begin(q, r);
        int steps = 0;
        bool within = true;
        const auto done_so_far = [&stepped] { return stepped.workTotal() - stepped.workLeft(); };
        for (bool done = stepped.workTotal() == 0; !done;)
        {
          const int before = done_so_far();
          done = stepped.step(budget);
          within = within && done_so_far() - before <= budget && done_so_far() - before > 0;
          ++steps;
        }
        const int total = stepped.workTotal(); // the work done (less than planned after an early stop)
        const bool ok = stepped.finish(spread);
        g_counting = false;
        allocations += g_allocations.exchange(0);
        ++trials;
        equal += ok && sameEstimate(one, spread);
        steps_right += steps == (total + budget - 1) / budget;
        bounded += within && !stepped.active();
      }
    }
    CHECK(allocations == 0, "%ld heap allocations inside begin / step / finish / cancel", allocations);
    CHECK(equal == trials, "%ld of %ld stepped isolations bitwise equal to isolate()", equal, trials);
    CHECK(steps_right == trials, "%ld of %ld took ceil(work / budget) steps", steps_right, trials);
    CHECK(bounded == trials, "%ld of %ld did at most the budget per step", bounded, trials);
    // no step at all: finish() does the work; an invalid begin: finish() refuses like isolate()
    stepped.begin(q, r);
    CHECK(stepped.finish(spread) && sameEstimate(one, spread), "finish without steps equals isolate()");
    Eigen::VectorXd bad = r;
    bad[1] = std::nan("");
    CHECK(!stepped.begin(q, bad) && !stepped.finish(spread) && spread.determined == reflexarm::Determined::None,
          "a NaN residual refused by begin and finish");
    CHECK(!stepped.finish(spread), "finish without begin refuses");
  }

  /// A copy of a configured isolator shares its geometry (immutable after configure): it isolates as the original
  /// does, and configuring the original anew (other surfaces) leaves the copy's results as they were.
  void testCopiesShareTheGeometry()
  {
    pinocchio::Model model;
    pinocchio::buildModels::manipulator(model);
    const int n = static_cast<int>(model.nv);
    auto p = params();
    p.significance = Eigen::VectorXd::Constant(1, 0.5);
    reflexarm::ContactIsolator original;
    original.configure(model, spheres(n, 61), p);
    const reflexarm::ContactIsolator copy = original;
    reflexarm::ContactIsolator reference;
    reference.configure(model, spheres(n, 61), p);
    std::mt19937 rng(9);
    std::uniform_real_distribution<double> u(-1.5, 1.5), f(-30.0, 30.0);
    Eigen::VectorXd q(n), r(n);
    reflexarm::ContactEstimateData a, b, c;
    long same = 0, differs = 0;
    for (int k = 0; k < 20; ++k)
    {
      for (int j = 0; j < n; ++j)
      {
        q[j] = u(rng);
        r[j] = f(rng);
      }
      reflexarm::ContactIsolator before = copy; // the copy, while the original still has the same surfaces
      before.isolate(q, r, a);
      original.configure(model, spheres(n, 23 + k), p); // other surfaces for the original
      reflexarm::ContactIsolator after = copy;
      after.isolate(q, r, b);
      reference.isolate(q, r, c);
      same += sameEstimate(a, b) && sameEstimate(a, c);
      reflexarm::ContactEstimateData d;
      original.isolate(q, r, d);
      differs += !sameEstimate(a, d);
    }
    CHECK(same == 20, "%ld of 20 isolations of a copy unchanged by configuring its original anew", same);
    CHECK(differs > 0, "the original's new surfaces changed none of its estimates: the test would see nothing");
  }

  /// begin(q, r, kin) from the caller's kinematics at q (computeJointJacobians' or computeCoriolisMatrix's Data, as
  /// the controller's tick passes its Coriolis Data): isolate()'s estimate bit for bit, in steps, without a heap
  /// allocation; a Data of another model refused. The work: ceil(m / kTracePoints) + m per candidate link.
  void testCallerKinematics()
  {
    pinocchio::Model model;
    pinocchio::buildModels::manipulator(model);
    const int n = static_cast<int>(model.nv);
    const auto surfaces = spheres(n, 97);
    auto p = params();
    p.significance = Eigen::VectorXd::Constant(1, 0.5);
    reflexarm::ContactIsolator iso, stepped;
    iso.configure(model, surfaces, p);
    stepped.configure(model, surfaces, p);
    pinocchio::Data jac(model), cor(model);
    std::mt19937 rng(13);
    std::uniform_real_distribution<double> u(-1.5, 1.5), f(-30.0, 30.0);
    Eigen::VectorXd q(n), dq(n), r(n);
    reflexarm::ContactEstimateData one, spread;
    long allocations = 0, equal = 0, trials = 0, work_right = 0;
    for (int k = 0; k < 40; ++k)
    {
      for (int j = 0; j < n; ++j)
      {
        q[j] = u(rng);
        dq[j] = u(rng);
        r[j] = f(rng) / (1 + (k % 3) * j);
      }
      iso.isolate(q, r, one);
      pinocchio::computeJointJacobians(model, jac, q);
      pinocchio::computeCoriolisMatrix(model, cor, q, dq);
      long work = 0;
      int last = -1;
      for (int j = 0; j < n; ++j)
        if (std::abs(r[j]) > 0.5)
          last = j;
      for (int j = std::max(last, 0); last >= 0 && j < n; ++j)
      {
        const long m = surfaces[static_cast<size_t>(j)].points.rows();
        work += (m + reflexarm::ContactIsolator::kTracePoints - 1) / reflexarm::ContactIsolator::kTracePoints + m;
      }
      for (const pinocchio::Data * kin : {&jac, &cor})
        for (const int budget : {5, 1000})
        {
          g_counting = true;
          const bool begun = stepped.begin(q, r, *kin);
          const int total = stepped.workTotal();
          for (bool done = total == 0; !done;)
            done = stepped.step(budget);
          const bool ok = stepped.finish(spread);
          g_counting = false;
          allocations += g_allocations.exchange(0);
          ++trials;
          equal += begun && ok && sameEstimate(one, spread);
          work_right += total == work;
        }
    }
    CHECK(allocations == 0, "%ld heap allocations inside begin(q, r, kin) / step / finish", allocations);
    CHECK(equal == trials, "%ld of %ld isolations from the caller's kinematics bitwise equal to isolate()", equal, trials);
    CHECK(work_right == trials, "%ld of %ld had ceil(m / kTracePoints) + m units per candidate link", work_right, trials);
    pinocchio::Model other;
    pinocchio::buildModels::humanoidRandom(other, true);
    const pinocchio::Data wrong(other);
    CHECK(!stepped.begin(q, r, wrong) && !stepped.finish(spread), "a Data of another model refused");
  }

  void testBadInput()
  {
    pinocchio::Model model;
    pinocchio::buildModels::manipulator(model);
    const int n = static_cast<int>(model.nv);
    reflexarm::ContactIsolator iso;
    reflexarm::ContactEstimateData out;
    const Eigen::VectorXd zero = Eigen::VectorXd::Zero(n);
    CHECK(!iso.isolate(zero, zero, out), "isolate before configure must refuse");
    iso.configure(model, spheres(n, 20), params());
    Eigen::VectorXd r = Eigen::VectorXd::Ones(n);
    r[2] = std::nan("");
    CHECK(!iso.isolate(zero, r, out) && out.determined == reflexarm::Determined::None, "NaN residual refused");
    CHECK(iso.isolate(zero, zero, out) && out.determined == reflexarm::Determined::None, "zero residual: none");
    auto throws = [&](const std::vector<LinkSurfaceData> & s, const reflexarm::IsolationParams & p,
                      const std::string & text) {
      try
      {
        reflexarm::ContactIsolator other;
        other.configure(model, s, p);
      }
      catch (const reflexarm::ConfigError & e)
      {
        return std::string(e.what()).find(text) != std::string::npos;
      }
      return false;
    };
    CHECK(throws(spheres(n - 1, 20), params(), "surfaces: one per joint expected"), "too few surfaces");
    auto p = params();
    p.significance = Eigen::VectorXd::Constant(n, -1.0);
    CHECK(throws(spheres(n, 20), p, "significance must be finite and > 0"), "negative significance");
    p = params();
    p.cone_edges = 2;
    CHECK(throws(spheres(n, 20), p, "cone_edges must be an integer >= 3; got 2"), "cone_edges");
    auto s = spheres(n, 20);
    s[1].normals(0, 0) = 2.0;
    CHECK(throws(s, params(), "surface of joint 1: normals must be unit vectors"), "non-unit normal");
    // an isolator whose configure() threw on its surfaces half-way (after it was configured before): it refuses to
    // isolate (no access to the surfaces it did not finish), and a copy of it too
    reflexarm::ContactIsolator half;
    half.configure(model, spheres(n, 20), params());
    bool threw = false;
    try
    {
      half.configure(model, s, params());
    }
    catch (const reflexarm::ConfigError &)
    {
      threw = true;
    }
    Eigen::VectorXd q0 = Eigen::VectorXd::Zero(n), r0 = Eigen::VectorXd::Constant(n, 5.0);
    const reflexarm::ContactIsolator half_copy = half;
    reflexarm::ContactIsolator copied = half_copy;
    CHECK(threw && !half.isolate(q0, r0, out) && !copied.isolate(q0, r0, out) && !half.begin(q0, r0),
          "an isolator whose configure threw on a surface isolates nothing");
  }

  /// psdRank<N> (the choice's link rank, the estimate's force rank): the Householder tridiagonal form keeps the
  /// eigenvalues (against Eigen's solver); the rank of B B^T with B of rank r is r; an eigenvalue within the
  /// factor-N bracket of the threshold is left undecided (-1) for the caller's eigenvalues.
  template <int N>
  void testPsdRank(std::mt19937 & rng)
  {
    using Mat = Eigen::Matrix<double, N, N>;
    std::normal_distribution<double> normal;
    const auto random = [&](int rows, int cols) {
      Eigen::MatrixXd m(rows, cols);
      for (int i = 0; i < rows; ++i)
        for (int j = 0; j < cols; ++j)
          m(i, j) = normal(rng);
      return m;
    };
    const double tol2 = 1e-12; // kRankTolerance^2
    for (int r = 0; r <= N; ++r)
      for (int trial = 0; trial < 20; ++trial)
      {
        const Eigen::MatrixXd B = random(N, r);
        const Mat G = B * B.transpose();
        const int rank = reflexarm::isolation_detail::psdRank<N>(G, tol2);
        CHECK(rank == r, "N %d: rank of B B^T with B of rank %d: %d", N, r, rank);
        Mat a = G;
        Eigen::Matrix<double, N, 1> diag;
        Eigen::Matrix<double, N - 1, 1> sub;
        reflexarm::isolation_detail::tridiagonalize<N>(a, diag, sub);
        Mat T = Mat::Zero();
        T.diagonal() = diag;
        for (int i = 0; i + 1 < N; ++i)
          T(i + 1, i) = T(i, i + 1) = sub[i];
        const Eigen::Matrix<double, N, 1> want = Eigen::SelfAdjointEigenSolver<Mat>(G).eigenvalues();
        const Eigen::Matrix<double, N, 1> got = Eigen::SelfAdjointEigenSolver<Mat>(T).eigenvalues();
        const double err = (got - want).cwiseAbs().maxCoeff() / std::max(want.cwiseAbs().maxCoeff(), 1e-300);
        CHECK(r == 0 || err < 1e-12, "N %d rank %d: tridiagonal eigenvalues off by %g relative", N, r, err);
      }
    // one eigenvalue at 1.5e-12 of the largest (1): between tol2 x trace / N and tol2 x trace (N - 1 = trace), undecided
    const Eigen::HouseholderQR<Eigen::MatrixXd> qr(random(N, N));
    const Mat Q = qr.householderQ();
    Eigen::Matrix<double, N, 1> ev = Eigen::Matrix<double, N, 1>::Ones();
    ev[0] = 1.5e-12;
    const Mat G = Q * ev.asDiagonal() * Q.transpose();
    CHECK(reflexarm::isolation_detail::psdRank<N>(G, tol2) == -1, "N %d: an eigenvalue at the threshold decided", N);
    const int exact = reflexarm::isolation_detail::psdRankExact<N>(G, tol2); // 1.5e-12 > tol2 x 1: counted
    CHECK(exact == N, "N %d: psdRankExact at the threshold: %d", N, exact);
    ev[0] = 1e-14; // well below: rank N - 1
    const Mat G2 = Q * ev.asDiagonal() * Q.transpose();
    CHECK(reflexarm::isolation_detail::psdRank<N>(G2, tol2) == N - 1, "N %d: a 1e-14 eigenvalue counted", N);
    CHECK(reflexarm::isolation_detail::psdRank<N>(Mat::Zero(), tol2) == 0, "N %d: zero matrix", N);
  }
} // namespace

int main()
{
  g_trace = std::getenv("TRACE_ALLOC") != nullptr; // the first allocation counted: its stack, then abort
  g_counting = true; // the counter counts (else "0 allocations" would mean nothing)
  delete[] new double[3];
  g_counting = false;
  CHECK(g_allocations.exchange(0) > 0, "the allocation counter counted nothing");
  testExactContactAndNoAllocation();
  testSteppedEqualsOneShot();
  testCopiesShareTheGeometry();
  testCallerKinematics();
  testBadInput();
  std::mt19937 rng(4);
  testPsdRank<3>(rng);
  testPsdRank<6>(rng);
  return checksReport();
}
