#pragma once
#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "absl/status/statusor.h"
#include "core/fitting/frames.h"
#include "core/fitting/neighborhood.h"
#include "core/fitting/options.h"
#include "core/util/run_context.h"
#include "core/util/uninitialized.h"

namespace geomfit {

/// Index of the Taylor coefficient c_jk (= d^{j+k} f / du^j dv^k at the origin) in the
/// degree-ordered basis u^j v^k / (j! k!) of (2.3.1): (0,0), (1,0), (0,1), (2,0), (1,1), ...
constexpr int TaylorIndex(int j, int k) { return (j + k) * (j + k + 1) / 2 + k; }

/// Per-vertex fit diagnostics flags (data, never an RPC failure).
enum FitFlag : uint8_t {
  kFlagTooFewPoints = 1,  ///< stencil smaller than #coefficients even after growth
  kFlagDowngraded = 2,    ///< the condition safeguard dropped one or more degrees
  kFlagBoundary = 4,      ///< vertex on the mesh boundary
  kFlagIsolated = 8,      ///< vertex in no face: no fit, quantities are NaN
  kFlagOscillation = 16,  ///< the oscillation safeguard (4.1.3) lowered the degree
};

struct VertexDiagnostics {
  int16_t points = 0;          ///< stencil points with nonzero weight (centre included)
  int8_t degree_requested = 0;
  int8_t degree_used = 0;      ///< after the condition safeguard (2.4)
  int16_t rank = 0;            ///< number of coefficients solved for
  uint8_t flags = 0;
  float condition = 0;         ///< 1-norm condition estimate of the scaled R
};

/// Position and first/second derivatives of a local parametrization x(u, v) at the
/// origin, in global coordinates (Table 3.1).
struct SurfaceJet {
  Eigen::Vector3d x;                 ///< x(0, 0)
  Eigen::Matrix<double, 3, 2> J;     ///< [x_u, x_v]
  Eigen::Vector3d xuu, xuv, xvv;
};

/// The weighted-least-squares fits of every vertex (2.2-2.4): immutable once built,
/// shared between requests (the server's fitting cache tier).
class SurfaceFits {
 public:
  const FitOptions& options() const { return options_; }
  /// Vertices stored: all of them, or a block's (FitSurfaceOnceInBlocks: first_vertex()
  /// on, and only those may be read).
  int num_vertices() const { return static_cast<int>(frames_.size()); }
  int first_vertex() const { return first_; }
  /// Values per coefficient: 1 for LHF (height), 3 for LOP (x, y, z).
  int dims() const { return options_.method == FitMethod::kLHF ? 1 : 3; }
  int num_coefficients() const { return NumCoefficients(options_.degree); }
  const LocalFrame& frame(int v) const { return frames_[v - first_]; }
  /// Coefficients of vertex v: dims() blocks of num_coefficients(), indexed by
  /// TaylorIndex, zero above the degree used. LHF: height over the frame; LOP:
  /// x, y, z relative to the frame origin. Derivatives are in frame units (u, v).
  const double* coefficients(int v) const {
    return coefficients_.data() + static_cast<size_t>(v - first_) * dims() * num_coefficients();
  }
  const VertexDiagnostics& diagnostics(int v) const { return diagnostics_[v - first_]; }
  const UninitializedVector<VertexDiagnostics>& diagnostics() const { return diagnostics_; }
  /// The stencils fitted over (unless FitRequest::keep_neighborhoods was false).
  const Neighborhoods& neighborhoods() const { return *neighborhoods_; }
  bool has_neighborhoods() const { return neighborhoods_ != nullptr; }
  /// Position and derivatives of vertex v's fit at its origin.
  SurfaceJet Jet(int v) const;
  /// Vertex v's fit evaluated at the orthogonal projection of `x` onto its frame's
  /// tangent plane: the point of the fitted surface and its (u, v) derivatives.
  struct LocalPoint {
    Eigen::Vector3d position, du, dv;
    Eigen::Vector3d normal;  ///< unit, du x dv / |du x dv|
  };
  LocalPoint Evaluate(int v, const Eigen::Vector3d& x) const;
  /// Stencil operators (if requested): coefficient i of vertex v's fit of any nodal
  /// field g over v's frame is sum_k stencil(v)[i * n + k] * g[points(v)[k]],
  /// with n = neighborhoods().Size(v), for i < stencil_rows(). The GFD operators of
  /// chapter 5 use these.
  bool has_stencils() const { return !stencil_offsets_.empty(); }
  /// Leading Taylor coefficients whose stencil rows are kept (FitRequest::stencil_order).
  int stencil_rows() const { return stencil_rows_; }
  const double* stencil(int v) const { return stencils_.data() + stencil_offsets_[v]; }
  size_t Bytes() const;

 private:
  friend class SurfaceFitter;
  FitOptions options_;
  std::shared_ptr<const Neighborhoods> neighborhoods_;
  // Sized without a serial fill: FitAll's threads write each vertex's (first touch).
  UninitializedVector<LocalFrame> frames_;
  UninitializedVector<double> coefficients_;
  UninitializedVector<VertexDiagnostics> diagnostics_;
  std::vector<size_t> stencil_offsets_;
  std::vector<double> stencils_;
  int stencil_rows_ = 0;
  int first_ = 0;  ///< the vertex of row 0 (a block's window; 0 for a whole fit)
};

/// What to build besides the fits.
struct FitRequest {
  bool stencils = false;  ///< also build the stencil operators
  /// Keep only the stencil rows of Taylor order <= this (2: value, first and second
  /// derivatives, what the GFD operators need); -1 keeps every row.
  int stencil_order = -1;
  /// Solve kWlsLanes vertices at once with the batched SIMD kernel (wls_batch.h); false
  /// solves every vertex with the scalar SolveWls (same results to round-off).
  bool batched_kernel = true;
  /// Height fits (LHF) without stencils set up in the batched kernel's lanes
  /// (FitHeightsBatch, wls_batch.h); false sets every vertex up as a WlsProblem first
  /// (tests: the same bits).
  bool lane_setup = true;
  /// Keep the stencils in the fits (SurfaceFits::neighborhoods()); false drops them once
  /// fitted (a caller that only evaluates quantities: their memory is reused).
  bool keep_neighborhoods = true;
};

/// Without this callback vertices are fitted in Topology::locality_order; with it, in
/// index blocks. Called once vertices [begin, end) of the final pass are fitted, from the fitting
/// thread(s): blocks arrive in any order, possibly concurrently. `fits` is still being
/// built; only the vertices of blocks already reported may be read. Lets a caller
/// evaluate and send results while the rest of the mesh is being fitted.
using FittedBlockFn = std::function<void(const SurfaceFits& fits, int64_t begin, int64_t end)>;

/// Fits every vertex. `neighborhoods` may be shared with other fits of the same
/// topology (pass the one built for RingSpecFor(options)); null builds it.
/// `ctx` gives the threads and is polled between blocks of vertices; progress phases (units:
/// blocks of 512 vertices) "noise test" (NoiseMode::kAuto; samples), "smooth i/S" per
/// smoothing pass, "frames" (two_pass's first fit), "normals" (FitOptions::normal_degree's pre-fit), then "fit" (the final pass).
/// Errors: INVALID_ARGUMENT for bad options or a mesh/topology mismatch,
/// CANCELLED / DEADLINE_EXCEEDED from the context.
absl::StatusOr<std::shared_ptr<const SurfaceFits>> FitSurface(
    const Mesh& mesh, const Topology& topo, const FitOptions& options,
    std::shared_ptr<const Neighborhoods> neighborhoods = nullptr, const FitRequest& request = {},
    const RunContext& ctx = {}, const FittedBlockFn& on_fitted = nullptr);

/// FitSurface of a mesh and its topology that nobody else needs (a one-off fit:
/// `geomfit curvature --local`), with the same results. On the plain path (one pass, no
/// noise mode, normal pre-fit or slope refinement, LHF or LOP) the fit frees what it no longer reads as soon as it can: the faces
/// and the topology's rows once the stencils' spans are built (the approximate normals
/// are computed before), the positions and normals once copied into the point records,
/// before the fit's own arrays are allocated, which then reuse that memory.
absl::StatusOr<std::shared_ptr<const SurfaceFits>> FitSurfaceOnce(Mesh mesh, Topology topo, const FitOptions& options,
                                                                   const FitRequest& request = {},
                                                                   const RunContext& ctx = {});

/// FitSurfaceOnce with the fits handed to `on_block` block by block and then dropped:
/// `fits` holds vertices [begin, end) alone (frame, coefficients and diagnostics of
/// those v; first_vertex() == begin), valid during the call; blocks of vertex indices in
/// any order, possibly concurrently. A caller that reduces each block to its own
/// results (`curvature --local`: EvaluateDifferentials) never holds the whole mesh's
/// frames and coefficients (~13 MB at 87k vertices, degree 2). Off FitSurfaceOnce's
/// plain path: one call with every vertex once the whole fit is done. Same results as
/// FitSurface.
absl::Status FitSurfaceOnceInBlocks(Mesh mesh, Topology topo, const FitOptions& options,
                                    const FittedBlockFn& on_block, const RunContext& ctx = {});

}  // namespace geomfit
