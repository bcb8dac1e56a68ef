#pragma once
// Cache keys: typed values compared bit for bit (doubles by their bits, enums, ints),
// built only by the functions below and never parsed back. A formatted key aliases
// (`%g` makes 1.5 and 1.5000001 one key); these cannot.
#include <cstdint>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "core/fitting/neighborhood.h"
#include "core/fitting/options.h"

namespace geomfit::server {

/// Cache tiers of DESIGN.md, in eviction order from last to first: fittings are
/// evicted before geometry, geometry before topology.
enum class Tier { kTopology = 0, kGeometry = 1, kFitting = 2 };
inline constexpr int kNumTiers = 3;
const char* TierName(Tier tier);

/// What a cache entry holds.
enum class EntryKind : uint8_t {
  kTopology,       ///< Topology of the mesh (every revision)
  kNeighborhoods,  ///< stencils of one RingSpec (every revision)
  kGeometry,       ///< Mesh of one revision
  kFits,           ///< SurfaceFits of one revision and FitOptions
  kFeatureFits,    ///< SurfaceFits of the mesh split along feature edges
  kDifferentials,  ///< Differentials of a fit (quantity mask)
  kOperatorPattern,  ///< OperatorAssembler of one RingSpec (every revision)
  kOperator,         ///< a GFD operator matrix of one revision and FitOptions
};

struct CacheKey {
  std::string mesh_id;
  int64_t revision = 0;  ///< 0: valid for every revision (topology tier)
  EntryKind kind = EntryKind::kTopology;
  std::vector<uint64_t> params;  ///< exact bits of everything the value depends on

  Tier tier() const;
  auto Tie() const { return std::tie(mesh_id, revision, kind, params); }
  friend bool operator<(const CacheKey& a, const CacheKey& b) { return a.Tie() < b.Tie(); }
  friend bool operator==(const CacheKey& a, const CacheKey& b) { return a.Tie() == b.Tie(); }
  friend bool operator!=(const CacheKey& a, const CacheKey& b) { return !(a == b); }
};

CacheKey TopologyKey(const std::string& mesh_id);
CacheKey NeighborhoodsKey(const std::string& mesh_id, const RingSpec& spec);
CacheKey GeometryKey(const std::string& mesh_id, int64_t revision);
/// `stencils`: fits that also carry their stencil operators.
CacheKey FitKey(const std::string& mesh_id, int64_t revision, const FitOptions& options, bool stencils);
/// Fits of the mesh split along `edges` (sorted vertex pairs, §4.1.4).
CacheKey FeatureFitKey(const std::string& mesh_id, int64_t revision, const std::vector<std::pair<int, int>>& edges,
                       const FitOptions& options, bool stencils);
/// The differential quantities `mask` of the fit `fit`.
CacheKey DifferentialsKey(const CacheKey& fit, uint32_t mask);

/// The operators' pattern over the stencils of `spec` (topology tier).
CacheKey OperatorPatternKey(const std::string& mesh_id, const RingSpec& spec);
/// The operator `op` (an OperatorKind value) of revision `revision` fitted under `options`.
CacheKey OperatorKey(const std::string& mesh_id, int64_t revision, const FitOptions& options, int op);

/// For logs and test messages only.
std::string DebugString(const CacheKey& key);

}  // namespace geomfit::server
