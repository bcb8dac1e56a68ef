#pragma once
// The durable part of a job (server/jobs): what MeshStore keeps so that a job outlives
// the server process. No protobuf or gRPC types.
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace geomfit::server {

/// Lifecycle of a job; the numbers are the proto's JobState values.
enum class JobState : int {
  kPending = 1,    ///< queued for a job thread
  kRunning = 2,
  kSucceeded = 3,  ///< results stored
  kFailed = 4,     ///< error set (including "interrupted by restart")
  kCancelled = 5,  ///< cancelled by a client; nothing stored
};

/// SUCCEEDED, FAILED or CANCELLED: nothing follows.
inline bool IsFinal(JobState s) { return s == JobState::kSucceeded || s == JobState::kFailed || s == JobState::kCancelled; }

inline std::string_view JobStateName(JobState s) {
  switch (s) {
    case JobState::kPending: return "PENDING";
    case JobState::kRunning: return "RUNNING";
    case JobState::kSucceeded: return "SUCCEEDED";
    case JobState::kFailed: return "FAILED";
    case JobState::kCancelled: return "CANCELLED";
  }
  return "UNKNOWN";
}

/// A mesh a job stored (a new mesh, or a new revision of one).
struct JobResultMesh {
  std::string mesh_id;
  int64_t revision = 0;
  bool operator==(const JobResultMesh& o) const { return mesh_id == o.mesh_id && revision == o.revision; }
};

/// One job as the store keeps it; written when the job is created, starts and ends.
struct JobRecord {
  std::string job_id;
  std::string kind;     ///< e.g. "refine"
  std::string options;  ///< opaque blob (the handlers' serialized request)
  JobState state = JobState::kPending;
  int64_t created_unix_ms = 0;
  int64_t updated_unix_ms = 0;
  /// Meshes stored so far (RUNNING), all of them (SUCCEEDED); none after FAILED or
  /// CANCELLED, except for a job interrupted by a restart: what it had stored.
  std::vector<JobResultMesh> results;
  int error_code = 0;                  ///< absl::StatusCode of a FAILED or CANCELLED job
  std::string error;                   ///< its message
  int64_t last_seq = 0;                ///< seq of the job's latest event when written
};

}  // namespace geomfit::server
