#include "server/cache.h"

#include <algorithm>
#include <chrono>

namespace geomfit::server {

const char* TierName(Tier tier) {
  switch (tier) {
    case Tier::kTopology: return "topology";
    case Tier::kGeometry: return "geometry";
    case Tier::kFitting: return "fitting";
  }
  return "?";
}

absl::StatusOr<Cache::Value> Cache::GetOrCompute(Tier tier, const std::string& key,
                                                 const ComputeFn& compute,
                                                 const CancellationToken* cancel, bool* hit) {
  const int t = static_cast<int>(tier);
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
    if (computed->bytes <= budget_) InsertLocked(tier, key, computed->value, computed->bytes);
  } else {
    flight->result = computed.status();
  }
  flight_done_.notify_all();
  return flight->result;
}

void Cache::Put(Tier tier, const std::string& key, Value value, int64_t bytes) {
  std::lock_guard<std::mutex> lock(mu_);
  if (auto it = entries_.find(key); it != entries_.end()) EraseLocked(it);
  if (bytes <= budget_) InsertLocked(tier, key, std::move(value), bytes);
}

void Cache::ErasePrefix(const std::string& prefix) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = entries_.lower_bound(prefix);
  while (it != entries_.end() && it->first.compare(0, prefix.size(), prefix) == 0) {
    auto next = std::next(it);
    EraseLocked(it);
    it = next;
  }
}

TierStats Cache::Stats(Tier tier) const {
  std::lock_guard<std::mutex> lock(mu_);
  return stats_[static_cast<int>(tier)];
}

int64_t Cache::bytes() const {
  std::lock_guard<std::mutex> lock(mu_);
  return bytes_;
}

namespace {

/// "<id>/r<N>/..." -> (id, N); N = -1 for keys of no revision ("<id>/topo", ...).
std::pair<std::string, int64_t> MeshRevision(const std::string& key) {
  const size_t slash = key.find('/');
  if (slash == std::string::npos || slash + 2 >= key.size() || key[slash + 1] != 'r') return {key, -1};
  int64_t n = 0;
  size_t i = slash + 2;
  for (; i < key.size() && key[i] >= '0' && key[i] <= '9'; ++i) n = 10 * n + (key[i] - '0');
  if (i == slash + 2 || i == key.size() || key[i] != '/') return {key, -1};
  return {key.substr(0, slash), n};
}

}  // namespace

bool Cache::RetiredLocked(const std::string& key) const {
  const auto [id, revision] = MeshRevision(key);
  if (revision < 0) return false;
  const auto it = floors_.find(id);
  return it != floors_.end() && revision < it->second;
}

void Cache::RetireRevisionsBelow(const std::string& id, int64_t revision) {
  std::lock_guard<std::mutex> lock(mu_);
  int64_t& floor = floors_[id];
  floor = std::max(floor, revision);
  const std::string prefix = id + "/r";
  for (auto it = entries_.lower_bound(prefix); it != entries_.end() && it->first.compare(0, prefix.size(), prefix) == 0;) {
    auto next = std::next(it);
    if (RetiredLocked(it->first)) EraseLocked(it);
    it = next;
  }
}

void Cache::EraseMesh(const std::string& id) {
  ErasePrefix(id + "/");
  std::lock_guard<std::mutex> lock(mu_);
  floors_.erase(id);
}

void Cache::InsertLocked(Tier tier, const std::string& key, Value value, int64_t bytes) {
  if (RetiredLocked(key)) return;
  const int t = static_cast<int>(tier);
  lru_[t].push_front(key);
  entries_[key] = Entry{std::move(value), bytes, tier, lru_[t].begin()};
  bytes_ += bytes;
  stats_[t].bytes += bytes;
  ++stats_[t].entries;
  EvictLocked(key);
}

void Cache::EraseLocked(std::map<std::string, Entry>::iterator it) {
  const int t = static_cast<int>(it->second.tier);
  lru_[t].erase(it->second.lru);
  bytes_ -= it->second.bytes;
  stats_[t].bytes -= it->second.bytes;
  --stats_[t].entries;
  entries_.erase(it);
}

void Cache::EvictLocked(const std::string& keep) {
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
