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

// Each vertex's adjacency gathered in one span, built once per call: its edge
// neighbours (topo.Neighbors order), then the corner rows (4 slots, -1 for triangles)
// of its faces (topo.VertexFaces order). A stencil point's ring step then reads one
// span instead of a face row per incident face, which on a mesh in external (random)
// vertex order was a cache miss each.
class Spans {
 public:
  Spans(const Topology& t, const Mesh& m, int threads) : offsets_(t.num_vertices + 1) {
    const int nv = t.num_vertices;
    offsets_[0] = 0;
    for (int v = 0; v < nv; ++v)
      offsets_[v + 1] = offsets_[v] + 2 + t.NumNeighbors(v) + 4 * t.NumVertexFaces(v);
    data_.resize(offsets_[nv]);
    ParallelForBlocks(nv, threads, [&](int64_t begin, int64_t end, int) {
      for (int64_t v = begin; v < end; ++v) {
        int32_t* out = data_.data() + offsets_[v];
        const int nn = t.NumNeighbors(v), nf = t.NumVertexFaces(v);
        *out++ = nn;
        *out++ = nf;
        out = std::copy(t.Neighbors(v), t.Neighbors(v) + nn, out);
        for (int j = 0; j < nf; ++j)
          out = std::copy_n(m.faces.data() + 4 * static_cast<int64_t>(t.VertexFaces(v)[j]), 4, out);
      }
    });
  }
  const int32_t* Of(int v) const { return data_.data() + offsets_[v]; }
  /// Prefetch hints: where v's span starts, and (once that is cached) its first lines.
  void PrefetchOffset(int v) const { __builtin_prefetch(offsets_.data() + v); }
  void PrefetchSpan(int v) const {
    const int32_t* p = Of(v);
    __builtin_prefetch(p);
    __builtin_prefetch(p + 16);
  }

 private:
  std::vector<int64_t> offsets_;
  std::vector<int32_t> data_;
};

// The points of the stencil being grown, with the half step at which each joined,
// stamped per stencil (no clearing between vertices).
class MarkTable {
 public:
  explicit MarkTable(int num_vertices) : slots_(num_vertices) {}
  void Start(uint32_t stamp) { stamp_ = stamp; }
  int Level(int32_t x) const { return slots_[x].stamp == stamp_ ? slots_[x].level : -1; }
  bool Insert(int32_t x, int level) {
    if (slots_[x].stamp == stamp_) return false;
    slots_[x] = {stamp_, level};
    return true;
  }

 private:
  struct Slot {
    uint32_t stamp = 0;
    int32_t level = 0;
  };
  std::vector<Slot> slots_;
  uint32_t stamp_ = 0;
};

// Grows one vertex's stencil ring by ring (2.1). One per thread, reused for every
// vertex of its block.
class RingGrower {
 public:
  RingGrower(const Topology& t, const Spans& spans) : t_(t), spans_(spans), marks_(t.num_vertices) {}

  // Fills `out` with v's stencil; returns the ring reached.
  float Grow(int v, const RingSpec& spec, std::vector<int32_t>& out) {
    out_ = &out;
    out.clear();
    marks_.Start(static_cast<uint32_t>(v) + 1);
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
  // Adds x to the stencil unless it is there already.
  void Add(int32_t x, int level) {
    if (!marks_.Insert(x, level)) return;
    out_->push_back(x);
    spans_.PrefetchOffset(x);  // its span is read next step: start the cache misses early
  }
  bool In(int32_t x, int max_level) const {
    const int level = marks_.Level(x);
    return level >= 0 && level <= max_level;
  }

  void Step() {
    const int k2 = half_steps_ - half_steps_ % 2;  // 2k for the current integer ring k
    std::vector<int32_t>& out = *out_;
    for (size_t i = layer_begin_; i < layer_end_; ++i) spans_.PrefetchSpan(out[i]);
    if (half_steps_ == 0) {
      // 0 -> 0.5: no edge has both ends in the 0-ring; nothing to add.
    } else if (half_steps_ % 2 == 0) {
      // k -> k + 0.5: faces on an edge (a, b) with a in layer k and b in the k-ring.
      for (size_t i = layer_begin_; i < layer_end_; ++i) {
        const int32_t a = out[i];
        const int32_t* span = spans_.Of(a);
        const int32_t* face = span + 2 + span[0];
        for (int j = 0; j < span[1]; ++j, face += 4) {
          const int n = face[3] < 0 ? 3 : 4;
          int c = 0;
          while (face[c] != a) ++c;
          if (!In(face[c + 1 < n ? c + 1 : 0], k2) && !In(face[c > 0 ? c - 1 : n - 1], k2)) continue;
          for (int q = 0; q < n; ++q) Add(face[q], k2 + 1);
        }
      }
    } else {
      // k + 0.5 -> k + 1: every edge neighbour of layer k; layer k+1 starts after the k-ring.
      const size_t k_ring_end = layer_end_;
      for (size_t i = layer_begin_; i < layer_end_; ++i) {
        const int32_t* span = spans_.Of(out[i]);
        for (int j = 0; j < span[0]; ++j) Add(span[2 + j], k2 + 2);
      }
      layer_begin_ = k_ring_end;
      layer_end_ = out.size();
    }
    ++half_steps_;
  }

  const Topology& t_;
  const Spans& spans_;
  MarkTable marks_;
  std::vector<int32_t>* out_ = nullptr;
  size_t layer_begin_ = 0, layer_end_ = 0;
  int half_steps_ = 0;
};

}  // namespace

Neighborhoods BuildNeighborhoods(const Topology& topo, const Mesh& mesh, const RingSpec& spec,
                                 int num_threads) {
  const int nv = topo.num_vertices;
  const int threads = ResolveThreads(num_threads);
  const Spans spans(topo, mesh, threads);
  std::vector<std::vector<int32_t>> block_indices(threads);
  std::vector<std::vector<int32_t>> block_sizes(threads);
  Neighborhoods nb;
  nb.rings.resize(nv);
  ParallelForBlocks(nv, threads, [&](int64_t begin, int64_t end, int b) {
    RingGrower grower(topo, spans);
    std::vector<int32_t> stencil;
    auto& idx = block_indices[b];
    idx.reserve((end - begin) * 24);
    block_sizes[b].reserve(end - begin);
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
