#pragma once
// The RPC logic: proto in -> absl::StatusOr<proto> out. No gRPC types here, so every
// handler is testable without a network; service.cc adapts them to the callback API.
#include <chrono>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/fitting/fit.h"
#include "core/mesh/topology.h"
#include "core/util/cancel.h"
#include "geomfit/v1/geomfit.pb.h"
#include "server/assembly.h"
#include "server/cache.h"
#include "server/evaluation.h"
#include "server/mesh_store.h"
#include "server/request_stats.h"

namespace geomfit::server {

struct HandlerOptions {
  int64_t max_vertices = 20'000'000;
  int64_t max_message_bytes = int64_t{64} << 20;
  int64_t chunk_rows = 0;            ///< default rows per streamed chunk; 0 = by chunk_bytes
  int64_t chunk_bytes = 128 << 10;   ///< target chunk size when no row count is set
  int threads = 0;             ///< numeric threads per computation
  bool prefetch = true;        ///< Prefetch after UpdatePositions (--prefetch)
  int workers = 2;             ///< reported by GetServerInfo
};

/// Receives a server-streaming handler's chunks as soon as each is ready (from any
/// thread; calls are serialized).
template <typename Response>
class ChunkSink {
 public:
  virtual ~ChunkSink() = default;
  /// `last`: no chunk follows; the handler then returns OK.
  virtual void Push(Response chunk, bool last) = 0;
};

template <typename Response>
struct ChunkCollector final : ChunkSink<Response> {
  std::vector<Response> chunks;
  void Push(Response chunk, bool) override { chunks.push_back(std::move(chunk)); }
};

/// INVALID_ARGUMENT for an empty mesh id.
absl::Status RequireId(const std::string& id);

class Handlers {
 public:
  Handlers(MeshStore* store, Cache* cache, const RequestStats* stats, HandlerOptions options);

  absl::StatusOr<v1::MeshInfo> UploadMesh(const UploadAssembler& upload);
  absl::StatusOr<v1::MeshInfo> UpdatePositions(const PositionsAssembler& update);
  /// UpdatePositions in one message.
  absl::StatusOr<v1::MeshInfo> SetPositions(const v1::SetPositionsRequest& request);
  absl::StatusOr<v1::MeshInfo> GetMesh(const v1::GetMeshRequest& request);
  absl::StatusOr<std::vector<v1::DownloadMeshResponse>> DownloadMesh(const v1::DownloadMeshRequest& request);
  absl::StatusOr<v1::ListMeshesResponse> ListMeshes(const v1::ListMeshesRequest& request);
  absl::StatusOr<v1::DeleteMeshResponse> DeleteMesh(const v1::DeleteMeshRequest& request);
  /// Fits (or reuses cached fits) and evaluates, polling `cancel`. Chunks go to `sink`
  /// as soon as their rows are evaluated: a fresh fit streams while it runs, and a
  /// request that finds the same computation running (another request's, or a
  /// prefetch) streams from it. The first chunk's summary names the mesh, revision and
  /// vertex count; the last chunk's is complete. After an error some chunks may be out.
  absl::Status ComputeDifferentials(const v1::ComputeDifferentialsRequest& request, const CancellationToken& cancel,
                                    ChunkSink<v1::ComputeDifferentialsResponse>* sink);
  /// The same, collected.
  absl::StatusOr<std::vector<v1::ComputeDifferentialsResponse>> ComputeDifferentials(
      const v1::ComputeDifferentialsRequest& request, const CancellationToken& cancel);
  class PendingPrefetch;
  /// Time stepping: once UpdatePositions made `revision`, the recomputation of the
  /// differentials last requested on revision - 1, registered at once, so that the
  /// step's ComputeDifferentials, however soon it comes, joins it (streaming from it)
  /// instead of starting its own a round trip later. Null unless the previous revision
  /// had such a request. The caller runs it once the update is acknowledged.
  std::unique_ptr<PendingPrefetch> PlanPrefetch(const std::string& id, int64_t revision);
  /// PlanPrefetch, run at once.
  void Prefetch(const std::string& id, int64_t revision, const CancellationToken& cancel);
  v1::ServerInfo GetServerInfo() const;
  v1::Statistics GetStatistics() const;

  // Chapter 4 (reconstruction_handlers.cc).
  absl::StatusOr<std::vector<v1::ProjectPointsResponse>> ProjectPoints(const v1::ProjectPointsRequest& request,
                                                                       const CancellationToken& cancel);
  absl::StatusOr<v1::HighOrderNodesResponse> HighOrderNodes(const v1::HighOrderNodesRequest& request,
                                                            const CancellationToken& cancel);
  absl::StatusOr<v1::MeshInfo> RefineMesh(const v1::RefineMeshRequest& request, const CancellationToken& cancel);
  absl::StatusOr<v1::IntegrateResponse> Integrate(const v1::IntegrateRequest& request,
                                                  const CancellationToken& cancel);

  const HandlerOptions& options() const { return options_; }

 private:
  /// Fits and differentials from the cache or computed; a fit computed here fills
  /// `progress` block by block (evaluating each block as soon as it is fitted). `mesh`:
  /// the revision's mesh if the caller holds it (`revision` is then resolved).
  absl::StatusOr<Evaluated> Evaluate(const std::string& id, int64_t revision, const FitOptions& options,
                                     uint32_t mask, const CancellationToken& cancel, Evaluation* progress = nullptr,
                                     std::shared_ptr<const Mesh> mesh = nullptr);
  /// The running evaluation of `revision` (resolved; its `mesh`), `options` and `mask`,
  /// or a new registered one the caller owns (`*owner`) and must Run.
  std::shared_ptr<Evaluation> JoinEvaluation(const std::string& id, int64_t revision, const FitOptions& options,
                                             uint32_t mask, std::shared_ptr<const Mesh> mesh, bool* owner);
  /// Owner: Evaluate into `ev`, end it and unregister it.
  absl::StatusOr<Evaluated> Run(const std::shared_ptr<Evaluation>& ev, const std::string& id, int64_t revision,
                                const FitOptions& options, const CancellationToken& cancel);
  /// Owner: ends `ev` with `result` (its followers get it) and unregisters it.
  void End(const std::shared_ptr<Evaluation>& ev, absl::StatusOr<Evaluated> result);
  /// What ComputeDifferentials last computed per mesh (for Prefetch).
  struct Recipe {
    FitOptions options;
    uint32_t mask = 0;
    int64_t revision = 0;
  };
  /// `stencils`: fits that also carry their stencil operators (field integration).
  /// `on_fitted`: see FitRequest (runs only if the fit is computed here); `mesh`: as
  /// for Evaluate.
  absl::StatusOr<Fitted> Fit(const std::string& id, int64_t revision, const FitOptions& options,
                             const CancellationToken& cancel, bool stencils = false,
                             const decltype(FitRequest::on_fitted)& on_fitted = nullptr,
                             std::shared_ptr<const Mesh> mesh = nullptr);
  /// Validates, hashes and stores a new mesh (UploadMesh, RefineMesh).
  absl::StatusOr<v1::MeshInfo> StoreNewMesh(Mesh mesh, const v1::MeshHeader& header);
  struct Reconstructed;
  /// The reconstructed surface of a request (fits from the cache).
  absl::StatusOr<std::unique_ptr<Reconstructed>> Reconstruct(const std::string& id, int64_t revision,
                                                             const v1::ReconstructionOptions& options,
                                                             bool stencils, const CancellationToken& cancel);
  /// Mesh `id` at `revision` (0 = latest) from the geometry tier.
  absl::StatusOr<std::shared_ptr<const Mesh>> Geometry(const std::string& id, int64_t revision,
                                                       int64_t* resolved_revision);
  absl::StatusOr<std::shared_ptr<const Topology>> TopologyOf(const std::string& id, const Mesh& mesh);
  /// Rows per streamed chunk: the request's, else the server's, else as many as fill
  /// chunk_bytes; never more than half the message limit.
  int64_t ChunkRows(int64_t requested, int64_t bytes_per_row) const;

  MeshStore* store_;
  Cache* cache_;
  const RequestStats* stats_;
  const HandlerOptions options_;
  std::mutex recipes_mu_;
  std::map<std::string, Recipe> recipes_;
  std::mutex evaluations_mu_;
  std::map<std::string, std::shared_ptr<Evaluation>> evaluations_;  ///< running, by differentials key
  const std::chrono::steady_clock::time_point started_ = std::chrono::steady_clock::now();
};

/// A prefetch registered by Handlers::PlanPrefetch: Run computes it; dropped unrun, it
/// ends as cancelled (requests that joined it then compute for themselves).
class Handlers::PendingPrefetch {
 public:
  PendingPrefetch(Handlers* handlers, std::shared_ptr<Evaluation> ev, std::string id, int64_t revision,
                  FitOptions options)
      : handlers_(handlers), ev_(std::move(ev)), id_(std::move(id)), revision_(revision), options_(options) {}
  ~PendingPrefetch();
  PendingPrefetch(const PendingPrefetch&) = delete;
  PendingPrefetch& operator=(const PendingPrefetch&) = delete;
  void Run(const CancellationToken& cancel);

 private:
  Handlers* handlers_;
  std::shared_ptr<Evaluation> ev_;
  const std::string id_;
  const int64_t revision_;
  const FitOptions options_;
  bool ran_ = false;
};

}  // namespace geomfit::server
