#include "server/workspace/workspace.h"

#include <algorithm>
#include <atomic>

#include <spdlog/spdlog.h>

#include "absl/strings/str_cat.h"
#include "core/fitting/neighborhood.h"
#include "core/mesh/content_hash.h"
#include "core/quantities/differentials.h"
#include "core/util/status_macros.h"
#include "core/util/timer.h"

namespace geomfit::server {
namespace {


int64_t DifferentialsBytes(const Differentials& d) {
  const size_t doubles = d.normals.size() + d.mean.size() + d.gaussian.size() + d.k1.size() + d.k2.size() +
                         d.dir1.size() + d.dir2.size() + d.tensor.size();
  return static_cast<int64_t>(sizeof(double) * doubles + sizeof(VertexDiagnostics) * d.diagnostics.size());
}

/// Bytes a fitting of `n` vertices needs at least (frames, coefficients, diagnostics).
int64_t EstimateFitBytes(int64_t n, const FitOptions& o) {
  const int dims = o.method == FitMethod::kLHF ? 1 : 3;
  return n * static_cast<int64_t>(sizeof(LocalFrame) + sizeof(VertexDiagnostics) +
                                  sizeof(double) * dims * NumCoefficients(o.degree));
}

template <typename T>
using Made = absl::StatusOr<std::pair<std::shared_ptr<const T>, int64_t>>;

}  // namespace

int64_t MeshBytes(const Mesh& m) {
  return static_cast<int64_t>(sizeof(double) * m.positions.size() + sizeof(int32_t) * m.faces.size());
}

Workspace::Workspace(MeshStore* store, Cache* cache, WorkspaceOptions options)
    : store_(store), cache_(cache), options_(options), quotas_(options.quotas) {}

std::string TenantPrefix(absl::string_view tenant) { return tenant.empty() ? "" : absl::StrCat(tenant, "/"); }

std::string TenantOfId(absl::string_view stored_id) {
  const size_t slash = stored_id.find('/');
  return slash == absl::string_view::npos ? "" : std::string(stored_id.substr(0, slash));
}

absl::Status CheckMeshMeta(const MeshMeta& meta) {
  if (meta.name.size() > kMaxNameBytes)
    return absl::InvalidArgumentError(absl::StrCat("name: ", meta.name.size(), " bytes, at most ", kMaxNameBytes));
  if (meta.labels.size() > kMaxLabels)
    return absl::InvalidArgumentError(absl::StrCat("labels: ", meta.labels.size(), ", at most ", kMaxLabels));
  for (const auto& [key, value] : meta.labels) {
    if (key.empty() || key.size() > kMaxLabelKeyBytes || value.size() > kMaxLabelValueBytes) {
      return absl::InvalidArgumentError(absl::StrCat("labels: a key of ", key.size(), " bytes (1..", kMaxLabelKeyBytes,
                                                     ") or a value of ", value.size(), " bytes (at most ",
                                                     kMaxLabelValueBytes, ")"));
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<MeshRecord> Workspace::AddMesh(Mesh mesh, const MeshMeta& meta) {
  GF_RETURN_IF_ERROR(CheckMeshMeta(meta));
  GF_ASSIGN_OR_RETURN(Topology topo, ValidateMesh(mesh));
  const int64_t bytes = MeshBytes(mesh) + static_cast<int64_t>(topo.Bytes());
  if (bytes > cache_->budget()) {
    return absl::ResourceExhaustedError(absl::StrCat("mesh needs ", bytes, " bytes of cache, the budget is ",
                                                     cache_->budget(), " (--cache-bytes)"));
  }
  MeshRecord info;
  info.content_hash = MeshContentHash(mesh, meta.name, meta.labels);  // the clients compute it too
  info.mesh_id = TenantPrefix(meta.tenant) + MeshIdOf(info.content_hash);
  info.num_vertices = mesh.NumVertices();
  info.num_faces = mesh.NumFaces();
  info.face_kind = FaceKindOf(mesh);
  info.name = meta.name;
  info.labels = meta.labels;
  info.num_boundary_edges = topo.num_boundary_edges;
  info.num_isolated_vertices = topo.num_isolated;
  AmendForPositions(mesh.positions, 1, &info);
  info.created_unix_ms = info.updated_unix_ms;
  GF_ASSIGN_OR_RETURN(MeshRecord stored, quotas_.Insert(*store_, info, mesh));
  if (stored.revision == 1) {
    const int64_t topo_bytes = static_cast<int64_t>(topo.Bytes());
    cache_->Put(TopologyKey(stored.mesh_id), std::make_shared<const Topology>(std::move(topo)), topo_bytes);
    const int64_t mesh_bytes = MeshBytes(mesh);
    cache_->Put(GeometryKey(stored.mesh_id, 1), std::make_shared<const Mesh>(std::move(mesh)), mesh_bytes);
  }
  return stored;
}

absl::StatusOr<MeshRecord> Workspace::UpdatePositions(const std::string& id, std::optional<int64_t> expected,
                                                      Positions positions) {
  int64_t revision = 0;
  GF_ASSIGN_OR_RETURN(std::shared_ptr<const Mesh> old, Geometry(id, &revision));
  if (expected && *expected != revision) return StaleRevision(id, *expected, revision);
  if (positions.rows() != old->NumVertices()) {
    return absl::InvalidArgumentError(absl::StrCat("update carried ", positions.rows(), " vertices; mesh '", id,
                                                   "' has ", old->NumVertices()));
  }
  auto mesh = std::make_shared<Mesh>();
  mesh->positions = std::move(positions);
  mesh->faces = old->faces;
  GF_RETURN_IF_ERROR(ValidateGeometry(*mesh));
  // The store checks `expected` again under its lock.
  GF_ASSIGN_OR_RETURN(MeshRecord info, store_->UpdatePositions(id, expected, mesh));
  // Requests holding the previous revision finish on it; the cache lets it go.
  cache_->RetireRevisionsBelow(id, info.revision);
  cache_->Put(GeometryKey(id, info.revision), mesh, MeshBytes(*mesh));
  return info;
}

absl::StatusOr<MeshRecord> Workspace::Info(const std::string& id) { return store_->GetInfo(id); }

absl::StatusOr<StoredMesh> Workspace::Stored(const std::string& id, int64_t revision) {
  GF_ASSIGN_OR_RETURN(StoredMesh stored, store_->Get(id));
  if (revision != 0 && revision != stored.info.revision) {
    return absl::NotFoundError(absl::StrCat("mesh '", id, "' revision ", revision, " is not kept (latest is ",
                                            stored.info.revision, ")"));
  }
  return stored;
}

absl::StatusOr<std::vector<MeshRecord>> Workspace::List(const std::string& after_id, int limit) {
  return store_->List(after_id, limit);
}

absl::Status Workspace::Delete(const std::string& id) {
  GF_RETURN_IF_ERROR(quotas_.Delete(*store_, id));
  cache_->EraseMesh(id);
  {
    std::lock_guard<std::mutex> lock(recipes_mu_);
    recipes_.erase(id);
  }
  // Running evaluations of the mesh finish for their requests but are not joined again.
  std::lock_guard<std::mutex> lock(evaluations_mu_);
  for (auto it = evaluations_.begin(); it != evaluations_.end();) {
    it = it->first.mesh_id == id ? evaluations_.erase(it) : std::next(it);
  }
  return absl::OkStatus();
}

absl::StatusOr<Snapshot> Workspace::Acquire(const std::string& id, int64_t revision) {
  Snapshot s;
  s.mesh_id = id;
  s.revision = revision;
  GF_ASSIGN_OR_RETURN(s.mesh, Geometry(id, &s.revision));
  GF_ASSIGN_OR_RETURN(s.topology, TopologyOf(id, *s.mesh));
  return s;
}

absl::StatusOr<std::shared_ptr<const Mesh>> Workspace::Geometry(const std::string& id, int64_t* revision) {
  const bool latest = *revision == 0;
  // "Latest" can move on between reading the revision and fetching it (a concurrent
  // update): then fetch the newer one, a few times at most.
  for (int attempt = 0;; ++attempt) {
    if (latest) {
      GF_ASSIGN_OR_RETURN(MeshRecord info, store_->GetInfo(id));
      *revision = info.revision;
    }
    const int64_t wanted = *revision;
    bool moved_on = false;
    auto mesh = cache_->Get<Mesh>(GeometryKey(id, wanted), [&]() -> Made<Mesh> {
      GF_ASSIGN_OR_RETURN(StoredMesh stored, store_->Get(id));
      if (stored.info.revision != wanted) {
        moved_on = true;
        return absl::NotFoundError(absl::StrCat("mesh '", id, "' revision ", wanted, " is not kept (latest is ",
                                                stored.info.revision, ")"));
      }
      return std::make_pair(stored.mesh, MeshBytes(*stored.mesh));
    });
    if (mesh.ok() || !latest || !moved_on || attempt == 3) return mesh;
  }
}

absl::StatusOr<std::shared_ptr<const Topology>> Workspace::TopologyOf(const std::string& id, const Mesh& mesh) {
  return cache_->Get<Topology>(TopologyKey(id), [&]() -> Made<Topology> {
    GF_ASSIGN_OR_RETURN(Topology t, BuildTopology(mesh));
    const int64_t bytes = static_cast<int64_t>(t.Bytes());
    return std::make_pair(std::make_shared<const Topology>(std::move(t)), bytes);
  });
}

absl::StatusOr<Fitted> Workspace::Fit(const Snapshot& s, const FitOptions& options, const RunContext& ctx,
                                      bool stencils, const FittedBlockFn& on_fitted) {
  Fitted f;
  f.revision = s.revision;
  if (const int64_t need = EstimateFitBytes(s.mesh->NumVertices(), options); need > cache_->budget()) {
    return absl::ResourceExhaustedError(absl::StrCat("fitting ", s.mesh->NumVertices(), " vertices at degree ",
                                                     options.degree, " needs about ", need,
                                                     " bytes; the cache budget is ", cache_->budget(),
                                                     " (--cache-bytes)"));
  }
  GF_ASSIGN_OR_RETURN(auto nbhd, NeighborhoodsOf(s, RingSpecFor(options), ctx));
  f.key = FitKey(s.mesh_id, s.revision, options, stencils);
  Stopwatch watch;
  GF_ASSIGN_OR_RETURN(f.fits, cache_->Get<SurfaceFits>(
                                  f.key,
                                  [&]() -> Made<SurfaceFits> {
                                    GF_ASSIGN_OR_RETURN(auto fits, FitSurface(*s.mesh, *s.topology, options, nbhd,
                                                                              FitRequest{stencils}, ctx, on_fitted));
                                    return std::make_pair(fits, static_cast<int64_t>(fits->Bytes()));
                                  },
                                  ctx.token(), &f.hit));
  f.ms = f.hit ? 0 : watch.Millis();
  GF_RETURN_IF_ERROR(ctx.Check());
  return f;
}

absl::StatusOr<std::shared_ptr<const Neighborhoods>> Workspace::NeighborhoodsOf(const Snapshot& s,
                                                                                 const RingSpec& spec,
                                                                                 const RunContext& ctx) {
  return cache_->Get<Neighborhoods>(
      NeighborhoodsKey(s.mesh_id, spec),
      [&]() -> Made<Neighborhoods> {
        auto n = std::make_shared<const Neighborhoods>(BuildNeighborhoods(*s.topology, *s.mesh, spec, ctx.threads()));
        // The default frame normals and their point records (FitInputCache) now, so the
        // entry's bytes count them; a later revision's replace them (the same size).
        n->fit_inputs.Get(*s.mesh, *s.topology, FitOptions().frame_normals, &n->ordered.order, ctx.threads());
        return std::make_pair(n, static_cast<int64_t>(n->Bytes()));
      },
      ctx.token());
}

absl::StatusOr<std::shared_ptr<const SparseMatrix>> Workspace::Operator(const Snapshot& s, const FitOptions& options,
                                                                        OperatorKind kind, const RunContext& ctx) {
  if (options.method != FitMethod::kLHF)
    return absl::InvalidArgumentError("options.method: the GFD operators need LHF fits (height functions)");
  if (const int64_t need = EstimateFitBytes(s.mesh->NumVertices(), options); need > cache_->budget())
    return absl::ResourceExhaustedError(absl::StrCat("operators of ", s.mesh->NumVertices(), " vertices need about ",
                                                     need, " bytes; the cache budget is ", cache_->budget()));
  const RingSpec spec = RingSpecFor(options);
  GF_ASSIGN_OR_RETURN(auto nbhd, NeighborhoodsOf(s, spec, ctx));
  GF_ASSIGN_OR_RETURN(auto assembler, cache_->Get<OperatorAssembler>(
                                          OperatorPatternKey(s.mesh_id, spec),
                                          [&]() -> Made<OperatorAssembler> {
                                            auto a = std::make_shared<const OperatorAssembler>(nbhd);
                                            // slots, columns and offsets: ~2 ints per stencil point
                                            return std::make_pair(a, static_cast<int64_t>(nbhd->StencilBytes()));
                                          },
                                          ctx.token()));
  return cache_->Get<SparseMatrix>(
      OperatorKey(s.mesh_id, s.revision, options, static_cast<int>(kind)),
      [&]() -> Made<SparseMatrix> {
        GF_ASSIGN_OR_RETURN(auto fits, FitForOperators(*s.mesh, *s.topology, options, nbhd, ctx));
        GF_ASSIGN_OR_RETURN(SparseMatrix m, assembler->Assemble(kind, *fits, ctx));
        const int64_t bytes = static_cast<int64_t>(m.nonZeros()) * 12 + (m.outerSize() + 1) * 4;
        return std::make_pair(std::make_shared<const SparseMatrix>(std::move(m)), bytes);
      },
      ctx.token());
}

absl::StatusOr<Evaluated> Workspace::Evaluate(const Snapshot& s, const FitOptions& options, uint32_t mask,
                                              const RunContext& ctx, Evaluation* progress) {
  Evaluated e;
  std::atomic<int64_t> evaluated{0};  // rows `progress` received during the fit
  FittedBlockFn on_fitted;
  if (progress) {
    on_fitted = [&](const SurfaceFits& fits, int64_t begin, int64_t end) {
      EvaluateDifferentials(fits, mask, begin, end, progress->filling().get());
      evaluated += end - begin;
      progress->Filled(begin, end);
    };
  }
  GF_ASSIGN_OR_RETURN(e.fitted, Fit(s, options, ctx, false, on_fitted));
  // Derived quantities belong to the fitting tier too: a repeated request only serializes.
  Stopwatch watch;
  GF_ASSIGN_OR_RETURN(e.values, cache_->Get<Differentials>(
                                    DifferentialsKey(e.fitted.key, mask),
                                    [&]() -> Made<Differentials> {
                                      std::shared_ptr<const Differentials> d;
                                      if (progress && evaluated == e.fitted.fits->num_vertices()) {
                                        d = progress->filling();  // evaluated during the fit
                                      } else {
                                        GF_ASSIGN_OR_RETURN(Differentials computed,
                                                            ComputeDifferentials(*e.fitted.fits, mask, ctx));
                                        d = std::make_shared<const Differentials>(std::move(computed));
                                      }
                                      return std::make_pair(d, DifferentialsBytes(*d));
                                    },
                                    ctx.token(), &e.hit));
  e.ms = e.hit ? 0 : watch.Millis();
  return e;
}

std::shared_ptr<Evaluation> Workspace::JoinEvaluation(const Snapshot& s, const FitOptions& options, uint32_t mask,
                                                      bool* owner) {
  CacheKey key = DifferentialsKey(FitKey(s.mesh_id, s.revision, options, false), mask);
  std::lock_guard<std::mutex> lock(evaluations_mu_);
  std::shared_ptr<Evaluation>& ev = evaluations_[key];
  *owner = ev == nullptr;
  if (*owner) ev = std::make_shared<Evaluation>(std::move(key), s.mesh, mask);
  return ev;
}

absl::StatusOr<Evaluated> Workspace::Run(const std::shared_ptr<Evaluation>& ev, const Snapshot& s,
                                         const FitOptions& options, const RunContext& ctx) {
  absl::StatusOr<Evaluated> e = Evaluate(s, options, ev->mask(), ctx, ev.get());
  End(ev, e);
  return e;
}

void Workspace::End(const std::shared_ptr<Evaluation>& ev, absl::StatusOr<Evaluated> result) {
  ev->Finish(std::move(result));  // before unregistering: a request arriving now finds the values
  std::lock_guard<std::mutex> lock(evaluations_mu_);
  const auto it = evaluations_.find(ev->key());
  if (it != evaluations_.end() && it->second == ev) evaluations_.erase(it);
}

void Workspace::Remember(const Snapshot& s, const FitOptions& options, uint32_t mask) {
  std::lock_guard<std::mutex> lock(recipes_mu_);
  Recipe& r = recipes_[s.mesh_id];
  if (s.revision >= r.revision) r = Recipe{options, mask, s.revision};
}

std::unique_ptr<Workspace::PendingPrefetch> Workspace::PlanPrefetch(const std::string& id, int64_t revision) {
  if (!options_.prefetch) return nullptr;
  Recipe recipe;
  {
    std::lock_guard<std::mutex> lock(recipes_mu_);
    auto it = recipes_.find(id);
    if (it == recipes_.end() || it->second.revision != revision - 1) return nullptr;
    recipe = it->second;
  }
  absl::StatusOr<Snapshot> s = Acquire(id, revision);
  if (!s.ok()) return nullptr;
  bool owner = false;
  std::shared_ptr<Evaluation> ev = JoinEvaluation(*s, recipe.options, recipe.mask, &owner);
  if (!owner) return nullptr;  // a request got there first
  return std::make_unique<PendingPrefetch>(this, std::move(ev), *std::move(s), recipe.options);
}

void Workspace::PendingPrefetch::Run(const CancellationToken& cancel) {
  ran_ = true;
  const absl::StatusOr<Evaluated> e = ws_->Run(ev_, snapshot_, options_, ws_->Context(&cancel));
  if (!e.ok()) {
    spdlog::debug("prefetch of {} revision {}: {}", snapshot_.mesh_id, snapshot_.revision, e.status().ToString());
  } else {
    spdlog::debug("prefetch of {} revision {}: fit {:.3f} ms, evaluate {:.3f} ms", snapshot_.mesh_id,
                  snapshot_.revision, e->fitted.ms, e->ms);
  }
}

Workspace::PendingPrefetch::~PendingPrefetch() {
  if (!ran_) ws_->End(ev_, absl::CancelledError("prefetch not run"));
}

absl::StatusOr<std::unique_ptr<Reconstructed>> Workspace::Reconstruct(const Snapshot& s,
                                                                      const ReconstructionOptions& ro,
                                                                      bool stencils, const RunContext& ctx) {
  GF_RETURN_IF_ERROR(ro.Validate());
  auto r = std::make_unique<Reconstructed>();
  r->snapshot = s;
  if (!ro.has_features()) {
    GF_ASSIGN_OR_RETURN(Fitted f, Fit(s, ro.fit, ctx, stencils));
    r->fits = f.fits;
    r->surface = MakeSurface(ro.method, *s.mesh, r->fits, ctx.threads());
    return r;
  }
  // Sharp features (§4.1.4): split the mesh along them and fit the split mesh; the fits
  // are cached under a key naming the feature edges.
  FeatureOptions fo;
  fo.angle_deg = ro.feature_angle_deg > 0 ? ro.feature_angle_deg : 180;
  fo.marked = ro.feature_edges;
  GF_ASSIGN_OR_RETURN(Features detected, DetectFeatures(*s.mesh, *s.topology, fo));
  r->features = std::make_shared<const Features>(std::move(detected));
  GF_ASSIGN_OR_RETURN(Topology split, BuildTopology(r->features->split));
  r->split_topology = std::make_shared<const Topology>(std::move(split));
  std::vector<std::pair<int, int>> edges(r->features->edges.begin(), r->features->edges.end());
  GF_ASSIGN_OR_RETURN(r->fits, cache_->Get<SurfaceFits>(
                                   FeatureFitKey(s.mesh_id, s.revision, edges, ro.fit, stencils),
                                   [&]() -> Made<SurfaceFits> {
                                     GF_ASSIGN_OR_RETURN(auto fits, FitSurface(r->features->split, *r->split_topology,
                                                                               ro.fit, nullptr, FitRequest{stencils}, ctx));
                                     return std::make_pair(fits, static_cast<int64_t>(fits->Bytes()));
                                   },
                                   ctx.token()));
  r->surface = std::make_unique<FeatureSurface>(*s.mesh, r->features,
                                                MakeSurface(ro.method, r->features->split, r->fits, ctx.threads()),
                                                ro.fit.degree);
  return r;
}

}  // namespace geomfit::server
