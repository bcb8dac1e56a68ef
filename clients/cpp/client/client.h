#pragma once
// geomfit::Client: the C++ client of the geomfit.v1 service, over core Eigen types.
// Every call has a deadline; UNAVAILABLE is retried with exponential backoff; with
// reupload_on_not_found the client keeps a copy of what it uploaded and re-uploads
// it (with the latest positions it sent) when the server has lost the mesh.
#include <chrono>
#include <functional>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "absl/status/statusor.h"
#include "core/fitting/options.h"
#include "core/mesh/mesh.h"
#include "core/operators/operators.h"
#include "core/integration/integrate.h"
#include "core/mechanics/membrane.h"
#include "core/quantities/differentials.h"
#include "core/reconstruction/meshing.h"
#include "core/reconstruction/projection.h"
#include "core/util/run_context.h"
#include "geomfit/v1/geomfit.pb.h"

namespace geomfit {


struct ClientOptions {
  std::string target = "127.0.0.1:50051";  ///< host:port
  std::chrono::milliseconds deadline{120'000};  ///< per call (per attempt)
  int max_attempts = 4;                     ///< attempts on UNAVAILABLE
  std::chrono::milliseconds initial_backoff{100};
  std::chrono::milliseconds max_backoff{2'000};
  bool reupload_on_not_found = false;
  int64_t chunk_rows = 16384;               ///< rows per upload chunk (384 KiB of positions)
  int64_t max_message_bytes = int64_t{64} << 20;
  /// Transport security (PEM file paths). TLS is on when `tls` is set or any of these
  /// is given; `tls_ca` verifies the server (empty: the system's roots); `tls_cert`
  /// and `tls_key` present a client certificate (mTLS).
  bool tls = false;
  std::string tls_ca, tls_cert, tls_key;
  /// Bearer token (server --auth-tokens): sent as `authorization: Bearer TOKEN`.
  std::string token;
  /// Progress of long calls, called on the calling thread as the server reports it:
  /// ProjectPoints, EvaluateFacePoints, ComputeDifferentials and ComputeMembrane ask for
  /// progress messages (the fit's passes "noise test", "smooth i/S", "frames", "fit";
  /// "membrane"); HighOrderNodes, Integrate and RefineMesh use their streaming variants
  /// (the unary calls on a server without them); ComputeDifferentials also reports the
  /// rows received (phase "compute") while no fit pass is under way (cached results, old servers).
  /// Null: no progress (and the plain calls).
  std::function<void(const Progress&)> progress;
};

/// What the server knows about a stored mesh.
struct RemoteMesh {
  std::string mesh_id;
  int64_t revision = 0;
  int64_t num_vertices = 0, num_faces = 0;
  std::string name, content_hash;
  std::map<std::string, std::string> labels;
  Eigen::Vector3d bbox_min = Eigen::Vector3d::Zero(), bbox_max = Eigen::Vector3d::Zero();
  int64_t num_boundary_edges = 0, num_isolated_vertices = 0;
};

/// Per-request diagnostics of a ComputeDifferentials call.
struct FitSummary {
  int64_t revision = 0;
  int degree_requested = 0, min_degree_used = 0;
  int64_t num_downgraded = 0, num_too_few_points = 0, num_boundary = 0, num_isolated = 0;
  bool fit_cache_hit = false;
  double fit_ms = 0, evaluate_ms = 0;
  double joined_compute_ms = 0;  ///< the computation this request joined (see the proto)
};

struct RemoteDifferentials {
  Differentials values;  ///< arrays not requested are empty
  FitSummary summary;
  v1::FitSummary wire_summary;  ///< the last chunk's complete summary, every field as sent
};

/// A ComputeMembrane call's arrays (those not requested are empty) and revisions.
struct RemoteMembrane {
  MembraneFields values;
  int64_t revision = 0;           ///< the reference's
  int64_t deformed_revision = 0;  ///< 0 when the positions were sent
  double fit_ms = 0, evaluate_ms = 0;
};

class Client {
 public:
  /// Creates the channel (does not wait for the server). A credential file that cannot
  /// be read fails here.
  static absl::StatusOr<std::unique_ptr<Client>> Create(const ClientOptions& options);
  /// Create, with an error from it returned by every call of the client instead.
  static std::unique_ptr<Client> Connect(const ClientOptions& options);
  ~Client();

  absl::StatusOr<RemoteMesh> Upload(const Mesh& mesh, const std::string& name = "",
                                    const std::map<std::string, std::string>& labels = {});
  /// New positions for the same faces; ABORTED if expected_revision is set and stale.
  absl::StatusOr<RemoteMesh> UpdatePositions(const std::string& mesh_id, const Positions& positions,
                                             std::optional<int64_t> expected_revision = std::nullopt);
  /// UpdatePositions without copying `positions` first (one SetPositions message when
  /// they fit in chunk_rows, else a stream), returning the server's MeshInfo as sent.
  absl::StatusOr<v1::MeshInfo> UpdatePositionsWire(const std::string& mesh_id, PositionsRef positions,
                                                   std::optional<int64_t> expected_revision = std::nullopt);
  absl::StatusOr<RemoteMesh> GetMesh(const std::string& mesh_id);
  absl::StatusOr<Mesh> Download(const std::string& mesh_id, RemoteMesh* info = nullptr);
  /// Every stored mesh (all pages).
  absl::StatusOr<std::vector<RemoteMesh>> ListMeshes();
  absl::Status DeleteMesh(const std::string& mesh_id);
  /// `quantities` is a mask of core Quantity bits; revision 0 = latest.
  absl::StatusOr<RemoteDifferentials> ComputeDifferentials(const std::string& mesh_id, const FitOptions& options,
                                                           uint32_t quantities = kAllQuantities,
                                                           int64_t revision = 0, bool diagnostics = false);
  /// The same with the request as on the wire (its mesh_id is resolved like the
  /// others'); wire_summary carries every field of the server's summary.
  absl::StatusOr<RemoteDifferentials> ComputeDifferentials(v1::ComputeDifferentialsRequest request);
  absl::StatusOr<v1::ServerInfo> GetServerInfo();
  absl::StatusOr<v1::Statistics> GetStatistics();
  /// grpc.health.v1 Check of `service` ("" = the whole server): "SERVING",
  /// "NOT_SERVING" (draining), "SERVICE_UNKNOWN" or "UNKNOWN"; an error status when
  /// the call fails (UNAVAILABLE: nothing listening).
  absl::StatusOr<std::string> CheckHealth(const std::string& service = "");

  // Chapter 4: the high-order surface (options as on the wire; default WALF with the
  // fit defaults and the oscillation safeguard on).
  /// Projections of xyz points near the surface onto it.
  absl::StatusOr<std::vector<ProjectedPoint>> ProjectPoints(const std::string& mesh_id, const Positions& points,
                                                            const v1::ReconstructionOptions& options = {});
  /// Positions and normals of face points (face + natural coordinates).
  absl::StatusOr<std::vector<ProjectedPoint>> EvaluateFacePoints(const std::string& mesh_id,
                                                                 const std::vector<FacePoint>& points,
                                                                 const v1::ReconstructionOptions& options = {});
  absl::StatusOr<HighOrderMesh> HighOrderNodes(const std::string& mesh_id, int order,
                                               const v1::ReconstructionOptions& options = {});
  /// Refines onto the surface; the server stores the result as a new mesh.
  absl::StatusOr<RemoteMesh> RefineMesh(const std::string& mesh_id, int factor,
                                        const v1::ReconstructionOptions& options = {}, const std::string& name = "");
  absl::StatusOr<Integrals> Integrate(const std::string& mesh_id, const IntegrationInput& input,
                                      const v1::ReconstructionOptions& options = {});

  // Jobs: work that outlives a call (see the proto's StartJob .. ListJobs).
  /// Queues a job; returns at once.
  absl::StatusOr<v1::Job> StartJob(v1::StartJobRequest request);
  /// Blocks, calling `on_event` for every event with seq >= from_event as it comes, until
  /// the job's final event (OK); `on_event` returning false stops early (OK). A dropped
  /// connection (UNAVAILABLE) is resumed from the last event seen, up to max_attempts
  /// times in a row. No deadline: jobs may run for hours.
  absl::Status WatchJob(const std::string& job_id, int64_t from_event,
                        const std::function<bool(const v1::JobEvent&)>& on_event);
  absl::StatusOr<v1::Job> CancelJob(const std::string& job_id);
  absl::StatusOr<v1::Job> GetJob(const std::string& job_id);
  /// Every job (all pages), in creation order.
  absl::StatusOr<std::vector<v1::Job>> ListJobs();

  // Flows and operators (chapter 5).
  /// StartJob with a flow spec; watch it with WatchJob.
  absl::StatusOr<v1::Job> StartFlow(v1::FlowJob spec);
  /// The GFD operator `kind` of the mesh's LHF fits under `options`, as a CSR matrix.
  absl::StatusOr<SparseMatrix> GetOperator(const std::string& mesh_id, v1::OperatorKind kind,
                                           const v1::FitOptions& options = {});
  /// The operator applied to `field` (n x 1 or n x 3 per vertex): n x k.
  absl::StatusOr<Eigen::MatrixXd> ApplyOperator(const std::string& mesh_id, v1::OperatorKind kind,
                                                const Eigen::MatrixXd& field, const v1::FitOptions& options = {});

  // Membranes (chapter 6).
  /// ComputeMembrane with the request as on the wire (its mesh_id is resolved like the
  /// others'; a deformed.mesh_id is sent as given).
  absl::StatusOr<RemoteMembrane> ComputeMembrane(v1::ComputeMembraneRequest request);
  /// StartJob with a membrane (pressure-load solve) spec; watch it with WatchJob.
  absl::StatusOr<v1::Job> StartMembraneSolve(v1::MembraneSolveJob spec);

  /// The server-side id currently standing for `mesh_id` (differs after a re-upload).
  std::string ResolveId(const std::string& mesh_id) const;

 private:
  struct Impl;
  explicit Client(std::unique_ptr<Impl> impl);
  /// Runs `fn` on the remote id of `mesh_id`; on NOT_FOUND re-uploads once if allowed.
  template <typename T, typename Fn>
  absl::StatusOr<T> WithMesh(const std::string& mesh_id, Fn fn);
  absl::StatusOr<std::vector<ProjectedPoint>> SendProject(const std::string& mesh_id, v1::ProjectPointsRequest request);

  std::unique_ptr<Impl> impl_;
};

}  // namespace geomfit
