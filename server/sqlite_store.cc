// Durable mesh store: one SQLite database in WAL mode with synchronous=FULL, so a
// committed upload or update survives kill -9 and power loss; each write is one
// transaction, so a half-finished upload is never visible.
#include <sqlite3.h>

#include <cstring>
#include <filesystem>
#include <mutex>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "core/util/status_macros.h"
#include "server/mesh_record.h"
#include "server/mesh_store.h"

namespace geomfit::server {
namespace {

/// A prepared statement, reset on destruction so the connection can be reused.
class Statement {
 public:
  Statement(sqlite3* db, const char* sql) : db_(db) {
    rc_ = sqlite3_prepare_v2(db, sql, -1, &stmt_, nullptr);
  }
  ~Statement() { sqlite3_finalize(stmt_); }
  Statement(const Statement&) = delete;
  Statement& operator=(const Statement&) = delete;

  absl::Status status() const {
    return rc_ == SQLITE_OK ? absl::OkStatus()
                            : absl::InternalError(absl::StrCat("sqlite prepare: ", sqlite3_errmsg(db_)));
  }
  void Bind(int i, const std::string& s) { sqlite3_bind_text(stmt_, i, s.data(), static_cast<int>(s.size()), SQLITE_TRANSIENT); }
  void Bind(int i, int64_t v) { sqlite3_bind_int64(stmt_, i, v); }
  void BindBlob(int i, const void* p, size_t n) {
    sqlite3_bind_blob64(stmt_, i, n ? p : "", n, SQLITE_STATIC);
  }
  /// true for a row, false when done; errors as INTERNAL.
  absl::StatusOr<bool> Step() {
    const int rc = sqlite3_step(stmt_);
    if (rc == SQLITE_ROW) return true;
    if (rc == SQLITE_DONE) return false;
    return absl::InternalError(absl::StrCat("sqlite step: ", sqlite3_errmsg(db_)));
  }
  int64_t Int(int col) { return sqlite3_column_int64(stmt_, col); }
  std::string Blob(int col) {
    const void* p = sqlite3_column_blob(stmt_, col);
    return std::string(static_cast<const char*>(p), static_cast<size_t>(sqlite3_column_bytes(stmt_, col)));
  }

 private:
  sqlite3* db_;
  sqlite3_stmt* stmt_ = nullptr;
  int rc_;
};

#define GF_JOB_COLUMNS "id, kind, options, state, created, updated, results, error_code, error, last_seq"
constexpr char kSelectJob[] = "SELECT " GF_JOB_COLUMNS " FROM jobs WHERE id = ?";
constexpr char kListJobs[] = "SELECT " GF_JOB_COLUMNS " FROM jobs WHERE id > ? ORDER BY id LIMIT ?";
#undef GF_JOB_COLUMNS

class SqliteStore final : public MeshStore {
 public:
  ~SqliteStore() override { sqlite3_close(db_); }

  absl::Status Open(const std::string& data_dir) {
    std::error_code ec;
    std::filesystem::create_directories(data_dir, ec);
    if (ec) return absl::FailedPreconditionError(absl::StrCat("--data-dir ", data_dir, ": ", ec.message()));
    path_ = (std::filesystem::path(data_dir) / "meshes.db").string();
    if (sqlite3_open_v2(path_.c_str(), &db_, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_FULLMUTEX,
                        nullptr) != SQLITE_OK) {
      return absl::FailedPreconditionError(absl::StrCat("cannot open ", path_, ": ", sqlite3_errmsg(db_)));
    }
    sqlite3_busy_timeout(db_, 5000);
    GF_RETURN_IF_ERROR(Exec("PRAGMA journal_mode=WAL"));
    GF_RETURN_IF_ERROR(Exec("PRAGMA synchronous=FULL"));
    GF_RETURN_IF_ERROR(Exec(
        "CREATE TABLE IF NOT EXISTS meshes (id TEXT PRIMARY KEY, revision INTEGER NOT NULL, "
        "info BLOB NOT NULL, faces BLOB NOT NULL, positions BLOB NOT NULL)"));
    return Exec(
        "CREATE TABLE IF NOT EXISTS jobs (id TEXT PRIMARY KEY, kind TEXT NOT NULL, options BLOB NOT NULL, "
        "state INTEGER NOT NULL, created INTEGER NOT NULL, updated INTEGER NOT NULL, results BLOB NOT NULL, "
        "error_code INTEGER NOT NULL, error BLOB NOT NULL, last_seq INTEGER NOT NULL)");
  }

  std::string Kind() const override { return "sqlite"; }

  absl::StatusOr<MeshRecord> Insert(const MeshRecord& info, const Mesh& mesh) override {
    std::lock_guard<std::mutex> lock(mu_);
    GF_RETURN_IF_ERROR(Exec("BEGIN IMMEDIATE"));
    absl::StatusOr<MeshRecord> result = InsertLocked(info, mesh);
    return Commit(std::move(result));
  }

  absl::StatusOr<MeshRecord> UpdatePositions(const std::string& id, std::optional<int64_t> expected,
                                               std::shared_ptr<const Mesh> moved) override {
    std::lock_guard<std::mutex> lock(mu_);
    GF_RETURN_IF_ERROR(Exec("BEGIN IMMEDIATE"));
    return Commit(UpdateLocked(id, expected, moved->positions));
  }

  absl::StatusOr<MeshRecord> GetInfo(const std::string& id) override {
    std::lock_guard<std::mutex> lock(mu_);
    return InfoLocked(id);
  }

  absl::StatusOr<StoredMesh> Get(const std::string& id) override {
    std::lock_guard<std::mutex> lock(mu_);
    Statement st(db_, "SELECT info, faces, positions FROM meshes WHERE id = ?");
    GF_RETURN_IF_ERROR(st.status());
    st.Bind(1, id);
    GF_ASSIGN_OR_RETURN(bool row, st.Step());
    if (!row) return MeshNotFound(id);
    StoredMesh out;
    GF_ASSIGN_OR_RETURN(out.info, ParseInfo(st.Blob(0), id));
    auto mesh = std::make_shared<Mesh>();
    const std::string faces = st.Blob(1), positions = st.Blob(2);
    const int64_t nv = out.info.num_vertices, nf = out.info.num_faces;
    if (faces.size() != sizeof(int32_t) * 4 * nf || positions.size() != sizeof(double) * 3 * nv) {
      return absl::DataLossError(absl::StrCat("mesh '", id, "': stored arrays do not match its counts"));
    }
    Faces& mf = mesh->faces.Mutable();
    mf.resize(nf, 4);
    mesh->positions.resize(nv, 3);
    std::memcpy(mf.data(), faces.data(), faces.size());
    std::memcpy(mesh->positions.data(), positions.data(), positions.size());
    out.mesh = std::move(mesh);
    return out;
  }

  absl::StatusOr<std::vector<MeshRecord>> List(const std::string& after_id, int limit) override {
    std::lock_guard<std::mutex> lock(mu_);
    Statement st(db_, "SELECT id, info FROM meshes WHERE id > ? ORDER BY id LIMIT ?");
    GF_RETURN_IF_ERROR(st.status());
    st.Bind(1, after_id);
    st.Bind(2, int64_t{limit});
    std::vector<MeshRecord> out;
    while (true) {
      GF_ASSIGN_OR_RETURN(bool row, st.Step());
      if (!row) break;
      GF_ASSIGN_OR_RETURN(MeshRecord info, ParseInfo(st.Blob(1), st.Blob(0)));
      out.push_back(std::move(info));
    }
    return out;
  }

  absl::Status Delete(const std::string& id) override {
    std::lock_guard<std::mutex> lock(mu_);
    Statement st(db_, "DELETE FROM meshes WHERE id = ?");
    GF_RETURN_IF_ERROR(st.status());
    st.Bind(1, id);
    GF_RETURN_IF_ERROR(st.Step().status());
    if (sqlite3_changes(db_) == 0) return MeshNotFound(id);
    return absl::OkStatus();
  }

  StoreStats Stats() override {
    std::lock_guard<std::mutex> lock(mu_);
    StoreStats s;
    Statement st(db_, "SELECT COUNT(*) FROM meshes");
    if (st.status().ok() && st.Step().value_or(false)) s.meshes = st.Int(0);
    std::error_code ec;
    for (const char* suffix : {"", "-wal"}) {
      const auto size = std::filesystem::file_size(path_ + suffix, ec);
      if (!ec) s.bytes += static_cast<int64_t>(size);
    }
    return s;
  }

  absl::Status PutJob(const JobRecord& r) override {
    std::lock_guard<std::mutex> lock(mu_);
    Statement st(db_,
                 "INSERT OR REPLACE INTO jobs (id, kind, options, state, created, updated, results, error_code, "
                 "error, last_seq) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
    GF_RETURN_IF_ERROR(st.status());
    std::string results;  // "mesh_id revision" lines (mesh ids hold no blanks)
    for (const JobResultMesh& m : r.results) absl::StrAppend(&results, m.mesh_id, " ", m.revision, "\n");
    st.Bind(1, r.job_id);
    st.Bind(2, r.kind);
    st.BindBlob(3, r.options.data(), r.options.size());
    st.Bind(4, int64_t{static_cast<int>(r.state)});
    st.Bind(5, r.created_unix_ms);
    st.Bind(6, r.updated_unix_ms);
    st.BindBlob(7, results.data(), results.size());
    st.Bind(8, int64_t{r.error_code});
    st.BindBlob(9, r.error.data(), r.error.size());
    st.Bind(10, r.last_seq);
    return st.Step().status();  // autocommit: durable (synchronous=FULL) on return
  }

  absl::StatusOr<JobRecord> GetJob(const std::string& job_id) override {
    std::lock_guard<std::mutex> lock(mu_);
    Statement st(db_, kSelectJob);
    GF_RETURN_IF_ERROR(st.status());
    st.Bind(1, job_id);
    GF_ASSIGN_OR_RETURN(bool row, st.Step());
    if (!row) return JobNotFound(job_id);
    return ReadJob(st);
  }

  absl::StatusOr<std::vector<JobRecord>> ListJobs(const std::string& after_id, int limit) override {
    std::lock_guard<std::mutex> lock(mu_);
    Statement st(db_, kListJobs);
    GF_RETURN_IF_ERROR(st.status());
    st.Bind(1, after_id);
    st.Bind(2, int64_t{limit});
    std::vector<JobRecord> out;
    while (true) {
      GF_ASSIGN_OR_RETURN(bool row, st.Step());
      if (!row) break;
      GF_ASSIGN_OR_RETURN(JobRecord r, ReadJob(st));
      out.push_back(std::move(r));
    }
    return out;
  }

 private:
  static absl::StatusOr<JobRecord> ReadJob(Statement& st) {
    JobRecord r;
    r.job_id = st.Blob(0);
    r.kind = st.Blob(1);
    r.options = st.Blob(2);
    const int64_t state = st.Int(3);
    if (state < static_cast<int>(JobState::kPending) || state > static_cast<int>(JobState::kCancelled))
      return absl::DataLossError(absl::StrCat("job '", r.job_id, "': stored state ", state, " is unknown"));
    r.state = static_cast<JobState>(state);
    r.created_unix_ms = st.Int(4);
    r.updated_unix_ms = st.Int(5);
    for (absl::string_view line : absl::StrSplit(st.Blob(6), '\n', absl::SkipEmpty())) {
      std::pair<std::string, std::string> f = absl::StrSplit(line, ' ');
      JobResultMesh m{f.first, 0};
      if (!absl::SimpleAtoi(f.second, &m.revision))
        return absl::DataLossError(absl::StrCat("job '", r.job_id, "': corrupt result '", line, "'"));
      r.results.push_back(std::move(m));
    }
    r.error_code = static_cast<int>(st.Int(7));
    r.error = st.Blob(8);
    r.last_seq = st.Int(9);
    return r;
  }

  absl::Status Exec(const char* sql) {
    char* err = nullptr;
    if (sqlite3_exec(db_, sql, nullptr, nullptr, &err) != SQLITE_OK) {
      absl::Status s = absl::InternalError(absl::StrCat("sqlite '", sql, "': ", err ? err : "?"));
      sqlite3_free(err);
      return s;
    }
    return absl::OkStatus();
  }

  /// Commits on success, rolls back on failure; the acknowledgement follows the fsync.
  absl::StatusOr<MeshRecord> Commit(absl::StatusOr<MeshRecord> result) {
    if (!result.ok()) {
      Exec("ROLLBACK").IgnoreError();
      return result;
    }
    absl::Status s = Exec("COMMIT");
    if (!s.ok()) {
      Exec("ROLLBACK").IgnoreError();
      return s;
    }
    return result;
  }

  static absl::StatusOr<MeshRecord> ParseInfo(const std::string& blob, const std::string& id) {
    v1::MeshInfo info;
    if (!info.ParseFromString(blob)) return absl::DataLossError("mesh '" + id + "': corrupt info record");
    return FromProto(info);
  }

  absl::StatusOr<MeshRecord> InfoLocked(const std::string& id) {
    Statement st(db_, "SELECT info FROM meshes WHERE id = ?");
    GF_RETURN_IF_ERROR(st.status());
    st.Bind(1, id);
    GF_ASSIGN_OR_RETURN(bool row, st.Step());
    if (!row) return MeshNotFound(id);
    return ParseInfo(st.Blob(0), id);
  }

  absl::StatusOr<MeshRecord> InsertLocked(const MeshRecord& info, const Mesh& mesh) {
    absl::StatusOr<MeshRecord> existing = InfoLocked(info.mesh_id);
    if (existing.ok() || !absl::IsNotFound(existing.status())) return existing;
    Statement st(db_, "INSERT INTO meshes (id, revision, info, faces, positions) VALUES (?, ?, ?, ?, ?)");
    GF_RETURN_IF_ERROR(st.status());
    const std::string blob = ToProto(info).SerializeAsString();
    st.Bind(1, info.mesh_id);
    st.Bind(2, info.revision);
    st.BindBlob(3, blob.data(), blob.size());
    st.BindBlob(4, mesh.faces.data(), sizeof(int32_t) * mesh.faces.size());
    st.BindBlob(5, mesh.positions.data(), sizeof(double) * mesh.positions.size());
    GF_RETURN_IF_ERROR(st.Step().status());
    return info;
  }

  absl::StatusOr<MeshRecord> UpdateLocked(const std::string& id, std::optional<int64_t> expected,
                                            const Positions& positions) {
    GF_ASSIGN_OR_RETURN(MeshRecord info, InfoLocked(id));
    if (expected && *expected != info.revision) return StaleRevision(id, *expected, info.revision);
    GF_RETURN_IF_ERROR(CheckVertexCount(id, positions.rows(), info.num_vertices));
    AmendForPositions(positions, info.revision + 1, &info);
    Statement st(db_, "UPDATE meshes SET revision = ?, info = ?, positions = ? WHERE id = ?");
    GF_RETURN_IF_ERROR(st.status());
    const std::string blob = ToProto(info).SerializeAsString();
    st.Bind(1, info.revision);
    st.BindBlob(2, blob.data(), blob.size());
    st.BindBlob(3, positions.data(), sizeof(double) * positions.size());
    st.Bind(4, id);
    GF_RETURN_IF_ERROR(st.Step().status());
    return info;
  }

  std::mutex mu_;
  sqlite3* db_ = nullptr;
  std::string path_;
};

}  // namespace

absl::StatusOr<std::unique_ptr<MeshStore>> OpenSqliteStore(const std::string& data_dir) {
  auto store = std::make_unique<SqliteStore>();
  GF_RETURN_IF_ERROR(store->Open(data_dir));
  return std::unique_ptr<MeshStore>(std::move(store));
}

}  // namespace geomfit::server
