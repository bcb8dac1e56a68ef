#include "server/workspace/keys.h"

#include <cstring>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"

namespace geomfit::server {
namespace {

uint64_t Bits(double x) {
  uint64_t b;
  std::memcpy(&b, &x, sizeof b);
  return b;
}

CacheKey Key(const std::string& id, int64_t revision, EntryKind kind, std::vector<uint64_t> params = {}) {
  return CacheKey{id, revision, kind, std::move(params)};
}

std::vector<uint64_t> FitParams(const FitOptions& options, bool stencils) {
  const FitOptionsBits bits = FitOptionsIdentity(options);
  std::vector<uint64_t> p(bits.begin(), bits.end());
  p.push_back(stencils);
  return p;
}

}  // namespace

const char* TierName(Tier tier) {
  switch (tier) {
    case Tier::kTopology: return "topology";
    case Tier::kGeometry: return "geometry";
    case Tier::kFitting: return "fitting";
  }
  return "?";
}

Tier CacheKey::tier() const {
  switch (kind) {
    case EntryKind::kTopology:
    case EntryKind::kNeighborhoods:
    case EntryKind::kOperatorPattern: return Tier::kTopology;
    case EntryKind::kGeometry: return Tier::kGeometry;
    default: return Tier::kFitting;
  }
}

CacheKey TopologyKey(const std::string& id) { return Key(id, 0, EntryKind::kTopology); }

CacheKey NeighborhoodsKey(const std::string& id, const RingSpec& s) {
  return Key(id, 0, EntryKind::kNeighborhoods,
             {Bits(s.rings), s.adaptive, static_cast<uint64_t>(s.min_points),
              static_cast<uint64_t>(s.min_points_boundary), Bits(s.max_rings), static_cast<uint64_t>(s.max_points)});
}

CacheKey OperatorPatternKey(const std::string& id, const RingSpec& s) {
  CacheKey k = NeighborhoodsKey(id, s);
  k.kind = EntryKind::kOperatorPattern;
  return k;
}

CacheKey OperatorKey(const std::string& id, int64_t revision, const FitOptions& options, int op) {
  std::vector<uint64_t> p = FitParams(options, true);
  p.push_back(static_cast<uint64_t>(op));
  return Key(id, revision, EntryKind::kOperator, std::move(p));
}

CacheKey GeometryKey(const std::string& id, int64_t revision) { return Key(id, revision, EntryKind::kGeometry); }

CacheKey FitKey(const std::string& id, int64_t revision, const FitOptions& options, bool stencils) {
  return Key(id, revision, EntryKind::kFits, FitParams(options, stencils));
}

CacheKey FeatureFitKey(const std::string& id, int64_t revision, const std::vector<std::pair<int, int>>& edges,
                       const FitOptions& options, bool stencils) {
  std::vector<uint64_t> p = FitParams(options, stencils);
  p.reserve(p.size() + edges.size());
  for (const auto& [a, b] : edges) p.push_back(static_cast<uint64_t>(static_cast<uint32_t>(a)) << 32 | static_cast<uint32_t>(b));
  return Key(id, revision, EntryKind::kFeatureFits, std::move(p));
}

CacheKey DifferentialsKey(const CacheKey& fit, uint32_t mask) {
  CacheKey k = fit;
  k.kind = EntryKind::kDifferentials;
  k.params.push_back(static_cast<uint64_t>(fit.kind));
  k.params.push_back(mask);
  return k;
}

std::string DebugString(const CacheKey& k) {
  return absl::StrCat(k.mesh_id, "/r", k.revision, "/", static_cast<int>(k.kind), "/",
                      absl::StrJoin(k.params, ","));
}

}  // namespace geomfit::server
