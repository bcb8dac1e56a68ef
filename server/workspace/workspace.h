#pragma once
// The engine without protobuf or gRPC: the mesh store, the three cache tiers under typed
// keys, per-request snapshots, single-flight fits, progressive evaluation and prefetch.
// Handlers translate proto <-> these calls; jobs call them directly.
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/fitting/fit.h"
#include "core/mesh/topology.h"
#include "core/operators/operators.h"
#include "core/reconstruction/features.h"
#include "core/reconstruction/options.h"
#include "core/reconstruction/surface.h"
#include "core/util/run_context.h"
#include "server/mesh_store.h"
#include "server/workspace/cache.h"
#include "server/workspace/evaluation.h"
#include "server/workspace/keys.h"
#include "server/workspace/quotas.h"

namespace geomfit::server {

struct WorkspaceOptions {
  int64_t max_vertices = 20'000'000;
  int threads = 0;        ///< numeric threads per computation; 0 = all cores
  bool prefetch = true;   ///< after a position update, recompute the last step's differentials
  StoreQuotaLimits quotas{};  ///< per tenant (--quota-meshes, --quota-bytes); 0 = unlimited
};

/// What a new mesh is called.
struct MeshMeta {
  std::string name;
  std::map<std::string, std::string> labels;
  std::string tenant{};  ///< the id namespace: "" = the single tenant (ids are content hashes)
};

/// Limits of a mesh's name and labels (bytes): a listing stays small.
constexpr size_t kMaxNameBytes = 256, kMaxLabels = 32, kMaxLabelKeyBytes = 64, kMaxLabelValueBytes = 256;
/// INVALID_ARGUMENT naming the limit a name or label exceeds (never echoing them).
absl::Status CheckMeshMeta(const MeshMeta& meta);

/// Tenant namespaces of stored ids: tenant T's mesh X is stored as "T/X" (the service
/// scopes ids on the way in and out, server/rpc/tenancy.h), so identical uploads by two
/// tenants are two meshes; the single tenant's ids are the bare content-hash ids.
std::string TenantPrefix(absl::string_view tenant);
/// The tenant of a stored id ("" if unscoped): meshes derived from it live there too.
std::string TenantOfId(absl::string_view stored_id);

/// One revision of a mesh with its topology: acquired once by a request and held to
/// its end, so an update or a cache eviction meanwhile cannot take it away.
struct Snapshot {
  std::string mesh_id;
  int64_t revision = 0;
  std::shared_ptr<const Mesh> mesh;
  std::shared_ptr<const Topology> topology;
};

/// A snapshot's reconstructed surface and everything it holds on to.
struct Reconstructed {
  Snapshot snapshot;
  std::shared_ptr<const Features> features;  ///< with sharp features: fits are of the split mesh
  std::shared_ptr<const Topology> split_topology;
  std::shared_ptr<const SurfaceFits> fits;
  std::unique_ptr<ReconstructedSurface> surface;
};

class Workspace {
 public:
  Workspace(MeshStore* store, Cache* cache, WorkspaceOptions options);

  const WorkspaceOptions& options() const { return options_; }
  /// The run context of a request: the server's threads, the request's token.
  RunContext Context(const CancellationToken* cancel) const { return RunContext(cancel, options_.threads); }

  // Meshes.
  /// Validates, hashes and stores a new mesh; identical content returns the stored one.
  absl::StatusOr<MeshRecord> AddMesh(Mesh mesh, const MeshMeta& meta);
  /// New positions as revision + 1 (ABORTED if `expected_revision` is set and stale);
  /// topology caches survive, requests holding the old revision finish on it.
  absl::StatusOr<MeshRecord> UpdatePositions(const std::string& id, std::optional<int64_t> expected_revision,
                                             Positions positions);
  absl::StatusOr<MeshRecord> Info(const std::string& id);
  /// The stored mesh at `revision` (0 = latest; only the latest is kept).
  absl::StatusOr<StoredMesh> Stored(const std::string& id, int64_t revision);
  absl::StatusOr<std::vector<MeshRecord>> List(const std::string& after_id, int limit);
  absl::Status Delete(const std::string& id);

  /// Mesh `id` at `revision` (0 = latest) with its topology.
  absl::StatusOr<Snapshot> Acquire(const std::string& id, int64_t revision);

  // Fits and differentials.
  /// The fits of `s` under `options`, from the cache or computed (single-flight).
  /// `on_fitted` runs only if the fit is computed here.
  absl::StatusOr<Fitted> Fit(const Snapshot& s, const FitOptions& options, const RunContext& ctx,
                             bool stencils = false, const FittedBlockFn& on_fitted = nullptr);
  /// Fits plus differentials `mask`; a fit computed here fills `progress` block by block.
  absl::StatusOr<Evaluated> Evaluate(const Snapshot& s, const FitOptions& options, uint32_t mask,
                                     const RunContext& ctx, Evaluation* progress = nullptr);
  /// The running evaluation of (s, options, mask), or a new registered one that the
  /// caller owns (`*owner`) and must Run or End.
  std::shared_ptr<Evaluation> JoinEvaluation(const Snapshot& s, const FitOptions& options, uint32_t mask,
                                             bool* owner);
  /// Owner: Evaluate into `ev`, then End it.
  absl::StatusOr<Evaluated> Run(const std::shared_ptr<Evaluation>& ev, const Snapshot& s, const FitOptions& options,
                                const RunContext& ctx);
  /// Owner: ends `ev` with `result` (its followers get it) and unregisters it.
  void End(const std::shared_ptr<Evaluation>& ev, absl::StatusOr<Evaluated> result);

  // Prefetch for time stepping.
  /// What a prefetch repeats after the next update of `s`'s mesh.
  void Remember(const Snapshot& s, const FitOptions& options, uint32_t mask);
  class PendingPrefetch;
  /// Once an update made `revision`: the recomputation of what was remembered for
  /// revision - 1, registered at once so that the step's request joins it. Null if
  /// there is nothing to repeat or prefetch is off. Run it once the update is answered.
  std::unique_ptr<PendingPrefetch> PlanPrefetch(const std::string& id, int64_t revision);

  // Reconstruction (chapter 4).
  absl::StatusOr<std::unique_ptr<Reconstructed>> Reconstruct(const Snapshot& s, const ReconstructionOptions& options,
                                                             bool stencils, const RunContext& ctx);

  // GFD operators (chapter 5).
  /// The operator `kind` of `s`'s LHF fits under `options`: the pattern (an
  /// OperatorAssembler) from the topology tier, the matrix from the fitting tier.
  absl::StatusOr<std::shared_ptr<const SparseMatrix>> Operator(const Snapshot& s, const FitOptions& options,
                                                               OperatorKind kind, const RunContext& ctx);

  const Cache& cache() const { return *cache_; }
  /// Stored meshes per tenant: AddMesh and Delete go through it; Load it before serving.
  StoreQuotas& quotas() { return quotas_; }
  MeshStore& store() const { return *store_; }

 private:
  absl::StatusOr<std::shared_ptr<const Mesh>> Geometry(const std::string& id, int64_t* revision);
  absl::StatusOr<std::shared_ptr<const Topology>> TopologyOf(const std::string& id, const Mesh& mesh);
  /// The stencils of `s`'s mesh under `spec`, from the topology tier.
  absl::StatusOr<std::shared_ptr<const Neighborhoods>> NeighborhoodsOf(const Snapshot& s, const RingSpec& spec,
                                                                       const RunContext& ctx);

  struct Recipe {
    FitOptions options;
    uint32_t mask = 0;
    int64_t revision = 0;
  };
  MeshStore* store_;
  Cache* cache_;
  const WorkspaceOptions options_;
  std::mutex recipes_mu_;
  std::map<std::string, Recipe> recipes_;
  std::mutex evaluations_mu_;
  std::map<CacheKey, std::shared_ptr<Evaluation>> evaluations_;  ///< running, by differentials key
  StoreQuotas quotas_;
};

/// A prefetch registered by PlanPrefetch: Run computes it; dropped unrun, it ends as
/// cancelled (requests that joined it then compute for themselves).
class Workspace::PendingPrefetch {
 public:
  PendingPrefetch(Workspace* ws, std::shared_ptr<Evaluation> ev, Snapshot snapshot, FitOptions options)
      : ws_(ws), ev_(std::move(ev)), snapshot_(std::move(snapshot)), options_(options) {}
  ~PendingPrefetch();
  PendingPrefetch(const PendingPrefetch&) = delete;
  PendingPrefetch& operator=(const PendingPrefetch&) = delete;
  void Run(const CancellationToken& cancel);

 private:
  Workspace* ws_;
  std::shared_ptr<Evaluation> ev_;
  const Snapshot snapshot_;
  const FitOptions options_;
  bool ran_ = false;
};

/// Bytes of a mesh's arrays.
int64_t MeshBytes(const Mesh& mesh);

}  // namespace geomfit::server
