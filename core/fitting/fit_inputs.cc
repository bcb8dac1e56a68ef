#include "core/fitting/fit_inputs.h"

#include <cstring>
#include <utility>

#include "core/fitting/frames.h"
#include "core/util/parallel.h"

namespace geomfit {

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
      std::memcmp(kept->positions.data(), mesh.positions.data(), sizeof(double) * mesh.positions.size()) == 0)
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
