#pragma once
// Progressive evaluation: the differentials of one (mesh revision, fit options,
// quantities) filled in vertex blocks while the fit runs, so every request that wants
// them can stream rows before the whole mesh is fitted. One thread computes (the
// owner: a request or a prefetch); the others follow.
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <string>

#include "absl/status/statusor.h"
#include "core/fitting/fit.h"
#include "core/quantities/differentials.h"
#include "core/util/cancel.h"
#include "server/workspace/keys.h"

namespace geomfit::server {

/// The fits of a request, from the fitting tier or computed (single-flight).
struct Fitted {
  std::shared_ptr<const SurfaceFits> fits;
  int64_t revision = 0;  ///< resolved (never 0)
  CacheKey key;          ///< fitting-tier key: derived entries extend it
  bool hit = false;
  double ms = 0;
};

/// Fits plus differential quantities, each from the cache or computed.
struct Evaluated {
  Fitted fitted;
  std::shared_ptr<const Differentials> values;
  bool hit = false;
  double ms = 0;
};

class Evaluation {
 public:
  /// `key`: the differentials' cache key; `mesh`: the revision evaluated (held, so an
  /// update cannot take it away meanwhile).
  Evaluation(CacheKey key, std::shared_ptr<const Mesh> mesh, uint32_t mask);

  const CacheKey& key() const { return key_; }
  const std::shared_ptr<const Mesh>& mesh() const { return mesh_; }
  int64_t num_vertices() const { return num_vertices_; }
  uint32_t mask() const { return mask_; }
  /// The arrays being filled (owner only; allocated on first use, thread-safe).
  const std::shared_ptr<Differentials>& filling();

  /// Owner: rows [begin, end) of filling() are final (any order, any thread). Wakes the
  /// followers and calls the listener (outside the lock).
  void Filled(int64_t begin, int64_t end);
  /// Owner: the evaluation ended; its values are filling() itself when the owner
  /// computed them, else cached arrays.
  void Finish(absl::StatusOr<Evaluated> result);
  /// Called after each Filled, on the filling thread (the owning request streams from it).
  void SetListener(std::function<void()> listener) { listener_ = std::move(listener); }

  using EndHook = std::function<void(const absl::StatusOr<Evaluated>&)>;
  /// Follower: `hook` runs once with the result, on the owner's thread, as soon as the
  /// evaluation ends (the follower's last chunk goes out without waiting for the
  /// follower to wake). Returns a handle for Unfollow.
  int Follow(EndHook hook);
  /// Follower: after this returns the hook has run to completion (true) or never will
  /// (false). Every Follow needs an Unfollow before what its hook uses goes away.
  bool Unfollow(int handle);

  /// Rows [0, filled()) are final.
  int64_t filled() const;
  /// Follower: waits until at least `rows` rows are final or the evaluation ended, or
  /// the token trips (its status). Returns the final row count.
  absl::StatusOr<int64_t> WaitFor(int64_t rows, const CancellationToken& cancel);
  bool ended() const;
  /// Once ended: the owner's result.
  absl::StatusOr<Evaluated> result() const;
  /// The arrays final rows are read from: filling() until the end, then the result's
  /// values; null while no row is final.
  const Differentials* values() const;

 private:
  const CacheKey key_;
  const std::shared_ptr<const Mesh> mesh_;
  const int64_t num_vertices_;
  const uint32_t mask_;
  std::once_flag allocated_;
  std::shared_ptr<Differentials> filling_;
  std::function<void()> listener_;
  mutable std::mutex mu_;
  std::condition_variable cv_;
  int64_t filled_ = 0;
  std::map<int64_t, int64_t> pending_;  ///< reported blocks beyond filled_: begin -> end
  int64_t wake_at_ = std::numeric_limits<int64_t>::max();  ///< least row count a follower waits for
  bool ended_ = false;
  absl::StatusOr<Evaluated> result_;
  std::map<int, EndHook> hooks_;  ///< not run yet, by handle
  int next_hook_ = 0;
  bool running_hooks_ = false;
};

/// Follow/Unfollow for the length of a scope.
class FollowGuard {
 public:
  FollowGuard(Evaluation* ev, Evaluation::EndHook hook) : ev_(ev), handle_(ev->Follow(std::move(hook))) {}
  ~FollowGuard() { Unfollow(); }
  FollowGuard(const FollowGuard&) = delete;
  FollowGuard& operator=(const FollowGuard&) = delete;
  /// Whether the hook ran (see Evaluation::Unfollow); later calls repeat the answer.
  bool Unfollow() {
    if (!unfollowed_) ran_ = ev_->Unfollow(handle_);
    unfollowed_ = true;
    return ran_;
  }

 private:
  Evaluation* ev_;
  const int handle_;
  bool unfollowed_ = false, ran_ = false;
};

}  // namespace geomfit::server
