// GetServerInfo and GetStatistics.
#include <limits>

#include "server/handlers/handlers.h"

namespace geomfit::server {
namespace {
constexpr const char* kVersion = "0.1.0";
}  // namespace

v1::ServerInfo Handlers::GetServerInfo() const {
  v1::ServerInfo info;
  info.set_version(kVersion);
  info.set_api_version("geomfit.v1");
  info.set_max_message_bytes(options_.max_message_bytes);
  info.set_max_vertices(options_.max_vertices);
  info.set_cache_bytes(ws_->cache().budget());
  info.set_store(ws_->store().Kind());
  info.set_max_degree(kMaxDegree);
  info.set_compute_workers(options_.workers);
  info.set_default_chunk_rows(options_.chunk_rows);
  info.set_default_chunk_bytes(options_.chunk_bytes);
  for (const char* c : {"UploadMesh", "UpdatePositions", "SetPositions", "GetMesh", "DownloadMesh", "ListMeshes", "DeleteMesh",
                        "ComputeDifferentials", "GetServerInfo", "GetStatistics", "ProjectPoints",
                        "HighOrderNodes", "RefineMesh", "Integrate", "HighOrderNodesStream", "IntegrateStream",
                        "RefineMeshStream", "progress", "reconstruction:WALF",
                        "reconstruction:CMF", "fit_method:LHF",
                        "fit_method:LOP", "faces:triangle", "faces:quad", "faces:mixed"}) {
    info.add_capabilities(c);
  }
  return info;
}

v1::Statistics Handlers::GetStatistics() const {
  v1::Statistics s;
  for (const auto& [name, m] : stats_->Snapshot()) {
    v1::MethodStatistics* ms = s.add_methods();
    ms->set_method(name);
    ms->set_count(m.count);
    ms->set_errors(m.errors);
    ms->set_total_ms(m.total_ms);
    ms->set_max_ms(m.max_ms);
    int64_t cumulative = 0;
    for (size_t i = 0; i < m.buckets.size(); ++i) {
      cumulative += m.buckets[i];
      const auto& bounds = RequestStats::BucketsMs();
      ms->add_bucket_upper_ms(i < bounds.size() ? bounds[i] : std::numeric_limits<double>::infinity());
      ms->add_bucket_count(cumulative);
    }
  }
  for (Tier tier : {Tier::kTopology, Tier::kGeometry, Tier::kFitting}) {
    const TierStats t = ws_->cache().Stats(tier);
    v1::CacheStatistics* c = s.add_caches();
    c->set_tier(TierName(tier));
    c->set_entries(t.entries);
    c->set_bytes(t.bytes);
    c->set_hits(t.hits);
    c->set_misses(t.misses);
    c->set_evictions(t.evictions);
  }
  s.set_cache_bytes(ws_->cache().bytes());
  s.set_cache_budget_bytes(ws_->cache().budget());
  const StoreStats store = ws_->store().Stats();
  s.set_stored_meshes(store.meshes);
  s.set_stored_bytes(store.bytes);
  s.set_uptime_seconds(std::chrono::duration<double>(std::chrono::steady_clock::now() - started_).count());
  return s;
}

}  // namespace geomfit::server
