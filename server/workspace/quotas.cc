#include "server/workspace/quotas.h"

#include <vector>

#include "absl/strings/str_cat.h"
#include "core/util/status_macros.h"
#include "server/workspace/workspace.h"

namespace geomfit::server {

int64_t StoredBytes(const MeshRecord& r) {
  return r.num_vertices * 3 * static_cast<int64_t>(sizeof(double)) +
         r.num_faces * static_cast<int64_t>(Faces::ColsAtCompileTime * sizeof(int32_t));
}

absl::Status StoreQuotas::Load(MeshStore& store) {
  if (!enabled()) return absl::OkStatus();
  std::lock_guard<std::mutex> lock(mu_);
  usage_.clear();
  std::string after;
  while (true) {
    GF_ASSIGN_OR_RETURN(std::vector<MeshRecord> page, store.List(after, 1000));
    for (const MeshRecord& r : page) {
      TenantUsage& u = usage_[TenantOfId(r.mesh_id)];
      ++u.meshes;
      u.bytes += StoredBytes(r);
    }
    if (page.size() < 1000) return absl::OkStatus();
    after = page.back().mesh_id;
  }
}

absl::StatusOr<MeshRecord> StoreQuotas::Insert(MeshStore& store, const MeshRecord& info, const Mesh& mesh) {
  if (!enabled()) return store.Insert(info, mesh);
  std::lock_guard<std::mutex> lock(mu_);
  if (store.GetInfo(info.mesh_id).ok()) return store.Insert(info, mesh);  // returns the stored one
  TenantUsage& u = usage_[TenantOfId(info.mesh_id)];
  const int64_t bytes = StoredBytes(info);
  if (limits_.meshes > 0 && u.meshes + 1 > limits_.meshes) {
    return absl::ResourceExhaustedError(absl::StrCat("tenant quota --quota-meshes=", limits_.meshes,
                                                     " reached: delete a mesh to store another"));
  }
  if (limits_.bytes > 0 && u.bytes + bytes > limits_.bytes) {
    return absl::ResourceExhaustedError(absl::StrCat("tenant quota --quota-bytes=", limits_.bytes, " reached: ",
                                                     u.bytes, " bytes stored, the mesh needs ", bytes));
  }
  GF_ASSIGN_OR_RETURN(MeshRecord stored, store.Insert(info, mesh));
  ++u.meshes;
  u.bytes += bytes;
  return stored;
}

absl::Status StoreQuotas::Delete(MeshStore& store, const std::string& id) {
  if (!enabled()) return store.Delete(id);
  std::lock_guard<std::mutex> lock(mu_);
  GF_ASSIGN_OR_RETURN(const MeshRecord info, store.GetInfo(id));
  GF_RETURN_IF_ERROR(store.Delete(id));
  TenantUsage& u = usage_[TenantOfId(id)];
  --u.meshes;
  u.bytes -= StoredBytes(info);
  return absl::OkStatus();
}

TenantUsage StoreQuotas::Usage(const std::string& tenant) const {
  std::lock_guard<std::mutex> lock(mu_);
  const auto it = usage_.find(tenant);
  return it == usage_.end() ? TenantUsage() : it->second;
}

}  // namespace geomfit::server
