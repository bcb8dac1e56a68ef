#pragma once
#include <cstdint>
#include <memory>
#include <mutex>
#include <vector>

#include "core/fitting/options.h"
#include "core/fitting/wls_batch.h"
#include "core/mesh/topology.h"

namespace geomfit {

/// What every plain fit of one geometry over one set of stencils reads besides the
/// stencils: the approximate vertex normals of FitOptions::frame_normals and their point
/// records in the stencils' work order (Neighborhoods::ordered). Immutable.
struct FitInputs {
  NormalWeighting weighting = NormalWeighting::kArea;
  Positions positions;           ///< the geometry these come from (the cache's key)
  Positions normals;             ///< ApproximateVertexNormals(mesh, topo, weighting)
  PointRecords records;          ///< MakePointRecords in the work order; empty without one

  size_t Bytes() const {
    return 8 * (positions.size() + normals.size()) + sizeof(PointRecord) * records.size();
  }
};

/// The FitInputs of `mesh` computed now, without the key (`positions` empty): a one-off
/// fit's, over stencils nobody else fits over.
std::shared_ptr<FitInputs> MakeFitInputs(const Mesh& mesh, const Topology& topo, NormalWeighting weighting,
                                         const std::vector<int32_t>* order, int num_threads);

/// The FitInputs of the geometries fitted over one Neighborhoods, one per normal
/// weighting, computed on first use and kept while the positions stay the same (a new
/// geometry replaces them: the server keeps one Neighborhoods for every revision of a
/// mesh). Thread-safe. Copies start empty; moves take the entries.
class FitInputCache {
 public:
  FitInputCache() = default;
  FitInputCache(const FitInputCache&) {}
  FitInputCache& operator=(const FitInputCache&);
  FitInputCache(FitInputCache&& other) noexcept;
  FitInputCache& operator=(FitInputCache&& other) noexcept;

  /// The inputs of `mesh` (whose topology is `topo`, the stencils' one) under
  /// `weighting`, records in `order` (null or empty: none): the kept ones if they were
  /// computed from the same positions (compared bit for bit), else computed now.
  std::shared_ptr<const FitInputs> Get(const Mesh& mesh, const Topology& topo, NormalWeighting weighting,
                                       const std::vector<int32_t>* order, int num_threads) const;
  size_t Bytes() const;

 private:
  static constexpr int kWeightings = 2;
  mutable std::mutex mu_;
  mutable std::shared_ptr<const FitInputs> entries_[kWeightings];
};

}  // namespace geomfit
