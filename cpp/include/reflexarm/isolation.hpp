// reflexarm: collision isolation and identification from the joint residual (the C++ port of
// reflexarm.control.collision.isolate.ContactIsolator and identify.ContactIdentifier).
//
// Same algorithm, same results: the most distal significant joint gives the candidate links; every candidate
// point of every candidate link is scored by the friction-pyramid constrained least squares
// min |W (J_p^T f - r)| (interior 3x3, facets 2x2, edges, apex); the most proximal link within the tolerance of
// the best fit is chosen; what the residual determines follows from the ranks and the consistent set.
// configure() sizes every buffer once; isolate() allocates nothing and throws nothing. begin/step/finish spread the
// same computation over calls (bounded work per call), with the same result bit for bit.
#pragma once

#include <memory>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

#include "pinocchio/multibody.hpp"

#include "reflexarm/defined_data.hpp"
#include "reflexarm/params.hpp"

namespace reflexarm
{

  /// Sampled collision surface of the link moved by one joint, in the Pinocchio joint frame
  /// (reflexarm.robots.collision_geometry.LinkSurface). Zero rows: a link without collision geometry.
  struct LinkSurfaceData
  {
    using Rows3 = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
    Rows3 points;  ///< (m, 3) surface points [m]
    Rows3 normals; ///< (m, 3) outward unit normals
  };

  /// Parameters of ContactIsolator::configure (the Python ContactIsolator's keyword arguments).
  struct IsolationParams
  {
    /// per-joint level [Nm] above which a residual component counts, > 0 (size n, or 1: broadcast)
    Eigen::VectorXd significance = Eigen::VectorXd::Constant(1, 1.0);
    double fit_tolerance = 0.0;        ///< absolute part of the fit tolerance (weighted norm), >= 0
    double relative_tolerance = 0.05;  ///< relative part, a fraction of |W r|, >= 0
    double friction_coefficient = 0.5; ///< mu of the friction pyramid, >= 0
    int cone_edges = 8;                ///< generators of the pyramid, >= 3
  };

  /// What a joint residual determines (values as reflexarm.control.collision.contact.Determined's order).
  enum class Determined
  {
    PointAndForce = 0,
    ForceOnly = 1,
    LinkOnly = 2,
    None = 3
  };

  /// Why the estimate is what it is (the Python face writes the reason text from it and the numbers).
  enum class IsolationCause
  {
    Determined = 0,         ///< POINT_AND_FORCE (link rank >= 5) or FORCE_ONLY (forces agree)
    NoSignificantJoint = 1, ///< NONE
    NoGeometry = 2,         ///< LINK_ONLY: the chosen link has no collision geometry
    ForceRankDeficient = 3, ///< LINK_ONLY: J_c^T has rank < 3 at the best point
    ForcesDisagree = 4,     ///< LINK_ONLY: link rank < 5 and the forces along the consistent set disagree
    NoSingleContact = 5     ///< LINK_ONLY: no candidate explains the residual within the tolerance
  };

  /// The result of one isolate() call (ContactEstimate plus the numbers of its reason).
  struct ContactEstimateData
  {
    int link = -1;                   ///< 0-based joint whose link was hit; -1 for none
    bool has_point = false;          ///< point determined
    bool has_force = false;          ///< force determined
    Eigen::Vector3d point = Eigen::Vector3d::Zero(); ///< world [m] (the best point, also when undetermined)
    Eigen::Vector3d force = Eigen::Vector3d::Zero(); ///< world [N] (the best force, also when undetermined)
    double fit_error = 0.0;          ///< unweighted |J_c^T f - r| [Nm]; NaN for none
    Determined determined = Determined::None;
    IsolationCause cause = IsolationCause::NoSignificantJoint;
    int first_candidate = -1;        ///< candidate links are first_candidate .. n-1
    int candidate_count = 0;
    int consistent_points = 0;       ///< points within the tolerance of the best on the chosen link
    double point_spread = 0.0;       ///< their largest distance from the best point [m]; NaN if not applicable
    int links_examined = 0;          ///< candidate links fitted, from the first on (the fit stops once the choice is
                                     ///< settled: see ContactIsolator::step)
    double best_fit = 0.0;           ///< best weighted fit error over the candidate links examined
    double tolerance = 0.0;          ///< fit_tolerance + relative_tolerance |W r|
    int link_rank = 0;               ///< rank of the chosen link's Jacobian (its first link+1 columns)
    int force_rank = 0;              ///< rank of J_p J_p^T at the best point
    double force_variation = 0.0;    ///< relative magnitude spread of the consistent forces
    double direction_variation_deg = 0.0; ///< their largest angle to the best force [deg]
    double max_significance_ratio = 0.0;  ///< max_j |r_j| / significance_j
  };

  /// Isolation and identification on a fixed-base serial arm with revolute/prismatic joints (nq == nv == n).
  class ContactIsolator
  {
  public:
    /// the per-joint significance levels [Nm] (size n once configured): a joint is significant above its level
    const Eigen::VectorXd & significance() const noexcept { return significance_; }

    /// Allocates everything. Throws ConfigError on bad input (sizes, signs, non-finite values).
    void configure(
      const pinocchio::Model & model, const std::vector<LinkSurfaceData> & surfaces, const IsolationParams & params);

    /// Contact from the residual at q. Returns false (and out.determined = None) if q or residual has the wrong
    /// size or a non-finite value. Allocation-free, never throws.
    bool isolate(
      const Eigen::Ref<const Eigen::VectorXd> & q,
      const Eigen::Ref<const Eigen::VectorXd> & residual,
      ContactEstimateData & out) noexcept;

    /// The same isolation spread over calls, bounded work per call (the real-time tick's form):
    ///   begin(q, residual)  the candidate links and their kinematics (one computeJointJacobians), no fit;
    ///   begin(q, residual, kin)  the same from the caller's kinematics at q: kin is a Data of the configured model
    ///                       whose oMi and J hold the joint placements and the world-frame joint Jacobians at q (as
    ///                       computeJointJacobians, computeCoriolisMatrix or the forward pass of computeRNEADerivatives
    ///                       leave them); the same result bit for bit, no Pinocchio call (the controller's tick passes
    ///                       its Coriolis Data, computed at q earlier in the same tick and still in cache);
    ///   step(point_budget)  at most point_budget units of the fit, true when none is left;
    ///   finishStep()        one stage of the choice after the fit: 1. the most proximal link within the tolerance
    ///                       of the best fit and the rank of its Jacobian, 2. its estimate (the consistent set, the
    ///                       force's rank, what is determined); true when none is left (each about the cost of a
    ///                       few points of pass 2, so that no call costs much more than a step of a few points);
    ///   finish(out)         the estimate (runs any work and stage still left first; after them, a copy).
    /// The work is, per candidate link from the most proximal on, pass 1 (the link's terms, then the trace of
    /// A = J_p W W J_p^T of each point: one unit per kTracePoints points, the link's last unit the rest) then pass 2
    /// (A and b = J_p W W r of each point, the lower bound of its error, then unless the bound rules it out the
    /// constrained fit and its error: one unit per point); a link without geometry is one unit (the wrench fit). A
    /// unit costs at most about one pass-2 point (see kTracePoints). A step may go on from one link to the next;
    /// pass 1's largest trace (the floor of the edges) is kept per link until its pass 2, the best point per link
    /// across the steps. So work_total() = sum over candidate links of ceil(m / kTracePoints) + m (m >= 1 points)
    /// or 1 (no geometry), and the work is done after ceil(work_total() / point_budget) steps. The fit stops early,
    /// with the same estimate, once the links fitted so far settle the choice (the first of them within the
    /// tolerance of their best fit is within the tolerance itself: chosen whatever the later links hold, see
    /// settled()): work_total() then becomes the work done, the sum over the links examined (the estimate's
    /// links_examined), and best_fit is the best over them.
    /// begin + step... + finishStep... + finish gives bitwise the result of isolate(), which is begin + step(all) +
    /// finish. finishStep() before the fit is done does nothing and returns false; with nothing to fit (no
    /// significant joint, invalid input) it has no stage and returns true.
    /// begin() returns false (and finish() writes what isolate() writes for it) on a q or residual of the
    /// wrong size or a non-finite value. Allocation-free, never throw.
    bool begin(
      const Eigen::Ref<const Eigen::VectorXd> & q, const Eigen::Ref<const Eigen::VectorXd> & residual) noexcept;
    /// (kin of another size than the configured model: refused like a q of the wrong size)
    bool begin(
      const Eigen::Ref<const Eigen::VectorXd> & q,
      const Eigen::Ref<const Eigen::VectorXd> & residual,
      const pinocchio::Data & kin) noexcept;
    bool step(int point_budget) noexcept;
    bool finishStep() noexcept;
    bool finish(ContactEstimateData & out) noexcept;
    /// Drops an isolation under way (finish() then writes what it writes before any begin()).
    void cancel() noexcept;
    /// begin() was called and finish() not yet.
    bool active() const noexcept
    {
      return active_;
    }
    /// Units of work of the isolation begun (0: nothing to fit; after an early stop the units done) and units left.
    int workTotal() const noexcept
    {
      return work_total_;
    }
    int workLeft() const noexcept
    {
      return work_total_ - work_done_;
    }
    /// Stages of finishStep() left (2 after a begin() with work, 0 without; 0 once they ran).
    int finishStepsLeft() const noexcept
    {
      return valid_ && first_ >= 0 ? kFinishSteps - stage_ : 0;
    }
    static constexpr int kFinishSteps = 2;
    /// Pass-1 points per unit of work: a pass-1 point (the trace of A from the link's terms, ~20 flops) costs
    /// ~1/30 of a pass-2 point that is not pruned (A, b, the pyramid's 8 edges and facets, the error: ~600 flops;
    /// measured 4.6-5.7 ns against 0.14-0.17 us on a 6-joint arm, 400 points a link); 16 of them make a unit of about
    /// half a pass-2 point, so that no unit costs more than a pass-2 point even at twice that ratio.
    static constexpr int kTracePoints = 16;
    /// Candidate points of the isolation begun whose constrained fit was skipped so far: their unconstrained
    /// least-squares error (a lower bound of the constrained one) already exceeded the link's best + tolerance, so
    /// they can be neither the best point nor in its consistent set (the result is the same as without skipping).
    long prunedPoints() const noexcept
    {
      return pruned_;
    }

    int nv() const noexcept
    {
      return n_;
    }
    const Eigen::VectorXd & weights() const noexcept
    {
      return weights_;
    }

  private:
    using Rows3 = LinkSurfaceData::Rows3;
    using Jac = Eigen::Matrix<double, 6, Eigen::Dynamic>;

    /// A link's candidate points and their friction pyramids, fixed by configure(): shared by the copies of an
    /// isolator (a copy, e.g. of a controller, does not duplicate the megabytes of a fine geometry)
    struct LinkGeometry
    {
      Rows3 points_local;  ///< (m, 3) candidate points, joint frame
      Rows3 generators;    ///< (m K, 3) unit edges of the pyramid, joint frame
      Rows3 facet_normals; ///< (m K, 3) inward facet normals, joint frame
    };

    struct LinkBuffers
    {
      Rows3 forces;        ///< (m, 3) best force per point, joint frame (pruned points: not written)
      Eigen::VectorXd errors; ///< (m) weighted fit errors; +inf for a point pruned by its lower bound
      Jac jacobian;       ///< LOCAL_WORLD_ALIGNED joint Jacobian at the last call
      Eigen::Matrix3d rotation;
      Eigen::Vector3d origin;
      int best = -1;
      double best_error = 0.0;
      double max_trace = 0.0; ///< pass 1's largest trace so far
      double floor = 0.0;     ///< the edges' floor, from pass 1, for pass 2
    };

    /// the terms of the trace of A in the link's joint frame (at the start of its pass 1)
    void linkTerms(int link) noexcept;
    bool beginWith(
      const Eigen::Ref<const Eigen::VectorXd> & q,
      const Eigen::Ref<const Eigen::VectorXd> & residual,
      const pinocchio::Data * kin) noexcept;
    /// pass 1 over points [begin, end) of a link: the largest trace of A
    void traceRange(int link, Eigen::Index begin, Eigen::Index end) noexcept;
    /// pass 2 over points [begin, end): the constrained fit, the errors, the best point so far
    void fitRange(int link, Eigen::Index begin, Eigen::Index end) noexcept;
    /// fitRange with the pyramid's edge count KC fixed at compile time (0: K_ at run time)
    template <int KC>
    void fitRangeK(int link, Eigen::Index begin, Eigen::Index end) noexcept;
    /// IsolationParams::cone_edges' default, the edge count fitRange has a compiled form for
    static constexpr int kDefaultConeEdges = 8;
    /// finish()'s stages: the choice of the link and its rank (1), its estimate (2), into estimate_
    void chooseLink() noexcept;
    void estimateLink(int link, double tolerance, ContactEstimateData & out) noexcept;
    int linkRank(int link) noexcept;
    double wrenchError(int link) noexcept;
    /// after a link's fit: true when the links fitted so far settle the choice (step() then ends the work)
    bool settled() const noexcept;

    pinocchio::Model model_;
    pinocchio::Data data_ = definedData(); // defined LLTs: a never-configured isolator copies cleanly (UBSan)
    int n_ = 0;
    int K_ = 8;
    IsolationParams params_;
    Eigen::VectorXd significance_, weights_;
    Eigen::VectorXd residual_, weighted_residual_, wrench_r_;
    Eigen::VectorXd h_, gg_, g12_, x1_, x2_, t_;
    Rows3 ad_; ///< (K, 3) A d_k of the point under fit
    // the link under fit (linkTerms), joint frame: with u_c, v_c the rows of W J^T rotated into it (row c of W J_p^T
    // at the point p is u_c + v_c x p), trace A(p) = tr P + 2 tr(Q [p]x) + |p|^2 tr S - p^T S p, P = sum u u^T,
    // Q = sum u v^T, S = sum v v^T; b(p) = ur + vr x p, ur = sum (W r)_c u_c, vr = sum (W r)_c v_c
    Eigen::Matrix<double, Eigen::Dynamic, 6, Eigen::RowMajor> uv_; ///< (n, 6) rows [u_c, v_c]
    Eigen::Matrix3d P_, Q_, S_;
    Eigen::Vector3d ur_, vr_;
    double wr2_ = 0.0;       ///< |W r|^2
    double tolerance_ = 0.0; ///< fit_tolerance + relative_tolerance |W r| (the consistent set's, and the pruning's)
    long pruned_ = 0;        ///< points of the isolation begun whose constrained fit the lower bound skipped
    Eigen::MatrixXd wrench_b_;
    Eigen::JacobiSVD<Eigen::MatrixXd> wrench_svd_;
    std::vector<LinkBuffers> links_;
    std::shared_ptr<const std::vector<LinkGeometry>> geometry_; ///< per link, immutable after configure()
    const LinkGeometry & geometry(int link) const noexcept
    {
      return (*geometry_)[static_cast<size_t>(link)];
    }
    // the isolation under way (begin / step / finish)
    bool active_ = false, valid_ = false;
    int first_ = -1;          ///< most distal significant joint (-1: none)
    double ratio_ = 0.0;      ///< max_j |r_j| / significance_j
    int work_total_ = 0, work_done_ = 0;
    int cur_link_ = 0, cur_pass_ = 1; ///< where the next step goes on: link, pass (1 or 2), point
    Eigen::Index cur_point_ = 0;
    int stage_ = 0;                 ///< finishStep()'s stages done (0 .. kFinishSteps)
    ContactEstimateData estimate_;  ///< the estimate the stages write, finish() copies
  };

} // namespace reflexarm
