// Issue 19: the cost of each dynamics term of the momentum observer on one arm, Pinocchio's algorithms against
// reflexarm::ResidualTerms (one pass over the tree for M dq, C^T dq, g, J^T F), in thread CPU time (best of 5 runs of
// 20000 random states; the machine is shared). Not part of make bench (it compiles against Pinocchio, ~1 min):
//   .venv/bin/python -c "from reflexarm import load_robot; load_robot('atlas_v5_left_arm')._model.saveToText('/tmp/atlas.txt')"
//   P=.venv/lib/python3.11/site-packages/cmeel.prefix
//   g++ -O3 -DNDEBUG -std=c++17 -DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS -DBOOST_MPL_LIMIT_LIST_SIZE=30 \
//     -DBOOST_MPL_LIMIT_VECTOR_SIZE=30 -DPINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION -Icpp/include -isystem $P/include \
//     -isystem $P/include/eigen3 bench/replay_terms_timing.cpp cpp/src/residual_terms.cpp -o /tmp/replay_terms \
//     -Wl,-rpath,$P/lib $P/lib/libpinocchio_default.so $P/lib/libboost_serialization.so
//   /tmp/replay_terms /tmp/atlas.txt 18      # the model file and the sensor frame id (robot.sensor_frame_id)
#include <algorithm>
#include <cstdlib>
#include <ctime>
#include <cstdio>
#include <random>
#include <vector>

#include "pinocchio/multibody.hpp"
#include "pinocchio/algorithm/kinematics.hpp"
#include "pinocchio/algorithm/rnea.hpp"
#include "pinocchio/algorithm/frames.hpp"
#include "pinocchio/algorithm/crba.hpp"
#include "pinocchio/serialization.hpp"
#include "reflexarm/residual_terms.hpp"

using namespace pinocchio;

int main(int argc, char ** argv)
{
  if (argc != 3)
  {
    std::fprintf(stderr, "usage: %s model.txt sensor_frame_id\n", argv[0]);
    return 2;
  }
  Model model;
  model.loadFromText(argv[1]);
  Model model0 = model;
  model0.gravity.linear().setZero();
  const int n = model.nv;
  const FrameIndex fid = static_cast<FrameIndex>(std::atoi(argv[2]));
  Data dg(model), dc(model), dp(model0), dj(model), df(model), dm(model);
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> U(-1, 1);
  const int N = 20000;
  std::vector<Eigen::VectorXd> Q(N), V(N);
  for (int k = 0; k < N; ++k)
  {
    Q[k] = Eigen::VectorXd(n);
    V[k] = Eigen::VectorXd(n);
    for (int i = 0; i < n; ++i)
    {
      Q[k][i] = U(rng);
      V[k][i] = U(rng);
    }
  }
  Eigen::Matrix<double, 6, 1> F;
  for (int i = 0; i < 6; ++i)
    F[i] = U(rng);
  reflexarm::ResidualTerms plain(model, fid, false), efc(model, fid, true);
  std::vector<double> terms(4 * n);
  Eigen::VectorXd zeros = Eigen::VectorXd::Zero(n), acc = zeros, p(n), ct(n), g(n), jtf(n), gg(n);
  Eigen::Matrix<double, 6, Eigen::Dynamic> J(6, n);
  double sink = 0;
  auto bench = [&](const char * name, auto && f) {
    for (int k = 0; k < 2000; ++k)
      f(k);
    double best = 1e9;
    for (int rep = 0; rep < 5; ++rep)
    {
      timespec a, b;
      clock_gettime(CLOCK_THREAD_CPUTIME_ID, &a);
      for (int k = 0; k < N; ++k)
        f(k);
      clock_gettime(CLOCK_THREAD_CPUTIME_ID, &b);
      best = std::min(best, ((b.tv_sec - a.tv_sec) * 1e9 + (b.tv_nsec - a.tv_nsec)) / 1e3 / N);
    }
    const double us = best;
    std::printf("%-40s %.3f us\n", name, us);
  };
  using CR = Eigen::Ref<const Eigen::VectorXd>;
  bench("computeGeneralizedGravity", [&](int k) { sink += computeGeneralizedGravity(model, dg, CR(Q[k]))[0]; });
  bench("computeCoriolisMatrix", [&](int k) { sink += computeCoriolisMatrix(model, dc, CR(Q[k]), CR(V[k]))(0, 0); });
  bench("C^T dq from C (loop)", [&](int k) {
    const auto & C = dc.C;
    for (int i = 0; i < n; ++i)
    {
      double s = 0;
      for (int j = 0; j < n; ++j)
        s += C(j, i) * V[k][j];
      acc[i] = s;
    }
    sink += acc[0];
  });
  bench("rnea(model0, q, 0, dq) = M dq", [&](int k) { sink += rnea(model0, dp, CR(Q[k]), CR(zeros), CR(V[k]))[0]; });
  bench("rnea(model0, q, 0, 0) = ff (hold)", [&](int k) { sink += rnea(model0, dp, CR(Q[k]), CR(zeros), CR(zeros))[0]; });
  bench("computeFrameJacobian LOCAL", [&](int k) {
    Eigen::VectorXd qq = Q[k];
    computeFrameJacobian(model, dj, qq, fid, LOCAL, J);
    sink += J(0, 0);
  });
  bench("crba", [&](int k) { sink += crba(model, dm, CR(Q[k]))(0, 0); });
  bench("forwardKinematics(q, v)", [&](int k) { forwardKinematics(model, df, Q[k], V[k]); sink += df.v[1].angular()[0]; });
  bench("ResidualTerms: p, C^T dq, g", [&](int k) { plain.compute(Q[k].data(), V[k].data(), F.data(), terms.data()); sink += terms[0]; });
  bench("ResidualTerms: p, C^T dq, g, J^T F", [&](int k) { efc.compute(Q[k].data(), V[k].data(), F.data(), terms.data()); sink += terms[0]; });
  // check against pinocchio
  double ep = 0, ec = 0, eg = 0, ej = 0, mag = 0;
  for (int k = 0; k < 2000; ++k)
  {
    efc.compute(Q[k].data(), V[k].data(), F.data(), terms.data());
    p = Eigen::Map<Eigen::VectorXd>(terms.data(), n);
    ct = Eigen::Map<Eigen::VectorXd>(terms.data() + n, n);
    g = Eigen::Map<Eigen::VectorXd>(terms.data() + 2 * n, n);
    jtf = Eigen::Map<Eigen::VectorXd>(terms.data() + 3 * n, n);
    Eigen::VectorXd pr = rnea(model0, dp, CR(Q[k]), CR(zeros), CR(V[k]));
    const Eigen::MatrixXd & C = computeCoriolisMatrix(model, dc, CR(Q[k]), CR(V[k]));
    Eigen::VectorXd ctr = C.transpose() * V[k];
    Eigen::VectorXd gr = computeGeneralizedGravity(model, dg, CR(Q[k]));
    Eigen::VectorXd qq = Q[k];
    J.setZero();
    computeFrameJacobian(model, dj, qq, fid, LOCAL, J);
    Eigen::VectorXd jr = J.transpose() * F;
    ep = std::max(ep, (p - pr).cwiseAbs().maxCoeff());
    ec = std::max(ec, (ct - ctr).cwiseAbs().maxCoeff());
    eg = std::max(eg, (g - gr).cwiseAbs().maxCoeff());
    ej = std::max(ej, (jtf - jr).cwiseAbs().maxCoeff());
    mag = std::max(mag, gr.cwiseAbs().maxCoeff());
  }
  std::printf("max |diff|: p %.3g  C^T dq %.3g  g %.3g (|g| up to %.3g)  J^T F %.3g\n", ep, ec, eg, mag, ej);
  std::printf("%g\n", sink);
}
