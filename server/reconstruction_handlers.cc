// Chapter-4 RPCs: ProjectPoints, HighOrderNodes, RefineMesh, Integrate. The surface is
// rebuilt per request from cached vertex fits (WALF evaluation is cheap; CMF solves
// per point).
#include <algorithm>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/integration/integrate.h"
#include "core/reconstruction/features.h"
#include "core/reconstruction/meshing.h"
#include "core/reconstruction/projection.h"
#include "core/util/status_macros.h"
#include "proto/wire.h"
#include "server/handlers.h"

namespace geomfit::server {

/// A request's surface and everything it holds on to.
struct Handlers::Reconstructed {
  std::shared_ptr<const Mesh> mesh;
  std::shared_ptr<const Topology> topo;
  std::shared_ptr<const Features> features;  // with sharp features: fits are of the split mesh
  std::shared_ptr<const Topology> split_topo;
  std::shared_ptr<const SurfaceFits> fits;
  std::unique_ptr<ReconstructedSurface> surface;
  int64_t revision = 0;
};

namespace {

absl::StatusOr<ReconstructionMethod> MethodOf(v1::Reconstruction r) {
  switch (r) {
    case v1::RECONSTRUCTION_UNSPECIFIED:
    case v1::RECONSTRUCTION_WALF: return ReconstructionMethod::kWalf;
    case v1::RECONSTRUCTION_CMF: return ReconstructionMethod::kCmf;
    case v1::RECONSTRUCTION_LINEAR: return ReconstructionMethod::kLinear;
    default: break;
  }
  return absl::InvalidArgumentError(absl::StrCat("options.method: unknown reconstruction ", static_cast<int>(r)));
}

absl::Status CheckRevision(int64_t revision) {
  return revision < 0 ? absl::InvalidArgumentError("revision must not be negative") : absl::OkStatus();
}

}  // namespace

absl::StatusOr<std::unique_ptr<Handlers::Reconstructed>> Handlers::Reconstruct(
    const std::string& id, int64_t revision, const v1::ReconstructionOptions& ro, bool stencils,
    const CancellationToken& cancel) {
  GF_RETURN_IF_ERROR(CheckRevision(revision));
  GF_ASSIGN_OR_RETURN(const ReconstructionMethod method, MethodOf(ro.method()));
  absl::StatusOr<FitOptions> parsed = wire::FromProto(ro.fit());
  if (!parsed.ok()) return absl::InvalidArgumentError(absl::StrCat("options.fit: ", parsed.status().message()));
  FitOptions options = *parsed;
  options.num_threads = options_.threads;
  if (!ro.fit().has_oscillation_safeguard()) options.oscillation_safeguard = true;  // (4.1.3) for surfaces
  if (!(ro.feature_angle_deg() >= 0 && ro.feature_angle_deg() <= 180))
    return absl::InvalidArgumentError(absl::StrFormat("options.feature_angle_deg = %g is out of range [0, 180]",
                                                      ro.feature_angle_deg()));
  auto r = std::make_unique<Reconstructed>();
  const bool features = ro.feature_angle_deg() > 0 || ro.feature_edges().shape_size() > 0;
  if (!features) {
    GF_ASSIGN_OR_RETURN(Fitted f, Fit(id, revision, options, cancel, stencils));
    r->revision = f.revision;
    r->fits = f.fits;
    GF_ASSIGN_OR_RETURN(r->mesh, Geometry(id, f.revision, &r->revision));
    GF_ASSIGN_OR_RETURN(r->topo, TopologyOf(id, *r->mesh));
    r->surface = MakeSurface(method, *r->mesh, r->fits);
    return r;
  }
  // Sharp features (4.1.4): split the mesh along them and fit the split mesh; the
  // fits are cached under a key naming the features.
  GF_ASSIGN_OR_RETURN(r->mesh, Geometry(id, revision, &r->revision));
  GF_ASSIGN_OR_RETURN(r->topo, TopologyOf(id, *r->mesh));
  FeatureOptions fo;
  fo.angle_deg = ro.feature_angle_deg() > 0 ? ro.feature_angle_deg() : 180;
  if (ro.feature_edges().shape_size() > 0) {
    GF_ASSIGN_OR_RETURN(const wire::RowsXi e, wire::DecodeInts(ro.feature_edges(), "options.feature_edges", {2}));
    for (Eigen::Index i = 0; i < e.rows(); ++i) fo.marked.emplace_back(e(i, 0), e(i, 1));
  }
  GF_ASSIGN_OR_RETURN(Features detected, DetectFeatures(*r->mesh, *r->topo, fo));
  r->features = std::make_shared<const Features>(std::move(detected));
  GF_ASSIGN_OR_RETURN(Topology split, BuildTopology(r->features->split));
  r->split_topo = std::make_shared<const Topology>(std::move(split));
  std::string edges_key;
  for (auto [a, b] : r->features->edges) absl::StrAppend(&edges_key, a, "-", b, ",");
  const std::string key = absl::StrCat(id, "/r", r->revision, "/featfit/", std::hash<std::string>()(edges_key), "/",
                                       FitOptionsKey(options), stencils ? "/stencils" : "");
  GF_ASSIGN_OR_RETURN(
      r->fits, cache_->Get<SurfaceFits>(
                   Tier::kFitting, key,
                   [&]() -> absl::StatusOr<std::pair<std::shared_ptr<const SurfaceFits>, int64_t>> {
                     FitRequest req;
                     req.cancel = &cancel;
                     req.stencils = stencils;
                     GF_ASSIGN_OR_RETURN(auto fits, FitSurface(r->features->split, *r->split_topo, options, nullptr, req));
                     return std::make_pair(fits, static_cast<int64_t>(fits->Bytes()));
                   },
                   &cancel));
  r->surface = std::make_unique<FeatureSurface>(*r->mesh, r->features,
                                                MakeSurface(method, r->features->split, r->fits), options.degree);
  return r;
}

absl::StatusOr<std::vector<v1::ProjectPointsResponse>> Handlers::ProjectPoints(const v1::ProjectPointsRequest& request,
                                                                               const CancellationToken& cancel) {
  GF_RETURN_IF_ERROR(RequireId(request.mesh_id()));
  if (request.chunk_rows() < 0) return absl::InvalidArgumentError("chunk_rows must not be negative");
  const bool xyz = request.points().shape_size() > 0;
  const bool face_points = request.faces().shape_size() > 0 || request.natural().shape_size() > 0;
  if (xyz == face_points)
    return absl::InvalidArgumentError("give either points (#P x 3) or faces (#P) with natural (#P x 2)");
  std::vector<ProjectedPoint> out;
  GF_ASSIGN_OR_RETURN(auto r, Reconstruct(request.mesh_id(), request.revision(), request.options(), false, cancel));
  if (xyz) {
    GF_ASSIGN_OR_RETURN(const wire::RowsXd p, wire::DecodeDoubles(request.points(), "points", {3}));
    GF_RETURN_IF_ERROR(geomfit::ProjectPoints(*r->surface, *r->topo, Positions(p), &out, options_.threads));
  } else {
    GF_ASSIGN_OR_RETURN(const wire::RowsXi f, wire::DecodeInts(request.faces(), "faces", {0}));
    GF_ASSIGN_OR_RETURN(const wire::RowsXd n, wire::DecodeDoubles(request.natural(), "natural", {2}));
    if (f.size() != n.rows())
      return absl::InvalidArgumentError(absl::StrFormat("faces has %d entries but natural has %d rows", f.size(), n.rows()));
    std::vector<FacePoint> fp(n.rows());
    for (Eigen::Index i = 0; i < n.rows(); ++i) fp[i] = {f.data()[i], n(i, 0), n(i, 1)};
    std::vector<SurfacePoint> sp;
    GF_RETURN_IF_ERROR(EvaluatePoints(*r->surface, fp, &sp, options_.threads));
    out.resize(sp.size());
    for (size_t i = 0; i < sp.size(); ++i) out[i] = {fp[i], sp[i], 0.0};
  }
  GF_RETURN_IF_ERROR(cancel.Check());
  const int64_t n = static_cast<int64_t>(out.size());
  const int64_t rows = ChunkRows(request.chunk_rows(), 8 * 9 + 4);
  std::vector<v1::ProjectPointsResponse> chunks;
  for (int64_t b = 0; b == 0 || b < n; b += rows) {
    const int64_t m = std::min(rows, n - b);
    v1::ProjectPointsResponse& c = chunks.emplace_back();
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
  }
  return chunks;
}

absl::StatusOr<v1::HighOrderNodesResponse> Handlers::HighOrderNodes(const v1::HighOrderNodesRequest& request,
                                                                    const CancellationToken& cancel) {
  GF_RETURN_IF_ERROR(RequireId(request.mesh_id()));
  const int order = request.order() == 0 ? 2 : request.order();
  if (order != 2 && order != 3) return absl::InvalidArgumentError(absl::StrCat("order ", order, " must be 2 or 3"));
  GF_ASSIGN_OR_RETURN(auto r, Reconstruct(request.mesh_id(), request.revision(), request.options(), false, cancel));
  GF_ASSIGN_OR_RETURN(const HighOrderMesh ho, MakeHighOrderMesh(*r->surface, *r->topo, order, options_.threads));
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
                                                  const CancellationToken& cancel) {
  GF_RETURN_IF_ERROR(RequireId(request.mesh_id()));
  const int factor = request.factor() == 0 ? 2 : request.factor();
  if (factor < 2 || factor > 8) return absl::InvalidArgumentError(absl::StrCat("factor ", factor, " is out of range [2, 8]"));
  GF_ASSIGN_OR_RETURN(auto r, Reconstruct(request.mesh_id(), request.revision(), request.options(), false, cancel));
  if (static_cast<int64_t>(r->mesh->NumFaces()) * factor * factor > options_.max_vertices)
    return absl::ResourceExhaustedError(absl::StrFormat("refining %d faces by %d would exceed --max-vertices (%d)",
                                                        r->mesh->NumFaces(), factor, options_.max_vertices));
  GF_ASSIGN_OR_RETURN(Mesh refined, geomfit::RefineMesh(*r->surface, *r->topo, factor, options_.threads));
  GF_RETURN_IF_ERROR(cancel.Check());
  v1::MeshHeader header;
  GF_ASSIGN_OR_RETURN(const v1::MeshInfo source, store_->GetInfo(request.mesh_id()));
  header.set_name(request.name().empty() ? absl::StrCat(source.name(), " refined x", factor) : request.name());
  (*header.mutable_labels())["refined_from"] = request.mesh_id();
  return StoreNewMesh(std::move(refined), header);
}

absl::StatusOr<v1::IntegrateResponse> Handlers::Integrate(const v1::IntegrateRequest& request,
                                                          const CancellationToken& cancel) {
  GF_RETURN_IF_ERROR(RequireId(request.mesh_id()));
  if (request.options().method() == v1::RECONSTRUCTION_CMF)
    return absl::InvalidArgumentError("options.method: integration supports WALF and LINEAR, not CMF");
  if (request.options().feature_angle_deg() > 0 || request.options().feature_edges().shape_size() > 0)
    return absl::InvalidArgumentError("options: integration does not support sharp features yet");
  if (request.quadrature_degree() < 0 || request.quadrature_degree() > 30)
    return absl::InvalidArgumentError(absl::StrCat("quadrature_degree ", request.quadrature_degree(), " is out of range [0, 30]"));
  IntegrationInput in;
  in.quadrature_degree = request.quadrature_degree();
  const bool fields = request.scalars().shape_size() > 0 || request.vectors().shape_size() > 0;
  if (request.scalars().shape_size() > 0) {
    // One field as a 1-D array, or up to 8 as #V x s.
    const bool one = request.scalars().shape_size() == 1;
    GF_ASSIGN_OR_RETURN(const wire::RowsXd s, one ? wire::DecodeDoubles(request.scalars(), "scalars", {0})
                                                  : wire::DecodeDoubles(request.scalars(), "scalars", {1, 2, 3, 4, 5, 6, 7, 8}));
    in.scalars = s;
  }
  if (request.vectors().shape_size() > 0) {
    GF_ASSIGN_OR_RETURN(const wire::RowsXd v, wire::DecodeDoubles(request.vectors(), "vectors", {3}));
    in.vectors = v;
  }
  GF_ASSIGN_OR_RETURN(auto r, Reconstruct(request.mesh_id(), request.revision(), request.options(), fields, cancel));
  GF_ASSIGN_OR_RETURN(const Integrals result, geomfit::Integrate(*r->surface, in, options_.threads));
  GF_RETURN_IF_ERROR(cancel.Check());
  v1::IntegrateResponse out;
  out.set_area(result.area);
  out.set_volume(result.volume);
  for (double s : result.scalars) out.add_scalars(s);
  out.set_flux(result.flux);
  out.set_quadrature_points(result.quadrature_points);
  out.set_revision(r->revision);
  return out;
}

}  // namespace geomfit::server
