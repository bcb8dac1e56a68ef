#include "server/assembly.h"

#include <cstring>

#include "absl/strings/str_cat.h"
#include "core/util/status_macros.h"
#include "proto/wire.h"

namespace geomfit::server {
namespace {

absl::Status TooManyVertices(int64_t n, int64_t limit) {
  return absl::ResourceExhaustedError(
      absl::StrCat("mesh has ", n, " vertices; this server accepts at most ", limit, " (--max-vertices)"));
}

}  // namespace

template <typename T, int kWidth>
absl::Status RowBuffer<T, kWidth>::Append(int64_t offset, const wire::ArrayView<T>& data, int64_t limit) {
  const int64_t rows = data.rows;
  const int64_t chunk = chunks_++;
  if (offset != this->rows()) {
    return absl::InvalidArgumentError(absl::StrCat(field_, " chunk ", chunk, ": ", offset_name_, " is ",
                                                   offset, ", expected ", this->rows(),
                                                   " (chunks must be contiguous and in order)"));
  }
  if (offset + rows > limit) {
    return absl::InvalidArgumentError(absl::StrCat(field_, " chunk ", chunk, ": rows ", offset, "..",
                                                   offset + rows - 1, " exceed the declared count ", limit));
  }
  const size_t old = values_.size();
  values_.resize(old + static_cast<size_t>(rows) * kWidth, T(-1));
  data.CopyRows(values_.data() + old, kWidth);
  return absl::OkStatus();
}

template class RowBuffer<double, 3>;
template class RowBuffer<int32_t, 4>;

absl::Status UploadAssembler::Add(const v1::UploadMeshRequest& request) {
  bytes_ += static_cast<int64_t>(request.ByteSizeLong());
  switch (request.chunk_case()) {
    case v1::UploadMeshRequest::kHeader: {
      if (has_header_) return absl::InvalidArgumentError("header: sent twice");
      const v1::MeshHeader& h = request.header();
      if (h.num_vertices() < 3) {
        return absl::InvalidArgumentError(absl::StrCat("header.num_vertices: ", h.num_vertices(), ", need at least 3"));
      }
      if (h.num_faces() < 1) {
        return absl::InvalidArgumentError(absl::StrCat("header.num_faces: ", h.num_faces(), ", need at least 1"));
      }
      if (h.num_vertices() > max_vertices_) return TooManyVertices(h.num_vertices(), max_vertices_);
      if (h.num_faces() > 4 * max_vertices_) {
        return absl::ResourceExhaustedError(absl::StrCat("mesh has ", h.num_faces(), " faces; this server accepts at most ",
                                                         4 * max_vertices_, " (4 x --max-vertices)"));
      }
      header_ = h;
      has_header_ = true;
      return absl::OkStatus();
    }
    case v1::UploadMeshRequest::kPositions: {
      if (!has_header_) return absl::InvalidArgumentError("positions chunk before the header (send the header first)");
      const v1::PositionsChunk& c = request.positions();
      GF_ASSIGN_OR_RETURN(auto m, wire::ViewDoubles(c.positions(), "positions", {3}));
      return positions_.Append(c.vertex_offset(), m, header_.num_vertices());
    }
    case v1::UploadMeshRequest::kFaces: {
      if (!has_header_) return absl::InvalidArgumentError("faces chunk before the header (send the header first)");
      const v1::FacesChunk& c = request.faces();
      GF_ASSIGN_OR_RETURN(auto m, wire::ViewInts(c.faces(), "faces", {3, 4}));
      return faces_.Append(c.face_offset(), m, header_.num_faces());
    }
    case v1::UploadMeshRequest::CHUNK_NOT_SET:
      break;
  }
  return absl::InvalidArgumentError("UploadMeshRequest: empty chunk (set header, positions or faces)");
}

absl::StatusOr<Mesh> UploadAssembler::Finish() const {
  if (!has_header_) return absl::InvalidArgumentError("upload stream ended without a header");
  if (positions_.rows() != header_.num_vertices()) {
    return absl::InvalidArgumentError(absl::StrCat("upload stream ended after ", positions_.rows(), " of ",
                                                   header_.num_vertices(), " vertices"));
  }
  if (faces_.rows() != header_.num_faces()) {
    return absl::InvalidArgumentError(absl::StrCat("upload stream ended after ", faces_.rows(), " of ",
                                                   header_.num_faces(), " faces"));
  }
  Mesh mesh;
  mesh.positions = Eigen::Map<const Positions>(positions_.values().data(), positions_.rows(), 3);
  mesh.faces = Eigen::Map<const Faces>(faces_.values().data(), faces_.rows(), 4);
  if (header_.face_kind() != v1::FACE_KIND_UNSPECIFIED && header_.face_kind() != wire::KindOf(mesh)) {
    return absl::InvalidArgumentError(absl::StrCat("header.face_kind is ", v1::FaceKind_Name(header_.face_kind()),
                                                   " but the faces are ", v1::FaceKind_Name(wire::KindOf(mesh))));
  }
  return mesh;
}

absl::Status PositionsAssembler::Add(const v1::UpdatePositionsRequest& request) {
  switch (request.chunk_case()) {
    case v1::UpdatePositionsRequest::kHeader: return AddHeader(request.header());
    case v1::UpdatePositionsRequest::kPositions: return AddPositions(request.positions());
    case v1::UpdatePositionsRequest::CHUNK_NOT_SET: break;
  }
  return absl::InvalidArgumentError("UpdatePositionsRequest: empty chunk (set header or positions)");
}

absl::Status PositionsAssembler::AddHeader(const v1::UpdateHeader& header) {
  bytes_ += static_cast<int64_t>(header.ByteSizeLong());
  if (has_header_) return absl::InvalidArgumentError("header: sent twice");
  if (header.mesh_id().empty()) return absl::InvalidArgumentError("header.mesh_id: empty");
  header_ = header;
  has_header_ = true;
  return absl::OkStatus();
}

absl::Status PositionsAssembler::AddPositions(const v1::PositionsChunk& chunk) {
  bytes_ += static_cast<int64_t>(chunk.ByteSizeLong());
  if (!has_header_) return absl::InvalidArgumentError("positions chunk before the header (send the header first)");
  GF_ASSIGN_OR_RETURN(auto m, wire::ViewDoubles(chunk.positions(), "positions", {3}));
  return positions_.Append(chunk.vertex_offset(), m, expected_ > 0 ? expected_ : max_vertices_);
}

absl::StatusOr<Positions> PositionsAssembler::Finish(int64_t num_vertices) const {
  if (!has_header_) return absl::InvalidArgumentError("update stream ended without a header");
  if (positions_.rows() != num_vertices) {
    return absl::InvalidArgumentError(absl::StrCat("update carried ", positions_.rows(),
                                                   " vertices; mesh '", header_.mesh_id(), "' has ",
                                                   num_vertices));
  }
  return Positions(Eigen::Map<const Positions>(positions_.values().data(), num_vertices, 3));
}

}  // namespace geomfit::server
