#pragma once
// Reassembly of client-streamed meshes and positions. Chunks of each array must
// arrive in order (vertex_offset / face_offset = rows received so far), so a gap, an
// overlap or a truncated stream is reported with the offending offset.
#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/mesh/mesh.h"
#include "geomfit/v1/geomfit.pb.h"
#include "proto/wire.h"

namespace geomfit::server {

/// Rows of one array (positions: 3 doubles; faces: 4 ints, triangles padded with -1).
template <typename T, int kWidth>
class RowBuffer {
 public:
  RowBuffer(const char* field, const char* offset_name) : field_(field), offset_name_(offset_name) {}
  /// Appends the rows of `data` (width <= kWidth; short rows padded with -1); checks
  /// the offset and `limit`.
  absl::Status Append(int64_t offset, const wire::ArrayView<T>& data, int64_t limit);
  int64_t rows() const { return static_cast<int64_t>(values_.size()) / kWidth; }
  const std::vector<T>& values() const { return values_; }

 private:
  const char* field_;
  const char* offset_name_;
  int64_t chunks_ = 0;
  std::vector<T> values_;
};

/// Collects an UploadMesh stream: header first, then positions and faces chunks.
class UploadAssembler {
 public:
  explicit UploadAssembler(int64_t max_vertices) : max_vertices_(max_vertices) {}
  absl::Status Add(const v1::UploadMeshRequest& request);
  /// The complete mesh; INVALID_ARGUMENT if the header or any rows are missing.
  absl::StatusOr<Mesh> Finish() const;
  const v1::MeshHeader& header() const { return header_; }
  bool has_header() const { return has_header_; }
  /// What the stream will hold at most once the header is in: the declared rows, and
  /// the mesh Finish builds from them.
  int64_t DeclaredBytes() const { return 2 * (24 * header_.num_vertices() + 16 * header_.num_faces()); }
  int64_t bytes() const { return bytes_; }
  std::string mesh_id() const { return ""; }  ///< known only once stored

 private:
  const int64_t max_vertices_;
  bool has_header_ = false;
  v1::MeshHeader header_;
  int64_t bytes_ = 0;
  RowBuffer<double, 3> positions_{"positions", "vertex_offset"};
  RowBuffer<int32_t, 4> faces_{"faces", "face_offset"};
};

/// Collects an UpdatePositions stream: header first, then positions chunks.
class PositionsAssembler {
 public:
  explicit PositionsAssembler(int64_t max_vertices) : max_vertices_(max_vertices) {}
  absl::Status Add(const v1::UpdatePositionsRequest& request);
  absl::Status AddHeader(const v1::UpdateHeader& header);
  absl::Status AddPositions(const v1::PositionsChunk& chunk);
  /// The positions; INVALID_ARGUMENT if the header is missing or rows != num_vertices.
  absl::StatusOr<Positions> Finish(int64_t num_vertices) const;
  /// Every row received (the engine checks the count against its mesh).
  absl::StatusOr<Positions> Finish() const { return Finish(positions_.rows()); }
  const v1::UpdateHeader& header() const { return header_; }
  bool has_header() const { return has_header_; }
  /// The mesh has `num_vertices` (known once the header is in): more rows are refused.
  void Expect(int64_t num_vertices) { expected_ = num_vertices; }
  /// The expected rows and the positions Finish builds from them (0 before Expect).
  int64_t DeclaredBytes() const { return 2 * 24 * expected_; }
  int64_t bytes() const { return bytes_; }
  std::string mesh_id() const { return header_.mesh_id(); }

 private:
  const int64_t max_vertices_;
  int64_t expected_ = 0;  ///< 0: up to max_vertices
  bool has_header_ = false;
  v1::UpdateHeader header_;
  int64_t bytes_ = 0;
  RowBuffer<double, 3> positions_{"positions", "vertex_offset"};
};

}  // namespace geomfit::server
