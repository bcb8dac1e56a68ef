#include "core/fitting/fit.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <string>
#include <string_view>


#include <Eigen/Eigenvalues>

#include "absl/strings/str_format.h"
#include "core/fitting/fit_inputs.h"
#include "core/fitting/hermite.h"
#include "core/fitting/noise.h"
#include "core/fitting/parametric.h"
#include "core/fitting/plane_slopes.h"
#include "core/fitting/slopes.h"
#include "core/fitting/wls.h"
#include "core/fitting/wls_batch.h"
#include "core/util/status_macros.h"
#include "core/util/parallel.h"

namespace geomfit {
namespace {

// Everything a vertex fit reads, and where it writes.
struct FitInput {
  const Mesh& mesh;
  const Neighborhoods& nb;
  const Positions& normals;  // per-vertex normals for frames and the safeguard weights
  const FitOptions& o;
  double cos_cut;  // cos(safeguard angle) of (2.2.1)
  const Topology& topo;      // for the comparison parametrizations (parametric.h)
  // Position and normal of vertex p at points[slot(p)]: a copy in the order vertices
  // are fitted in, so neighbouring stencils read neighbouring memory (the same doubles
  // as mesh.positions and normals, so the same results).
  const PointRecord* points;
  const int32_t* rank;  // slot of each vertex; null: the vertex's own index
  const uint8_t* fixed_tangent;  // per vertex: keep the frame's tangent plane (or null)
  bool hermite;                  // Hermite curvatures where the tangent plane is fixed
  int Slot(int p) const { return rank ? rank[p] : p; }
};

struct FitOutput {
  LocalFrame* frame;
  double* coefficients;  // dims x ncoef
  VertexDiagnostics* diag;
  double* stencil;       // stencil_rows x stencil size, or null
  int stencil_rows;      // leading Taylor coefficients kept in `stencil`
};

WlsSettings SettingsFor(const FitOptions& o, int stencil_rows) {
  WlsSettings S;
  S.degree = o.degree;
  S.interpolate = o.interpolate;
  S.weight_epsilon = o.weight_epsilon;
  S.cond_threshold = o.cond_threshold;
  S.oscillation_safeguard = o.oscillation_safeguard;
  S.op_rows = stencil_rows;
  return S;
}

// The problem of one vertex (2.2-2.4): its stencil in the frame of its approximate
// normal, rows filtered by the normal-angle safeguard gamma_i of (2.2.1). Returns false
// for an isolated vertex (no frame, nothing to solve; its outputs are written).
bool SetUpVertex(int v, const FitInput& in, const FitOutput& out, WlsProblem& P) {
  const FitOptions& o = in.o;
  const int n_pts = in.nb.Size(v);
  const int32_t* pts = in.nb.Points(v);
  const int dims = o.method == FitMethod::kLHF ? 1 : 3;
  const int ncoef = NumCoefficients(o.degree);
  const int first = o.interpolate ? 1 : 0;  // the centre is a row unless interpolating
  VertexDiagnostics& diag = *out.diag;
  diag.degree_requested = static_cast<int8_t>(o.degree);

  using Vec = Eigen::Map<const Eigen::Vector3d>;
  const double* self = in.points[in.Slot(v)].p;
  const Eigen::Vector3d x0 = Vec(self);
  const Eigen::Vector3d m0 = Vec(self + 3);
  if (m0.squaredNorm() == 0) {  // isolated vertex: no faces, no frame
    diag.flags |= kFlagIsolated;
    *out.frame = FrameFromNormal(x0, Eigen::Vector3d::UnitZ());
    std::fill(out.coefficients, out.coefficients + dims * ncoef, 0.0);
    return false;
  }
  const LocalFrame frame = FrameFromNormal(x0, m0);
  *out.frame = frame;

  const double cos_cut = in.cos_cut;
  P.dims = dims;
  P.rows = n_pts - first;
  int used = first;
  for (int i = first; i < n_pts; ++i) {
    const int r = i - first;
    const double* q = in.points[in.Slot(pts[i])].p;
    const Eigen::Vector3d d = Vec(q) - x0;
    P.u[r] = d.dot(frame.t1);
    P.v[r] = d.dot(frame.t2);
    const double g = i == 0 ? 1.0 : Vec(q + 3).dot(m0);
    P.gamma[r] = g >= cos_cut ? g : 0.0;
    used += P.gamma[r] > 0;
    if (dims == 1) {
      P.rhs[0][r] = d.dot(frame.normal);
    } else {
      for (int q = 0; q < 3; ++q) P.rhs[q][r] = d(q);
    }
  }
  if (o.method == FitMethod::kXu || o.method == FitMethod::kLSCM)
    ParametrizeStencil(o.method, in.mesh, in.topo, pts, n_pts, first, frame, &P);
  diag.points = static_cast<int16_t>(used);
  if (used < ncoef) diag.flags |= kFlagTooFewPoints;
  return true;
}

// Hermite curvatures (FitOptions::hermite_hessian): the Hessian is the weighted
// least-squares fit of e^T Hess e to the rows of HermiteRowOf (hermite.h; 4h/r^2 - g/r,
// the quartic term cancels, the cubic one halves and enters only through the stencil's
// odd moments; 6h/r^2 - 2g/r, which cancels the cubic term instead, measured 2-8x less
// accurate, bench/README.md), with g from the point's refined (O(h^3)) normal. On too few
// or too clustered directions the plain fit's Hessian stays.
void FitHermiteHessian(int v, const FitInput& in, const FitOutput& out, const WlsProblem& P) {
  const LocalFrame& fr = *out.frame;
  const int32_t* pts = in.nb.Points(v);
  const int first = in.o.interpolate ? 1 : 0;
  double radius2 = 0;
  for (int r = 0; r < P.rows; ++r)
    if (P.gamma[r] > 0) radius2 = std::max(radius2, P.u[r] * P.u[r] + P.v[r] * P.v[r]);
  if (radius2 == 0) return;
  constexpr double kEps = 0.1;  // the row weights' eps (hermite.h)
  Eigen::Matrix3d M = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  for (int r = 0; r < P.rows; ++r) {
    const Eigen::Map<const Eigen::Vector3d> n(in.points[in.Slot(pts[r + first])].n);
    double value, c0, c1, c2, inv_r2, weight;
    HermiteRowOf(P.u[r], P.v[r], P.rhs[0][r], n.dot(fr.t1), n.dot(fr.t2), n.dot(fr.normal), P.gamma[r], 1 / radius2,
                 kEps, value, c0, c1, c2, inv_r2, weight);
    if (!(weight > 0)) continue;
    const Eigen::Vector3d a(c0, c1, c2);
    M += weight * a * a.transpose();
    b += weight * value * a;
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
  eig.computeDirect(M);
  const Eigen::Vector3d lambda = eig.eigenvalues();  // ascending
  if (!(lambda(0) > 1e-3 * lambda(2))) return;
  const Eigen::Vector3d c = eig.eigenvectors() * (eig.eigenvectors().transpose() * b).cwiseQuotient(lambda);
  out.coefficients[TaylorIndex(2, 0)] = c(0);
  out.coefficients[TaylorIndex(1, 1)] = c(1);
  out.coefficients[TaylorIndex(0, 2)] = c(2);
}

// A solution's diagnostics.
void SetDiagnostics(const WlsSolution& sol, VertexDiagnostics& diag) {
  diag.degree_used = static_cast<int8_t>(sol.degree_used);
  diag.rank = static_cast<int16_t>(sol.rank);
  diag.condition = static_cast<float>(sol.condition);
  if (sol.condition_downgraded || sol.degree_used < 1) diag.flags |= kFlagDowngraded;
  if (sol.oscillation_downgraded) diag.flags |= kFlagOscillation;
}

// Diagnostics and stencil rows of a solved vertex; `op` is SolveWls's operator.
void FinishVertex(int v, const FitInput& in, const FitOutput& out, const WlsProblem& P,
                  const WlsSolution& sol, const double* op) {
  SetDiagnostics(sol, *out.diag);
  if (in.fixed_tangent && in.fixed_tangent[v] && sol.degree_used >= 1)  // normal refinement
    out.coefficients[TaylorIndex(1, 0)] = out.coefficients[TaylorIndex(0, 1)] = 0;
  if (in.hermite && in.fixed_tangent && in.fixed_tangent[v] && sol.degree_used >= 2) FitHermiteHessian(v, in, out, P);

  if (out.stencil) {  // operator rows over the stencil points (centre first)
    const int n_pts = in.nb.Size(v), first = in.o.interpolate ? 1 : 0;
    std::fill(out.stencil, out.stencil + static_cast<size_t>(out.stencil_rows) * n_pts, 0.0);
    if (sol.degree_used < 1) return;
    for (int c = 0; c < out.stencil_rows; ++c) {
      double* row = out.stencil + static_cast<size_t>(c) * n_pts;
      double sum = 0;
      for (int r = 0; r < P.rows; ++r) sum += row[r + first] = op[c * P.rows + r];
      if (in.o.interpolate) row[0] = (c == 0 ? 1.0 : 0.0) - sum;  // values relative to the centre
    }
  }
}

// Vertices waiting for the batched kernel, kWlsLanes at a time (heap: ~800 KB).
struct FitBatch {
  WlsBatchWorkspace work;
  WlsProblem problems[kWlsLanes];
  double ops[kWlsLanes][kMaxCoefficients * kMaxStencil];
  FitOutput outs[kWlsLanes];
  int vertex[kWlsLanes];
  int count = 0;

  // Solves the queued vertices: the batched kernel first, SolveWls for the lanes it
  // leaves (safeguard paths).
  void Flush(const FitInput& in, const WlsSettings& S, bool batched) {
    const WlsProblem* p[kWlsLanes];
    double* coef[kWlsLanes];
    double* op[kWlsLanes];
    WlsSolution sol[kWlsLanes];
    for (int l = 0; l < count; ++l) {
      p[l] = &problems[l];
      coef[l] = outs[l].coefficients;
      op[l] = outs[l].stencil ? ops[l] : nullptr;
    }
    const bool svd = in.o.solver == WlsSolver::kSVD;  // the comparison solver: scalar only
    const int solved = batched && !svd ? SolveWlsBatch(p, count, S, coef, op, sol, work) : 0;
    for (int l = 0; l < count; ++l) {
      if (!(solved >> l & 1))
        sol[l] = svd ? SolveWlsSvd(problems[l], S, coef[l], op[l]) : SolveWls(problems[l], S, coef[l], op[l]);
      FinishVertex(vertex[l], in, outs[l], problems[l], sol[l], op[l]);
    }
    count = 0;
  }
};

// Height fits (LHF, no stencils) set up in the kernel's lanes by FitHeightsBatch,
// kWlsLanes vertices at a time; the lanes it leaves are set up again by SetUpVertex and
// go to `batch` (SolveWlsBatch's QR, SolveWls): the same results as without this queue.
struct HeightQueue {
  HeightLane lanes[kWlsLanes];
  FitOutput outs[kWlsLanes];
  int vertex[kWlsLanes];
  int count = 0;

  void Flush(const FitInput& in, const HeightLanesInput& hin, const WlsSettings& S, FitBatch& batch) {
    WlsSolution sol[kWlsLanes];
    int used[kWlsLanes];
    const int solved = count > 0 ? FitHeightsBatch(hin, lanes, count, S, sol, used, batch.work) : 0;
    const int ncoef = NumCoefficients(in.o.degree);
    for (int l = 0; l < count; ++l) {
      if (solved >> l & 1) {
        VertexDiagnostics& diag = *outs[l].diag;
        diag.points = static_cast<int16_t>(used[l]);
        if (used[l] < ncoef) diag.flags |= kFlagTooFewPoints;
        SetDiagnostics(sol[l], diag);
        continue;
      }
      const int slot = batch.count;
      SetUpVertex(vertex[l], in, outs[l], batch.problems[slot]);  // not isolated: queued
      batch.outs[slot] = outs[l];
      batch.vertex[slot] = vertex[l];
      if (++batch.count == kWlsLanes) batch.Flush(in, S, true);
    }
    count = 0;
  }
};

}  // namespace

SurfaceJet SurfaceFits::Jet(int v) const {
  const LocalFrame& fr = frame(v);
  const double* c = coefficients(v);
  const int n = num_coefficients();
  auto at = [&](int d, int j, int k) { return TaylorIndex(j, k) < n ? c[d * n + TaylorIndex(j, k)] : 0.0; };
  SurfaceJet jet;
  if (dims() == 1) {
    jet.x = fr.origin + at(0, 0, 0) * fr.normal;
    jet.J.col(0) = fr.t1 + at(0, 1, 0) * fr.normal;
    jet.J.col(1) = fr.t2 + at(0, 0, 1) * fr.normal;
    jet.xuu = at(0, 2, 0) * fr.normal;
    jet.xuv = at(0, 1, 1) * fr.normal;
    jet.xvv = at(0, 0, 2) * fr.normal;
  } else {
    for (int d = 0; d < 3; ++d) {
      jet.x(d) = fr.origin(d) + at(d, 0, 0);
      jet.J(d, 0) = at(d, 1, 0);
      jet.J(d, 1) = at(d, 0, 1);
      jet.xuu(d) = at(d, 2, 0);
      jet.xuv(d) = at(d, 1, 1);
      jet.xvv(d) = at(d, 0, 2);
    }
  }
  return jet;
}

SurfaceFits::LocalPoint SurfaceFits::Evaluate(int v, const Eigen::Vector3d& x) const {
  const LocalFrame& fr = frame(v);
  const Eigen::Vector3d d = x - fr.origin;
  const double u = d.dot(fr.t1), w = d.dot(fr.t2);
  const int n = num_coefficients(), deg = options_.degree;
  const double* c = coefficients(v);
  LocalPoint p;
  if (dims() == 1) {  // x = origin + u t1 + v t2 + f(u, v) m (Table 3.1)
    double f, fu, fv;
    EvalTaylor(c, deg, u, w, &f, &fu, &fv);
    p.position = x + (f - d.dot(fr.normal)) * fr.normal;
    p.du = fr.t1 + fu * fr.normal;
    p.dv = fr.t2 + fv * fr.normal;
    p.normal = (fr.normal - fu * fr.t1 - fv * fr.t2) * (1 / std::sqrt(1 + fu * fu + fv * fv));
  } else {  // x = origin + (X(u, v), Y(u, v), Z(u, v))
    for (int k = 0; k < 3; ++k) EvalTaylor(c + k * n, deg, u, w, &p.position(k), &p.du(k), &p.dv(k));
    p.position += fr.origin;
    p.normal = p.du.cross(p.dv).normalized();
  }
  return p;
}

size_t SurfaceFits::Bytes() const {
  return sizeof(*this) + frames_.size() * sizeof(LocalFrame) + coefficients_.size() * 8 +
         diagnostics_.size() * sizeof(VertexDiagnostics) + stencil_offsets_.size() * 8 +
         stencils_.size() * 8;
}

class SurfaceFitter {
 public:
  static absl::StatusOr<std::shared_ptr<const SurfaceFits>> Fit(
      const Mesh& mesh, const Topology& topo, const FitOptions& o,
      std::shared_ptr<const Neighborhoods> nb, const FitRequest& req, const RunContext& ctx,
      const FittedBlockFn& on_fitted, Mesh* consumable_mesh = nullptr, Topology* consumable_topo = nullptr,
      const FittedBlockFn* blocks = nullptr) {
    if (absl::Status s = ValidateFitOptions(o); !s.ok()) return s;
    if (topo.num_vertices != mesh.NumVertices() || topo.num_faces != mesh.NumFaces())
      return absl::InvalidArgumentError(absl::StrFormat(
          "topology (%d vertices, %d faces) does not match the mesh (%d vertices, %d faces)",
          topo.num_vertices, topo.num_faces, mesh.NumVertices(), mesh.NumFaces()));
    const bool own_nb = !nb;  // stencils of this fit alone: nothing to cache with them
    const std::shared_ptr<const Neighborhoods> given_nb = nb;
    // FitSurfaceOnce's plain path: the mesh and topology are freed as soon as they are
    // read (fit.h), the normals computed before the faces go.
    const bool consume = consumable_mesh != nullptr && own_nb && PlainFit(o) && !on_fitted;
    // FitSurfaceOnceInBlocks: each block's fits handed over in a window of their own.
    const FittedBlockFn* const windows = consume && blocks && *blocks && !req.stencils ? blocks : nullptr;
    std::shared_ptr<FitInputs> consumed_inputs;
    if (consume) consumed_inputs = MakeFitInputs(mesh, topo, o.frame_normals, nullptr, ctx.threads());
    const std::function<void()> faces_read = [&] {
      consumable_mesh->faces = SharedFaces();
      for (std::vector<int32_t>* row : {&consumable_topo->vf_offsets, &consumable_topo->vf_faces,
                                        &consumable_topo->vv_offsets, &consumable_topo->vv})
        std::vector<int32_t>().swap(*row);
      std::vector<uint8_t>().swap(consumable_topo->is_isolated);
    };
    if (own_nb)
      nb = std::make_shared<Neighborhoods>(
          BuildNeighborhoods(topo, mesh, RingSpecFor(o), ctx.threads(), consume ? faces_read : nullptr));
    if (static_cast<int>(nb->offsets.size()) != mesh.NumVertices() + 1)
      return absl::InvalidArgumentError("neighborhoods do not match the mesh");
    // Once the point records hold them (FitAll).
    const std::function<void()> positions_read = [&] {
      consumable_mesh->positions.resize(0, 3);
      consumed_inputs->normals.resize(0, 3);
    };

    // The approximate normals, computed once per stencils and geometry (FitInputCache),
    // with their point records in the stencils' order; copied once a pass changes them.
    const Neighborhoods* const cached_nb = nb.get();
    const std::shared_ptr<const FitInputs> inputs =
        consume  ? consumed_inputs
        : own_nb ? MakeFitInputs(mesh, topo, o.frame_normals, &nb->ordered.order, ctx.threads())
                 : nb->fit_inputs.Get(mesh, topo, o.frame_normals, &nb->ordered.order, ctx.threads());
    Positions own_normals;
    const Positions* frame_normals = &inputs->normals;
    auto writable_normals = [&]() -> Positions& {
      if (frame_normals != &own_normals) own_normals = inputs->normals, frame_normals = &own_normals;
      return own_normals;
    };
    // Noise-aware fitting (noise.h): `o` resolved, smoothing-by-projection passes first.
    FitOptions eff = o;
    NoiseSchedule schedule;
    double noise_over_h = 0;
    if (o.noise != NoiseMode::kOff) {
      // Reported as a phase where it decides (auto); with kOn it only sets the schedule.
      GF_ASSIGN_OR_RETURN(const NoiseEstimate est,
                          EstimateNoise(mesh, topo, *frame_normals, o.noise == NoiseMode::kAuto ? ctx : ctx.WithProgress(nullptr)));
      if (o.noise == NoiseMode::kAuto) eff.noise = NoisyAt(est, o.degree) ? NoiseMode::kOn : NoiseMode::kOff;
      schedule = NoiseScheduleFor(o.degree, est.residual_ratio, est.cubic_ratio);
      noise_over_h = est.noise_over_h;
      schedule.smoothing_points_factor = NoiseSmoothingPointsFactor(est, o.degree, schedule.smoothing_degree);  // noise.h
    }
    // The final fit's stencils (the clean ones under light noise, when not set explicitly).
    FitOptions final_spec = eff;
    bool clean_tangent = false;  // the final fit keeps a clean-stencil fit's tangent plane
    if (eff.noise == NoiseMode::kOn && schedule.final_clean_stencils) {
      final_spec.noise = NoiseMode::kOff;
      if (final_spec.min_points_factor == 0) final_spec.min_points_factor = schedule.final_points_factor;
      if (final_spec.rings == 0) final_spec.rings = schedule.final_rings, clean_tangent = schedule.final_rings > 0;
    }
    if (RingSpecFor(final_spec).rings != RingSpecFor(o).rings ||
        RingSpecFor(final_spec).min_points != RingSpecFor(o).min_points)
      nb = std::make_shared<Neighborhoods>(BuildNeighborhoods(topo, mesh, RingSpecFor(final_spec), ctx.threads()));
    eff.interpolate = eff.Interpolates();
    if (eff.noise == NoiseMode::kOn) eff.weight_epsilon = kNoiseWeightEpsilon;
    // The schedule's passes, then its local ones (noise.h), when the count is automatic.
    const bool scheduled = eff.noise == NoiseMode::kOn && o.smoothing_passes < 0;
    const int smoothing = scheduled ? schedule.smoothing_passes + schedule.local_passes + schedule.unshrink_passes
                                    : eff.SmoothingPasses();
    std::vector<double> local_smoothing;  // the local passes' steps per vertex
    const int passes = smoothing + (o.two_pass ? 2 : 1);
    Mesh smoothed;  // positions after the smoothing passes (faces unused)
    const Mesh* input = &mesh;
    auto fits = std::make_shared<SurfaceFits>();
    // Frames and safeguard weights from fitted normals; `adopted` marks the vertices set.
    auto adopt_normals = [&](const SurfaceFits& from, std::vector<uint8_t>* adopted) {
      Positions& normals = writable_normals();
      ParallelFor(mesh.NumVertices(), ctx.threads(), [&](int64_t v) {
        if (from.diagnostics_[v].degree_used < 1) return;
        const SurfaceJet jet = from.Jet(static_cast<int>(v));
        Eigen::Vector3d n = jet.J.col(0).cross(jet.J.col(1));
        if (n.dot(normals.row(v)) < 0) n = -n;
        if (n.norm() == 0) return;
        normals.row(v) = n.normalized();
        if (adopted) (*adopted)[v] = 1;
      });
    };
    std::vector<uint8_t> fixed_tangent;  // normal refinement (FitOptions::normal_degree)
    std::shared_ptr<const Neighborhoods> smoothing_nb;  // the noise mode's smoothing fits' stencils
    std::shared_ptr<const Neighborhoods> tangent_nb;    // the clean tangent pre-fit's stencils (final_rings)
    std::shared_ptr<SurfaceFits> boundary_fits;  // cubic smoothing fits for the boundary vertices
    std::shared_ptr<SurfaceFits> high_fits;      // smoothing fits of smoothing_degree_high
    std::shared_ptr<const Neighborhoods> high_nb;
    std::shared_ptr<SurfaceFits> grown_fits;  // smoothing fits on grown stencils (smoothing_points_factor)
    std::shared_ptr<const Neighborhoods> grown_nb;
    const bool has_boundary = topo.num_boundary_edges > 0;
    for (int pass = 0; pass < passes; ++pass) {
      if (pass > 0) adopt_normals(*fits, nullptr);
      if (pass > 0 && pass <= smoothing) {
        const bool local = scheduled && pass > schedule.smoothing_passes;
        const bool unshrink = scheduled && pass > schedule.smoothing_passes + schedule.local_passes;
        std::vector<double> back;
        if (unshrink) back = UnshrinkSteps(*fits, ctx.threads());
        const double* step = unshrink ? back.data() : local ? local_smoothing.data() : nullptr;
        if (high_fits)  // two smoothing degrees (noise.h, BlendFootPoints)
          smoothed.positions = BlendFootPoints(*fits, *high_fits, input->positions, mesh, noise_over_h,
                                               kFootPointBlendSpread, step, ctx.threads());
        else if (grown_fits)  // grown stencils where they agree with the noise mode's own (noise.h)
          smoothed.positions = BlendFootPoints(*grown_fits, *fits, input->positions, mesh, noise_over_h,
                                               kFootPointBlendSpread, step, ctx.threads());
        else
          smoothed.positions = ProjectOntoFits(*fits, input->positions, ctx.threads(), step);
        high_fits.reset(), grown_fits.reset();
        // Auto at degree >= 3: the first pass moved the vertices by more than the noise
        // (its bias: the coarse bump), so the default fit is kept (noise.h).
        if (o.noise == NoiseMode::kAuto && o.degree >= 3 && pass == 1 &&
            SmoothingBiasDominates(mesh.positions, smoothed.positions, mesh, noise_over_h)) {
          FitOptions off = o;
          off.noise = NoiseMode::kOff;
          return Fit(mesh, topo, off, own_nb ? nullptr : given_nb, req, ctx, on_fitted, consumable_mesh, consumable_topo,
                     blocks);
        }
        if (boundary_fits && !unshrink)  // vertices within a ring of the boundary onto their cubic fits
          ParallelFor(mesh.NumVertices(), ctx.threads(), [&](int64_t v) {
            bool near = topo.is_boundary[v];
            for (int k = 0; k < topo.NumNeighbors(static_cast<int>(v)); ++k)
              near |= topo.is_boundary[topo.Neighbors(static_cast<int>(v))[k]] != 0;
            if (near && boundary_fits->diagnostics_[v].degree_used >= 1)
              smoothed.positions.row(v) = boundary_fits->Jet(static_cast<int>(v)).x.transpose();
          });
        smoothed.faces = mesh.faces;
        input = &smoothed;
      }
      FitOptions pass_options = eff;
      if (pass < smoothing) pass_options.interpolate = false;  // smoothing fits approximate
      const bool last = pass == passes - 1;
      std::shared_ptr<const Neighborhoods> pass_nb = nb;
      if (eff.noise == NoiseMode::kOn) {  // the smoothing fits' degree, the final fit's weights (noise.h)
        if (last) pass_options.weight_epsilon = schedule.final_weight_epsilon;
        if (last && schedule.final_interpolates) pass_options.interpolate = true;  // nearly clean (noise.h)
        if (pass < smoothing) {  // the noise mode's own stencils; rings and factor apply to the final fit
          pass_options = NoiseSmoothingOptions(eff, schedule);
          const RingSpec spec = RingSpecFor(pass_options), final_rings = RingSpecFor(final_spec);
          if (spec.rings != final_rings.rings || spec.min_points != final_rings.min_points ||
              spec.min_points_boundary != final_rings.min_points_boundary) {
            if (!smoothing_nb)
              smoothing_nb = std::make_shared<Neighborhoods>(BuildNeighborhoods(topo, mesh, spec, ctx.threads()));
            pass_nb = smoothing_nb;
          }
        }
      }
      // Progress phases: "smooth i/S" per smoothing pass, "frames" (two_pass's first fit),
      // "normals" (the normal refinement's pre-fit), "fit".
      const std::string phase = pass < smoothing ? absl::StrFormat("smooth %d/%d", pass + 1, smoothing)
                                : last           ? std::string("fit")
                                                 : std::string("frames");
      // Degree 2 (3) on a nearly clean mesh: the smoothed mesh interpolated, slope refinement
      // (the degree-3 Hermite curvatures, FitOptions::cubic_hermite; noise.h).
      const bool slope_final = last && eff.noise == NoiseMode::kOn && (schedule.slope_passes > 0 || schedule.hermite_final) &&
                               !req.stencils && o.normal_degree <= o.degree && !o.hermite_hessian;
      if (slope_final) {
        pass_options.noise = NoiseMode::kOff;
        pass_options.interpolate = true;
        pass_options.weight_epsilon = o.weight_epsilon;
        pass_options.normal_degree = 0;
        pass_options.slope_refinement = schedule.slope_passes;
        pass_options.quadratic_hermite = false;
      }
      // The final frames from a higher-degree fit, or (noise schedule with final_rings) from
      // the same degree's fit on the clean stencils, which the final fit's smaller ones keep.
      if (last && !slope_final && (eff.NormalDegree() > eff.degree || clean_tangent)) {
        FitOptions pre = eff;
        pre.degree = pre.normal_degree = eff.NormalDegree();
        pre.rings = pre.min_points_factor = 0;
        if (clean_tangent) {
          pre.noise = NoiseMode::kOff;
          pre.weight_epsilon = schedule.tangent_weight_epsilon > 0 ? schedule.tangent_weight_epsilon
                                                                   : schedule.final_weight_epsilon;
          if (schedule.final_interpolates) pre.interpolate = true;
        }
        if (eff.noise == NoiseMode::kOn && !clean_tangent)  // one-sided stencils: more points (noise.h)
          pre.boundary_points_factor = std::max(pre.boundary_points_factor, kNoiseNormalBoundaryPointsFactor);
        const auto pre_nb = std::make_shared<Neighborhoods>(BuildNeighborhoods(topo, *input, RingSpecFor(pre), ctx.threads()));
        if (clean_tangent) tangent_nb = pre_nb;
        SurfaceFits pre_fits;
        if (absl::Status s = FitAll(*input, topo, pre, pre_nb, *frame_normals, FitRequest{}, ctx, nullptr, nullptr, "normals",
                                    pre_fits);
            !s.ok())
          return s;
        fixed_tangent.assign(mesh.NumVertices(), 0);
        adopt_normals(pre_fits, &fixed_tangent);
        if (eff.noise == NoiseMode::kOn && schedule.normal_points_factor > 0) {  // heavy noise: noise.h
          pre.min_points_factor = schedule.normal_points_factor;
          SurfaceFits large;
          const auto large_nb = std::make_shared<Neighborhoods>(BuildNeighborhoods(topo, *input, RingSpecFor(pre), ctx.threads()));
          if (absl::Status s = FitAll(*input, topo, pre, large_nb, *frame_normals, FitRequest{}, ctx, nullptr, nullptr, "normals",
                                      large);
              !s.ok())
            return s;
          BlendLargeStencilNormals(large, fixed_tangent, &writable_normals(), ctx.threads());
        }
      }
      fits = std::make_shared<SurfaceFits>();
      // Slope refinement (slopes.h) after the final fit: its blocks are reported once refined.
      const bool slopes = last && (pass_options.SlopePasses() > 0 || pass_options.QuadraticHermite() || pass_options.CubicHermite() || pass_options.JetHermite()) &&
                          !req.stencils;
      const bool plane_slopes = last && pass_options.PlaneHermite() && !req.stencils;  // plane_slopes.h
      // The noise schedule's final fit from two stencil sets (noise.h).
      const bool blend = last && eff.noise == NoiseMode::kOn && schedule.two_scale_final && !req.stencils &&
                         pass_options.method == FitMethod::kLHF && (clean_tangent ? tangent_nb : smoothing_nb);
      // The cached point records while the geometry, normals and stencils are the cache's.
      const bool cached = input == &mesh && frame_normals == &inputs->normals && pass_nb.get() == cached_nb;
      if (absl::Status s = FitAll(*input, topo, pass_options, pass_nb, *frame_normals, req, ctx,
                                  last && !slopes && !plane_slopes && !blend ? &on_fitted : nullptr,
                                  fixed_tangent.empty() ? nullptr : fixed_tangent.data(), phase, *fits,
                                  cached ? &inputs->records : nullptr, consume ? &positions_read : nullptr,
                                  last ? windows : nullptr);
          !s.ok())
        return s;
      if (slopes) {
        GF_RETURN_IF_ERROR(RefineSlopes(*input, topo, *pass_nb, std::cos(pass_options.safeguard_angle_deg * M_PI / 180.0),
                                        pass_options.CubicHermite() ? kCubicSlopePasses : pass_options.SlopePasses(),
                                        ctx, fits->diagnostics_.data(),
                                        fits->frames_.data(), fits->coefficients_.data(), fits->num_coefficients(),
                                        pass_options.QuadraticHermite() ? kQuadraticSlopePasses : 0,
                                        pass_options.weight_epsilon));
        if (on_fitted) on_fitted(*fits, 0, mesh.NumVertices());
      }
      if (plane_slopes) {
        GF_RETURN_IF_ERROR(RefinePlaneNormals(*input, *pass_nb, std::cos(pass_options.safeguard_angle_deg * M_PI / 180.0),
                                              pass_options.weight_epsilon, ctx, fits->diagnostics_.data(),
                                              fits->frames_.data(), fits->coefficients_.data(), fits->num_coefficients()));
        if (on_fitted) on_fitted(*fits, 0, mesh.NumVertices());
      }
      if (blend) {
        SurfaceFits other;
        const std::shared_ptr<const Neighborhoods>& other_nb = clean_tangent ? tangent_nb : smoothing_nb;
        GF_RETURN_IF_ERROR(FitAll(*input, topo, pass_options, other_nb, *frame_normals, FitRequest{}, ctx, nullptr,
                                  fixed_tangent.empty() ? nullptr : fixed_tangent.data(), phase, other));
        TwoScaleFinalFit(*fits, other, *other_nb, kTwoScaleSpread, fits->coefficients_.data(), ctx.threads());
        if (on_fitted) on_fitted(*fits, 0, mesh.NumVertices());
      }
      if (scheduled && pass == 0 && schedule.local_passes > 0)
        local_smoothing = schedule.curvature_steps ? CurvatureSmoothingSteps(*fits, kTwoScaleSpread, ctx.threads())
                                                   : LocalSmoothingSteps(*fits, mesh, noise_over_h, ctx.threads());
      // Nearly clean: the smoothing and local passes' second degree (noise.h, BlendFootPoints).
      if (scheduled && pass < schedule.smoothing_passes + schedule.local_passes && schedule.smoothing_degree_high > 0) {
        NoiseSchedule high = schedule;
        high.smoothing_degree = schedule.smoothing_degree_high;
        const FitOptions ho = NoiseSmoothingOptions(eff, high);
        if (!high_nb) high_nb = std::make_shared<Neighborhoods>(BuildNeighborhoods(topo, mesh, RingSpecFor(ho), ctx.threads()));
        high_fits = std::make_shared<SurfaceFits>();
        GF_RETURN_IF_ERROR(FitAll(*input, topo, ho, high_nb, *frame_normals, FitRequest{}, ctx, nullptr, nullptr, phase,
                                  *high_fits));
      }
      // The same smoothing fits on grown stencils, blended with them per vertex (noise.h,
      // NoiseSmoothingPointsFactor).
      if (scheduled && pass < schedule.smoothing_passes + schedule.local_passes && schedule.smoothing_points_factor > 0) {
        FitOptions go = NoiseSmoothingOptions(eff, schedule);
        go.min_points_factor = schedule.smoothing_points_factor, go.max_points = kMaxStencil;
        if (!grown_nb) grown_nb = std::make_shared<Neighborhoods>(BuildNeighborhoods(topo, mesh, RingSpecFor(go), ctx.threads()));
        grown_fits = std::make_shared<SurfaceFits>();
        GF_RETURN_IF_ERROR(FitAll(*input, topo, go, grown_nb, *frame_normals, FitRequest{}, ctx, nullptr, nullptr, phase,
                                  *grown_fits));
      }
      // Moderate noise: the smoothing fits above cubic extrapolate the one-sided stencils
      // of the boundary (normal Linf 1.3x there, bench/README.md third round); cubic ones.
      if (eff.noise == NoiseMode::kOn && pass < smoothing && schedule.cubic_near_boundary && has_boundary) {
        NoiseSchedule cubic = schedule;
        cubic.smoothing_degree = 3;
        boundary_fits = std::make_shared<SurfaceFits>();
        if (absl::Status s = FitAll(*input, topo, NoiseSmoothingOptions(eff, cubic), pass_nb, *frame_normals, FitRequest{}, ctx,
                                    nullptr, nullptr, phase, *boundary_fits);
            !s.ok())
          return s;
      }
    }
    if (!req.keep_neighborhoods) fits->neighborhoods_.reset();
    return std::shared_ptr<const SurfaceFits>(std::move(fits));
  }

  // Whether a fit of `o` is one pass over the mesh's own stencils and normals (no noise
  // mode, smoothing, pre-fit or refinement; no comparison parametrization, which reads
  // faces): after its point records are made it reads neither the mesh nor the topology
  // (is_boundary aside).
  static bool PlainFit(const FitOptions& o) {
    return o.noise == NoiseMode::kOff && o.SmoothingPasses() == 0 && !o.two_pass && o.NormalDegree() <= o.degree &&
           o.SlopePasses() == 0 && !o.PlaneHermite() && !o.QuadraticHermite() && !o.CubicHermite() && !o.JetHermite() && (o.method == FitMethod::kLHF || o.method == FitMethod::kLOP);
  }

 private:
  static absl::Status FitAll(const Mesh& mesh, const Topology& topo, const FitOptions& o,
                             const std::shared_ptr<const Neighborhoods>& nb, const Positions& normals,
                             const FitRequest& req, const RunContext& ctx, const FittedBlockFn* on_fitted,
                             const uint8_t* fixed_tangent, std::string_view phase, SurfaceFits& f,
                             const PointRecords* cached_records = nullptr,
                             const std::function<void()>* positions_read = nullptr,
                             const FittedBlockFn* windows = nullptr) {
    const int nv = mesh.NumVertices();
    f.options_ = o;
    f.neighborhoods_ = nb;
    const int64_t stride = f.dims() * f.num_coefficients();
    if (req.stencils) {
      const int order = req.stencil_order < 0 ? o.degree : std::min(req.stencil_order, o.degree);
      f.stencil_rows_ = NumCoefficients(order);
      f.stencil_offsets_.resize(nv + 1);
      f.stencil_offsets_[0] = 0;
      for (int v = 0; v < nv; ++v)
        f.stencil_offsets_[v + 1] = f.stencil_offsets_[v] + static_cast<size_t>(f.stencil_rows_) * nb->Size(v);
      f.stencils_.assign(f.stencil_offsets_[nv], 0.0);
    }
    // Vertices in the topology's locality order (neighbouring stencils share cache
    // lines), unless blocks must be reported as index ranges: the stencils in that order
    // (the neighbourhoods', else ordered here), positions and normals copied in it.
    const bool local_order =
        !(on_fitted && *on_fitted) && !windows && static_cast<int>(topo.locality_order.size()) == nv;
    OrderedStencils own;
    if (local_order && static_cast<int>(nb->ordered.order.size()) != nv)
      own = OrderStencils(*nb, topo.locality_order, ctx.threads());
    const OrderedStencils* os = !local_order ? nullptr : own.empty() ? &nb->ordered : &own;
    // `cached_records` (MakePointRecords of this mesh and normals in nb->ordered's order)
    // when the caller has them.
    PointRecords own_records;
    const bool use_cached = cached_records && os == &nb->ordered && !cached_records->empty();
    if (!use_cached) own_records = MakePointRecords(mesh.positions, normals, os ? os->order.data() : nullptr, ctx.threads());
    const PointRecords& points = use_cached ? *cached_records : own_records;
    // Called once the records hold the positions and normals (`mesh.positions` and
    // `normals` are not read below; FitSurfaceOnce frees them here), before the arrays
    // below are allocated: they then take that memory.
    if (positions_read) (*positions_read)();
    // Frames, coefficients and diagnostics unwritten here (a serial pass over ~14 MB at
    // 87k vertices, degree 2, ~10% of a 1-thread run): the fit loop resets each vertex's.
    // `windows`: none for the whole mesh; each block's in its own window below.
    if (!windows) {
      f.frames_.resize(nv);
      f.coefficients_.resize(static_cast<size_t>(nv) * stride);
      f.diagnostics_.resize(nv);
    }
    const FitInput in{mesh, *nb, normals, o, std::cos(o.safeguard_angle_deg * M_PI / 180.0), topo,
                      points.data(), os ? os->rank.data() : nullptr, fixed_tangent,
                      fixed_tangent != nullptr && o.HermiteHessian()};
    const WlsSettings settings = SettingsFor(o, f.stencil_rows_);
    // Height fits without stencils, refinement or comparison solvers are set up in the
    // batched kernel's lanes (FitHeightsBatch).
    const bool lane_setup = req.batched_kernel && req.lane_setup && o.method == FitMethod::kLHF && !req.stencils &&
                            o.solver != WlsSolver::kSVD && !o.oscillation_safeguard && fixed_tangent == nullptr &&
                            WlsBatchNormalEquations();
    const HeightLanesInput hin{in.points, in.cos_cut};
    constexpr int64_t kGrain = 512;
    // Blocks of kGrain vertices in contiguous shares per thread (ChunkShares): a thread's
    // next block is the one whose point records it prefetches below.
    return ParallelForShares(nv, kGrain, ctx, [&](int64_t begin, int64_t end) {
      std::unique_ptr<FitBatch> batch(new FitBatch);  // default-initialized: no 800 KB memset
      HeightQueue heights;
      // Where the block's outputs go: f's rows, or (windows) the block's own window,
      // whose row 0 is vertex `first`.
      SurfaceFits window;
      SurfaceFits& g = windows ? window : f;
      const int64_t first = windows ? begin : 0;
      if (windows) {
        const int64_t rows = end - begin;
        window.options_ = o;
        window.first_ = static_cast<int>(first);
        window.frames_.resize(rows);
        window.coefficients_.resize(rows * stride);
        window.diagnostics_.resize(rows);
      }
      const auto vertex_at = [&](int64_t k) -> int64_t { return os ? os->order[k] : k; };
      // The lanes read their stencils in slots: the ordered ones, else (vertex order) the
      // neighbourhoods' own.
      const bool ordered_lanes = lane_setup && os;
      // Lanes are queued by stencil size (a stable counting sort of the block), so the
      // stencils of a batch differ little in size: few padded rows. Each lane's result
      // is independent of its batch.
      const int n = static_cast<int>(end - begin);
      int64_t walk[kGrain];
      if (lane_setup) {
        int at[kMaxStencil + 2] = {};
        const std::vector<int32_t>& offsets = os ? os->offsets : nb->offsets;
        const auto size_of = [&](int64_t k) { return std::min<int>(offsets[k + 1] - offsets[k], kMaxStencil); };
        for (int64_t k = begin; k < end; ++k) ++at[size_of(k) + 1];
        for (int c = 1; c <= kMaxStencil + 1; ++c) at[c] += at[c - 1];
        for (int64_t k = begin; k < end; ++k) walk[at[size_of(k)]++] = k;
      } else {
        for (int j = 0; j < n; ++j) walk[j] = begin + j;
      }
      for (int j = 0; j < n; ++j) {
        const int64_t k = walk[j];
        // Prefetch: the CSR offsets 16 vertices ahead, the stencil indices 8 ahead and
        // their slots 4 ahead (the neighbourhoods are in the input numbering, the walk in
        // locality order: each vertex's stencil is a random read). The ordered stencils
        // are read in sequence.
        if (!ordered_lanes && j + 16 < n) __builtin_prefetch(nb->offsets.data() + vertex_at(walk[j + 16]));
        if (j + 8 < n) {
          const int64_t w = vertex_at(walk[j + 8]);
          if (!ordered_lanes) {
            const int32_t* p = nb->Points(static_cast<int>(w));
            __builtin_prefetch(p);
            __builtin_prefetch(p + 16);
          }
          // Its outputs too (input numbering: random lines; a store that misses holds up
          // every later store).
          const char* fr = reinterpret_cast<const char*>(&g.frames_[w - first]);
          __builtin_prefetch(fr, 1);
          __builtin_prefetch(fr + sizeof(LocalFrame) - 1, 1);
          __builtin_prefetch(&g.diagnostics_[w - first], 1);
          const double* c = g.coefficients_.data() + (w - first) * stride;
          __builtin_prefetch(c, 1);
          __builtin_prefetch(c + stride - 1, 1);
          __builtin_prefetch(&topo.is_boundary[w]);
        }
        // The next block's point records, one a vertex: the lanes read this block's in
        // stencil-size order, which no hardware prefetcher follows.
        if (lane_setup && end + j < nv) __builtin_prefetch(in.points + end + j);
        if (!ordered_lanes && os && j + 4 < n) {
          const int w = static_cast<int>(vertex_at(walk[j + 4]));
          const int32_t* p = nb->Points(w);
          for (int i = 0, n = nb->Size(w); i < n; ++i) __builtin_prefetch(os->rank.data() + p[i]);
        }
        const int64_t v = vertex_at(k);
        const int64_t row = v - first;
        g.diagnostics_[row] = VertexDiagnostics{};
        if (topo.is_boundary[v]) g.diagnostics_[row].flags = kFlagBoundary;
        const FitOutput out{&g.frames_[row], g.coefficients_.data() + row * stride,
                            &g.diagnostics_[row], req.stencils ? f.stencils_.data() + f.stencil_offsets_[v] : nullptr,
                            f.stencil_rows_};
        if (lane_setup) {
          if (Eigen::Map<const Eigen::Vector3d>(in.points[os ? k : v].n).squaredNorm() != 0) {  // else isolated: below
            out.diag->degree_requested = static_cast<int8_t>(o.degree);
            const int32_t* points = os ? os->points.data() + os->offsets[k] : nb->Points(static_cast<int>(v));
            const int size = os ? os->offsets[k + 1] - os->offsets[k] : nb->Size(static_cast<int>(v));
            heights.lanes[heights.count] = HeightLane{static_cast<int>(os ? k : v), points, size, out.frame,
                                                      out.coefficients};
            heights.outs[heights.count] = out;
            heights.vertex[heights.count] = static_cast<int>(v);
            if (++heights.count == kWlsLanes) heights.Flush(in, hin, settings, *batch);
            continue;
          }
        }
        // A lane's frame and coefficients are written whole by FitHeightsBatch or, for the
        // lanes it leaves, by SetUpVertex and the solvers (SolveWls zeroes its output
        // first); the other paths start from reset outputs.
        g.frames_[row] = LocalFrame{};
        std::fill_n(g.coefficients_.data() + row * stride, stride, 0.0);
        const int slot = batch->count;
        if (!SetUpVertex(static_cast<int>(v), in, out, batch->problems[slot])) continue;
        batch->outs[slot] = out;
        batch->vertex[slot] = static_cast<int>(v);
        if (++batch->count == kWlsLanes) batch->Flush(in, settings, req.batched_kernel);
      }
      heights.Flush(in, hin, settings, *batch);
      batch->Flush(in, settings, req.batched_kernel);
      if (windows)
        (*windows)(window, begin, end);
      else if (on_fitted && *on_fitted)
        (*on_fitted)(f, begin, end);
    }, phase);
  }
};

absl::StatusOr<std::shared_ptr<const SurfaceFits>> FitSurface(
    const Mesh& mesh, const Topology& topo, const FitOptions& options,
    std::shared_ptr<const Neighborhoods> neighborhoods, const FitRequest& request, const RunContext& ctx,
    const FittedBlockFn& on_fitted) {
  return SurfaceFitter::Fit(mesh, topo, options, std::move(neighborhoods), request, ctx, on_fitted);
}

absl::StatusOr<std::shared_ptr<const SurfaceFits>> FitSurfaceOnce(Mesh mesh, Topology topo, const FitOptions& options,
                                                                   const FitRequest& request, const RunContext& ctx) {
  return SurfaceFitter::Fit(mesh, topo, options, nullptr, request, ctx, nullptr, &mesh, &topo);
}

absl::Status FitSurfaceOnceInBlocks(Mesh mesh, Topology topo, const FitOptions& options,
                                    const FittedBlockFn& on_block, const RunContext& ctx) {
  FitRequest request;
  request.keep_neighborhoods = false;
  const int nv = mesh.NumVertices();
  GF_ASSIGN_OR_RETURN(const auto fits,
                      SurfaceFitter::Fit(mesh, topo, options, nullptr, request, ctx, nullptr, &mesh, &topo, &on_block));
  // Off the plain path the fits are whole: one block.
  if (fits->num_vertices() == nv && nv > 0) on_block(*fits, 0, nv);
  return absl::OkStatus();
}

}  // namespace geomfit
