#include <chrono>
#include <map>
#include <mutex>

#include "absl/strings/str_cat.h"
#include "server/mesh_store.h"

namespace geomfit::server {

namespace {

size_t MeshBytes(const Mesh& m) {
  return sizeof(double) * m.positions.size() + sizeof(int32_t) * m.faces.size();
}

class MemoryStore final : public MeshStore {
 public:
  std::string Kind() const override { return "memory"; }

  absl::StatusOr<MeshRecord> Insert(const MeshRecord& info, const Mesh& mesh) override {
    std::lock_guard<std::mutex> lock(mu_);
    auto [it, inserted] = meshes_.try_emplace(info.mesh_id);
    if (inserted) it->second = {info, std::make_shared<const Mesh>(mesh)};
    return it->second.info;
  }

  absl::StatusOr<MeshRecord> UpdatePositions(const std::string& id, std::optional<int64_t> expected,
                                               std::shared_ptr<const Mesh> moved) override {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = meshes_.find(id);
    if (it == meshes_.end()) return MeshNotFound(id);
    StoredMesh& s = it->second;
    if (expected && *expected != s.info.revision) return StaleRevision(id, *expected, s.info.revision);
    if (absl::Status c = CheckVertexCount(id, moved->positions.rows(), s.info.num_vertices); !c.ok()) return c;
    AmendForPositions(moved->positions, s.info.revision + 1, &s.info);
    s.mesh = std::move(moved);
    return s.info;
  }

  absl::StatusOr<MeshRecord> GetInfo(const std::string& id) override {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = meshes_.find(id);
    if (it == meshes_.end()) return MeshNotFound(id);
    return it->second.info;
  }

  absl::StatusOr<StoredMesh> Get(const std::string& id) override {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = meshes_.find(id);
    if (it == meshes_.end()) return MeshNotFound(id);
    return it->second;
  }

  absl::StatusOr<std::vector<MeshRecord>> List(const std::string& after_id, int limit) override {
    std::lock_guard<std::mutex> lock(mu_);
    std::vector<MeshRecord> out;
    for (auto it = meshes_.upper_bound(after_id); it != meshes_.end() && static_cast<int>(out.size()) < limit; ++it)
      out.push_back(it->second.info);
    return out;
  }

  absl::Status Delete(const std::string& id) override {
    std::lock_guard<std::mutex> lock(mu_);
    if (meshes_.erase(id) == 0) return MeshNotFound(id);
    return absl::OkStatus();
  }

  StoreStats Stats() override {
    std::lock_guard<std::mutex> lock(mu_);
    StoreStats s;
    s.meshes = static_cast<int64_t>(meshes_.size());
    for (const auto& [id, m] : meshes_) s.bytes += static_cast<int64_t>(MeshBytes(*m.mesh));
    return s;
  }

  absl::Status PutJob(const JobRecord& record) override {
    std::lock_guard<std::mutex> lock(mu_);
    jobs_[record.job_id] = record;
    return absl::OkStatus();
  }

  absl::StatusOr<JobRecord> GetJob(const std::string& job_id) override {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = jobs_.find(job_id);
    if (it == jobs_.end()) return JobNotFound(job_id);
    return it->second;
  }

  absl::StatusOr<std::vector<JobRecord>> ListJobs(const std::string& after_id, int limit) override {
    std::lock_guard<std::mutex> lock(mu_);
    std::vector<JobRecord> out;
    for (auto it = jobs_.upper_bound(after_id); it != jobs_.end() && static_cast<int>(out.size()) < limit; ++it)
      out.push_back(it->second);
    return out;
  }

 private:
  std::mutex mu_;
  std::map<std::string, StoredMesh> meshes_;
  std::map<std::string, JobRecord> jobs_;
};

}  // namespace

std::unique_ptr<MeshStore> NewMemoryStore() { return std::make_unique<MemoryStore>(); }

}  // namespace geomfit::server
