#pragma once
#include <cstdint>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace geomfit {

/// #V x 3 vertex positions, row-major (the wire and numpy layout).
using Positions = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
/// Positions without an owning copy: a Positions, or a Map over rows of 3 contiguous
/// doubles (a numpy array, say); other layouts are copied into a temporary.
using PositionsRef = Eigen::Ref<const Positions, 0, Eigen::OuterStride<3>>;
/// #F x 4 vertex indices, row-major; triangles have -1 in the last column. Faces are
/// counter-clockwise seen from outside, so normals point outward.
using Faces = Eigen::Matrix<int32_t, Eigen::Dynamic, 4, Eigen::RowMajor>;

/// A triangle, quad or mixed surface mesh. Plain data; see topology.h for adjacency
/// and validation.
struct Mesh {
  Positions positions;
  Faces faces;

  int NumVertices() const { return static_cast<int>(positions.rows()); }
  int NumFaces() const { return static_cast<int>(faces.rows()); }
  int FaceSize(int f) const { return faces(f, 3) < 0 ? 3 : 4; }
  /// The corners after and before corner c of face f (no integer division: hot loops).
  int32_t Next(int f, int c) const { return faces(f, c + 1 < FaceSize(f) ? c + 1 : 0); }
  int32_t Prev(int f, int c) const { return faces(f, c > 0 ? c - 1 : FaceSize(f) - 1); }
  bool HasQuads() const {
    for (int f = 0; f < NumFaces(); ++f)
      if (faces(f, 3) >= 0) return true;
    return false;
  }
};

/// Builds a Faces array from a #F x 3 triangle array.
inline Faces TrianglesToFaces(const Eigen::Matrix<int32_t, Eigen::Dynamic, 3, Eigen::RowMajor>& tris) {
  Faces f(tris.rows(), 4);
  f.leftCols<3>() = tris;
  f.col(3).setConstant(-1);
  return f;
}

}  // namespace geomfit
