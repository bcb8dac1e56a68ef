#pragma once
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <list>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <utility>

#include "absl/status/statusor.h"
#include "core/util/cancel.h"
#include "server/workspace/keys.h"

namespace geomfit::server {

struct TierStats {
  int64_t entries = 0, bytes = 0, hits = 0, misses = 0, evictions = 0;
};

/// A byte-bounded LRU cache of immutable values with single-flight computation:
/// concurrent requests for a missing key wait for one computation. Keys are typed
/// (keys.h); a key's tier follows from its kind. Thread-safe.
class Cache {
 public:
  using Value = std::shared_ptr<const void>;
  struct Computed {
    Value value;
    int64_t bytes = 0;
  };
  using ComputeFn = std::function<absl::StatusOr<Computed>()>;

  explicit Cache(int64_t budget_bytes) : budget_(budget_bytes) {}

  /// The value of `key`, computing it (once across concurrent callers) if missing.
  /// Waiters give up with the token's status; a leader that was cancelled does not
  /// fail its waiters (one of them computes instead). `hit` (optional) reports
  /// whether the value was already cached. A value larger than the whole budget is
  /// returned but not kept.
  absl::StatusOr<Value> GetOrCompute(const CacheKey& key, const ComputeFn& compute,
                                     const CancellationToken* cancel = nullptr, bool* hit = nullptr);

  template <typename T>
  absl::StatusOr<std::shared_ptr<const T>> Get(
      const CacheKey& key,
      const std::function<absl::StatusOr<std::pair<std::shared_ptr<const T>, int64_t>>()>& compute,
      const CancellationToken* cancel = nullptr, bool* hit = nullptr) {
    auto r = GetOrCompute(
        key,
        [&]() -> absl::StatusOr<Computed> {
          auto v = compute();
          if (!v.ok()) return v.status();
          return Computed{std::move(v->first), v->second};
        },
        cancel, hit);
    if (!r.ok()) return r.status();
    return std::static_pointer_cast<const T>(*r);
  }

  /// Inserts (or replaces) a value computed elsewhere.
  void Put(const CacheKey& key, Value value, int64_t bytes);
  /// Drops the entries of mesh `id`'s revisions below `revision` and
  /// keeps them out from now on: a computation that finishes after its revision was
  /// replaced returns its value to its callers but does not cache it.
  void RetireRevisionsBelow(const std::string& id, int64_t revision);
  /// Drops every entry of mesh `id` and forgets its retired revisions.
  void EraseMesh(const std::string& id);

  TierStats Stats(Tier tier) const;
  int64_t bytes() const;
  int64_t budget() const { return budget_; }

 private:
  struct Entry {
    Value value;
    int64_t bytes = 0;
    std::list<CacheKey>::iterator lru;  ///< position in lru_[tier] (front = newest)
  };
  struct Flight {
    bool done = false;
    absl::StatusOr<Value> result;
  };

  using Entries = std::map<CacheKey, Entry>;
  void InsertLocked(const CacheKey& key, Value value, int64_t bytes);
  /// Whether `key` names a revision below its mesh's retirement floor.
  bool RetiredLocked(const CacheKey& key) const;
  void EraseLocked(Entries::iterator it);
  void EvictLocked(const CacheKey& keep);
  /// The first entry of mesh `id`.
  Entries::iterator FirstOfLocked(const std::string& id);

  const int64_t budget_;
  mutable std::mutex mu_;
  std::condition_variable flight_done_;
  Entries entries_;
  std::map<CacheKey, std::shared_ptr<Flight>> flights_;
  std::list<CacheKey> lru_[kNumTiers];
  std::map<std::string, int64_t> floors_;  ///< mesh id -> lowest live revision
  TierStats stats_[kNumTiers];
  int64_t bytes_ = 0;
};

}  // namespace geomfit::server
