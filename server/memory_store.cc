#include <chrono>
#include <map>
#include <mutex>

#include "absl/strings/str_cat.h"
#include "server/mesh_store.h"

namespace geomfit::server {

int64_t NowUnixMs() {
  return std::chrono::duration_cast<std::chrono::milliseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

std::string Bounded(const std::string& client_text) {
  constexpr size_t kMax = 80;  // error messages echo at most this much of a client's id
  return client_text.size() <= kMax ? client_text : absl::StrCat(client_text.substr(0, kMax), "...");
}

absl::Status MeshNotFound(const std::string& id) {
  return absl::NotFoundError(absl::StrCat("mesh '", Bounded(id), "' not found"));
}

absl::Status StaleRevision(const std::string& id, int64_t expected, int64_t actual) {
  return absl::AbortedError(absl::StrCat("mesh '", id, "' is at revision ", actual,
                                         ", not the expected_revision ", expected));
}

absl::Status CheckVertexCount(const std::string& id, int64_t rows, int64_t num_vertices) {
  if (rows == num_vertices) return absl::OkStatus();
  return absl::InvalidArgumentError(
      absl::StrCat("positions: ", rows, " rows, mesh '", id, "' has ", num_vertices, " vertices"));
}

absl::Status JobNotFound(const std::string& job_id) {
  return absl::NotFoundError(absl::StrCat("job '", Bounded(job_id), "' not found"));
}

absl::Status MeshStore::PutJob(const JobRecord&) {
  return absl::UnimplementedError(Kind() + " store keeps no job records");
}
absl::StatusOr<JobRecord> MeshStore::GetJob(const std::string&) {
  return absl::UnimplementedError(Kind() + " store keeps no job records");
}
absl::StatusOr<std::vector<JobRecord>> MeshStore::ListJobs(const std::string&, int) {
  return absl::UnimplementedError(Kind() + " store keeps no job records");
}


FaceKind FaceKindOf(const Mesh& mesh) {
  int quads = 0;
  for (int f = 0; f < mesh.NumFaces(); ++f) quads += mesh.FaceSize(f) == 4;
  if (quads == 0) return FaceKind::kTriangle;
  return quads == mesh.NumFaces() ? FaceKind::kQuad : FaceKind::kMixed;
}

void AmendForPositions(const Positions& positions, int64_t revision, MeshRecord* info) {
  info->revision = revision;
  info->updated_unix_ms = NowUnixMs();
  info->has_bounds = positions.rows() > 0;
  if (positions.rows() == 0) return;
  double lo[3], hi[3];
  const double* p = positions.data();
  for (int i = 0; i < 3; ++i) lo[i] = hi[i] = p[i];
  for (int64_t k = 3; k < positions.size(); k += 3) {  // one pass over the row-major array
    for (int i = 0; i < 3; ++i) {
      lo[i] = std::min(lo[i], p[k + i]);
      hi[i] = std::max(hi[i], p[k + i]);
    }
  }
  for (int i = 0; i < 3; ++i) {
    info->min[i] = lo[i];
    info->max[i] = hi[i];
  }
}

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
