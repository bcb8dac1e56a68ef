#pragma once
// Per-tenant quotas of stored meshes (--quota-meshes, --quota-bytes). The usage is
// derived from the store at start-up and kept up to date by every insert and delete
// that goes through here, never persisted: with the SQLite store it survives restarts
// because the meshes do.
#include <cstdint>
#include <map>
#include <mutex>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "server/mesh_store.h"

namespace geomfit::server {

/// 0 = unlimited.
struct StoreQuotaLimits {
  int64_t meshes = 0;  ///< stored meshes per tenant
  int64_t bytes = 0;   ///< their bytes (StoredBytes) per tenant
};

struct TenantUsage {
  int64_t meshes = 0;
  int64_t bytes = 0;
};

/// What a stored mesh counts against --quota-bytes: its arrays, 24 bytes per vertex and
/// 16 per face (MeshBytes). The store keeps only the latest revision, so position
/// updates (and a flow's snapshots) do not change it.
int64_t StoredBytes(const MeshRecord& record);

/// The tenant (Workspace TenantOfId) of each stored mesh is charged for it.
class StoreQuotas {
 public:
  explicit StoreQuotas(StoreQuotaLimits limits) : limits_(limits) {}
  /// False when both limits are 0: then nothing is counted and inserts go straight through.
  bool enabled() const { return limits_.meshes > 0 || limits_.bytes > 0; }
  /// Counts every stored mesh (call once, before serving).
  absl::Status Load(MeshStore& store);
  /// store.Insert charged to the mesh's tenant. A mesh that exists already is returned
  /// as stored (idempotent upload) and charged nothing; a new one that would exceed a
  /// limit is RESOURCE_EXHAUSTED naming it ("tenant quota --quota-meshes=3 reached").
  absl::StatusOr<MeshRecord> Insert(MeshStore& store, const MeshRecord& info, const Mesh& mesh);
  /// store.Delete, credited to the mesh's tenant.
  absl::Status Delete(MeshStore& store, const std::string& id);
  TenantUsage Usage(const std::string& tenant) const;

 private:
  const StoreQuotaLimits limits_;
  /// Held across the check and the store write, so concurrent uploads cannot both pass
  /// a limit (the stores serialize their writes anyway).
  mutable std::mutex mu_;
  std::map<std::string, TenantUsage> usage_;
};

}  // namespace geomfit::server
