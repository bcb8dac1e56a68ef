// ComputeDifferentials: a fit streamed while it runs, or joined while another request
// (or a prefetch) computes it.
#include <algorithm>
#include <atomic>
#include <memory>
#include <optional>

#include "absl/strings/str_cat.h"
#include "core/quantities/differentials.h"
#include "core/util/status_macros.h"
#include "proto/wire.h"
#include "server/handlers/handlers.h"
#include "server/handlers/progress.h"

namespace geomfit::server {
namespace {

using wire::EncodeRows;

void EncodeDiagnostics(const std::vector<VertexDiagnostics>& d, int64_t begin, int64_t rows,
                       v1::VertexDiagnostics* out) {
  std::vector<int32_t> points(rows), degree(rows), flags(rows);
  std::vector<double> condition(rows);
  for (int64_t i = 0; i < rows; ++i) {
    const VertexDiagnostics& v = d[begin + i];
    points[i] = v.points;
    degree[i] = v.degree_used;
    flags[i] = v.flags;
    condition[i] = v.condition;
  }
  wire::EncodeInts(points.data(), rows, 0, out->mutable_points());
  wire::EncodeInts(degree.data(), rows, 0, out->mutable_degree_used());
  wire::EncodeInts(flags.data(), rows, 0, out->mutable_flags());
  wire::EncodeDoubles(condition.data(), rows, 0, out->mutable_condition());
}

/// Rows [b, b + m) of `d` as one response chunk.
v1::ComputeDifferentialsResponse EncodeChunk(const Differentials& d, int64_t b, int64_t m, uint32_t mask,
                                             bool diagnostics) {
  v1::ComputeDifferentialsResponse r;
  r.set_vertex_offset(b);
  r.set_num_vertices(m);
  if (mask & kNormals) EncodeRows(d.normals, b, m, r.mutable_normals());
  if (mask & kMeanCurvature) EncodeRows(d.mean, b, m, r.mutable_mean());
  if (mask & kGaussianCurvature) EncodeRows(d.gaussian, b, m, r.mutable_gaussian());
  if (mask & kPrincipalCurvatures) {
    EncodeRows(d.k1, b, m, r.mutable_k1());
    EncodeRows(d.k2, b, m, r.mutable_k2());
  }
  if (mask & kPrincipalDirections) {
    EncodeRows(d.dir1, b, m, r.mutable_dir1());
    EncodeRows(d.dir2, b, m, r.mutable_dir2());
  }
  if (mask & kCurvatureTensor) EncodeRows(d.tensor, b, m, r.mutable_tensor());
  if (diagnostics) EncodeDiagnostics(d.diagnostics, b, m, r.mutable_diagnostics());
  return r;
}

/// One ComputeDifferentials response: chunks of `rows` vertices, handed to the sink as
/// soon as their rows are final, and encoded lazily (ChunkSink::PushLazy) from the
/// arrays, which each pending chunk holds (through the evaluation that fills them, see
/// Pin): neither a fitting thread nor the owner sending a follower's last chunks ever
/// waits for a slow reader. The first chunk's summary is `header`; the last one's is
/// complete.
class DifferentialsStream {
 public:
  DifferentialsStream(uint32_t mask, bool diagnostics, int64_t n, int64_t rows, v1::FitSummary header,
                      ChunkSink<v1::ComputeDifferentialsResponse>* sink)
      : mask_(mask), diagnostics_(diagnostics), n_(n), rows_(rows), header_(std::move(header)), sink_(sink) {}

  /// Keeps what Emit's arrays belong to alive until their chunks are written.
  void Pin(std::shared_ptr<const void> owner) {
    std::lock_guard<std::mutex> lock(mu_);
    owner_ = std::move(owner);
  }
  /// The row count that completes the next chunk.
  int64_t next() const {
    std::lock_guard<std::mutex> lock(mu_);
    return std::min(n_, sent_ + rows_);
  }
  /// Rows sent so far.
  int64_t sent() const {
    std::lock_guard<std::mutex> lock(mu_);
    return sent_;
  }
  /// Sends every whole chunk of rows [0, filled) not sent yet, except the last one;
  /// within the last chunk, rows [sent, filled) while some are still to come.
  void Emit(const Differentials* d, int64_t filled) {
    std::lock_guard<std::mutex> lock(mu_);
    EmitLocked(d, filled);
    if (d && sent_ + rows_ >= n_ && sent_ < filled && filled < n_) Send(Pinned(d), filled - sent_, nullptr);
  }
  /// Emit(ev.values(), ev.filled()) for the fitting threads of `ev`'s owner: a thread
  /// that finds another one sending leaves its rows to it instead of waiting.
  void EmitFrom(const Evaluation& ev) {
    more_ = true;
    do {
      std::unique_lock<std::mutex> lock(mu_, std::try_to_lock);
      if (!lock.owns_lock()) return;  // the sender checks more_ after unlocking
      while (more_.exchange(false)) EmitLocked(ev.values(), ev.filled());
    } while (more_);
  }
  /// Sends the remaining rows; the last chunk carries `summary`.
  void Finish(const std::shared_ptr<const Differentials>& d, const v1::FitSummary& summary) {
    std::lock_guard<std::mutex> lock(mu_);
    while (sent_ + rows_ < n_) Send(d, rows_, nullptr);
    Send(d, n_ - sent_, &summary);
  }

 private:
  void EmitLocked(const Differentials* d, int64_t filled) {
    while (d && sent_ + rows_ <= filled && sent_ + rows_ < n_) Send(Pinned(d), rows_, nullptr);
  }
  /// `d` (arrays of the pinned evaluation), owning the evaluation.
  std::shared_ptr<const Differentials> Pinned(const Differentials* d) const { return {owner_, d}; }
  void Send(const std::shared_ptr<const Differentials>& d, int64_t m, const v1::FitSummary* summary) {
    std::optional<v1::FitSummary> says;
    if (summary) {
      says = *summary;
    } else if (sent_ == 0) {
      says = header_;
    }
    sink_->PushLazy(
        [d, b = sent_, m, mask = mask_, diagnostics = diagnostics_, says = std::move(says)] {
          v1::ComputeDifferentialsResponse chunk = EncodeChunk(*d, b, m, mask, diagnostics);
          if (says) *chunk.mutable_summary() = *says;
          return chunk;
        },
        summary != nullptr);
    sent_ += m;
  }

  const uint32_t mask_;
  const bool diagnostics_;
  const int64_t n_, rows_;
  const v1::FitSummary header_;
  ChunkSink<v1::ComputeDifferentialsResponse>* sink_;
  mutable std::mutex mu_;
  int64_t sent_ = 0;
  std::shared_ptr<const void> owner_;  ///< the evaluation Emit's arrays belong to
  std::atomic<bool> more_{false};  ///< EmitFrom has rows for the thread that is sending
};

/// Bytes per vertex of a ComputeDifferentials response.
int64_t RowBytes(uint32_t mask, bool diagnostics) {
  int64_t doubles = 0;
  if (mask & kNormals) doubles += 3;
  if (mask & kMeanCurvature) doubles += 1;
  if (mask & kGaussianCurvature) doubles += 1;
  if (mask & kPrincipalCurvatures) doubles += 2;
  if (mask & kPrincipalDirections) doubles += 6;
  if (mask & kCurvatureTensor) doubles += 9;
  return std::max<int64_t>(8, 8 * doubles + (diagnostics ? 20 : 0));
}

/// What a response's first chunk says before the fit is done.
v1::FitSummary SummaryHeader(const std::string& id, int64_t revision, int64_t n, const FitOptions& options) {
  v1::FitSummary s;
  s.set_mesh_id(id);
  s.set_revision(revision);
  s.set_num_vertices(n);
  s.set_degree_requested(options.degree);
  s.set_options_key(FitOptionsKey(options));  // readable; never a cache key
  return s;
}

/// The complete summary of an evaluation.
v1::FitSummary Summarize(const std::string& id, const Evaluated& e, const FitOptions& options) {
  const SurfaceFits& fits = *e.fitted.fits;
  v1::FitSummary s = SummaryHeader(id, e.fitted.revision, fits.num_vertices(), options);
  s.set_fit_cache_hit(e.fitted.hit);
  s.set_fit_ms(e.fitted.ms);
  s.set_evaluate_ms(e.ms);
  s.set_quantities_cache_hit(e.hit);
  int min_degree = options.degree;
  std::vector<int64_t> by_degree(kMaxDegree + 1, 0);
  for (const VertexDiagnostics& d : fits.diagnostics()) {
    ++by_degree[std::clamp<int>(d.degree_used, 0, kMaxDegree)];
    if (d.flags & kFlagOscillation) s.set_num_oscillation_downgraded(s.num_oscillation_downgraded() + 1);
    if (d.flags & kFlagIsolated) {
      s.set_num_isolated(s.num_isolated() + 1);
      continue;
    }
    min_degree = std::min<int>(min_degree, d.degree_used);
    if (d.flags & kFlagDowngraded) s.set_num_downgraded(s.num_downgraded() + 1);
    if (d.flags & kFlagTooFewPoints) s.set_num_too_few_points(s.num_too_few_points() + 1);
    if (d.flags & kFlagBoundary) s.set_num_boundary(s.num_boundary() + 1);
  }
  s.set_min_degree_used(min_degree);
  for (int64_t n : by_degree) s.add_vertices_by_degree(n);
  return s;
}

}  // namespace

absl::Status Handlers::ComputeDifferentials(const v1::ComputeDifferentialsRequest& request,
                                           const CancellationToken& cancel,
                                           ChunkSink<v1::ComputeDifferentialsResponse>* sink) {
  const std::string& id = request.mesh_id();
  GF_RETURN_IF_ERROR(RequireId(id));
  if (request.revision() < 0 || request.chunk_rows() < 0) {
    return absl::InvalidArgumentError("revision and chunk_rows must not be negative");
  }
  absl::StatusOr<FitOptions> parsed = wire::FromProto(request.options());
  if (!parsed.ok()) return absl::InvalidArgumentError(absl::StrCat("options: ", parsed.status().message()));
  const FitOptions options = *parsed;
  GF_ASSIGN_OR_RETURN(const uint32_t mask, wire::QuantityMask(request.quantities()));
  // Held to the end: an update may replace the revision in the cache meanwhile.
  GF_ASSIGN_OR_RETURN(const Snapshot snap, ws_->Acquire(id, request.revision()));
  // Progress messages of the fit's passes: before the result chunks, among those of the last.
  ProgressThrottle throttle(ProgressMessages(sink));
  const RunContext ctx = Context(cancel, request.progress() ? throttle.Callback() : nullptr);
  const int64_t revision = snap.revision, n = snap.mesh->NumVertices();
  DifferentialsStream stream(mask, request.diagnostics(), n,
                             ChunkRows(request.chunk_rows(), RowBytes(mask, request.diagnostics())),
                             SummaryHeader(id, revision, n, options), sink);
  // What a prefetch repeats after the next update: recorded once the request succeeded,
  // before its last chunk (the client may send that update as soon as it has it).
  auto remember = [&] { ws_->Remember(snap, options, mask); };
  bool owner = false;
  const std::shared_ptr<Evaluation> ev = ws_->JoinEvaluation(snap, options, mask, &owner);
  stream.Pin(ev);
  if (owner) {
    ev->SetListener([&stream, raw = ev.get()] { stream.EmitFrom(*raw); });
    const absl::StatusOr<Evaluated> e = ws_->Evaluate(snap, options, mask, ctx, ev.get());
    if (e.ok()) {
      remember();
      stream.Finish(e->values, Summarize(id, *e, options));
    }
    ws_->End(ev, e);  // then the followers' last chunks
    return e.status();
  }
  // Follow the running evaluation: whole chunks as their rows are final, then within
  // the last chunk every fitted block, so that the owner, which sends what is left as
  // soon as it ends, has at most one block to send.
  FollowGuard follow(ev.get(), [&](const absl::StatusOr<Evaluated>& result) {
    if (!result.ok()) return;
    Evaluated shared = *result;  // not computed for this request: a hit, as for a joined cache flight
    shared.fitted.hit = shared.hit = true;
    shared.fitted.ms = shared.ms = 0;
    v1::FitSummary summary = Summarize(id, shared, options);
    summary.set_joined_compute_ms(result->fitted.ms + result->ms);
    remember();
    stream.Finish(shared.values, summary);
  });
  for (int64_t filled = 0; !ev->ended();) {
    const int64_t next = stream.next();
    // Within the last chunk: any row not sent yet, until all are final (the owner
    // sends the last ones with the summary).
    const int64_t want = next < n ? next : filled < n ? stream.sent() + 1 : n + 1;
    GF_ASSIGN_OR_RETURN(filled, ev->WaitFor(want, cancel));
    stream.Emit(ev->values(), filled);
  }
  if (follow.Unfollow() && ev->result().ok()) return absl::OkStatus();  // the owner sent the rest
  // Its owner gave up (cancelled): compute the rest here. Values are deterministic, so
  // the rows already sent agree.
  GF_ASSIGN_OR_RETURN(const Evaluated e, ws_->Evaluate(snap, options, mask, ctx));
  remember();
  stream.Finish(e.values, Summarize(id, e, options));
  return absl::OkStatus();
}

absl::StatusOr<std::vector<v1::ComputeDifferentialsResponse>> Handlers::ComputeDifferentials(
    const v1::ComputeDifferentialsRequest& request, const CancellationToken& cancel) {
  return Collected<v1::ComputeDifferentialsResponse>(
      [&](ChunkSink<v1::ComputeDifferentialsResponse>* sink) { return ComputeDifferentials(request, cancel, sink); });
}

void Handlers::Prefetch(const std::string& id, int64_t revision, const CancellationToken& cancel) {
  if (std::unique_ptr<Workspace::PendingPrefetch> p = PlanPrefetch(id, revision)) p->Run(cancel);
}

int64_t Handlers::ChunkRows(int64_t requested, int64_t bytes_per_row) const {
  const int64_t by_limit = std::max<int64_t>(1, options_.max_message_bytes / 2 / bytes_per_row);
  if (requested <= 0) requested = options_.chunk_rows;
  if (requested <= 0) requested = std::max<int64_t>(1, options_.chunk_bytes / bytes_per_row);
  return std::min(requested, by_limit);
}

}  // namespace geomfit::server
