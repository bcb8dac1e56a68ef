#pragma once
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include <array>
#include <map>

#include "core/mesh/mesh.h"
#include "server/jobs/job_record.h"

namespace geomfit::server {

/// Kinds of faces of a mesh (numbered as v1::FaceKind).
enum class FaceKind { kUnspecified = 0, kTriangle = 1, kQuad = 2, kMixed = 3 };
FaceKind FaceKindOf(const Mesh& mesh);

/// A mesh's metadata at its latest revision.
struct MeshRecord {
  std::string mesh_id;
  int64_t revision = 0;  ///< 1 after upload, +1 per position update
  int64_t num_vertices = 0, num_faces = 0;
  FaceKind face_kind = FaceKind::kUnspecified;
  std::string name;
  std::map<std::string, std::string> labels;
  bool has_bounds = false;  ///< false for a mesh of no vertices
  std::array<double, 3> min{}, max{};
  std::string content_hash;  ///< of the uploaded faces, positions, name and labels (hex)
  int64_t created_unix_ms = 0, updated_unix_ms = 0;
  int64_t num_boundary_edges = 0, num_isolated_vertices = 0;
};

/// A stored mesh: its metadata (at the latest revision) and arrays.
struct StoredMesh {
  MeshRecord info;
  std::shared_ptr<const Mesh> mesh;
};

struct StoreStats {
  int64_t meshes = 0;
  int64_t bytes = 0;  ///< array bytes held (memory) or database file size (sqlite)
};

/// Durable (or throwaway) home of uploaded meshes; only the latest revision's
/// positions are kept. Every method is thread-safe; a write returns only once it is
/// durable, and is atomic (a failed or half-finished write is never visible).
class MeshStore {
 public:
  virtual ~MeshStore() = default;
  virtual std::string Kind() const = 0;
  /// Stores a new mesh (info.mesh_id set, revision 1). If the id exists already,
  /// nothing is written and the existing info is returned (idempotent upload).
  virtual absl::StatusOr<MeshRecord> Insert(const MeshRecord& info, const Mesh& mesh) = 0;
  /// Makes `moved` (the stored faces, new positions) revision + 1. NOT_FOUND for an
  /// unknown id; ABORTED when expected_revision is set and differs from the stored
  /// revision. The memory store keeps `moved` itself, so an update copies nothing.
  virtual absl::StatusOr<MeshRecord> UpdatePositions(const std::string& id,
                                                       std::optional<int64_t> expected_revision,
                                                       std::shared_ptr<const Mesh> moved) = 0;
  virtual absl::StatusOr<MeshRecord> GetInfo(const std::string& id) = 0;
  virtual absl::StatusOr<StoredMesh> Get(const std::string& id) = 0;
  /// Up to `limit` meshes with id > after_id, in id order.
  virtual absl::StatusOr<std::vector<MeshRecord>> List(const std::string& after_id, int limit) = 0;
  /// NOT_FOUND for an unknown id.
  virtual absl::Status Delete(const std::string& id) = 0;
  virtual StoreStats Stats() = 0;

  // Job records (server/jobs/job_manager.h). The defaults answer UNIMPLEMENTED.
  /// Inserts or replaces the record of record.job_id; durable on return.
  virtual absl::Status PutJob(const JobRecord& record);
  /// NOT_FOUND for an unknown id.
  virtual absl::StatusOr<JobRecord> GetJob(const std::string& job_id);
  /// Up to `limit` jobs with id > after_id, in id order.
  virtual absl::StatusOr<std::vector<JobRecord>> ListJobs(const std::string& after_id, int limit);
};

/// In-process store for throwaway runs and tests.
std::unique_ptr<MeshStore> NewMemoryStore();
/// SQLite store in `data_dir`/meshes.db (created if missing): WAL, synchronous=FULL.
absl::StatusOr<std::unique_ptr<MeshStore>> OpenSqliteStore(const std::string& data_dir);

/// The info fields that change with positions (bounding box, revision, time).
void AmendForPositions(const Positions& positions, int64_t revision, MeshRecord* info);
int64_t NowUnixMs();
/// NOT_FOUND naming the mesh.
/// At most 80 bytes of a client-supplied id or name, for error messages.
std::string Bounded(const std::string& client_text);
absl::Status MeshNotFound(const std::string& id);
absl::Status StaleRevision(const std::string& id, int64_t expected, int64_t actual);
/// INVALID_ARGUMENT unless an update carries one row per vertex.
/// NOT_FOUND naming the job.
absl::Status JobNotFound(const std::string& job_id);
absl::Status CheckVertexCount(const std::string& id, int64_t rows, int64_t num_vertices);

}  // namespace geomfit::server
