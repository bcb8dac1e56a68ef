#include "core/fitting/neighborhood.h"

#include <algorithm>
#include <cmath>
#include <memory>

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
  if (o.method == FitMethod::kXu) s.rings = 1, s.adaptive = false, s.max_rings = std::max(1.0, o.max_rings);  // 1-ring only
  return s;
}

namespace {

// The order to grow stencils in. Meshes numbered with locality (edges join near
// indices: generators, most meshers, a LocalityRelabelling, whose topology has no
// locality_order: no pass over the edges to tell) keep their order; others (an external
// mesher's or a shuffled numbering) are grown in breadth-first order over the edges,
// from each unvisited vertex in index order, so consecutive stencils share cache lines.
std::vector<int32_t> GrowthOrder(const Topology& t) {
  const int nv = t.num_vertices;
  std::vector<int32_t> order;
  order.reserve(nv);
  if (t.locality_order.empty() || HasLocalNumbering(t)) {
    for (int v = 0; v < nv; ++v) order.push_back(v);
    return order;
  }
  if (static_cast<int>(t.locality_order.size()) == nv) return t.locality_order;  // the same sweep, built
  std::vector<uint8_t> seen(nv, 0);
  for (int s = 0; s < nv; ++s) {
    if (seen[s]) continue;
    seen[s] = 1;
    size_t head = order.size();
    order.push_back(s);
    for (; head < order.size(); ++head) {
      const int32_t v = order[head];
      for (int j = 0; j < t.NumNeighbors(v); ++j) {
        const int32_t w = t.Neighbors(v)[j];
        if (!seen[w]) {
          seen[w] = 1;
          order.push_back(w);
        }
      }
    }
  }
  return order;
}

// Each vertex's adjacency gathered in one span: its number of neighbours and of faces,
// its edge neighbours (topo.Neighbors order), then one 4-int record per incident face
// (topo.VertexFaces order): the face's other corners in the face's row order (the
// vertex itself left out), -1 padding a triangle's, then which of the three is opposite
// the vertex in a quad (-1 for a triangle). A stencil point's ring step then reads one
// span instead of a face row per incident face (on an external numbering a cache miss
// each) and needs no search for the vertex in the row (a branch the predictor misses on
// an irregular mesh, whose rows start at any corner). Meshes of triangles alone keep the
// records' first 2 ints (the rest is -1, -1): 80 bytes a valence-6 vertex instead of 128.
int FaceRecordInts(const Topology& t) { return t.has_quads ? 4 : 2; }
int SpanSize(const Topology& t, int v) {
  return 2 + t.NumNeighbors(v) + FaceRecordInts(t) * t.NumVertexFaces(v);
}

void FillSpan(const Topology& t, const Mesh& m, int v, int32_t* out) {
  const int nn = t.NumNeighbors(v), nf = t.NumVertexFaces(v), rec = FaceRecordInts(t);
  *out++ = nn;
  *out++ = nf;
  out = std::copy(t.Neighbors(v), t.Neighbors(v) + nn, out);
  for (int j = 0; j < nf; ++j, out += rec) {
    const int32_t* row = m.faces.data() + 4 * static_cast<int64_t>(t.VertexFaces(v)[j]);
    const int n = row[3] < 0 ? 3 : 4;
    const int c = (row[1] == v) + 2 * (row[2] == v) + 3 * (row[3] == v);  // branch-free
    int32_t r[4];
    for (int q = 0, k = 0; q < 4; ++q)
      if (q != c) r[k++] = row[q];  // row[3] = -1 lands in r[2] for a triangle
    r[3] = n == 4 ? (c + 2) % 4 - ((c + 2) % 4 > c) : -1;
    std::copy_n(r, rec, out);
  }
}

// Every vertex's span, built once per call.
class Spans {
 public:
  /// Spans laid out in `order` (a permutation of the vertices).
  Spans(const Topology& t, const Mesh& m, const std::vector<int32_t>& order, int threads)
      : offsets_(t.num_vertices) {
    const int nv = t.num_vertices;
    int64_t at = 0;
    for (int i = 0; i < nv; ++i) {
      const int v = order[i];
      offsets_[v] = at;
      at += SpanSize(t, v);
    }
    data_.resize(at);
    ParallelForBlocks(nv, threads, [&](int64_t begin, int64_t end, int) {
      for (int64_t i = begin; i < end; ++i) FillSpan(t, m, order[i], data_.data() + offsets_[order[i]]);
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
  bool Has(int32_t x) const { return slots_[x].stamp == stamp_; }
  void Set(int32_t x, int level) { slots_[x] = {stamp_, level}; }
  void Erase(int32_t x) { slots_[x].stamp = 0; }  // no stencil's stamp
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

// Near-duplicate points (marching-cubes meshes: a surface passing close to a grid node
// puts the vertices on its edges within a fraction of h of each other). Of a triangle whose
// shortest edge is below kNearDuplicate x its longest, the higher-numbered end of that edge
// is flagged; with RingSpec::count_near_duplicates the growth (2.1) does not count flagged
// points towards min_points (bench/README.md, `mclinf`). gmsh and generated meshes have
// none (edge ratios >= 0.17).
constexpr double kNearDuplicate = 0.1;

// The vertex face `row` flags, or -1. The test first, branch-free (it rarely holds), then
// which edge: the pass costs about the zero-area test's (ValidateGeometry).
inline int32_t FlaggedEnd(const double* P, const int32_t* row) {
  if (row[3] >= 0) return -1;  // triangles only
  const double* p0 = P + 3 * static_cast<int64_t>(row[0]);
  const double* p1 = P + 3 * static_cast<int64_t>(row[1]);
  const double* p2 = P + 3 * static_cast<int64_t>(row[2]);
  const double a0 = p1[0] - p0[0], a1 = p1[1] - p0[1], a2 = p1[2] - p0[2];
  const double b0 = p2[0] - p1[0], b1 = p2[1] - p1[1], b2 = p2[2] - p1[2];
  const double c0 = p0[0] - p2[0], c1 = p0[1] - p2[1], c2 = p0[2] - p2[2];
  const double e2[3] = {a0 * a0 + a1 * a1 + a2 * a2, b0 * b0 + b1 * b1 + b2 * b2, c0 * c0 + c1 * c1 + c2 * c2};
  if (!(std::min({e2[0], e2[1], e2[2]}) < kNearDuplicate * kNearDuplicate * std::max({e2[0], e2[1], e2[2]})))
    return -1;
  const int s = e2[0] <= e2[1] ? (e2[0] <= e2[2] ? 0 : 2) : (e2[1] <= e2[2] ? 1 : 2);  // edge (row[s], row[s + 1])
  return std::max(row[s], row[s == 2 ? 0 : s + 1]);
}

// Every vertex's flag; empty when none is flagged.
std::vector<uint8_t> NearDuplicates(const Mesh& m, int threads) {
  std::vector<std::vector<int32_t>> found(threads);
  const double* P = m.positions.data();
  const int32_t* rows = m.faces.data();
  ParallelForBlocks(m.NumFaces(), threads, [&](int64_t begin, int64_t end, int b) {
    for (int64_t f = begin; f < end; ++f)
      if (const int32_t x = FlaggedEnd(P, rows + 4 * f); x >= 0) found[b].push_back(x);
  });
  std::vector<uint8_t> flags;
  for (const auto& list : found)
    for (int32_t x : list) {
      if (flags.empty()) flags.assign(m.NumVertices(), 0);
      flags[x] = 1;
    }
  return flags;
}

// Grows one vertex's stencil ring by ring (2.1). One per thread, reused for every
// vertex of its block. Reads the spans of `spans`, or with kFans (FanSteps take most
// stencils whole; `spans` null) fills one at a time where needed.
template <bool kFans>
class RingGrower {
 public:
  // `near_duplicates`: NearDuplicates' flags (when spec.count_near_duplicates), or null to
  // test each point's faces as met (a few stencils: BuildNeighborhoodsOf).
  RingGrower(const Topology& t, const Mesh& m, const Spans* spans, const RingSpec& spec,
             const std::vector<uint8_t>* near_duplicates)
      : t_(t), m_(m), spans_(spans), spec_(spec),
        near_(near_duplicates && !near_duplicates->empty() ? near_duplicates->data() : nullptr),
        test_(!near_duplicates && spec.count_near_duplicates),
        marks_(t.num_vertices),
        fans_(kFans && t.fan_rows && !t.has_quads),
        start_(static_cast<int>(std::lround(2 * spec.rings))),
        max_steps_(std::max(start_, static_cast<int>(std::lround(2 * spec.max_rings)))) {}

  // Prefetch hint for a vertex grown soon: its neighbours' rows (FanSteps read them).
  void Prefetch(int v) const {
    if constexpr (!kFans) return;
    for (int j = 0; j < t_.NumNeighbors(v); ++j) __builtin_prefetch(t_.Neighbors(t_.Neighbors(v)[j]));
  }

  // Fills `out` with v's stencil; returns the ring reached.
  float Grow(int v, std::vector<int32_t>& out) {
    const RingSpec& spec = spec_;
    out_ = &out;
    out.clear();
    marks_.Start(static_cast<uint32_t>(v) + 1);
    const int start = start_, max_steps = max_steps_;
    if (!fans_ || start < 3 || !FanSteps(v, spec.max_points)) {
      out.clear();
      Add(v, 0);
      layer_begin_ = 0;
      layer_end_ = 1;
      half_steps_ = 0;
    }
    const size_t want = t_.is_boundary[v] ? spec.min_points_boundary : spec.min_points;
    while (half_steps_ < max_steps) {
      const bool required = half_steps_ < start;
      if (!required && (!spec.adaptive || Distinct(out, want) >= want)) break;
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
  // Points counted towards min_points: all but the flagged near-duplicates.
  size_t Distinct(const std::vector<int32_t>& out, size_t want) {
    if ((!near_ && !test_) || out.size() < want) return out.size();
    size_t n = out.size();
    if (near_) {
      for (int32_t x : out) n -= near_[x];
      return n;
    }
    if (tested_.empty()) tested_.assign(t_.num_vertices, -1);
    for (int32_t x : out) {
      if (tested_[x] < 0) {
        tested_[x] = 0;
        for (int j = 0; j < t_.NumVertexFaces(x); ++j)
          tested_[x] |= FlaggedEnd(m_.positions.data(), m_.faces.data() + 4 * int64_t{t_.VertexFaces(x)[j]}) == x;
      }
      n -= tested_[x];
    }
    return n;
  }

  // Adds x to the stencil unless it is there already.
  void Add(int32_t x, int level) {
    if (!marks_.Insert(x, level)) return;
    out_->push_back(x);
    if constexpr (!kFans) spans_->PrefetchOffset(x);  // its span is read next step: start the cache misses early
  }

  // v's span: built, or filled in the scratch span (valid until the next call).
  const int32_t* SpanOf(int v) {
    if constexpr (!kFans) return spans_->Of(v);
    scratch_.resize(SpanSize(t_, v));
    FillSpan(t_, m_, v, scratch_.data());
    return scratch_.data();
  }

  // Steps 0 -> 1.5 at once where the 1.5-ring is a plain polygon walk: v's and its
  // neighbours' faces form cyclic fans (interior vertices of a topology with
  // Topology::fan_rows: face j of v is (v, n[j], n[j + 1 mod #n]) in its row's
  // orientation, n: v's neighbours), no neighbour u_i of v is adjacent to
  // another than u_{i-1} and u_{i+1} (no chord), and the flaps f_i (the corner across
  // the edge (u_i, u_{i+1}) from v's face i) are distinct and not in the 1-ring. Then
  // u_i's faces with an edge to the 1-ring are exactly its four faces on the edges to
  // v, u_{i-1} and u_{i+1}, so the general step adds the f_i alone, each first met
  // at the first of its two ends in v's neighbour order: u_0 adds f_{n-1} and f_0 in
  // the order of their faces at u_0, u_i adds f_i (0 < i < n - 1). The stencil, its
  // order and the marks are the general steps'; with the neighbour rows as stored, no
  // search and no mark test of a neighbour's whole fan. Returns false (marks cleared,
  // `out` to be reset) where a condition fails: the general steps take over.
  bool FanSteps(int v, int max_points) {
    const int n = t_.NumNeighbors(v);
    if (t_.is_boundary[v] || n < 3 || 2 * n + 1 > max_points) return false;
    const int32_t* u = t_.Neighbors(v);
    flaps_.resize(n);
    at_.resize(n);
    int first_order = 0;  // at u_0: whether f_0's face comes after f_{n-1}'s
    for (int i = 0; i < n; ++i) {
      if (t_.is_boundary[u[i]]) return false;
      const int d = t_.NumNeighbors(u[i]);
      const int32_t* w = t_.Neighbors(u[i]);
      int q = 0;  // v's position among u_i's neighbours: u_i's face q - 1 is v's face i
      for (int j = 1; j < d; ++j) q = w[j] == v ? j : q;
      const int before = q >= 2 ? q - 2 : q - 2 + d;  // f_i: across (u_i, u_{i+1})
      flaps_[i] = w[before];
      at_[i] = q;
      if (i == 0) first_order = before > (q + 1 < d ? q + 1 : q + 1 - d);  // f_{n-1}'s face: q + 1
    }
    out_->push_back(v);
    marks_.Set(v, 0);
    for (int i = 0; i < n; ++i) {
      out_->push_back(u[i]);
      marks_.Set(u[i], 2);
    }
    bool plain = true;
    for (int i = 0; i < n; ++i) {  // no chord: u_i's neighbours other than f_i, u_{i+1}, v, u_{i-1}, f_{i-1}
      const int d = t_.NumNeighbors(u[i]);
      const int32_t* w = t_.Neighbors(u[i]);
      const int q = at_[i];
      for (int t = 3; t <= d - 3; ++t) plain &= !marks_.Has(w[q + t < d ? q + t : q + t - d]);
    }
    if (plain) {  // the flaps, unless one is in the 1-ring or twice
      const auto add = [&](int32_t f) {
        plain &= !marks_.Has(f);
        marks_.Set(f, 3);
        out_->push_back(f);
      };
      add(flaps_[first_order ? n - 1 : 0]);
      add(flaps_[first_order ? 0 : n - 1]);
      for (int i = 1; i + 1 < n; ++i) add(flaps_[i]);
    }
    if (!plain) {
      for (int32_t x : *out_) marks_.Erase(x);
      return false;
    }
    layer_begin_ = 1;
    layer_end_ = 1 + n;
    half_steps_ = 3;
    return true;
  }

  bool In(int32_t x, int max_level) const {
    const int level = marks_.Level(x);
    return level >= 0 && level <= max_level;
  }

  void Step() {
    const int k2 = half_steps_ - half_steps_ % 2;  // 2k for the current integer ring k
    std::vector<int32_t>& out = *out_;
    if constexpr (!kFans)
      for (size_t i = layer_begin_; i < layer_end_; ++i) spans_->PrefetchSpan(out[i]);
    if (half_steps_ == 0) {
      // 0 -> 0.5: no edge has both ends in the 0-ring; nothing to add.
    } else if (half_steps_ % 2 == 0) {
      // k -> k + 0.5: faces on an edge (a, b) with a in layer k and b in the k-ring.
      // Adding a face's corners in row order, a (already in) left out.
      for (size_t i = layer_begin_; i < layer_end_; ++i) {
        const int32_t* span = SpanOf(out[i]);
        const int32_t* face = span + 2 + span[0];
        if (!t_.has_quads) {  // 2-int records: a triangle's other corners
          for (int j = 0; j < span[1]; ++j, face += 2)
            if (In(face[0], k2) || In(face[1], k2)) Add(face[0], k2 + 1), Add(face[1], k2 + 1);
          continue;
        }
        for (int j = 0; j < span[1]; ++j, face += 4) {
          const int opposite = face[3];
          if (!(In(face[0], k2) && opposite != 0) && !(In(face[1], k2) && opposite != 1) &&
              !(opposite >= 0 && opposite != 2 && In(face[2], k2)))
            continue;
          Add(face[0], k2 + 1);
          Add(face[1], k2 + 1);
          if (face[2] >= 0) Add(face[2], k2 + 1);
        }
      }
    } else {
      // k + 0.5 -> k + 1: every edge neighbour of layer k; layer k+1 starts after the k-ring.
      const size_t k_ring_end = layer_end_;
      for (size_t i = layer_begin_; i < layer_end_; ++i) {
        if constexpr (kFans) {  // no span to fill: the rows suffice
          for (int j = 0; j < t_.NumNeighbors(out[i]); ++j) Add(t_.Neighbors(out[i])[j], k2 + 2);
        } else {
          const int32_t* span = spans_->Of(out[i]);
          for (int j = 0; j < span[0]; ++j) Add(span[2 + j], k2 + 2);
        }
      }
      layer_begin_ = k_ring_end;
      layer_end_ = out.size();
    }
    ++half_steps_;
  }

  const Topology& t_;
  const Mesh& m_;
  const Spans* spans_;
  const RingSpec spec_;
  const uint8_t* near_;  // NearDuplicates' flags (null: none flagged, or test_)
  const bool test_;      // flags tested as met, kept in tested_ (-1: untested)
  std::vector<int8_t> tested_;
  MarkTable marks_;
  const bool fans_;  // FanSteps apply (rows in fan order, triangles)
  const int start_, max_steps_;  // half steps: required, at most
  std::vector<int32_t> scratch_;
  std::vector<int32_t> flaps_, at_;  // FanSteps: f_i, v's position at u_i
  std::vector<int32_t>* out_ = nullptr;
  size_t layer_begin_ = 0, layer_end_ = 0;
  int half_steps_ = 0;
};

// BuildNeighborhoods' growth: each stencil of `order` into its block's buffer, its size
// and start there (a function per grower kind: one loop calling both slowed the span
// path by 2-3% at degree 6).
template <bool kFans>
void GrowStencils(const Topology& topo, const Mesh& mesh, const Spans* spans, const RingSpec& spec,
                  const std::vector<int32_t>& order, const std::vector<uint8_t>& near_duplicates,
                  int threads, std::vector<float>& rings,
                  std::vector<std::vector<int32_t>>& block_indices, std::vector<int32_t>& sizes,
                  std::vector<int64_t>& start) {
  ParallelForBlocks(topo.num_vertices, threads, [&](int64_t begin, int64_t end, int b) {
    RingGrower<kFans> grower(topo, mesh, spans, spec, &near_duplicates);
    std::vector<int32_t> stencil;
    auto& idx = block_indices[b];
    if (kFans) {
      // A 1.5-ring stencil on a fan is the vertex, its n neighbours and n flaps: 1 + 2n;
      // below min_points it grows to 2 rings, ~1 + 3n among valence-6 vertices (+10%
      // for the rest), so one block grown in vertex order fits BuildNeighborhoods'
      // no-copy test and stays where it is (no copy above it).
      int64_t fan_points = 0;
      for (int64_t i = begin; i < end; ++i) {
        const int n = topo.NumNeighbors(order[i]);
        fan_points += 1 + 2 * n >= spec.min_points ? 1 + 2 * n : 1 + 3 * n;
      }
      idx.reserve(fan_points + fan_points / 10 + 64);
    } else {
      idx.reserve((end - begin) * std::max(24, 2 * spec.min_points));  // stencils rarely pass 1.5x min_points
    }
    for (int64_t i = begin; i < end; ++i) {
      const int v = order[i];
      if (kFans && i + 4 < end) grower.Prefetch(order[i + 4]);
      rings[v] = grower.Grow(v, stencil);
      sizes[v] = static_cast<int32_t>(stencil.size());
      start[v] = static_cast<int64_t>(idx.size());
      idx.insert(idx.end(), stencil.begin(), stencil.end());
    }
  });
}

}  // namespace

Neighborhoods BuildNeighborhoods(const Topology& topo, const Mesh& mesh, const RingSpec& spec,
                                 int num_threads, const std::function<void()>& faces_read) {
  const int nv = topo.num_vertices;
  const int threads = ResolveThreads(num_threads);
  // Stencils are grown in GrowthOrder (each is independent of the order) and then
  // copied to vertex order.
  const std::vector<int32_t> order = GrowthOrder(topo);
  const std::vector<uint8_t> near_duplicates =
      spec.count_near_duplicates ? NearDuplicates(mesh, threads) : std::vector<uint8_t>();
  // FanSteps on rows in fan order where stencils start at 1.5 rings (most stop there,
  // with no spans: the rest fill theirs as they go). Stencils starting further out use
  // the spans throughout (FanSteps there as fast as the general steps: their spans are
  // needed anyway).
  const bool fans = topo.fan_rows && !topo.has_quads && std::lround(2 * spec.rings) == 3;
  std::unique_ptr<const Spans> spans;
  if (!fans) spans = std::make_unique<const Spans>(topo, mesh, order, threads);
  // The span growth reads the spans and topo.is_boundary alone; FanSteps read the rows.
  if (faces_read && !fans) faces_read();
  std::vector<std::vector<int32_t>> block_indices(threads);
  std::vector<int32_t> sizes(nv);
  std::vector<int64_t> start(nv);  // in the block's buffer, then final
  Neighborhoods nb;
  nb.rings.resize(nv);
  if (fans)
    GrowStencils<true>(topo, mesh, nullptr, spec, order, near_duplicates, threads, nb.rings, block_indices, sizes, start);
  else
    GrowStencils<false>(topo, mesh, spans.get(), spec, order, near_duplicates, threads, nb.rings, block_indices, sizes, start);
  if (faces_read && fans) faces_read();
  spans.reset();  // its memory (~128 bytes a vertex) takes the stencils below
  nb.offsets.resize(nv + 1);
  nb.offsets[0] = 0;
  for (int v = 0; v < nv; ++v) nb.offsets[v + 1] = nb.offsets[v] + sizes[v];
  if (threads == 1 || nv == 1) {
    bool identity = true;
    for (int i = 0; i < nv && identity; ++i) identity = order[i] == i;
    // One block grown in vertex order is the result, where it was grown: its spare
    // capacity is address space that nothing touches, while an exact copy would land
    // above it on fresh pages (the block is the heap's top then: +18 MB touched at
    // degree 6 on an 87k-vertex mesh). Fan stencils reserve close to their size.
    if (identity) nb.indices = std::move(block_indices[0]);
  }
  if (nb.indices.empty()) {
    nb.indices.resize(nb.offsets[nv]);
    ParallelForBlocks(nv, threads, [&](int64_t begin, int64_t end, int b) {
      for (int64_t i = begin; i < end; ++i) {
        const int v = order[i];
        std::copy_n(block_indices[b].begin() + start[v], sizes[v], nb.indices.begin() + nb.offsets[v]);
      }
    });
    std::vector<std::vector<int32_t>>().swap(block_indices);
    std::vector<int64_t>().swap(start);
  }
  if (static_cast<int>(topo.locality_order.size()) == nv) nb.ordered = OrderStencils(nb, topo.locality_order, threads);
  return nb;
}

Neighborhoods BuildNeighborhoodsOf(const Topology& topo, const Mesh& mesh, const RingSpec& spec,
                                   const std::vector<int32_t>& vertices, int num_threads) {
  const int n = static_cast<int>(vertices.size());
  const int threads = ResolveThreads(num_threads);
  std::vector<std::vector<int32_t>> stencils(n);
  Neighborhoods nb;
  nb.rings.resize(n);
  // The grower that fills spans as it goes (no spans of the whole mesh for a few stencils).
  ParallelForBlocks(n, threads, [&](int64_t begin, int64_t end, int) {
    RingGrower<true> grower(topo, mesh, nullptr, spec, nullptr);
    for (int64_t i = begin; i < end; ++i) nb.rings[i] = grower.Grow(vertices[i], stencils[i]);
  });
  nb.offsets.resize(n + 1);
  nb.offsets[0] = 0;
  for (int i = 0; i < n; ++i) nb.offsets[i + 1] = nb.offsets[i] + static_cast<int32_t>(stencils[i].size());
  nb.indices.reserve(nb.offsets[n]);
  for (const auto& s : stencils) nb.indices.insert(nb.indices.end(), s.begin(), s.end());
  return nb;
}

OrderedStencils OrderStencils(const Neighborhoods& nb, std::vector<int32_t> order, int num_threads) {
  const int nv = static_cast<int>(nb.offsets.size()) - 1;
  OrderedStencils s;
  s.order = std::move(order);
  s.rank.resize(nv);
  s.offsets.resize(nv + 1);
  s.offsets[0] = 0;
  for (int k = 0; k < nv; ++k) {
    const int v = s.order[k];
    s.rank[v] = k;
    s.offsets[k + 1] = s.offsets[k] + nb.Size(v);
  }
  s.points.resize(s.offsets[nv]);
  ParallelForBlocks(nv, ResolveThreads(num_threads), [&](int64_t begin, int64_t end, int) {
    for (int64_t k = begin; k < end; ++k) {
      const int v = s.order[k];
      if (k + 8 < end) __builtin_prefetch(nb.Points(s.order[k + 8]));  // rows in vertex order: random
      const int32_t* p = nb.Points(v);
      int32_t* out = s.points.data() + s.offsets[k];
      for (int i = 0, n = nb.Size(v); i < n; ++i) out[i] = s.rank[p[i]];
    }
  });
  return s;
}

}  // namespace geomfit
