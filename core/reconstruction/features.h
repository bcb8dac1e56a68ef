#pragma once
#include <map>
#include <memory>
#include <vector>

#include "absl/status/statusor.h"
#include "core/reconstruction/surface.h"

namespace geomfit {

/// Sharp features (4.1.4): feature edges, the mesh split virtually along them, and the
/// ridge curves between corners.
struct FeatureOptions {
  double angle_deg = 45;  ///< an edge is a feature if its faces' normals differ by more
  /// User-marked feature edges (vertex pairs), in addition to the angle test.
  std::vector<std::pair<int32_t, int32_t>> marked;
};

struct Features {
  /// Sorted feature edges (lo, hi).
  std::vector<std::pair<int32_t, int32_t>> edges;
  /// Per vertex: number of incident feature edges (0 smooth, 2 ridge, else corner).
  std::vector<int32_t> valence;
  /// Ridge curves: vertex chains split at corners (closed loops repeat their first vertex).
  std::vector<std::vector<int32_t>> curves;
  /// The mesh split along feature edges: vertices on ridges are duplicated per side,
  /// so stencils never cross a ridge; faces keep their ids.
  Mesh split;
  std::vector<int32_t> split_to_original;  ///< split vertex -> original vertex
  bool IsFeature(int a, int b) const;
};

/// Detects feature edges and builds the split mesh and the ridge curves. Errors name a
/// marked edge that is not an edge of the mesh.
absl::StatusOr<Features> DetectFeatures(const Mesh& mesh, const Topology& topo, const FeatureOptions& options);

/// A reconstruction that respects features: faces are evaluated on a surface built
/// from the split mesh (one-sided fits), and points on feature edges on the ridge
/// curves, reconstructed by one-dimensional fits of degree `degree` blended linearly
/// along each edge (WALF for curves), so the two sides of a ridge meet exactly. Inside
/// a face with a feature edge the edge's offset from the one-sided surface is blended
/// in, linearly fading towards the opposite corner (a curved-edge element map), so the
/// face follows the ridge curve and its integrals do too (4.3).
class FeatureSurface final : public ReconstructedSurface {
 public:
  /// `surface` must be built over `features.split` (which must outlive this object).
  FeatureSurface(const Mesh& mesh, std::shared_ptr<const Features> features,
                 std::unique_ptr<ReconstructedSurface> surface, int degree);
  SurfacePoint Evaluate(const FacePoint& p) const override;
  const Mesh& mesh() const override { return mesh_; }
  /// The surface over `features().split` that evaluates every point off feature edges.
  const ReconstructedSurface& inner() const { return *surface_; }
  const Features& features() const { return *features_; }

 private:
  // Point at parameter t in [0, 1] along ridge edge a -> b, and optionally d/dt.
  Eigen::Vector3d CurvePoint(int a, int b, double t, Eigen::Vector3d* dt = nullptr) const;
  const Mesh& mesh_;
  std::shared_ptr<const Features> features_;
  std::unique_ptr<ReconstructedSurface> surface_;
  int degree_;
  // Per ridge vertex: curve fit in a frame (origin, tangent) with coefficients of the
  // two normal-plane offsets as polynomials of the tangential coordinate.
  struct CurveFit {
    Eigen::Vector3d origin, tangent, n1, n2;
    double c1[kMaxDegree + 1] = {0}, c2[kMaxDegree + 1] = {0};
    int degree = 0;
  };
  std::map<std::pair<int, int>, CurveFit> fits_;  // (node, neighbour along its curve) -> fit
};

}  // namespace geomfit
