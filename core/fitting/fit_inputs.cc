#include "core/fitting/fit_inputs.h"

#include <atomic>
#include <cstring>
#include <utility>

#include "core/fitting/frames.h"
#include "core/util/parallel.h"

namespace geomfit {
namespace {

// memcmp(a, b, bytes) == 0, compared in parallel blocks when large (the cache's key check
// would otherwise be a serial pass over the positions on every fit).
bool BytesEqual(const void* a, const void* b, size_t bytes, int num_threads) {
  constexpr size_t kBlock = size_t{1} << 18;
  if (bytes < 2 * kBlock) return std::memcmp(a, b, bytes) == 0;
  std::atomic<bool> equal{true};
  const auto* x = static_cast<const char*>(a);
  const auto* y = static_cast<const char*>(b);
  ParallelForBlocks(static_cast<int64_t>(bytes), num_threads, [&](int64_t begin, int64_t end, int) {
    if (std::memcmp(x + begin, y + begin, static_cast<size_t>(end - begin)) != 0) equal = false;
  });
  return equal;
}

}  // namespace

std::shared_ptr<FitInputs> MakeFitInputs(const Mesh& mesh, const Topology& topo, NormalWeighting weighting,
                                         const std::vector<int32_t>* order, int num_threads) {
  auto made = std::make_shared<FitInputs>();
  made->weighting = weighting;
  made->normals = ApproximateVertexNormals(mesh, topo, weighting, num_threads);
  if (order && !order->empty())
    made->records = MakePointRecords(mesh.positions, made->normals, order->data(), num_threads);
  return made;
}

FitInputCache& FitInputCache::operator=(const FitInputCache&) {
  std::lock_guard<std::mutex> lock(mu_);
  for (auto& e : entries_) e.reset();
  return *this;
}

FitInputCache::FitInputCache(FitInputCache&& other) noexcept {
  std::lock_guard<std::mutex> lock(other.mu_);
  for (int i = 0; i < kWeightings; ++i) entries_[i] = std::move(other.entries_[i]);
}

FitInputCache& FitInputCache::operator=(FitInputCache&& other) noexcept {
  if (this == &other) return *this;
  std::scoped_lock lock(mu_, other.mu_);
  for (int i = 0; i < kWeightings; ++i) entries_[i] = std::move(other.entries_[i]);
  return *this;
}

std::shared_ptr<const FitInputs> FitInputCache::Get(const Mesh& mesh, const Topology& topo, NormalWeighting weighting,
                                                    const std::vector<int32_t>* order, int num_threads) const {
  const int slot = static_cast<int>(weighting);
  std::shared_ptr<const FitInputs> kept;
  {
    std::lock_guard<std::mutex> lock(mu_);
    kept = entries_[slot];
  }
  const bool with_records = order && !order->empty();
  if (kept && kept->positions.rows() == mesh.positions.rows() && kept->records.empty() != with_records &&
      BytesEqual(kept->positions.data(), mesh.positions.data(), sizeof(double) * mesh.positions.size(), num_threads))
    return kept;
  auto made = MakeFitInputs(mesh, topo, weighting, order, num_threads);
  made->positions = mesh.positions;
  std::lock_guard<std::mutex> lock(mu_);
  entries_[slot] = made;
  return made;
}

size_t FitInputCache::Bytes() const {
  std::lock_guard<std::mutex> lock(mu_);
  size_t bytes = 0;
  for (const auto& e : entries_)
    if (e) bytes += e->Bytes();
  return bytes;
}

}  // namespace geomfit
