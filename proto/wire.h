#pragma once
// Conversions between geomfit.v1 wire messages and core types, shared by the server
// and the C++ client. Arrays are little-endian bytes plus a row-major shape.
#include <cstdint>
#include <cstring>
#include <initializer_list>
#include <vector>
#include "absl/strings/string_view.h"

#include <Eigen/Core>

#include "absl/status/statusor.h"
#include "core/fitting/fit.h"
#include "core/fitting/options.h"
#include "core/reconstruction/options.h"
#include "core/mesh/mesh.h"
#include "core/quantities/differentials.h"
#include "geomfit/v1/geomfit.pb.h"

namespace geomfit::wire {

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "wire arrays assume a little-endian host");

using RowsXd = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using RowsXi = Eigen::Matrix<int32_t, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

/// Writes rows x cols doubles (cols == 0: a 1-D array of `rows`).
void EncodeDoubles(const double* data, int64_t rows, int64_t cols, v1::DoubleArray* out);
void EncodeInts(const int32_t* data, int64_t rows, int64_t cols, v1::Int32Array* out);
/// Rows [begin, begin + rows) of a row-major Eigen array (a vector: 1-D).
template <typename Array>
void EncodeRows(const Array& a, int64_t begin, int64_t rows, v1::DoubleArray* out) {
  const int64_t cols = Array::ColsAtCompileTime == 1 ? 0 : a.cols();
  EncodeDoubles(a.data() + begin * (cols > 1 ? cols : 1), rows, cols, out);
}

/// A validated wire array, still in the message's bytes (which need not be aligned
/// for T, so read it with CopyTo or CopyRows).
template <typename T>
struct ArrayView {
  const char* bytes;
  int64_t rows, cols;
  void CopyTo(T* out) const { CopyRows(out, cols); }
  /// Row r goes to out + r * stride (stride >= cols; the rest of each row is untouched).
  void CopyRows(T* out, int64_t stride) const {
    if (stride == cols) {
      if (rows > 0) std::memcpy(out, bytes, sizeof(T) * static_cast<size_t>(rows * cols));
      return;
    }
    for (int64_t r = 0; r < rows; ++r) std::memcpy(out + r * stride, bytes + sizeof(T) * r * cols, sizeof(T) * cols);
  }
};

/// Checks a 2-D array whose column count must be one of `allowed_cols` (or a 1-D
/// array when allowed_cols is {0}) without copying it. Errors as DecodeDoubles.
absl::StatusOr<ArrayView<double>> ViewDoubles(const v1::DoubleArray& a, absl::string_view field,
                                              std::initializer_list<int64_t> allowed_cols);
absl::StatusOr<ArrayView<int32_t>> ViewInts(const v1::Int32Array& a, absl::string_view field,
                                            std::initializer_list<int64_t> allowed_cols);

/// Decodes a 2-D array whose column count must be one of `allowed_cols` (or a 1-D
/// array when allowed_cols is {0}). Errors name `field` and say what is wrong.
absl::StatusOr<RowsXd> DecodeDoubles(const v1::DoubleArray& a, absl::string_view field,
                                     std::initializer_list<int64_t> allowed_cols);
absl::StatusOr<RowsXi> DecodeInts(const v1::Int32Array& a, absl::string_view field,
                                  std::initializer_list<int64_t> allowed_cols);

/// Proto options (unset = default) -> core options; validated by ValidateFitOptions.
/// Unset fields take `base`'s values (the core defaults unless given).
absl::StatusOr<FitOptions> FromProto(const v1::FitOptions& p);
absl::StatusOr<FitOptions> FromProto(const v1::FitOptions& p, FitOptions base);
/// Unset fields take ReconstructionOptions' defaults; errors name the field
/// ("fit: ...", "method: ...", "feature_angle_deg ...").
absl::StatusOr<ReconstructionOptions> FromProto(const v1::ReconstructionOptions& p);
v1::ReconstructionOptions ToProto(const ReconstructionOptions& o);
v1::FitOptions ToProto(const FitOptions& o);

/// Quantity list -> core Quantity bit mask; empty = normals, H, K, k1/k2.
absl::StatusOr<uint32_t> QuantityMask(const google::protobuf::RepeatedField<int>& quantities);
void AddQuantities(uint32_t mask, v1::ComputeDifferentialsRequest* request);

/// Face kind of a mesh from its faces.
v1::FaceKind KindOf(const Mesh& mesh);

/// gRPC metadata key carrying the mesh id of every mesh-scoped call (and the id an
/// upload will get: MeshIdOf(MeshContentHash(...)), core/mesh/content_hash.h), for
/// cache-affine routers (deploy/router).
inline constexpr char kMeshIdMetadata[] = "x-mesh-id";

/// The UploadMesh stream of `mesh`: `header` (counts and kind filled in), then
/// positions and faces in chunks of at most `chunk_rows` rows. Pure-triangle meshes
/// send #F x 3 faces.
std::vector<v1::UploadMeshRequest> UploadChunks(const Mesh& mesh, v1::MeshHeader header, int64_t chunk_rows);
/// The UpdatePositions stream: header, then positions chunks.
std::vector<v1::UpdatePositionsRequest> UpdateChunks(PositionsRef positions, v1::UpdateHeader header,
                                                     int64_t chunk_rows);

/// Reassembles a ComputeDifferentials response stream into core arrays.
class DifferentialsReader {
 public:
  /// Errors (INVALID_ARGUMENT / DATA_LOSS) name the chunk and array that is wrong.
  absl::Status Add(const v1::ComputeDifferentialsResponse& chunk);
  /// The arrays; DATA_LOSS if the chunks did not cover every vertex.
  absl::StatusOr<Differentials> Finish();
  const v1::FitSummary& summary() const { return summary_; }

 private:
  v1::FitSummary summary_;
  bool started_ = false;
  int64_t rows_ = 0, chunks_ = 0;
  Differentials out_;
};

}  // namespace geomfit::wire
