// Chapter-4 RPCs: ProjectPoints, HighOrderNodes, RefineMesh. The surface is rebuilt per
// request from cached vertex fits (WALF evaluation is cheap; CMF solves per point).
#include <algorithm>
#include <memory>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/reconstruction/meshing.h"
#include "core/reconstruction/projection.h"
#include "core/util/status_macros.h"
#include "proto/wire.h"
#include "server/handlers/handlers.h"
#include "server/handlers/progress.h"
#include "server/mesh_record.h"

namespace geomfit::server {

absl::StatusOr<Snapshot> Handlers::Acquire(const std::string& id, int64_t revision) {
  GF_RETURN_IF_ERROR(RequireId(id));
  if (revision < 0) return absl::InvalidArgumentError("revision must not be negative");
  return ws_->Acquire(id, revision);
}

absl::StatusOr<std::unique_ptr<Reconstructed>> Handlers::Reconstruct(const std::string& id, int64_t revision,
                                                                     const v1::ReconstructionOptions& options,
                                                                     bool stencils, const RunContext& ctx) {
  absl::StatusOr<ReconstructionOptions> ro = wire::FromProto(options);
  if (!ro.ok()) return absl::InvalidArgumentError(absl::StrCat("options.", ro.status().message()));
  GF_ASSIGN_OR_RETURN(const Snapshot snap, Acquire(id, revision));  // held to the end
  return ws_->Reconstruct(snap, *ro, stencils, ctx);
}

absl::Status Handlers::ProjectPoints(const v1::ProjectPointsRequest& request, const CancellationToken& cancel,
                                     ChunkSink<v1::ProjectPointsResponse>* sink) {
  GF_RETURN_IF_ERROR(RequireId(request.mesh_id()));
  if (request.chunk_rows() < 0) return absl::InvalidArgumentError("chunk_rows must not be negative");
  const bool xyz = request.points().shape_size() > 0;
  const bool face_points = request.faces().shape_size() > 0 || request.natural().shape_size() > 0;
  if (xyz == face_points)
    return absl::InvalidArgumentError("give either points (#P x 3) or faces (#P) with natural (#P x 2)");
  std::vector<ProjectedPoint> out;
  // Progress messages go out while the work runs, before any result chunk.
  ProgressThrottle throttle(ProgressMessages(sink));
  const RunContext ctx = Context(cancel, request.progress() ? throttle.Callback() : nullptr);
  GF_ASSIGN_OR_RETURN(auto r, Reconstruct(request.mesh_id(), request.revision(), request.options(), false, ctx));
  if (xyz) {
    GF_ASSIGN_OR_RETURN(const wire::RowsXd p, wire::DecodeDoubles(request.points(), "points", {3}));
    GF_RETURN_IF_ERROR(geomfit::ProjectPoints(*r->surface, *r->snapshot.topology, Positions(p), &out, ctx));
  } else {
    GF_ASSIGN_OR_RETURN(const wire::RowsXi f, wire::DecodeInts(request.faces(), "faces", {0}));
    GF_ASSIGN_OR_RETURN(const wire::RowsXd n, wire::DecodeDoubles(request.natural(), "natural", {2}));
    if (f.size() != n.rows())
      return absl::InvalidArgumentError(absl::StrFormat("faces has %d entries but natural has %d rows", f.size(), n.rows()));
    std::vector<FacePoint> fp(n.rows());
    for (Eigen::Index i = 0; i < n.rows(); ++i) fp[i] = {f.data()[i], n(i, 0), n(i, 1)};
    std::vector<SurfacePoint> sp;
    GF_RETURN_IF_ERROR(EvaluatePoints(*r->surface, fp, &sp, ctx));
    out.resize(sp.size());
    for (size_t i = 0; i < sp.size(); ++i) out[i] = {fp[i], sp[i], 0.0};
  }
  GF_RETURN_IF_ERROR(cancel.Check());
  const int64_t n = static_cast<int64_t>(out.size());
  const int64_t rows = ChunkRows(request.chunk_rows(), 8 * 9 + 4);
  auto points = std::make_shared<const std::vector<ProjectedPoint>>(std::move(out));
  PushRows(sink, std::move(points), n, rows, [](const std::vector<ProjectedPoint>& out, int64_t b, int64_t m) {
    v1::ProjectPointsResponse c;
    c.set_offset(b);
    wire::RowsXd pos(m, 3), nrm(m, 3), nat(m, 2), dist(m, 1);
    std::vector<int32_t> faces(m);
    for (int64_t i = 0; i < m; ++i) {
      const ProjectedPoint& q = out[b + i];
      pos.row(i) = q.point.position.transpose();
      nrm.row(i) = q.point.normal.transpose();
      nat.row(i) << q.where.xi, q.where.eta;
      dist(i, 0) = q.distance;
      faces[i] = q.where.face;
    }
    wire::EncodeDoubles(pos.data(), m, 3, c.mutable_positions());
    wire::EncodeDoubles(nrm.data(), m, 3, c.mutable_normals());
    wire::EncodeDoubles(nat.data(), m, 2, c.mutable_natural());
    wire::EncodeDoubles(dist.data(), m, 0, c.mutable_distances());
    wire::EncodeInts(faces.data(), m, 0, c.mutable_faces());
    return c;
  });
  return absl::OkStatus();
}

absl::StatusOr<v1::HighOrderNodesResponse> Handlers::HighOrderNodes(const v1::HighOrderNodesRequest& request,
                                                                    const CancellationToken& cancel,
                                                                    const RunContext::ProgressFn& progress) {
  GF_RETURN_IF_ERROR(RequireId(request.mesh_id()));
  const int order = request.order() == 0 ? kMinNodeOrder : request.order();
  GF_RETURN_IF_ERROR(CheckRange("order", order, kMinNodeOrder, kMaxNodeOrder));
  const RunContext ctx = Context(cancel, progress);
  GF_ASSIGN_OR_RETURN(auto r, Reconstruct(request.mesh_id(), request.revision(), request.options(), false, ctx));
  GF_ASSIGN_OR_RETURN(const HighOrderMesh ho, MakeHighOrderMesh(*r->surface, *r->snapshot.topology, order, ctx));
  GF_RETURN_IF_ERROR(cancel.Check());
  v1::HighOrderNodesResponse out;
  out.set_order(order);
  wire::EncodeDoubles(ho.nodes.data(), ho.nodes.rows(), 3, out.mutable_nodes());
  wire::EncodeInts(ho.offsets.data(), static_cast<int64_t>(ho.offsets.size()), 0, out.mutable_offsets());
  wire::EncodeInts(ho.elements.data(), static_cast<int64_t>(ho.elements.size()), 0, out.mutable_elements());
  if (static_cast<int64_t>(out.ByteSizeLong()) > options_.max_message_bytes)
    return absl::ResourceExhaustedError(absl::StrFormat(
        "the high-order mesh takes %d bytes, above the message limit of %d", out.ByteSizeLong(), options_.max_message_bytes));
  return out;
}

absl::StatusOr<v1::MeshInfo> Handlers::RefineMesh(const v1::RefineMeshRequest& request,
                                                  const CancellationToken& cancel,
                                                  const RunContext::ProgressFn& progress) {
  GF_RETURN_IF_ERROR(RequireId(request.mesh_id()));
  const int factor = request.factor() == 0 ? kMinRefineFactor : request.factor();
  GF_RETURN_IF_ERROR(CheckRange("factor", factor, kMinRefineFactor, kMaxRefineFactor));
  const RunContext ctx = Context(cancel, progress);
  GF_ASSIGN_OR_RETURN(auto r, Reconstruct(request.mesh_id(), request.revision(), request.options(), false, ctx));
  if (static_cast<int64_t>(r->snapshot.mesh->NumFaces()) * factor * factor > options_.max_vertices)
    return absl::ResourceExhaustedError(absl::StrFormat("refining %d faces by %d would exceed --max-vertices (%d)",
                                                        r->snapshot.mesh->NumFaces(), factor, options_.max_vertices));
  GF_ASSIGN_OR_RETURN(Mesh refined, geomfit::RefineMesh(*r->surface, *r->snapshot.topology, factor, ctx));
  GF_RETURN_IF_ERROR(cancel.Check());
  MeshMeta meta;
  GF_ASSIGN_OR_RETURN(const MeshRecord source, ws_->Info(request.mesh_id()));
  meta.name = request.name().empty() ? absl::StrCat(source.name, " refined x", factor) : request.name();
  meta.tenant = TenantOfId(request.mesh_id());  // a derived mesh is its source's tenant's
  meta.labels["refined_from"] = request.mesh_id().substr(TenantPrefix(meta.tenant).size());
  GF_ASSIGN_OR_RETURN(MeshRecord stored, ws_->AddMesh(std::move(refined), meta));
  return ToProto(stored);
}

}  // namespace geomfit::server
