// Mesh RPCs: upload, position updates, metadata, download, list, delete.
#include <algorithm>

#include "absl/strings/str_cat.h"
#include "core/util/status_macros.h"
#include "proto/wire.h"
#include "server/handlers/handlers.h"
#include "server/mesh_record.h"

namespace geomfit::server {
namespace {

MeshMeta MetaOf(const v1::MeshHeader& header) {
  MeshMeta meta;
  meta.name = header.name();
  meta.labels.insert(header.labels().begin(), header.labels().end());
  return meta;
}

std::optional<int64_t> ExpectedRevision(const v1::UpdateHeader& header) {
  if (!header.has_expected_revision()) return std::nullopt;
  return header.expected_revision();
}

absl::StatusOr<v1::MeshInfo> Wire(absl::StatusOr<MeshRecord> record) {
  if (!record.ok()) return record.status();
  return ToProto(*record);
}

}  // namespace

absl::Status RequireId(const std::string& id) {
  if (id.empty()) return absl::InvalidArgumentError("mesh_id: empty");
  return absl::OkStatus();
}

Handlers::Handlers(Workspace* workspace, const RequestStats* stats, HandlerOptions options)
    : ws_(workspace), stats_(stats), options_(options) {}

absl::StatusOr<v1::MeshInfo> Handlers::UploadMesh(const UploadAssembler& upload, const std::string& tenant) {
  GF_ASSIGN_OR_RETURN(Mesh mesh, upload.Finish());
  MeshMeta meta = MetaOf(upload.header());
  meta.tenant = tenant;
  return Wire(ws_->AddMesh(std::move(mesh), meta));
}

absl::StatusOr<v1::MeshInfo> Handlers::UpdatePositions(const PositionsAssembler& update) {
  if (!update.has_header()) return absl::InvalidArgumentError("update stream ended without a header");
  GF_ASSIGN_OR_RETURN(Positions positions, update.Finish());
  return Wire(ws_->UpdatePositions(update.header().mesh_id(), ExpectedRevision(update.header()), std::move(positions)));
}

absl::Status Handlers::ExpectPositions(PositionsAssembler* update) {
  GF_ASSIGN_OR_RETURN(const MeshRecord info, ws_->Info(update->header().mesh_id()));
  update->Expect(info.num_vertices);
  return absl::OkStatus();
}

absl::StatusOr<v1::MeshInfo> Handlers::SetPositions(const v1::SetPositionsRequest& request) {
  const v1::UpdateHeader& header = request.header();
  if (header.mesh_id().empty()) return absl::InvalidArgumentError("header.mesh_id: empty");
  if (request.positions().vertex_offset() != 0)
    return absl::InvalidArgumentError(absl::StrCat("positions.vertex_offset is ", request.positions().vertex_offset(),
                                                   ", expected 0 (SetPositions carries every vertex)"));
  GF_ASSIGN_OR_RETURN(const auto view, wire::ViewDoubles(request.positions().positions(), "positions", {3}));
  if (view.rows > options_.max_vertices)
    return absl::InvalidArgumentError(absl::StrCat("positions: ", view.rows, " rows exceed --max-vertices (",
                                                   options_.max_vertices, ")"));
  Positions positions(view.rows, 3);
  view.CopyTo(positions.data());  // straight from the message into the new revision
  return Wire(ws_->UpdatePositions(header.mesh_id(), ExpectedRevision(header), std::move(positions)));
}

absl::StatusOr<v1::MeshInfo> Handlers::GetMesh(const v1::GetMeshRequest& request) {
  GF_RETURN_IF_ERROR(RequireId(request.mesh_id()));
  return Wire(ws_->Info(request.mesh_id()));
}

namespace {

/// Info, then positions chunks, then faces chunks of `rows` rows, each encoded when asked.
class DownloadSource final : public ChunkSource<v1::DownloadMeshResponse> {
 public:
  DownloadSource(StoredMesh stored, int64_t rows) : stored_(std::move(stored)), rows_(rows) {}
  bool Next(v1::DownloadMeshResponse* chunk) override {
    chunk->Clear();
    const Mesh& mesh = *stored_.mesh;
    if (!sent_info_) {
      sent_info_ = true;
      *chunk->mutable_info() = ToProto(stored_.info);
      return true;
    }
    if (vertex_ < mesh.NumVertices()) {
      const int64_t n = std::min<int64_t>(rows_, mesh.NumVertices() - vertex_);
      v1::PositionsChunk* c = chunk->mutable_positions();
      c->set_vertex_offset(vertex_);
      wire::EncodeDoubles(mesh.positions.data() + 3 * vertex_, n, 3, c->mutable_positions());
      vertex_ += n;
      return true;
    }
    if (face_ < mesh.NumFaces()) {
      const int64_t n = std::min<int64_t>(rows_, mesh.NumFaces() - face_);
      v1::FacesChunk* c = chunk->mutable_faces();
      c->set_face_offset(face_);
      wire::EncodeInts(mesh.faces.data() + 4 * face_, n, 4, c->mutable_faces());
      face_ += n;
      return true;
    }
    return false;
  }

 private:
  const StoredMesh stored_;
  const int64_t rows_;
  bool sent_info_ = false;
  int64_t vertex_ = 0, face_ = 0;
};

}  // namespace

absl::StatusOr<std::unique_ptr<ChunkSource<v1::DownloadMeshResponse>>> Handlers::OpenDownload(
    const v1::DownloadMeshRequest& request) {
  GF_RETURN_IF_ERROR(RequireId(request.mesh_id()));
  if (request.revision() < 0 || request.chunk_rows() < 0) {
    return absl::InvalidArgumentError("revision and chunk_rows must not be negative");
  }
  GF_ASSIGN_OR_RETURN(StoredMesh stored, ws_->Stored(request.mesh_id(), request.revision()));
  return std::make_unique<DownloadSource>(std::move(stored), ChunkRows(request.chunk_rows(), 24));
}

absl::StatusOr<std::vector<v1::DownloadMeshResponse>> Handlers::DownloadMesh(
    const v1::DownloadMeshRequest& request) {
  GF_ASSIGN_OR_RETURN(auto source, OpenDownload(request));
  std::vector<v1::DownloadMeshResponse> out(1);
  while (source->Next(&out.back())) out.emplace_back();
  out.pop_back();
  return out;
}

absl::StatusOr<v1::ListMeshesResponse> Handlers::ListMeshes(const v1::ListMeshesRequest& request) {
  if (request.page_size() < 0 || request.page_size() > 1000) {
    return absl::InvalidArgumentError(absl::StrCat("page_size: ", request.page_size(), ", expected 0..1000"));
  }
  const int page = request.page_size() == 0 ? 100 : request.page_size();
  GF_ASSIGN_OR_RETURN(std::vector<MeshRecord> meshes, ws_->List(request.page_token(), page + 1));
  v1::ListMeshesResponse response;
  // Pages end by count or by bytes (half the message limit), whichever comes first.
  const int64_t budget = options_.max_message_bytes / 2;
  int64_t bytes = 0;
  for (int i = 0; i < static_cast<int>(meshes.size()) && i < page; ++i) {
    v1::MeshInfo info = ToProto(meshes[i]);
    bytes += static_cast<int64_t>(info.ByteSizeLong()) + 8;
    if (i > 0 && bytes > budget) break;
    *response.add_meshes() = std::move(info);
  }
  if (static_cast<int>(meshes.size()) > response.meshes_size()) {
    response.set_next_page_token(response.meshes(response.meshes_size() - 1).mesh_id());
  }
  return response;
}

absl::StatusOr<v1::DeleteMeshResponse> Handlers::DeleteMesh(const v1::DeleteMeshRequest& request) {
  GF_RETURN_IF_ERROR(RequireId(request.mesh_id()));
  GF_RETURN_IF_ERROR(ws_->Delete(request.mesh_id()));
  return v1::DeleteMeshResponse();
}

}  // namespace geomfit::server
