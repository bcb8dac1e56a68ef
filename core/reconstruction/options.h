#pragma once
// What a reconstruction (WALF / CMF / linear surface, and everything built on it:
// projection, high-order nodes, refinement, integration) computes: one set of defaults,
// mirrored by the proto message v1::ReconstructionOptions and used by the server, the CLI
// and both clients.
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "core/fitting/options.h"

namespace geomfit {

enum class ReconstructionMethod { kLinear, kWalf, kCmf };
const char* ReconstructionMethodName(ReconstructionMethod m);

/// Ranges of the reconstruction commands' parameters.
inline constexpr int kMinRefineFactor = 2, kMaxRefineFactor = 8;
inline constexpr int kMinNodeOrder = 2, kMaxNodeOrder = 3;

/// Vertex fits for surfaces: degree 3 (WALF/CMF distance O(h^4), §4.1.5) with the
/// oscillation safeguard (§4.1.3) on.
FitOptions DefaultReconstructionFit();

struct ReconstructionOptions {
  FitOptions fit = DefaultReconstructionFit();
  ReconstructionMethod method = ReconstructionMethod::kWalf;
  /// Sharp features (§4.1.4): edges whose faces' normals turn by more than this many
  /// degrees (0 = off), plus user-marked edges (vertex pairs). Stencils never cross them.
  double feature_angle_deg = 0;
  std::vector<std::pair<int, int>> feature_edges;

  bool has_features() const { return feature_angle_deg > 0 || !feature_edges.empty(); }
  /// OK, or INVALID_ARGUMENT naming the field ("fit.degree", "feature_angle_deg").
  absl::Status Validate() const;
};

/// INVALID_ARGUMENT naming `field` unless lo <= value <= hi.
absl::Status CheckRange(const char* field, int64_t value, int64_t lo, int64_t hi);

}  // namespace geomfit
