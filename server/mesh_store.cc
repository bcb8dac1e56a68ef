// What every MeshStore shares: record helpers and the errors they return.
#include <algorithm>
#include <chrono>

#include "absl/strings/str_cat.h"
#include "server/mesh_store.h"

namespace geomfit::server {

std::string Bounded(const std::string& client_text) {
  constexpr size_t kMax = 80;  // error messages echo at most this much of a client's id
  return client_text.size() <= kMax ? client_text : absl::StrCat(client_text.substr(0, kMax), "...");
}

int64_t NowUnixMs() {
  return std::chrono::duration_cast<std::chrono::milliseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
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

}  // namespace geomfit::server
