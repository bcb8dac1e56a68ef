#pragma once
#include <vector>

#include "absl/status/status.h"
#include "core/reconstruction/surface.h"

namespace geomfit {

/// Finds the closest point of the linear mesh to query points: a uniform grid over the
/// vertices gives the nearest vertex, whose two-ring of faces is searched exactly.
class PointLocator {
 public:
  PointLocator(const Mesh& mesh, const Topology& topo);
  /// Closest face point of the linear (bilinear) mesh near x.
  FacePoint Closest(const Eigen::Vector3d& x) const;

 private:
  int NearestVertex(const Eigen::Vector3d& x) const;
  const Mesh& mesh_;
  const Topology& topo_;
  Eigen::Vector3d lo_;
  double cell_;
  Eigen::Vector3i dims_;
  std::vector<int32_t> cell_offsets_, cell_vertices_;
};

struct ProjectedPoint {
  FacePoint where;
  SurfacePoint point;
  double distance = 0;  ///< |input - projected|
};

/// Projects arbitrary points near the surface onto the reconstructed surface (4.2.3):
/// the closest point of the linear mesh, then Gauss-Newton on the face's natural
/// coordinates towards the closest point of the reconstructed surface (kept in the
/// face). INVALID_ARGUMENT names a non-finite input point. Polls `ctx` (phase "project").
absl::Status ProjectPoints(const ReconstructedSurface& surface, const Topology& topo, const Positions& points,
                           std::vector<ProjectedPoint>* out, const RunContext& ctx = {});

}  // namespace geomfit
