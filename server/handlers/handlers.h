#pragma once
// Proto <-> engine translation: proto in -> absl::StatusOr<proto> out, one file per API
// area (meshes.cc, differentials.cc, reconstruction.cc, integration.cc, info.cc). The
// engine is the Workspace; no gRPC types here, so every handler is testable without a
// network; rpc/service.cc adapts them to the callback API.
#include <algorithm>
#include <chrono>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/util/cancel.h"
#include "geomfit/v1/geomfit.pb.h"
#include "server/assembly.h"
#include "server/request_stats.h"
#include "server/workspace/workspace.h"

namespace geomfit::server {

struct HandlerOptions {
  int64_t max_vertices = 20'000'000;
  int64_t max_message_bytes = int64_t{64} << 20;
  int64_t chunk_rows = 0;            ///< default rows per streamed chunk; 0 = by chunk_bytes
  int64_t chunk_bytes = 128 << 10;   ///< target chunk size when no row count is set
  int workers = 2;             ///< reported by GetServerInfo
};

/// Receives a server-streaming handler's chunks as soon as each is ready (from any
/// thread; calls are serialized). A transport holds at most two encoded chunks per
/// stream: Push may block until the reader has taken one (backpressure; it returns at
/// once, dropping the chunk, once the call is over), PushLazy never blocks.
template <typename Response>
class ChunkSink {
 public:
  virtual ~ChunkSink() = default;
  /// `last`: no chunk follows; the handler then returns OK.
  virtual void Push(Response chunk, bool last) = 0;
  /// A chunk encoded by `make` only when the transport is ready to write it, maybe on
  /// another thread after the handler returned: `make` owns (shared_ptr) what it reads.
  virtual void PushLazy(std::function<Response()> make, bool last) { Push(make(), last); }
};

template <typename Response>
struct ChunkCollector final : ChunkSink<Response> {
  std::vector<Response> chunks;
  void Push(Response chunk, bool) override { chunks.push_back(std::move(chunk)); }
};

/// The chunks `run(sink)` hands over, collected (in-process callers and tests).
template <typename Response, typename Run>
absl::StatusOr<std::vector<Response>> Collected(Run run) {
  ChunkCollector<Response> out;
  if (absl::Status s = run(&out); !s.ok()) return s;
  return std::move(out.chunks);
}

/// Rows [0, n) of `data` as lazy chunks of `rows` rows (one empty chunk when n is 0):
/// `encode(data, first_row, row_count)` makes each when the transport wants it, so a
/// reader that stops reading holds `data` and at most two encoded chunks.
template <typename Response, typename Data, typename Encode>
void PushRows(ChunkSink<Response>* sink, std::shared_ptr<const Data> data, int64_t n, int64_t rows, Encode encode) {
  for (int64_t b = 0; b == 0 || b < n; b += rows) {
    const int64_t m = std::min(rows, n - b);
    sink->PushLazy([data, b, m, encode] { return encode(*data, b, m); }, b + m >= n);
  }
}

/// A server stream's chunks, made one at a time when the transport wants the next
/// (PullReactor): a reader that stops reading holds O(one chunk).
template <typename Response>
class ChunkSource {
 public:
  virtual ~ChunkSource() = default;
  /// The next chunk into `chunk`; false when none is left.
  virtual bool Next(Response* chunk) = 0;
};

/// INVALID_ARGUMENT for an empty mesh id.
absl::Status RequireId(const std::string& id);

class Handlers {
 public:
  Handlers(Workspace* workspace, const RequestStats* stats, HandlerOptions options);

  // Meshes (meshes.cc).
  /// Stores the upload in `tenant`'s id namespace (Workspace TenantPrefix).
  absl::StatusOr<v1::MeshInfo> UploadMesh(const UploadAssembler& upload, const std::string& tenant = "");
  absl::StatusOr<v1::MeshInfo> UpdatePositions(const PositionsAssembler& update);
  /// Once an update stream's header is in: the mesh's vertex count becomes the rows the
  /// stream may send (NOT_FOUND for an unknown mesh).
  absl::Status ExpectPositions(PositionsAssembler* update);
  /// UpdatePositions in one message, decoded straight into the positions.
  absl::StatusOr<v1::MeshInfo> SetPositions(const v1::SetPositionsRequest& request);
  absl::StatusOr<v1::MeshInfo> GetMesh(const v1::GetMeshRequest& request);
  /// The stored mesh as chunks made on demand: info, positions, faces (holds the mesh).
  absl::StatusOr<std::unique_ptr<ChunkSource<v1::DownloadMeshResponse>>> OpenDownload(
      const v1::DownloadMeshRequest& request);
  /// OpenDownload, collected.
  absl::StatusOr<std::vector<v1::DownloadMeshResponse>> DownloadMesh(const v1::DownloadMeshRequest& request);
  absl::StatusOr<v1::ListMeshesResponse> ListMeshes(const v1::ListMeshesRequest& request);
  absl::StatusOr<v1::DeleteMeshResponse> DeleteMesh(const v1::DeleteMeshRequest& request);

  // Differentials (differentials.cc).
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
  /// Workspace::PlanPrefetch (time stepping; see there).
  std::unique_ptr<Workspace::PendingPrefetch> PlanPrefetch(const std::string& id, int64_t revision) {
    return ws_->PlanPrefetch(id, revision);
  }
  /// PlanPrefetch, run at once.
  void Prefetch(const std::string& id, int64_t revision, const CancellationToken& cancel);

  // Chapter 4 (reconstruction.cc, integration.cc). `progress` (optional) gets the
  // work's progress reports (fit, project / evaluate points, integrate), from any thread.
  /// Chunks to `sink`: with request.progress, progress messages (progress.h's
  /// ProgressThrottle) while the work runs, then the result chunks.
  absl::Status ProjectPoints(const v1::ProjectPointsRequest& request, const CancellationToken& cancel,
                             ChunkSink<v1::ProjectPointsResponse>* sink);
  /// The same, collected.
  absl::StatusOr<std::vector<v1::ProjectPointsResponse>> ProjectPoints(const v1::ProjectPointsRequest& request,
                                                                       const CancellationToken& cancel) {
    return Collected<v1::ProjectPointsResponse>(
        [&](ChunkSink<v1::ProjectPointsResponse>* sink) { return ProjectPoints(request, cancel, sink); });
  }
  absl::StatusOr<v1::HighOrderNodesResponse> HighOrderNodes(const v1::HighOrderNodesRequest& request,
                                                            const CancellationToken& cancel,
                                                            const RunContext::ProgressFn& progress = nullptr);
  absl::StatusOr<v1::MeshInfo> RefineMesh(const v1::RefineMeshRequest& request, const CancellationToken& cancel,
                                          const RunContext::ProgressFn& progress = nullptr);
  absl::StatusOr<v1::IntegrateResponse> Integrate(const v1::IntegrateRequest& request,
                                                  const CancellationToken& cancel,
                                                  const RunContext::ProgressFn& progress = nullptr);

  // GFD operators (operators.cc).
  absl::StatusOr<v1::GetOperatorResponse> GetOperator(const v1::GetOperatorRequest& request,
                                                      const CancellationToken& cancel);
  /// The operator times the field (n or n x 1 for scalar operands, n x 3 for vector ones).
  absl::StatusOr<v1::ApplyOperatorResponse> ApplyOperator(const v1::ApplyOperatorRequest& request,
                                                          const CancellationToken& cancel);

  // Membranes (membrane.cc).
  /// Stress, strain, stretches, von Mises stress, pressure and traction of a deformed
  /// membrane against the reference's cached fits, in chunks of rows (PushRows).
  absl::Status ComputeMembrane(const v1::ComputeMembraneRequest& request, const CancellationToken& cancel,
                               ChunkSink<v1::ComputeMembraneResponse>* sink);

  // Server (info.cc).
  v1::ServerInfo GetServerInfo() const;
  v1::Statistics GetStatistics() const;

  const HandlerOptions& options() const { return options_; }
  Workspace& workspace() { return *ws_; }

 private:
  struct OperatorMatrix {
    std::shared_ptr<const SparseMatrix> matrix;
    int64_t revision = 0;
    int64_t num_vertices = 0;
  };
  absl::StatusOr<OperatorMatrix> Operator(const std::string& mesh_id, int64_t revision, v1::OperatorKind kind,
                                          const v1::FitOptions& options, const CancellationToken& cancel);
  /// The snapshot a request names (revision 0 = latest; negative revisions rejected).
  absl::StatusOr<Snapshot> Acquire(const std::string& id, int64_t revision);
  /// A reconstruction request's snapshot and surface.
  absl::StatusOr<std::unique_ptr<Reconstructed>> Reconstruct(const std::string& id, int64_t revision,
                                                             const v1::ReconstructionOptions& options,
                                                             bool stencils, const RunContext& ctx);
  /// The request's RunContext: the workspace's threads, `cancel`, `progress` (may be null).
  RunContext Context(const CancellationToken& cancel, const RunContext::ProgressFn& progress) const {
    return ws_->Context(&cancel).WithProgress(progress);
  }
  /// Rows per streamed chunk: the request's, else the server's, else as many as fill
  /// chunk_bytes; never more than half the message limit.
  int64_t ChunkRows(int64_t requested, int64_t bytes_per_row) const;

  Workspace* ws_;
  const RequestStats* stats_;
  const HandlerOptions options_;
  const std::chrono::steady_clock::time_point started_ = std::chrono::steady_clock::now();
};

}  // namespace geomfit::server
