#include "core/mesh/topology.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <numeric>

#include "absl/strings/str_format.h"
#include "core/util/parallel.h"

namespace geomfit {
namespace {

// A half-edge filed under its lower endpoint (the bucket) with the higher one.
struct HalfEdge {
  int32_t hi;
  int32_t face;
  bool forward;  // face traverses lo -> hi
};

// Sorts one bucket by (hi, face). Half-edges are filed in face order, so a stable sort
// by hi suffices; buckets hold a vertex's few edges, so insertion sort, unless a
// vertex has a huge fan.
void SortBucket(HalfEdge* begin, HalfEdge* end) {
  if (end - begin > 32) {
    std::stable_sort(begin, end, [](const HalfEdge& x, const HalfEdge& y) { return x.hi < y.hi; });
    return;
  }
  for (HalfEdge* i = begin + 1; i < end; ++i) {
    const HalfEdge e = *i;
    HalfEdge* j = i;
    for (; j > begin && (j - 1)->hi > e.hi; --j) *j = *(j - 1);
    *j = e;
  }
}

// Smallest-root union-find over a handful of faces around one vertex.
int Find(std::vector<int>& parent, int i) {
  while (parent[i] != i) i = parent[i] = parent[parent[i]];
  return i;
}

// Locality order: breadth-first (Cuthill-McKee) sweeps over the edges from the lowest
// unvisited vertex, so vertices near in the order are near on the surface whatever the
// file's numbering.
void FillLocalityOrder(Topology* t) {
  const int nv = t->num_vertices;
  t->locality_order.resize(nv);
  std::vector<uint8_t> seen(nv, 0);
  int head = 0, tail = 0;
  for (int s = 0; s < nv; ++s) {
    if (seen[s]) continue;
    seen[s] = 1;
    t->locality_order[tail++] = s;
    for (; head < tail; ++head) {
      const int v = t->locality_order[head];
      for (int i = t->vv_offsets[v]; i < t->vv_offsets[v + 1]; ++i)
        if (!seen[t->vv[i]]) seen[t->vv[i]] = 1, t->locality_order[tail++] = t->vv[i];
    }
  }
}

}  // namespace

size_t Topology::Bytes() const {
  return sizeof(*this) +
         4 * (vf_offsets.size() + vf_faces.size() + vv_offsets.size() + vv.size() + locality_order.size() + vertex_source.size()) +
         is_boundary.size() + is_isolated.size();
}

namespace {

// Passes 1 and 2 of both builds (BuildTopology of a mesh, FanTopology of a relabelling).
// Pass 1 checks the faces (the index errors BuildTopology reports) and counts faces per
// vertex (t->vf_offsets) and, if `bucket` is given, half-edges per lower endpoint.
// Pass 2 files the faces under their vertices in face order, with each face filed under
// vertex a its corners after and before a (the "spokes" of the fan checks, which then
// read no face), and, with `bucket`, the half-edges under their lower endpoint (a
// counting sort: linear) into `edges`.
absl::Status FileFaces(const Mesh& mesh, Topology* t, std::vector<int32_t>* bucket, std::vector<HalfEdge>* edges,
                       std::vector<std::array<int32_t, 2>>* spokes) {
  const int nv = mesh.NumVertices(), nf = mesh.NumFaces();
  if (nv == 0) return absl::InvalidArgumentError("mesh has no vertices");
  if (nf == 0) return absl::InvalidArgumentError("mesh has no faces");
  t->num_vertices = nv;
  t->num_faces = nf;
  if (bucket) bucket->assign(nv + 1, 0);
  t->vf_offsets.assign(nv + 1, 0);
  for (int f = 0; f < nf; ++f) {
    const int32_t* idx = mesh.faces.data() + 4 * static_cast<int64_t>(f);
    const int n = idx[3] < 0 ? 3 : 4;
    if (n == 4) t->has_quads = true;
    for (int i = 0; i < n; ++i) {
      const int32_t a = idx[i];
      if (a < 0 || a >= nv)
        return absl::InvalidArgumentError(absl::StrFormat(
            "face %d: vertex index %d out of range [0, %d)", f, a, nv));
      for (int j = 0; j < i; ++j)
        if (idx[j] == a)
          return absl::InvalidArgumentError(
              absl::StrFormat("face %d: vertex %d appears twice", f, a));
    }
    for (int i = 0; i < n; ++i) {
      const int32_t a = idx[i];
      if (bucket) ++(*bucket)[std::min(a, idx[i + 1 < n ? i + 1 : 0]) + 1];
      ++t->vf_offsets[a + 1];
    }
  }
  if (bucket) std::partial_sum(bucket->begin(), bucket->end(), bucket->begin());
  std::partial_sum(t->vf_offsets.begin(), t->vf_offsets.end(), t->vf_offsets.begin());

  if (bucket) edges->resize((*bucket)[nv]);
  t->vf_faces.resize(t->vf_offsets[nv]);
  spokes->resize(t->vf_offsets[nv]);
  std::vector<int32_t> fill;
  if (bucket) fill.assign(bucket->begin(), bucket->end() - 1);
  std::vector<int32_t> vf_fill(t->vf_offsets.begin(), t->vf_offsets.end() - 1);
  for (int f = 0; f < nf; ++f) {
    const int32_t* idx = mesh.faces.data() + 4 * static_cast<int64_t>(f);
    const int n = idx[3] < 0 ? 3 : 4;
    for (int i = 0; i < n; ++i) {
      const int32_t a = idx[i], b = idx[i + 1 < n ? i + 1 : 0];
      if (bucket) (*edges)[fill[std::min(a, b)]++] = {std::max(a, b), f, a < b};
      const int32_t k = vf_fill[a]++;
      t->vf_faces[k] = f;
      (*spokes)[k] = {b, idx[i > 0 ? i - 1 : n - 1]};
    }
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<Topology> BuildTopology(const Mesh& mesh) {
  Topology t;
  std::vector<int32_t> bucket;
  std::vector<HalfEdge> edges;
  std::vector<std::array<int32_t, 2>> spokes;
  if (absl::Status s = FileFaces(mesh, &t, &bucket, &edges, &spokes); !s.ok()) return s;
  const int nv = t.num_vertices;
  // Buckets sorted by (hi, face): the half-edges are now in (lo, hi, face) order.
  for (int v = 0; v < nv; ++v) SortBucket(edges.data() + bucket[v], edges.data() + bucket[v + 1]);

  t.is_boundary.assign(nv, 0);
  std::vector<int32_t> degree(nv, 0);
  for (int lo = 0; lo < nv; ++lo) {
    const int32_t end = bucket[lo + 1];
    for (int32_t i = bucket[lo]; i < end;) {
      int32_t j = i + 1;
      while (j < end && edges[j].hi == edges[i].hi) ++j;
      const int32_t hi = edges[i].hi;
      if (j - i > 2)
        return absl::InvalidArgumentError(absl::StrFormat(
            "non-manifold edge (%d, %d): shared by %d faces (faces %d, %d, %d ...)", lo, hi,
            j - i, edges[i].face, edges[i + 1].face, edges[i + 2].face));
      if (j - i == 2 && edges[i].forward == edges[i + 1].forward)
        return absl::InvalidArgumentError(absl::StrFormat(
            "inconsistent orientation: faces %d and %d traverse edge (%d, %d) in the same direction",
            edges[i].face, edges[i + 1].face, lo, hi));
      if (j - i == 1) {
        t.is_boundary[lo] = t.is_boundary[hi] = 1;
        ++t.num_boundary_edges;
      }
      ++degree[lo];
      ++degree[hi];
      i = j;
    }
  }

  // vertex -> vertices (edges). Edges come in (lo, hi) order, so each vertex first
  // receives its lower neighbours in increasing order, then (from its own bucket) its
  // higher ones in increasing order: every row is sorted as filled.
  t.vv_offsets.assign(nv + 1, 0);
  for (int v = 0; v < nv; ++v) t.vv_offsets[v + 1] = t.vv_offsets[v] + degree[v];
  t.vv.resize(t.vv_offsets[nv]);
  {
    std::vector<int32_t>& fill = degree;  // reused as the fill cursor
    std::copy(t.vv_offsets.begin(), t.vv_offsets.end() - 1, fill.begin());
    for (int lo = 0; lo < nv; ++lo)
      for (int32_t i = bucket[lo]; i < bucket[lo + 1]; ++i) {
        if (i > bucket[lo] && edges[i].hi == edges[i - 1].hi) continue;
        t.vv[fill[lo]++] = edges[i].hi;
        t.vv[fill[edges[i].hi]++] = lo;
      }
  }
  edges = {};

  // Manifold vertices: the faces around each vertex form one fan (connected through
  // the edges incident on the vertex): union-find over its faces, joined where two
  // share a spoke (up to kPairwiseFan faces by comparing every pair, beyond by sorting
  // the spokes, keyed (other endpoint, local face)).
  constexpr int kPairwiseFan = 12;
  t.is_isolated.assign(nv, 0);
  std::vector<int> parent;
  std::vector<uint64_t> keys;
  for (int v = 0; v < nv; ++v) {
    const int k = t.NumVertexFaces(v);
    if (k == 0) {
      t.is_isolated[v] = 1;
      ++t.num_isolated;
      continue;
    }
    parent.resize(k);
    std::iota(parent.begin(), parent.end(), 0);
    const std::array<int32_t, 2>* s = spokes.data() + t.vf_offsets[v];
    if (k <= kPairwiseFan) {
      // A vertex's usual few faces: every pair compared (no sort; the same joins).
      for (int i = 1; i < k; ++i)
        for (int j = 0; j < i; ++j)
          if ((s[i][0] == s[j][0]) | (s[i][0] == s[j][1]) | (s[i][1] == s[j][0]) | (s[i][1] == s[j][1]))
            parent[Find(parent, i)] = Find(parent, j);
    } else {
      keys.resize(2 * k);
      for (int i = 0; i < k; ++i)
        for (int side = 0; side < 2; ++side)
          keys[2 * i + side] = static_cast<uint64_t>(s[i][side]) << 32 | static_cast<uint32_t>(i);
      std::sort(keys.begin(), keys.end());
      for (size_t i = 1; i < keys.size(); ++i)
        if (keys[i] >> 32 == keys[i - 1] >> 32)
          parent[Find(parent, static_cast<int>(keys[i] & 0xffffffffu))] =
              Find(parent, static_cast<int>(keys[i - 1] & 0xffffffffu));
    }
    int fans = 0;
    for (int i = 0; i < k; ++i) fans += Find(parent, i) == i;
    if (fans > 1)
      return absl::InvalidArgumentError(absl::StrFormat(
          "non-manifold vertex %d: its %d faces form %d separate fans", v, k, fans));
  }

  FillLocalityOrder(&t);
  return t;
}

namespace {

// A face is valid if its indices are in range and its area is not zero: zero means
// collinear or coincident corners, judged against the face's own longest edge so that
// tiny well-shaped faces (marching cubes makes them near grid samples) are fine.
inline bool FaceOk(const Mesh& mesh, int f) {
  const int nv = mesh.NumVertices(), n = mesh.FaceSize(f);
  const int32_t* idx = mesh.faces.data() + 4 * static_cast<int64_t>(f);
  for (int i = 0; i < n; ++i)
    if (idx[i] < 0 || idx[i] >= nv) return false;
  const double* P = mesh.positions.data();
  const double* p0 = P + 3 * idx[0];
  if (n == 3) {  // the common case, unrolled: |e1 x e2|^2 against the longest edge^4
    const double* p1 = P + 3 * idx[1];
    const double* p2 = P + 3 * idx[2];
    const double a0 = p1[0] - p0[0], a1 = p1[1] - p0[1], a2 = p1[2] - p0[2];
    const double b0 = p2[0] - p0[0], b1 = p2[1] - p0[1], b2 = p2[2] - p0[2];
    const double c0 = b0 - a0, c1 = b1 - a1, c2 = b2 - a2;
    const double x = a1 * b2 - a2 * b1, y = a2 * b0 - a0 * b2, z = a0 * b1 - a1 * b0;
    const double longest2 = std::max({a0 * a0 + a1 * a1 + a2 * a2, b0 * b0 + b1 * b1 + b2 * b2,
                                      c0 * c0 + c1 * c1 + c2 * c2});
    return x * x + y * y + z * z > 1e-24 * longest2 * longest2;
  }
  double ax = 0, ay = 0, az = 0, longest2 = 0;
  for (int i = 0; i < n; ++i) {
    const double* pa = P + 3 * idx[i];
    const double* pb = P + 3 * idx[i + 1 == n ? 0 : i + 1];
    const double a0 = pa[0] - p0[0], a1 = pa[1] - p0[1], a2 = pa[2] - p0[2];
    const double b0 = pb[0] - p0[0], b1 = pb[1] - p0[1], b2 = pb[2] - p0[2];
    ax += a1 * b2 - a2 * b1, ay += a2 * b0 - a0 * b2, az += a0 * b1 - a1 * b0;
    const double e0 = b0 - a0, e1 = b1 - a1, e2 = b2 - a2;
    longest2 = std::max(longest2, e0 * e0 + e1 * e1 + e2 * e2);
  }
  return ax * ax + ay * ay + az * az > 1e-24 * longest2 * longest2;
}

// The message about an invalid face.
absl::Status FaceError(const Mesh& mesh, int f) {
  for (int i = 0; i < mesh.FaceSize(f); ++i)
    if (mesh.faces(f, i) < 0 || mesh.faces(f, i) >= mesh.NumVertices())
      return absl::InvalidArgumentError(absl::StrFormat("face %d: vertex index out of range", f));
  // The area test squares squared lengths: edges beyond ~1e75 overflow it.
  for (int i = 0; i < mesh.FaceSize(f); ++i) {
    const auto a = mesh.positions.row(mesh.faces(f, i));
    const auto b = mesh.positions.row(mesh.faces(f, (i + 1) % mesh.FaceSize(f)));
    const double e2 = (b - a).squaredNorm();
    if (!std::isfinite(e2 * e2)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "face %d: coordinates too large (the area test overflows for edges longer than ~1e75)", f));
    }
  }
  return absl::InvalidArgumentError(
      absl::StrFormat("face %d has zero area (its corners are collinear or coincide)", f));
}

}  // namespace

absl::Status ValidateGeometry(const Mesh& mesh, int num_threads) {
  const int nv = mesh.NumVertices();
  for (int v = 0; v < nv; ++v)
    for (int c = 0; c < 3; ++c)
      if (!std::isfinite(mesh.positions(v, c)))
        return absl::InvalidArgumentError(absl::StrFormat(
            "vertex %d: coordinate %c is not finite (%g)", v, "xyz"[c], mesh.positions(v, c)));
  // Faces in parallel blocks; the error reported is always the lowest-numbered face's.
  // A few nanoseconds a face: below ~10^5 faces waking a thread team costs more.
  // A team asked for but unused also costs: its idle thread spins a while after.
  const int threads = mesh.NumFaces() < 100'000 ? 1 : ResolveThreads(num_threads);
  std::vector<int> first_bad(threads, std::numeric_limits<int>::max());
  ParallelForBlocks(mesh.NumFaces(), threads, [&](int64_t begin, int64_t end, int b) {
    for (int64_t f = begin; f < end; ++f)
      if (!FaceOk(mesh, static_cast<int>(f))) {
        first_bad[b] = static_cast<int>(f);
        return;
      }
  });
  const int bad = *std::min_element(first_bad.begin(), first_bad.end());
  return bad == std::numeric_limits<int>::max() ? absl::OkStatus() : FaceError(mesh, bad);
}

absl::StatusOr<Topology> ValidateMesh(const Mesh& mesh, int num_threads) {
  auto topo = BuildTopology(mesh);
  if (!topo.ok()) return topo.status();
  absl::Status geo = ValidateGeometry(mesh, num_threads);
  if (!geo.ok()) return geo;
  return topo;
}

}  // namespace geomfit

namespace geomfit {
namespace {

// The 10 bits of x spread to every third bit (Morton interleaving).
uint32_t Spread3(uint32_t x) {
  x = (x | x << 16) & 0x030000ffu;
  x = (x | x << 8) & 0x0300f00fu;
  x = (x | x << 4) & 0x030c30c3u;
  x = (x | x << 2) & 0x09249249u;
  return x;
}

// Sorts a row of distinct entries by key[entry] (distinct keys). Rows hold a vertex's
// few neighbours or faces, whose keys (source indices) come in no pattern: up to 8
// entries each go straight to their rank, counted by comparing every pair in 8 lanes
// (padded with the largest key; no branch, vectorised), more through std::sort.
void SortRowByKey(int32_t* begin, int32_t* end, const std::vector<int32_t>& key) {
  const int n = static_cast<int>(end - begin);
  if (n > 8) {
    std::sort(begin, end, [&](int32_t x, int32_t y) { return key[x] < key[y]; });
    return;
  }
  int32_t k[8], rank[8] = {}, out[8];
  for (int i = 0; i < n; ++i) k[i] = key[begin[i]];
  for (int i = n; i < 8; ++i) k[i] = std::numeric_limits<int32_t>::max();
  for (int j = 0; j < 8; ++j)
    for (int i = 0; i < 8; ++i) rank[i] += k[j] < k[i];
  for (int i = 0; i < n; ++i) out[rank[i]] = begin[i];
  std::copy_n(out, n, begin);
}

}  // namespace

bool HasLocalNumbering(const Mesh& mesh) {
  // The sum only grows, and the faces after f add at most 4 edges each: once it is over
  // the bound for the most edges the mesh can have, the answer is known (a scattered
  // numbering: after ~1/5 of its faces).
  const int nf = mesh.NumFaces();
  int64_t gap = 0, edges = 0;
  for (int f = 0; f < nf; ++f) {
    const int32_t* idx = mesh.faces.data() + 4 * static_cast<int64_t>(f);
    const int n = idx[3] < 0 ? 3 : 4;
    for (int c = 0; c < n; ++c) gap += std::abs(static_cast<int64_t>(idx[c]) - idx[c + 1 < n ? c + 1 : 0]);
    edges += n;
    if (f % 1024 == 1023 && !IsLocalIndexGap(gap, edges + 4 * static_cast<int64_t>(nf - 1 - f))) return false;
  }
  return IsLocalIndexGap(gap, edges);
}

bool HasLocalNumbering(const Topology& t) {
  int64_t gap = 0;
  for (int v = 0; v < t.num_vertices; ++v)
    for (int j = 0; j < t.NumNeighbors(v); ++j) gap += std::abs(v - t.Neighbors(v)[j]);
  return IsLocalIndexGap(gap, static_cast<int64_t>(t.vv.size()));
}

absl::StatusOr<LocalityRelabelling> RelabelForLocality(const Mesh& mesh, RowOrder order) {
  const int nv = mesh.NumVertices(), nf = mesh.NumFaces();
  if (nv == 0 || nf == 0) return absl::InvalidArgumentError("empty mesh");
  // Vertices by the Morton code of their cell in a 1024^3 grid over the bounding box
  // (non-finite coordinates in cell 0): an LSD radix sort, two passes of 15 bits, stable.
  double lo[3], hi[3], scale[3];
  for (int c = 0; c < 3; ++c) lo[c] = std::numeric_limits<double>::max(), hi[c] = -lo[c];
  const double* P = mesh.positions.data();
  for (int v = 0; v < nv; ++v)
    for (int c = 0; c < 3; ++c) {
      const double x = P[3 * static_cast<int64_t>(v) + c];
      if (std::isfinite(x)) lo[c] = std::min(lo[c], x), hi[c] = std::max(hi[c], x);
    }
  for (int c = 0; c < 3; ++c) scale[c] = hi[c] > lo[c] ? 1024.0 / (hi[c] - lo[c]) : 0.0;
  std::vector<uint32_t> code(nv);
  for (int v = 0; v < nv; ++v) {
    uint32_t key = 0;
    for (int c = 0; c < 3; ++c) {
      const double t = (P[3 * static_cast<int64_t>(v) + c] - lo[c]) * scale[c];
      key |= Spread3(t >= 0 && t < 1023.0 ? static_cast<uint32_t>(t) : t >= 1023.0 ? 1023u : 0u) << c;
    }
    code[v] = key;
  }
  LocalityRelabelling r;
  r.vertex_source.resize(nv);
  {
    constexpr int kBits = 15, kBuckets = 1 << kBits;
    std::vector<int32_t> tmp(nv), count(kBuckets + 1);
    std::iota(tmp.begin(), tmp.end(), 0);
    for (int pass = 0; pass < 2; ++pass) {
      const int shift = pass * kBits;
      std::fill(count.begin(), count.end(), 0);
      for (int v = 0; v < nv; ++v) ++count[(code[v] >> shift & (kBuckets - 1)) + 1];
      std::partial_sum(count.begin(), count.end(), count.begin());
      std::vector<int32_t>& out = pass == 0 ? r.vertex_source : tmp;
      const std::vector<int32_t>& in = pass == 0 ? tmp : r.vertex_source;
      for (int i = 0; i < nv; ++i) out[count[code[in[i]] >> shift & (kBuckets - 1)]++] = in[i];
    }
    r.vertex_source.swap(tmp);
  }
  std::vector<int32_t> relabel(nv);
  for (int v = 0; v < nv; ++v) relabel[r.vertex_source[v]] = v;
  r.mesh.positions.resize(nv, 3);
  for (int v = 0; v < nv; ++v) r.mesh.positions.row(v) = mesh.positions.row(r.vertex_source[v]);

  // Faces by their lowest relabelled vertex (a counting sort, stable), corners relabelled
  // in place (rotation kept), then for kRotational rotated to their corner furthest
  // along kRowDirection (the first of equals).
  Faces rows(nf, 4);
  std::vector<int32_t> start(nv + 1, 0);
  for (int f = 0; f < nf; ++f) {
    const int32_t* idx = mesh.faces.data() + 4 * static_cast<int64_t>(f);
    int32_t* out = rows.data() + 4 * static_cast<int64_t>(f);
    const int n = idx[3] < 0 ? 3 : 4;
    for (int c = 0; c < n; ++c)
      if (idx[c] < 0 || idx[c] >= nv) return absl::InvalidArgumentError("vertex index out of range");
    out[0] = relabel[idx[0]], out[1] = relabel[idx[1]], out[2] = relabel[idx[2]];
    out[3] = n == 3 ? -1 : relabel[idx[3]];
    ++start[std::min({out[0], out[1], out[2], n == 3 ? out[0] : out[3]}) + 1];
  }
  std::partial_sum(start.begin(), start.end(), start.begin());
  r.face_source.resize(nf);
  r.order = order;
  const bool rotational = order == RowOrder::kRotational;
  // kRotational: each vertex's distance along kRowDirection, computed once (not once
  // per incident face); each face rotated as it is filed, the first corner chosen with
  // no branch (which corner is furthest is anyone's guess on an irregular mesh).
  std::vector<double> along;
  if (rotational) {
    along.resize(nv);
    const double* Q = r.mesh.positions.data();
    for (int v = 0; v < nv; ++v) {
      const double* x = Q + 3 * static_cast<int64_t>(v);
      along[v] = x[0] * kRowDirection[0] + x[1] * kRowDirection[1] + x[2] * kRowDirection[2];
    }
  }
  Faces faces(nf, 4);
  for (int f = 0; f < nf; ++f) {
    const int32_t* in = rows.data() + 4 * static_cast<int64_t>(f);
    const int32_t g = start[std::min({in[0], in[1], in[2], in[3] < 0 ? in[0] : in[3]})]++;
    r.face_source[g] = f;
    int32_t* out = faces.data() + 4 * static_cast<int64_t>(g);
    if (!rotational) {
      std::copy_n(in, 4, out);
      continue;
    }
    // The corner furthest along kRowDirection, the first of equals.
    const int n = in[3] < 0 ? 3 : 4;
    int first = 0;
    double best = along[in[0]];
    for (int c = 1; c < n; ++c) {
      const double a = along[in[c]];
      first = a > best ? c : first;
      best = a > best ? a : best;
    }
    for (int c = 0; c < 4; ++c) {
      const int q = first + c;
      out[c] = c < n ? in[q < n ? q : q - n] : -1;
    }
  }
  r.mesh.faces = std::move(faces);
  return r;
}

namespace {

// BuildTopology(LocalityRelabelling): the relabelled mesh's topology from each vertex's
// fan alone, with no half-edge sort. BuildTopology's checks, vertex by vertex: an edge
// in more than two faces, or in two traversing it the same way, is a directed edge
// (v, b) in two faces, found at v as two faces with the same next spoke; otherwise each
// face has at most one successor around v (the face whose next spoke is its prev
// spoke) and one predecessor, so the faces form paths and cycles, joined exactly where
// BuildTopology's fan check joins them: one fan is one walk over all of them. A vertex
// is on the boundary exactly when its fan is open (its first face's next spoke is a
// boundary edge, counted there once). Errors name relabelled vertices only by kind.
// Per vertex: successors through `by_next` (spoke -> the local face whose next spoke it
// is; one array for all vertices, each entry stamped with the vertex that wrote it, so
// none is reset), predecessors as a bit mask (up to 32 faces), then one walk from the
// fan's start (RowOrder::kRotational) writing the final rows: its faces into a new face
// array, its spokes straight into vv (no copy back, no second pass over the spokes);
// rows then sorted by source index for kSource. Linear; the per-vertex scratch only
// grows. The spokes' positions (the start's scores) are prefetched 4 vertices ahead:
// ~0.6 ms of ~5 on the gmsh torus (bench/README.md, "Issue 15, eleventh round").
absl::StatusOr<Topology> FanTopology(const LocalityRelabelling& r) {
  const Mesh& m = r.mesh;
  Topology t;
  std::vector<std::array<int32_t, 2>> spokes;
  if (absl::Status s = FileFaces(m, &t, nullptr, nullptr, &spokes); !s.ok()) return s;
  const int nv = t.num_vertices;
  const double* P = m.positions.data();
  const double dx = kRowDirection[0], dy = kRowDirection[1], dz = kRowDirection[2];
  const bool rotational = r.order == RowOrder::kRotational;
  t.is_boundary.assign(nv, 0);
  t.is_isolated.assign(nv, 0);
  t.vv_offsets.resize(nv + 1);
  t.vv_offsets[0] = 0;
  // Each vertex's rows written once, in fan order: its faces into a new face array,
  // its spokes straight into vv (room for one more spoke per vertex; cut to size after).
  std::vector<int32_t> fan_faces(t.vf_faces.size());
  t.vv.resize(t.vf_faces.size() + nv);
  // by_next[spoke]: (v << 32 | i) while vertex v is read: stamped, so never reset.
  std::vector<int64_t> by_next(nv, -1);
  std::vector<int32_t> succ;
  std::vector<uint8_t> has_pred;
  constexpr int kAhead = 4;
  for (int v = 0; v < nv; ++v) {
    const int k = t.NumVertexFaces(v);
    const int32_t off = t.vf_offsets[v], vv_off = t.vv_offsets[v];
    if (k == 0) {
      t.is_isolated[v] = 1;
      ++t.num_isolated;
      t.vv_offsets[v + 1] = vv_off;
      continue;
    }
    const int32_t* faces = t.vf_faces.data() + off;
    const std::array<int32_t, 2>* sp = spokes.data() + off;
    if (rotational && v + kAhead < nv)  // the start's scores read the spokes' positions
      for (int32_t i = t.vf_offsets[v + kAhead]; i < t.vf_offsets[v + kAhead + 1]; ++i)
        __builtin_prefetch(P + 3 * static_cast<int64_t>(spokes[i][0]));
    if (static_cast<int>(succ.size()) < k) succ.resize(k), has_pred.resize(k);
    const int64_t stamp = static_cast<int64_t>(v) << 32;
    bool clash = false;
    for (int i = 0; i < k; ++i) {
      int64_t& slot = by_next[sp[i][0]];
      clash |= (slot & ~int64_t{0xffffffff}) == stamp;
      slot = stamp | i;
    }
    if (clash)
      return absl::InvalidArgumentError(
          absl::StrFormat("vertex %d: two faces traverse one of its edges the same way", v));
    // succ[i]: the face across the edge (v, prev spoke), or -1; which faces have a
    // predecessor: a bit mask (the usual few faces) or has_pred.
    const bool small = k <= 32;
    uint32_t pred = 0;
    if (!small) std::fill_n(has_pred.begin(), k, 0);
    for (int i = 0; i < k; ++i) {
      const int64_t slot = by_next[sp[i][1]];
      const int32_t j = (slot & ~int64_t{0xffffffff}) == stamp ? static_cast<int32_t>(slot) : -1;
      succ[i] = j;
      if (small)
        pred |= j >= 0 ? uint32_t{1} << j : 0u;
      else if (j >= 0)
        has_pred[j] = 1;
    }
    // The start: an open fan's first face (no predecessor); a closed fan's face whose
    // next spoke is nearest kRowDirection (cos^2 with its sign; kSource: any).
    int start = -1;
    if (small) {
      const uint32_t none = ~pred & (k == 32 ? ~0u : (uint32_t{1} << k) - 1);
      start = none != 0 ? __builtin_ctz(none) : -1;
    } else {
      for (int i = 0; i < k && start < 0; ++i)
        if (!has_pred[i]) start = i;
    }
    const bool open = start >= 0;
    if (!open && !rotational) start = 0;
    if (!open && rotational) {
      const double* x = P + 3 * static_cast<int64_t>(v);
      double best = -std::numeric_limits<double>::infinity();
      start = 0;
      for (int i = 0; i < k; ++i) {
        const double* y = P + 3 * static_cast<int64_t>(sp[i][0]);
        const double s0 = y[0] - x[0], s1 = y[1] - x[1], s2 = y[2] - x[2];
        const double dot = s0 * dx + s1 * dy + s2 * dz, len2 = s0 * s0 + s1 * s1 + s2 * s2;
        const double score = dot * std::abs(dot) / len2;
        if (score > best) best = score, start = i;
      }
    }
    // The walk: k faces from the start, none of them -1 or the start again.
    int32_t* out_faces = fan_faces.data() + off;
    int32_t* out_vv = t.vv.data() + vv_off;
    int i = start, last = start;
    for (int c = 0; c < k; ++c) {
      if (i < 0 || (c > 0 && i == start))
        return absl::InvalidArgumentError(absl::StrFormat("non-manifold vertex %d: its faces form several fans", v));
      out_faces[c] = faces[i];
      out_vv[c] = sp[i][0];
      last = i;
      i = succ[i];
    }
    if (open) out_vv[k] = sp[last][1];  // an open fan's last spoke
    t.is_boundary[v] = open;
    t.num_boundary_edges += open;
    t.vv_offsets[v + 1] = vv_off + k + open;
  }
  t.vf_faces.swap(fan_faces);
  t.vv.resize(t.vv_offsets[nv]);
  if (!rotational)
    for (int v = 0; v < nv; ++v) {
      SortRowByKey(t.vv.data() + t.vv_offsets[v], t.vv.data() + t.vv_offsets[v + 1], r.vertex_source);
      SortRowByKey(t.vf_faces.data() + t.vf_offsets[v], t.vf_faces.data() + t.vf_offsets[v + 1], r.face_source);
    }
  t.vertex_faces_ascending = false;  // and no locality order: the numbering is one
  t.fan_rows = rotational;
  return t;
}

}  // namespace

absl::StatusOr<Topology> BuildTopology(const LocalityRelabelling& relabelled) { return FanTopology(relabelled); }

}  // namespace geomfit
