#pragma once
#include <cstdint>
#include <memory>

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

/// The faces of a Mesh, shared by every copy of it: revisions of one upload (new positions,
/// same connectivity) and flow steps copy a pointer, not the array. Reading never copies;
/// writing goes through Mutable(), which copies first when another mesh shares the array
/// (copy-on-write), so a copy never sees another's edits.
class SharedFaces {
 public:
  SharedFaces() = default;
  SharedFaces(Faces f) : p_(std::make_shared<Faces>(std::move(f))) {}  // NOLINT: implicit on purpose
  template <typename Derived>
  SharedFaces(const Eigen::MatrixBase<Derived>& f) : SharedFaces(Faces(f)) {}  // NOLINT

  const Faces& get() const { return p_ ? *p_ : Empty(); }
  operator const Faces&() const { return get(); }  // NOLINT
  int32_t operator()(Eigen::Index f, Eigen::Index c) const { return (*p_)(f, c); }
  auto row(Eigen::Index f) const { return get().row(f); }
  Eigen::Index rows() const { return p_ ? p_->rows() : 0; }
  Eigen::Index cols() const { return 4; }
  Eigen::Index size() const { return p_ ? p_->size() : 0; }
  const int32_t* data() const { return get().data(); }

  /// The array, to write: a private copy first if another mesh shares it.
  Faces& Mutable() {
    if (!p_) {
      p_ = std::make_shared<Faces>(0, 4);
    } else if (p_.use_count() > 1) {
      p_ = std::make_shared<Faces>(*p_);
    }
    return *p_;
  }
  /// Equal contents (shared or not).
  bool operator==(const SharedFaces& other) const { return SharesWith(other) || get() == other.get(); }
  bool operator!=(const SharedFaces& other) const { return !(*this == other); }
  /// True when both refer to one array (tests and accounting).
  bool SharesWith(const SharedFaces& other) const { return p_ && p_ == other.p_; }

 private:
  static const Faces& Empty() {
    static const Faces empty(0, 4);
    return empty;
  }
  std::shared_ptr<Faces> p_;
};

/// A triangle, quad or mixed surface mesh. Plain data; see topology.h for adjacency
/// and validation.
struct Mesh {
  Positions positions;
  SharedFaces faces;

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
