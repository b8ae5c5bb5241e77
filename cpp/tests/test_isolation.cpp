// C++ tests of reflexarm::ContactIsolator: no heap allocation inside isolate(), a contact at a candidate point of
// a distal link recovered exactly (link, point, force), bad input refused (isolate returns false, configure throws
// ConfigError). The agreement with the Python ContactIsolator is tests/test_isolation_core.py.
// Exit code 0 when every check passes; prints "N passed, M failed".
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <new>
#include <random>
#include <string>

#include "pinocchio/algorithm/jacobian.hpp"
#include "pinocchio/multibody/sample-models.hpp"

#include "reflexarm/isolation.hpp"

// ------------------------------------------------------------------ counting allocations (glibc)
static std::atomic<long> g_allocations{0};
static std::atomic<bool> g_counting{false};
extern "C" void * __libc_malloc(std::size_t);
extern "C" void * __libc_calloc(std::size_t, std::size_t);
extern "C" void * __libc_realloc(void *, std::size_t);

static void count()
{
  if (g_counting.load(std::memory_order_relaxed))
    g_allocations.fetch_add(1, std::memory_order_relaxed);
}
void * operator new(std::size_t size)
{
  count();
  if (void * p = __libc_malloc(size ? size : 1))
    return p;
  throw std::bad_alloc();
}
void * operator new[](std::size_t size)
{
  return operator new(size);
}
void operator delete(void * p) noexcept
{
  std::free(p);
}
void operator delete[](void * p) noexcept
{
  std::free(p);
}
void operator delete(void * p, std::size_t) noexcept
{
  std::free(p);
}
void operator delete[](void * p, std::size_t) noexcept
{
  std::free(p);
}
extern "C" void * malloc(std::size_t size)
{
  count();
  return __libc_malloc(size);
}
extern "C" void * calloc(std::size_t n, std::size_t size)
{
  count();
  return __libc_calloc(n, size);
}
extern "C" void * realloc(void * ptr, std::size_t size)
{
  count();
  return __libc_realloc(ptr, size);
}

static int g_passed = 0, g_failed = 0;
#define CHECK(cond, ...)                                                                                     \
  do                                                                                                         \
  {                                                                                                          \
    if (cond)                                                                                                \
      ++g_passed;                                                                                            \
    else                                                                                                     \
    {                                                                                                        \
      ++g_failed;                                                                                            \
      std::printf("FAILED %s:%d: %s: ", __FILE__, __LINE__, #cond);                                          \
      std::printf(__VA_ARGS__);                                                                              \
      std::printf("\n");                                                                                     \
    }                                                                                                        \
  } while (0)

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
    long allocations = 0, exact = 0, trials = 0;
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
  }
} // namespace

int main()
{
  g_counting = true; // the counter counts (else "0 allocations" would mean nothing)
  delete[] new double[3];
  g_counting = false;
  CHECK(g_allocations.exchange(0) > 0, "the allocation counter counted nothing");
  testExactContactAndNoAllocation();
  testBadInput();
  std::printf("%d passed, %d failed\n", g_passed, g_failed);
  return g_failed == 0 ? 0 : 1;
}
