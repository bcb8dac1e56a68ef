#include "server/workspace/cache.h"

#include <algorithm>
#include <chrono>
#include <limits>

namespace geomfit::server {

absl::StatusOr<Cache::Value> Cache::GetOrCompute(const CacheKey& key, const ComputeFn& compute,
                                                 const CancellationToken* cancel, bool* hit) {
  const int t = static_cast<int>(key.tier());
  std::unique_lock<std::mutex> lock(mu_);
  while (true) {
    if (auto it = entries_.find(key); it != entries_.end()) {
      lru_[t].splice(lru_[t].begin(), lru_[t], it->second.lru);
      ++stats_[t].hits;
      if (hit) *hit = true;
      return it->second.value;
    }
    auto fit = flights_.find(key);
    if (fit == flights_.end()) break;  // nobody computes it: we lead
    std::shared_ptr<Flight> flight = fit->second;
    while (!flight->done) {
      if (cancel != nullptr) {
        if (absl::Status s = cancel->Check(); !s.ok()) return s;
      }
      flight_done_.wait_for(lock, std::chrono::milliseconds(20));
    }
    const absl::StatusCode code = flight->result.status().code();
    if (code != absl::StatusCode::kCancelled && code != absl::StatusCode::kDeadlineExceeded) {
      ++stats_[t].hits;
      if (hit) *hit = true;
      return flight->result;
    }
    // The leader was cancelled: look again (and possibly lead).
  }
  ++stats_[t].misses;
  if (hit) *hit = false;
  auto flight = std::make_shared<Flight>();
  flights_[key] = flight;
  lock.unlock();
  absl::StatusOr<Computed> computed = compute();
  lock.lock();
  flights_.erase(key);
  flight->done = true;
  if (computed.ok()) {
    flight->result = computed->value;
    if (computed->bytes <= budget_) InsertLocked(key, computed->value, computed->bytes);
  } else {
    flight->result = computed.status();
  }
  flight_done_.notify_all();
  return flight->result;
}

void Cache::Put(const CacheKey& key, Value value, int64_t bytes) {
  std::lock_guard<std::mutex> lock(mu_);
  if (auto it = entries_.find(key); it != entries_.end()) EraseLocked(it);
  if (bytes <= budget_) InsertLocked(key, std::move(value), bytes);
}

TierStats Cache::Stats(Tier tier) const {
  std::lock_guard<std::mutex> lock(mu_);
  return stats_[static_cast<int>(tier)];
}

int64_t Cache::bytes() const {
  std::lock_guard<std::mutex> lock(mu_);
  return bytes_;
}

Cache::Entries::iterator Cache::FirstOfLocked(const std::string& id) {
  CacheKey first;
  first.mesh_id = id;
  first.revision = std::numeric_limits<int64_t>::min();
  return entries_.lower_bound(first);
}

bool Cache::RetiredLocked(const CacheKey& key) const {
  if (key.revision <= 0) return false;  // every revision's entries
  const auto it = floors_.find(key.mesh_id);
  return it != floors_.end() && key.revision < it->second;
}

void Cache::RetireRevisionsBelow(const std::string& id, int64_t revision) {
  std::lock_guard<std::mutex> lock(mu_);
  int64_t& floor = floors_[id];
  floor = std::max(floor, revision);
  for (auto it = FirstOfLocked(id); it != entries_.end() && it->first.mesh_id == id;) {
    auto next = std::next(it);
    if (RetiredLocked(it->first)) EraseLocked(it);
    it = next;
  }
}

void Cache::EraseMesh(const std::string& id) {
  std::lock_guard<std::mutex> lock(mu_);
  for (auto it = FirstOfLocked(id); it != entries_.end() && it->first.mesh_id == id;) EraseLocked(it++);
  floors_.erase(id);
}

void Cache::InsertLocked(const CacheKey& key, Value value, int64_t bytes) {
  if (RetiredLocked(key)) return;
  const int t = static_cast<int>(key.tier());
  // A value computed twice (a prefetch and a request racing past each other) replaces
  // the first: its LRU node must go too, or eviction would later meet a node whose
  // entry is gone (found in the soak, bench/soak.py).
  if (auto it = entries_.find(key); it != entries_.end()) EraseLocked(it);
  lru_[t].push_front(key);
  entries_[key] = Entry{std::move(value), bytes, lru_[t].begin()};
  bytes_ += bytes;
  stats_[t].bytes += bytes;
  ++stats_[t].entries;
  EvictLocked(key);
}

void Cache::EraseLocked(Entries::iterator it) {
  const int t = static_cast<int>(it->first.tier());
  lru_[t].erase(it->second.lru);
  bytes_ -= it->second.bytes;
  stats_[t].bytes -= it->second.bytes;
  --stats_[t].entries;
  entries_.erase(it);
}

void Cache::EvictLocked(const CacheKey& keep) {
  for (int t = kNumTiers - 1; t >= 0 && bytes_ > budget_; --t) {
    auto victim = lru_[t].end();
    while (bytes_ > budget_ && victim != lru_[t].begin()) {
      --victim;
      if (*victim == keep) continue;
      auto it = entries_.find(*victim);
      victim = std::next(victim);  // EraseLocked invalidates the node; step past it first
      ++stats_[t].evictions;
      EraseLocked(it);
    }
  }
}

}  // namespace geomfit::server
