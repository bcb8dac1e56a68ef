#pragma once
#include <cmath>

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

/// The tangents of FrameFromNormal for the unit normal (n0, n1, n2), as scalars (also
/// used in vector lanes, core/fitting/slopes.cc).
inline void FrameTangents(double n0, double n1, double n2, double& t1x, double& t1y, double& t1z, double& t2x,
                          double& t2y, double& t2z) {
  const double a0 = std::abs(n0), a1 = std::abs(n1), a2 = std::abs(n2);
  const int axis = a1 < a0 ? (a2 < a1 ? 2 : 1) : (a2 < a0 ? 2 : 0);
  const double s = axis == 0 ? n0 : axis == 1 ? n1 : n2;  // a.dot(n), exact
  const double t0 = (axis == 0 ? 1.0 : 0.0) - s * n0, t1 = (axis == 1 ? 1.0 : 0.0) - s * n1,
               t2 = (axis == 2 ? 1.0 : 0.0) - s * n2;
  const double z = t0 * t0 + t1 * t1 + t2 * t2;
  const double r = z > 0 ? std::sqrt(z) : 1.0;
  t1x = z > 0 ? t0 / r : t0, t1y = z > 0 ? t1 / r : t1, t1z = z > 0 ? t2 / r : t2;
  t2x = n1 * t1z - n2 * t1y, t2y = n2 * t1x - n0 * t1z, t2z = n0 * t1y - n1 * t1x;
}

/// A frame whose normal is `n` (unit), with tangents chosen stably: t1 from the
/// coordinate axis least aligned with n (the first of equals), t2 = n x t1. Inline and
/// scalar (a call per fitted vertex): the operations of Eigen's
/// `(a - a.dot(n) * n).normalized()` and `n.cross(t1)` in their order, so the same bits.
inline LocalFrame FrameFromNormal(const Eigen::Vector3d& origin, const Eigen::Vector3d& n) {
  LocalFrame fr;
  fr.origin = origin;
  fr.normal = n;
  FrameTangents(n[0], n[1], n[2], fr.t1[0], fr.t1[1], fr.t1[2], fr.t2[0], fr.t2[1], fr.t2[2]);
  return fr;
}

/// Unit face normal (quads: cross product of the diagonals).
Eigen::Vector3d FaceNormal(const Mesh& mesh, int f);

/// Approximate unit vertex normals: area- or angle-weighted average of face normals.
/// Isolated vertices get (0, 0, 0).
Positions ApproximateVertexNormals(const Mesh& mesh, const Topology& topo,
                                   NormalWeighting weighting, int num_threads = 0);

}  // namespace geomfit
