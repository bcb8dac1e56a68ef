#include "core/fitting/neighborhood.h"

#include <algorithm>
#include <cmath>

#include "core/util/parallel.h"

namespace geomfit {

RingSpec RingSpecFor(const FitOptions& o) {
  RingSpec s;
  const int n = NumCoefficients(o.degree);
  s.rings = o.StartRings();
  s.adaptive = o.adaptive;
  s.min_points = static_cast<int>(std::ceil(o.MinPointsFactor() * n));
  s.min_points_boundary = static_cast<int>(std::ceil(o.boundary_points_factor * n));
  s.max_rings = std::max(o.max_rings, s.rings);
  s.max_points = o.max_points;
  return s;
}

namespace {

// Grows one vertex's stencil ring by ring (2.1).
class RingGrower {
 public:
  RingGrower(const Topology& t, const Mesh& m) : t_(t), m_(m), mark_(t.num_vertices) {}

  // Fills `out` with v's stencil; returns the ring reached.
  float Grow(int v, const RingSpec& spec, std::vector<int32_t>& out) {
    out_ = &out;
    out.clear();
    stamp_ = static_cast<uint32_t>(v) + 1;
    Add(v, 0);
    layer_begin_ = 0;
    layer_end_ = 1;
    half_steps_ = 0;
    const int start = static_cast<int>(std::lround(2 * spec.rings));
    const int max_steps = std::max(start, static_cast<int>(std::lround(2 * spec.max_rings)));
    const size_t want = t_.is_boundary[v] ? spec.min_points_boundary : spec.min_points;
    while (half_steps_ < max_steps) {
      const bool required = half_steps_ < start;
      if (!required && (!spec.adaptive || out.size() >= want)) break;
      const size_t before = out.size();
      Step();
      if (out.size() > static_cast<size_t>(spec.max_points)) {
        if (required && before == 1) {
          out.resize(spec.max_points);  // a huge first ring: keep its first points
        } else {
          out.resize(before);  // never half a ring: stop at the last complete one
          --half_steps_;
        }
        break;
      }
      if (out.size() == before && half_steps_ % 2 == 0) break;  // component exhausted
    }
    return 0.5f * half_steps_;
  }

 private:
  void Add(int32_t x, int level) {
    mark_[x] = {stamp_, level};
    out_->push_back(x);
  }
  bool Marked(int32_t x) const { return mark_[x].stamp == stamp_; }
  bool In(int32_t x, int max_level) const { return Marked(x) && mark_[x].level <= max_level; }

  void Step() {
    const int k2 = half_steps_ - half_steps_ % 2;  // 2k for the current integer ring k
    std::vector<int32_t>& out = *out_;
    if (half_steps_ == 0) {
      // 0 -> 0.5: no edge has both ends in the 0-ring; nothing to add.
    } else if (half_steps_ % 2 == 0) {
      // k -> k + 0.5: faces on an edge (a, b) with a in layer k and b in the k-ring.
      for (size_t i = layer_begin_; i < layer_end_; ++i) {
        const int32_t a = out[i];
        for (int j = 0; j < t_.NumVertexFaces(a); ++j) {
          const int f = t_.VertexFaces(a)[j], n = m_.FaceSize(f);
          int c = 0;
          while (m_.faces(f, c) != a) ++c;
          if (!In(m_.Next(f, c), k2) && !In(m_.Prev(f, c), k2)) continue;
          for (int q = 0; q < n; ++q)
            if (!Marked(m_.faces(f, q))) Add(m_.faces(f, q), k2 + 1);
        }
      }
    } else {
      // k + 0.5 -> k + 1: every edge neighbour of layer k; layer k+1 starts after the k-ring.
      const size_t k_ring_end = layer_end_;
      for (size_t i = layer_begin_; i < layer_end_; ++i) {
        const int32_t a = out[i];
        for (int j = 0; j < t_.NumNeighbors(a); ++j) {
          const int32_t b = t_.Neighbors(a)[j];
          if (!Marked(b)) Add(b, k2 + 2);
        }
      }
      layer_begin_ = k_ring_end;
      layer_end_ = out.size();
    }
    ++half_steps_;
  }

  const Topology& t_;
  const Mesh& m_;
  struct Mark {
    uint32_t stamp = 0;  // == stamp_: in the current stencil
    int32_t level = 0;   // half-step (2 x ring) at which it joined
  };
  std::vector<Mark> mark_;
  std::vector<int32_t>* out_ = nullptr;
  uint32_t stamp_ = 0;
  size_t layer_begin_ = 0, layer_end_ = 0;
  int half_steps_ = 0;
};

}  // namespace

Neighborhoods BuildNeighborhoods(const Topology& topo, const Mesh& mesh, const RingSpec& spec,
                                 int num_threads) {
  const int nv = topo.num_vertices;
  const int threads = ResolveThreads(num_threads);
  std::vector<std::vector<int32_t>> block_indices(threads);
  std::vector<std::vector<int32_t>> block_sizes(threads);
  Neighborhoods nb;
  nb.rings.resize(nv);
  ParallelForBlocks(nv, threads, [&](int64_t begin, int64_t end, int b) {
    RingGrower grower(topo, mesh);
    std::vector<int32_t> stencil;
    auto& idx = block_indices[b];
    idx.reserve((end - begin) * 24);
    for (int64_t v = begin; v < end; ++v) {
      nb.rings[v] = grower.Grow(static_cast<int>(v), spec, stencil);
      block_sizes[b].push_back(static_cast<int32_t>(stencil.size()));
      idx.insert(idx.end(), stencil.begin(), stencil.end());
    }
  });
  // Concatenate the blocks in order, each copied in parallel at its final offset.
  std::vector<size_t> block_start(threads + 1, 0);
  for (int b = 0; b < threads; ++b) block_start[b + 1] = block_start[b] + block_indices[b].size();
  nb.offsets.resize(nv + 1);
  nb.indices.resize(block_start[threads]);
  nb.offsets[0] = 0;
  ParallelForBlocks(nv, threads, [&](int64_t begin, int64_t, int b) {
    int32_t at = static_cast<int32_t>(block_start[b]);
    for (size_t i = 0; i < block_sizes[b].size(); ++i) nb.offsets[begin + i + 1] = at += block_sizes[b][i];
    std::copy(block_indices[b].begin(), block_indices[b].end(), nb.indices.begin() + block_start[b]);
  });
  return nb;
}

}  // namespace geomfit
