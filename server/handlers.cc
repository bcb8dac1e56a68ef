#include "server/handlers.h"

#include <algorithm>
#include <atomic>
#include <limits>
#include <map>
#include <optional>

#include <spdlog/spdlog.h>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/fitting/neighborhood.h"
#include "core/quantities/differentials.h"
#include "core/util/status_macros.h"
#include "core/util/timer.h"
#include "proto/wire.h"
#include "server/content_hash.h"

namespace geomfit::server {
namespace {

constexpr const char* kVersion = "0.1.0";

int64_t MeshBytes(const Mesh& m) {
  return static_cast<int64_t>(sizeof(double) * m.positions.size() + sizeof(int32_t) * m.faces.size());
}

/// Identity of an upload: faces, positions, name and (sorted) labels.
std::string HashUpload(const Mesh& mesh, const v1::MeshHeader& header) {
  return wire::MeshContentHash(mesh, header);  // the clients compute it too
}

std::string GeometryKey(const std::string& id, int64_t revision) {
  return absl::StrCat(id, "/r", revision, "/geom");
}

std::string RingSpecKey(const RingSpec& s) {
  return absl::StrFormat("%g/%d/%d/%d/%g/%d", s.rings, s.adaptive, s.min_points, s.min_points_boundary,
                         s.max_rings, s.max_points);
}

/// Bytes a fitting of `n` vertices needs at least (frames, coefficients, diagnostics).
int64_t EstimateFitBytes(int64_t n, const FitOptions& o) {
  const int dims = o.method == FitMethod::kLHF ? 1 : 3;
  return n * static_cast<int64_t>(sizeof(LocalFrame) + sizeof(VertexDiagnostics) +
                                  sizeof(double) * dims * NumCoefficients(o.degree));
}

int64_t DifferentialsBytes(const Differentials& d) {
  const size_t doubles = d.normals.size() + d.mean.size() + d.gaussian.size() + d.k1.size() + d.k2.size() +
                         d.dir1.size() + d.dir2.size() + d.tensor.size();
  return static_cast<int64_t>(sizeof(double) * doubles + sizeof(VertexDiagnostics) * d.diagnostics.size());
}

template <typename Array>
void EncodeRows(const Array& a, int64_t begin, int64_t rows, v1::DoubleArray* out) {
  const int64_t cols = Array::ColsAtCompileTime == 1 ? 0 : a.cols();
  wire::EncodeDoubles(a.data() + begin * std::max<int64_t>(cols, 1), rows, cols, out);
}

void EncodeDiagnostics(const std::vector<VertexDiagnostics>& d, int64_t begin, int64_t rows,
                       v1::VertexDiagnostics* out) {
  std::vector<int32_t> points(rows), degree(rows), flags(rows);
  std::vector<double> condition(rows);
  for (int64_t i = 0; i < rows; ++i) {
    const VertexDiagnostics& v = d[begin + i];
    points[i] = v.points;
    degree[i] = v.degree_used;
    flags[i] = v.flags;
    condition[i] = v.condition;
  }
  wire::EncodeInts(points.data(), rows, 0, out->mutable_points());
  wire::EncodeInts(degree.data(), rows, 0, out->mutable_degree_used());
  wire::EncodeInts(flags.data(), rows, 0, out->mutable_flags());
  wire::EncodeDoubles(condition.data(), rows, 0, out->mutable_condition());
}

/// Rows [b, b + m) of `d` as one response chunk.
v1::ComputeDifferentialsResponse EncodeChunk(const Differentials& d, int64_t b, int64_t m, uint32_t mask,
                                             bool diagnostics) {
  v1::ComputeDifferentialsResponse r;
  r.set_vertex_offset(b);
  r.set_num_vertices(m);
  if (mask & kNormals) EncodeRows(d.normals, b, m, r.mutable_normals());
  if (mask & kMeanCurvature) EncodeRows(d.mean, b, m, r.mutable_mean());
  if (mask & kGaussianCurvature) EncodeRows(d.gaussian, b, m, r.mutable_gaussian());
  if (mask & kPrincipalCurvatures) {
    EncodeRows(d.k1, b, m, r.mutable_k1());
    EncodeRows(d.k2, b, m, r.mutable_k2());
  }
  if (mask & kPrincipalDirections) {
    EncodeRows(d.dir1, b, m, r.mutable_dir1());
    EncodeRows(d.dir2, b, m, r.mutable_dir2());
  }
  if (mask & kCurvatureTensor) EncodeRows(d.tensor, b, m, r.mutable_tensor());
  if (diagnostics) EncodeDiagnostics(d.diagnostics, b, m, r.mutable_diagnostics());
  return r;
}

/// One ComputeDifferentials response: chunks of `rows` vertices, sent as soon as their
/// rows are final. The first chunk's summary is `header`; the last one's is complete.
class DifferentialsStream {
 public:
  DifferentialsStream(uint32_t mask, bool diagnostics, int64_t n, int64_t rows, v1::FitSummary header,
                      ChunkSink<v1::ComputeDifferentialsResponse>* sink)
      : mask_(mask), diagnostics_(diagnostics), n_(n), rows_(rows), header_(std::move(header)), sink_(sink) {}

  /// The row count that completes the next chunk.
  int64_t next() const {
    std::lock_guard<std::mutex> lock(mu_);
    return std::min(n_, sent_ + rows_);
  }
  /// Rows sent so far.
  int64_t sent() const {
    std::lock_guard<std::mutex> lock(mu_);
    return sent_;
  }
  /// Sends every whole chunk of rows [0, filled) not sent yet, except the last one;
  /// within the last chunk, rows [sent, filled) while some are still to come.
  void Emit(const Differentials* d, int64_t filled) {
    std::lock_guard<std::mutex> lock(mu_);
    EmitLocked(d, filled);
    if (d && sent_ + rows_ >= n_ && sent_ < filled && filled < n_) Send(*d, filled - sent_, nullptr);
  }
  /// Emit(ev.values(), ev.filled()) for the fitting threads of `ev`'s owner: a thread
  /// that finds another one sending leaves its rows to it instead of waiting.
  void EmitFrom(const Evaluation& ev) {
    more_ = true;
    do {
      std::unique_lock<std::mutex> lock(mu_, std::try_to_lock);
      if (!lock.owns_lock()) return;  // the sender checks more_ after unlocking
      while (more_.exchange(false)) EmitLocked(ev.values(), ev.filled());
    } while (more_);
  }
  /// Sends the remaining rows; the last chunk carries `summary`.
  void Finish(const Differentials& d, const v1::FitSummary& summary) {
    std::lock_guard<std::mutex> lock(mu_);
    while (sent_ + rows_ < n_) Send(d, rows_, nullptr);
    Send(d, n_ - sent_, &summary);
  }

 private:
  void EmitLocked(const Differentials* d, int64_t filled) {
    while (d && sent_ + rows_ <= filled && sent_ + rows_ < n_) Send(*d, rows_, nullptr);
  }
  void Send(const Differentials& d, int64_t m, const v1::FitSummary* summary) {
    v1::ComputeDifferentialsResponse chunk = EncodeChunk(d, sent_, m, mask_, diagnostics_);
    if (summary) {
      *chunk.mutable_summary() = *summary;
    } else if (sent_ == 0) {
      *chunk.mutable_summary() = header_;
    }
    sent_ += m;
    sink_->Push(std::move(chunk), summary != nullptr);
  }

  const uint32_t mask_;
  const bool diagnostics_;
  const int64_t n_, rows_;
  const v1::FitSummary header_;
  ChunkSink<v1::ComputeDifferentialsResponse>* sink_;
  mutable std::mutex mu_;
  int64_t sent_ = 0;
  std::atomic<bool> more_{false};  ///< EmitFrom has rows for the thread that is sending
};

/// Fitting-tier key of a fit.
std::string FitKey(const std::string& id, int64_t revision, const FitOptions& options, bool stencils) {
  return absl::StrCat(id, "/r", revision, "/fit/", FitOptionsKey(options), stencils ? "/stencils" : "");
}

/// Fitting-tier key of the differentials `mask` of a fit.
std::string DifferentialsKey(const std::string& fit_key, uint32_t mask) { return absl::StrCat(fit_key, "/q", mask); }

/// Bytes per vertex of a ComputeDifferentials response.
int64_t RowBytes(uint32_t mask, bool diagnostics) {
  int64_t doubles = 0;
  if (mask & kNormals) doubles += 3;
  if (mask & kMeanCurvature) doubles += 1;
  if (mask & kGaussianCurvature) doubles += 1;
  if (mask & kPrincipalCurvatures) doubles += 2;
  if (mask & kPrincipalDirections) doubles += 6;
  if (mask & kCurvatureTensor) doubles += 9;
  return std::max<int64_t>(8, 8 * doubles + (diagnostics ? 20 : 0));
}

/// What a response's first chunk says before the fit is done.
v1::FitSummary SummaryHeader(const std::string& id, int64_t revision, int64_t n, const FitOptions& options) {
  v1::FitSummary s;
  s.set_mesh_id(id);
  s.set_revision(revision);
  s.set_num_vertices(n);
  s.set_degree_requested(options.degree);
  s.set_options_key(FitOptionsKey(options));
  return s;
}

/// The complete summary of an evaluation.
v1::FitSummary Summarize(const std::string& id, const Evaluated& e, const FitOptions& options) {
  const SurfaceFits& fits = *e.fitted.fits;
  v1::FitSummary s = SummaryHeader(id, e.fitted.revision, fits.num_vertices(), options);
  s.set_fit_cache_hit(e.fitted.hit);
  s.set_fit_ms(e.fitted.ms);
  s.set_evaluate_ms(e.ms);
  s.set_quantities_cache_hit(e.hit);
  int min_degree = options.degree;
  std::vector<int64_t> by_degree(kMaxDegree + 1, 0);
  for (const VertexDiagnostics& d : fits.diagnostics()) {
    ++by_degree[std::clamp<int>(d.degree_used, 0, kMaxDegree)];
    if (d.flags & kFlagOscillation) s.set_num_oscillation_downgraded(s.num_oscillation_downgraded() + 1);
    if (d.flags & kFlagIsolated) {
      s.set_num_isolated(s.num_isolated() + 1);
      continue;
    }
    min_degree = std::min<int>(min_degree, d.degree_used);
    if (d.flags & kFlagDowngraded) s.set_num_downgraded(s.num_downgraded() + 1);
    if (d.flags & kFlagTooFewPoints) s.set_num_too_few_points(s.num_too_few_points() + 1);
    if (d.flags & kFlagBoundary) s.set_num_boundary(s.num_boundary() + 1);
  }
  s.set_min_degree_used(min_degree);
  for (int64_t n : by_degree) s.add_vertices_by_degree(n);
  return s;
}

}  // namespace

absl::Status RequireId(const std::string& id) {
  if (id.empty()) return absl::InvalidArgumentError("mesh_id: empty");
  return absl::OkStatus();
}

Handlers::Handlers(MeshStore* store, Cache* cache, const RequestStats* stats, HandlerOptions options)
    : store_(store), cache_(cache), stats_(stats), options_(options) {}

absl::StatusOr<v1::MeshInfo> Handlers::UploadMesh(const UploadAssembler& upload) {
  GF_ASSIGN_OR_RETURN(Mesh mesh, upload.Finish());
  return StoreNewMesh(std::move(mesh), upload.header());
}

absl::StatusOr<v1::MeshInfo> Handlers::StoreNewMesh(Mesh mesh, const v1::MeshHeader& header) {
  GF_ASSIGN_OR_RETURN(Topology topo, ValidateMesh(mesh));
  const int64_t bytes = MeshBytes(mesh) + static_cast<int64_t>(topo.Bytes());
  if (bytes > cache_->budget()) {
    return absl::ResourceExhaustedError(absl::StrCat("mesh needs ", bytes, " bytes of cache, the budget is ",
                                                     cache_->budget(), " (--cache-bytes)"));
  }
  v1::MeshInfo info;
  info.set_content_hash(HashUpload(mesh, header));
  info.set_mesh_id(wire::MeshIdOf(info.content_hash()));
  info.set_num_vertices(mesh.NumVertices());
  info.set_num_faces(mesh.NumFaces());
  info.set_face_kind(wire::KindOf(mesh));
  info.set_name(header.name());
  *info.mutable_labels() = header.labels();
  info.set_num_boundary_edges(topo.num_boundary_edges);
  info.set_num_isolated_vertices(topo.num_isolated);
  AmendForPositions(mesh.positions, 1, &info);
  info.set_created_unix_ms(info.updated_unix_ms());
  GF_ASSIGN_OR_RETURN(v1::MeshInfo stored, store_->Insert(info, mesh));
  if (stored.revision() == 1) {
    const int64_t topo_bytes = static_cast<int64_t>(topo.Bytes());
    cache_->Put(Tier::kTopology, stored.mesh_id() + "/topo", std::make_shared<const Topology>(std::move(topo)),
                topo_bytes);
    const int64_t mesh_bytes = MeshBytes(mesh);
    cache_->Put(Tier::kGeometry, GeometryKey(stored.mesh_id(), 1), std::make_shared<const Mesh>(std::move(mesh)),
                mesh_bytes);
  }
  return stored;
}

absl::StatusOr<v1::MeshInfo> Handlers::UpdatePositions(const PositionsAssembler& update) {
  if (!update.has_header()) return absl::InvalidArgumentError("update stream ended without a header");
  const v1::UpdateHeader& header = update.header();
  int64_t revision = 0;
  GF_ASSIGN_OR_RETURN(std::shared_ptr<const Mesh> old, Geometry(header.mesh_id(), 0, &revision));
  if (header.has_expected_revision() && header.expected_revision() != revision) {
    return StaleRevision(header.mesh_id(), header.expected_revision(), revision);
  }
  auto mesh = std::make_shared<Mesh>();
  GF_ASSIGN_OR_RETURN(mesh->positions, update.Finish(old->NumVertices()));
  mesh->faces = old->faces;
  GF_RETURN_IF_ERROR(ValidateGeometry(*mesh));
  std::optional<int64_t> expected;  // the store checks again under its lock
  if (header.has_expected_revision()) expected = header.expected_revision();
  GF_ASSIGN_OR_RETURN(v1::MeshInfo info, store_->UpdatePositions(header.mesh_id(), expected, mesh));
  // Requests holding the previous revision finish on it; the cache lets it go.
  cache_->RetireRevisionsBelow(header.mesh_id(), info.revision());
  cache_->Put(Tier::kGeometry, GeometryKey(info.mesh_id(), info.revision()), mesh, MeshBytes(*mesh));
  return info;
}

absl::StatusOr<v1::MeshInfo> Handlers::SetPositions(const v1::SetPositionsRequest& request) {
  PositionsAssembler update(options_.max_vertices);
  GF_RETURN_IF_ERROR(update.AddHeader(request.header()));
  GF_RETURN_IF_ERROR(update.AddPositions(request.positions()));
  return UpdatePositions(update);
}

absl::StatusOr<v1::MeshInfo> Handlers::GetMesh(const v1::GetMeshRequest& request) {
  GF_RETURN_IF_ERROR(RequireId(request.mesh_id()));
  return store_->GetInfo(request.mesh_id());
}

absl::StatusOr<std::vector<v1::DownloadMeshResponse>> Handlers::DownloadMesh(
    const v1::DownloadMeshRequest& request) {
  GF_RETURN_IF_ERROR(RequireId(request.mesh_id()));
  if (request.revision() < 0 || request.chunk_rows() < 0) {
    return absl::InvalidArgumentError("revision and chunk_rows must not be negative");
  }
  GF_ASSIGN_OR_RETURN(StoredMesh stored, store_->Get(request.mesh_id()));
  if (request.revision() != 0 && request.revision() != stored.info.revision()) {
    return absl::NotFoundError(absl::StrCat("mesh '", request.mesh_id(), "' revision ", request.revision(),
                                            " is not kept (latest is ", stored.info.revision(), ")"));
  }
  const Mesh& mesh = *stored.mesh;
  std::vector<v1::DownloadMeshResponse> out(1);
  *out[0].mutable_info() = stored.info;
  const int64_t rows = ChunkRows(request.chunk_rows(), 24);
  for (int64_t b = 0; b < mesh.NumVertices(); b += rows) {
    const int64_t n = std::min<int64_t>(rows, mesh.NumVertices() - b);
    v1::PositionsChunk* c = out.emplace_back().mutable_positions();
    c->set_vertex_offset(b);
    wire::EncodeDoubles(mesh.positions.data() + 3 * b, n, 3, c->mutable_positions());
  }
  for (int64_t b = 0; b < mesh.NumFaces(); b += rows) {
    const int64_t n = std::min<int64_t>(rows, mesh.NumFaces() - b);
    v1::FacesChunk* c = out.emplace_back().mutable_faces();
    c->set_face_offset(b);
    wire::EncodeInts(mesh.faces.data() + 4 * b, n, 4, c->mutable_faces());
  }
  return out;
}

absl::StatusOr<v1::ListMeshesResponse> Handlers::ListMeshes(const v1::ListMeshesRequest& request) {
  if (request.page_size() < 0 || request.page_size() > 1000) {
    return absl::InvalidArgumentError(absl::StrCat("page_size: ", request.page_size(), ", expected 0..1000"));
  }
  const int page = request.page_size() == 0 ? 100 : request.page_size();
  GF_ASSIGN_OR_RETURN(std::vector<v1::MeshInfo> meshes, store_->List(request.page_token(), page + 1));
  v1::ListMeshesResponse response;
  for (int i = 0; i < static_cast<int>(meshes.size()) && i < page; ++i) *response.add_meshes() = std::move(meshes[i]);
  if (static_cast<int>(meshes.size()) > page) response.set_next_page_token(response.meshes(page - 1).mesh_id());
  return response;
}

absl::StatusOr<v1::DeleteMeshResponse> Handlers::DeleteMesh(const v1::DeleteMeshRequest& request) {
  GF_RETURN_IF_ERROR(RequireId(request.mesh_id()));
  GF_RETURN_IF_ERROR(store_->Delete(request.mesh_id()));
  cache_->EraseMesh(request.mesh_id());
  {  // a computation still running finishes for its callers; nobody else joins it
    std::lock_guard<std::mutex> lock(evaluations_mu_);
    const std::string prefix = request.mesh_id() + "/";
    for (auto it = evaluations_.lower_bound(prefix); it != evaluations_.end() && absl::StartsWith(it->first, prefix);) {
      it = evaluations_.erase(it);
    }
  }
  std::lock_guard<std::mutex> lock(recipes_mu_);
  recipes_.erase(request.mesh_id());
  return v1::DeleteMeshResponse();
}

absl::StatusOr<Fitted> Handlers::Fit(const std::string& id, int64_t revision, const FitOptions& options,
                                     const CancellationToken& cancel, bool stencils,
                                     const decltype(FitRequest::on_fitted)& on_fitted,
                                     std::shared_ptr<const Mesh> mesh) {
  Fitted f;
  f.revision = revision;
  if (!mesh) {
    GF_ASSIGN_OR_RETURN(mesh, Geometry(id, revision, &f.revision));
  }
  GF_ASSIGN_OR_RETURN(std::shared_ptr<const Topology> topo, TopologyOf(id, *mesh));
  if (const int64_t need = EstimateFitBytes(mesh->NumVertices(), options); need > cache_->budget()) {
    return absl::ResourceExhaustedError(absl::StrCat("fitting ", mesh->NumVertices(), " vertices at degree ",
                                                     options.degree, " needs about ", need,
                                                     " bytes; the cache budget is ", cache_->budget(),
                                                     " (--cache-bytes)"));
  }
  const RingSpec spec = RingSpecFor(options);
  GF_ASSIGN_OR_RETURN(
      std::shared_ptr<const Neighborhoods> nbhd,
      cache_->Get<Neighborhoods>(
          Tier::kTopology, absl::StrCat(id, "/nbhd/", RingSpecKey(spec)),
          [&]() -> absl::StatusOr<std::pair<std::shared_ptr<const Neighborhoods>, int64_t>> {
            auto n = std::make_shared<const Neighborhoods>(BuildNeighborhoods(*topo, *mesh, spec, options_.threads));
            return std::make_pair(n, static_cast<int64_t>(n->Bytes()));
          },
          &cancel));
  f.key = FitKey(id, f.revision, options, stencils);
  Stopwatch watch;
  GF_ASSIGN_OR_RETURN(
      f.fits, cache_->Get<SurfaceFits>(
                  Tier::kFitting, f.key,
                  [&]() -> absl::StatusOr<std::pair<std::shared_ptr<const SurfaceFits>, int64_t>> {
                    FitRequest fit_request;
                    fit_request.cancel = &cancel;
                    fit_request.stencils = stencils;
                    fit_request.on_fitted = on_fitted;
                    GF_ASSIGN_OR_RETURN(auto fits, FitSurface(*mesh, *topo, options, nbhd, fit_request));
                    return std::make_pair(fits, static_cast<int64_t>(fits->Bytes()));
                  },
                  &cancel, &f.hit));
  f.ms = f.hit ? 0 : watch.Millis();
  GF_RETURN_IF_ERROR(cancel.Check());
  return f;
}

absl::Status Handlers::ComputeDifferentials(const v1::ComputeDifferentialsRequest& request,
                                           const CancellationToken& cancel,
                                           ChunkSink<v1::ComputeDifferentialsResponse>* sink) {
  const std::string& id = request.mesh_id();
  GF_RETURN_IF_ERROR(RequireId(id));
  if (request.revision() < 0 || request.chunk_rows() < 0) {
    return absl::InvalidArgumentError("revision and chunk_rows must not be negative");
  }
  absl::StatusOr<FitOptions> parsed = wire::FromProto(request.options());
  if (!parsed.ok()) return absl::InvalidArgumentError(absl::StrCat("options: ", parsed.status().message()));
  FitOptions options = *parsed;
  options.num_threads = options_.threads;
  GF_ASSIGN_OR_RETURN(const uint32_t mask, wire::QuantityMask(request.quantities()));
  // Held to the end: an update may replace the revision in the cache meanwhile.
  int64_t revision = 0;
  GF_ASSIGN_OR_RETURN(const std::shared_ptr<const Mesh> mesh, Geometry(id, request.revision(), &revision));
  const int64_t n = mesh->NumVertices();
  DifferentialsStream stream(mask, request.diagnostics(), n,
                             ChunkRows(request.chunk_rows(), RowBytes(mask, request.diagnostics())),
                             SummaryHeader(id, revision, n, options), sink);
  // What a prefetch repeats after the next update: recorded once the request succeeded,
  // before its last chunk (the client may send that update as soon as it has it).
  auto remember = [&] {
    std::lock_guard<std::mutex> lock(recipes_mu_);
    Recipe& r = recipes_[id];
    if (revision >= r.revision) r = Recipe{options, mask, revision};
  };
  bool owner = false;
  const std::shared_ptr<Evaluation> ev = JoinEvaluation(id, revision, options, mask, mesh, &owner);
  if (owner) {
    ev->SetListener([&stream, raw = ev.get()] { stream.EmitFrom(*raw); });
    const absl::StatusOr<Evaluated> e = Evaluate(id, revision, options, mask, cancel, ev.get(), mesh);
    if (e.ok()) {
      remember();
      stream.Finish(*e->values, Summarize(id, *e, options));
    }
    End(ev, e);  // then the followers' last chunks
    return e.status();
  }
  // Follow the running evaluation: whole chunks as their rows are final, then within
  // the last chunk every fitted block, so that the owner, which sends what is left as
  // soon as it ends, has at most one block to send.
  FollowGuard follow(ev.get(), [&](const absl::StatusOr<Evaluated>& result) {
    if (!result.ok()) return;
    Evaluated shared = *result;  // not computed for this request: a hit, as for a joined cache flight
    shared.fitted.hit = shared.hit = true;
    shared.fitted.ms = shared.ms = 0;
    v1::FitSummary summary = Summarize(id, shared, options);
    summary.set_joined_compute_ms(result->fitted.ms + result->ms);
    remember();
    stream.Finish(*shared.values, summary);
  });
  for (int64_t filled = 0; !ev->ended();) {
    const int64_t next = stream.next();
    // Within the last chunk: any row not sent yet, until all are final (the owner
    // sends the last ones with the summary).
    const int64_t want = next < n ? next : filled < n ? stream.sent() + 1 : n + 1;
    GF_ASSIGN_OR_RETURN(filled, ev->WaitFor(want, cancel));
    stream.Emit(ev->values(), filled);
  }
  if (follow.Unfollow() && ev->result().ok()) return absl::OkStatus();  // the owner sent the rest
  // Its owner gave up (cancelled): compute the rest here. Values are deterministic, so
  // the rows already sent agree.
  GF_ASSIGN_OR_RETURN(const Evaluated e, Evaluate(id, revision, options, mask, cancel, nullptr, mesh));
  remember();
  stream.Finish(*e.values, Summarize(id, e, options));
  return absl::OkStatus();
}

absl::StatusOr<std::vector<v1::ComputeDifferentialsResponse>> Handlers::ComputeDifferentials(
    const v1::ComputeDifferentialsRequest& request, const CancellationToken& cancel) {
  ChunkCollector<v1::ComputeDifferentialsResponse> out;
  GF_RETURN_IF_ERROR(ComputeDifferentials(request, cancel, &out));
  return std::move(out.chunks);
}

std::shared_ptr<Evaluation> Handlers::JoinEvaluation(const std::string& id, int64_t revision,
                                                     const FitOptions& options, uint32_t mask,
                                                     std::shared_ptr<const Mesh> mesh, bool* owner) {
  const std::string key = DifferentialsKey(FitKey(id, revision, options, false), mask);
  std::lock_guard<std::mutex> lock(evaluations_mu_);
  std::shared_ptr<Evaluation>& ev = evaluations_[key];
  *owner = ev == nullptr;
  if (*owner) ev = std::make_shared<Evaluation>(key, std::move(mesh), mask);
  return ev;
}

absl::StatusOr<Evaluated> Handlers::Run(const std::shared_ptr<Evaluation>& ev, const std::string& id,
                                        int64_t revision, const FitOptions& options,
                                        const CancellationToken& cancel) {
  absl::StatusOr<Evaluated> e = Evaluate(id, revision, options, ev->mask(), cancel, ev.get(), ev->mesh());
  End(ev, e);
  return e;
}

void Handlers::End(const std::shared_ptr<Evaluation>& ev, absl::StatusOr<Evaluated> result) {
  ev->Finish(std::move(result));  // before unregistering: a request arriving now finds the values
  std::lock_guard<std::mutex> lock(evaluations_mu_);
  const auto it = evaluations_.find(ev->key());
  if (it != evaluations_.end() && it->second == ev) evaluations_.erase(it);
}

absl::StatusOr<Evaluated> Handlers::Evaluate(const std::string& id, int64_t revision, const FitOptions& options,
                                             uint32_t mask, const CancellationToken& cancel, Evaluation* progress,
                                             std::shared_ptr<const Mesh> mesh) {
  Evaluated e;
  std::atomic<int64_t> evaluated{0};  // rows `progress` received during the fit
  decltype(FitRequest::on_fitted) on_fitted;
  if (progress) {
    on_fitted = [&](const SurfaceFits& fits, int64_t begin, int64_t end) {
      EvaluateDifferentials(fits, mask, begin, end, progress->filling().get());
      evaluated += end - begin;
      progress->Filled(begin, end);
    };
  }
  GF_ASSIGN_OR_RETURN(e.fitted, Fit(id, revision, options, cancel, false, on_fitted, std::move(mesh)));
  // Derived quantities belong to the fitting tier too: a repeated request only
  // serializes.
  Stopwatch watch;
  GF_ASSIGN_OR_RETURN(
      e.values, cache_->Get<Differentials>(
                    Tier::kFitting, DifferentialsKey(e.fitted.key, mask),
                    [&]() -> absl::StatusOr<std::pair<std::shared_ptr<const Differentials>, int64_t>> {
                      std::shared_ptr<const Differentials> d;
                      if (progress && evaluated == e.fitted.fits->num_vertices()) {
                        d = progress->filling();  // evaluated during the fit
                      } else {
                        d = std::make_shared<const Differentials>(
                            geomfit::ComputeDifferentials(*e.fitted.fits, mask, options_.threads));
                      }
                      return std::make_pair(d, DifferentialsBytes(*d));
                    },
                    &cancel, &e.hit));
  e.ms = e.hit ? 0 : watch.Millis();
  return e;
}

std::unique_ptr<Handlers::PendingPrefetch> Handlers::PlanPrefetch(const std::string& id, int64_t revision) {
  if (!options_.prefetch) return nullptr;
  Recipe recipe;
  {
    std::lock_guard<std::mutex> lock(recipes_mu_);
    auto it = recipes_.find(id);
    if (it == recipes_.end() || it->second.revision != revision - 1) return nullptr;
    recipe = it->second;
  }
  int64_t resolved = 0;
  absl::StatusOr<std::shared_ptr<const Mesh>> mesh = Geometry(id, revision, &resolved);
  if (!mesh.ok()) return nullptr;
  bool owner = false;
  std::shared_ptr<Evaluation> ev = JoinEvaluation(id, resolved, recipe.options, recipe.mask, *mesh, &owner);
  if (!owner) return nullptr;  // a request got there first
  return std::make_unique<PendingPrefetch>(this, std::move(ev), id, resolved, recipe.options);
}

void Handlers::Prefetch(const std::string& id, int64_t revision, const CancellationToken& cancel) {
  if (std::unique_ptr<PendingPrefetch> p = PlanPrefetch(id, revision)) p->Run(cancel);
}

void Handlers::PendingPrefetch::Run(const CancellationToken& cancel) {
  ran_ = true;
  const absl::StatusOr<Evaluated> e = handlers_->Run(ev_, id_, revision_, options_, cancel);
  if (!e.ok()) {
    spdlog::debug("prefetch of {} revision {}: {}", id_, revision_, e.status().ToString());
  } else {
    spdlog::debug("prefetch of {} revision {}: fit {:.3f} ms, evaluate {:.3f} ms", id_, revision_, e->fitted.ms,
                  e->ms);
  }
}

Handlers::PendingPrefetch::~PendingPrefetch() {
  if (!ran_) handlers_->End(ev_, absl::CancelledError("prefetch not run"));
}

v1::ServerInfo Handlers::GetServerInfo() const {
  v1::ServerInfo info;
  info.set_version(kVersion);
  info.set_api_version("geomfit.v1");
  info.set_max_message_bytes(options_.max_message_bytes);
  info.set_max_vertices(options_.max_vertices);
  info.set_cache_bytes(cache_->budget());
  info.set_store(store_->Kind());
  info.set_max_degree(kMaxDegree);
  info.set_compute_workers(options_.workers);
  info.set_default_chunk_rows(options_.chunk_rows);
  info.set_default_chunk_bytes(options_.chunk_bytes);
  for (const char* c : {"UploadMesh", "UpdatePositions", "SetPositions", "GetMesh", "DownloadMesh", "ListMeshes", "DeleteMesh",
                        "ComputeDifferentials", "GetServerInfo", "GetStatistics", "ProjectPoints",
                        "HighOrderNodes", "RefineMesh", "Integrate", "reconstruction:WALF",
                        "reconstruction:CMF", "fit_method:LHF",
                        "fit_method:LOP", "faces:triangle", "faces:quad", "faces:mixed"}) {
    info.add_capabilities(c);
  }
  return info;
}

v1::Statistics Handlers::GetStatistics() const {
  v1::Statistics s;
  for (const auto& [name, m] : stats_->Snapshot()) {
    v1::MethodStatistics* ms = s.add_methods();
    ms->set_method(name);
    ms->set_count(m.count);
    ms->set_errors(m.errors);
    ms->set_total_ms(m.total_ms);
    ms->set_max_ms(m.max_ms);
    int64_t cumulative = 0;
    for (size_t i = 0; i < m.buckets.size(); ++i) {
      cumulative += m.buckets[i];
      const auto& bounds = RequestStats::BucketsMs();
      ms->add_bucket_upper_ms(i < bounds.size() ? bounds[i] : std::numeric_limits<double>::infinity());
      ms->add_bucket_count(cumulative);
    }
  }
  for (Tier tier : {Tier::kTopology, Tier::kGeometry, Tier::kFitting}) {
    const TierStats t = cache_->Stats(tier);
    v1::CacheStatistics* c = s.add_caches();
    c->set_tier(TierName(tier));
    c->set_entries(t.entries);
    c->set_bytes(t.bytes);
    c->set_hits(t.hits);
    c->set_misses(t.misses);
    c->set_evictions(t.evictions);
  }
  s.set_cache_bytes(cache_->bytes());
  s.set_cache_budget_bytes(cache_->budget());
  const StoreStats store = store_->Stats();
  s.set_stored_meshes(store.meshes);
  s.set_stored_bytes(store.bytes);
  s.set_uptime_seconds(std::chrono::duration<double>(std::chrono::steady_clock::now() - started_).count());
  return s;
}

absl::StatusOr<std::shared_ptr<const Mesh>> Handlers::Geometry(const std::string& id, int64_t revision,
                                                               int64_t* resolved_revision) {
  GF_RETURN_IF_ERROR(RequireId(id));
  const bool latest = revision == 0;
  // "Latest" can move on between reading the revision and fetching it (a concurrent
  // UpdatePositions): then fetch the newer one, a few times at most.
  for (int attempt = 0;; ++attempt) {
    if (latest) {
      GF_ASSIGN_OR_RETURN(v1::MeshInfo info, store_->GetInfo(id));
      revision = info.revision();
    }
    *resolved_revision = revision;
    bool moved_on = false;
    auto mesh = cache_->Get<Mesh>(Tier::kGeometry, GeometryKey(id, revision),
                                  [&]() -> absl::StatusOr<std::pair<std::shared_ptr<const Mesh>, int64_t>> {
                                    GF_ASSIGN_OR_RETURN(StoredMesh stored, store_->Get(id));
                                    if (stored.info.revision() != revision) {
                                      moved_on = true;
                                      return absl::NotFoundError(absl::StrCat(
                                          "mesh '", id, "' revision ", revision, " is not kept (latest is ",
                                          stored.info.revision(), ")"));
                                    }
                                    return std::make_pair(stored.mesh, MeshBytes(*stored.mesh));
                                  });
    if (mesh.ok() || !latest || !moved_on || attempt == 3) return mesh;
  }
}

absl::StatusOr<std::shared_ptr<const Topology>> Handlers::TopologyOf(const std::string& id, const Mesh& mesh) {
  return cache_->Get<Topology>(Tier::kTopology, id + "/topo",
                               [&]() -> absl::StatusOr<std::pair<std::shared_ptr<const Topology>, int64_t>> {
                                 GF_ASSIGN_OR_RETURN(Topology t, BuildTopology(mesh));
                                 const int64_t bytes = static_cast<int64_t>(t.Bytes());
                                 return std::make_pair(std::make_shared<const Topology>(std::move(t)), bytes);
                               });
}

int64_t Handlers::ChunkRows(int64_t requested, int64_t bytes_per_row) const {
  const int64_t by_limit = std::max<int64_t>(1, options_.max_message_bytes / 2 / bytes_per_row);
  if (requested <= 0) requested = options_.chunk_rows;
  if (requested <= 0) requested = std::max<int64_t>(1, options_.chunk_bytes / bytes_per_row);
  return std::min(requested, by_limit);
}

}  // namespace geomfit::server
