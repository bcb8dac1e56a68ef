#pragma once
#include <Eigen/Core>

#include "core/fitting/options.h"
#include "core/mesh/topology.h"

namespace geomfit {

/// Orthonormal right-handed local frame at a vertex: (t1, t2, normal), normal = t1 x t2.
struct LocalFrame {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  Eigen::Vector3d t1 = Eigen::Vector3d::UnitX(), t2 = Eigen::Vector3d::UnitY(),
                  normal = Eigen::Vector3d::UnitZ();
};

/// A frame whose normal is `n` (unit), with tangents chosen stably.
LocalFrame FrameFromNormal(const Eigen::Vector3d& origin, const Eigen::Vector3d& n);

/// Unit face normal (quads: cross product of the diagonals).
Eigen::Vector3d FaceNormal(const Mesh& mesh, int f);

/// Approximate unit vertex normals: area- or angle-weighted average of face normals.
/// Isolated vertices get (0, 0, 0).
Positions ApproximateVertexNormals(const Mesh& mesh, const Topology& topo,
                                   NormalWeighting weighting, int num_threads = 0);

}  // namespace geomfit
