#pragma once
#include <algorithm>
#include <array>
#include <cstdint>
#include <random>
#include <utility>
#include <vector>

#include "core/mesh/mesh.h"

namespace geomfit::testing_util {

/// A mesh from a vertex list and faces of 3 or 4 indices (tests).
inline Mesh MakeMesh(const std::vector<std::array<double, 3>>& verts, const std::vector<std::vector<int>>& faces) {
  Mesh m;
  m.positions.resize(verts.size(), 3);
  for (size_t v = 0; v < verts.size(); ++v)
    for (int c = 0; c < 3; ++c) m.positions(v, c) = verts[v][c];
  m.faces.Mutable().setConstant(faces.size(), 4, -1);
  for (size_t f = 0; f < faces.size(); ++f)
    for (size_t i = 0; i < faces[f].size(); ++i) m.faces.Mutable()(f, i) = faces[f][i];
  return m;
}

/// Relabels the vertices by a random permutation `perm` (old -> new; returned when
/// asked): the same surface in an external mesher's order, faces unchanged otherwise.
inline Mesh ShuffleVertices(const Mesh& m, uint64_t seed, std::vector<int32_t>* perm_out = nullptr) {
  const int nv = m.NumVertices();
  std::vector<int32_t> perm(nv);
  for (int v = 0; v < nv; ++v) perm[v] = v;
  std::mt19937_64 rng(seed);
  std::shuffle(perm.begin(), perm.end(), rng);
  Mesh s;
  s.positions.resize(nv, 3);
  for (int v = 0; v < nv; ++v) s.positions.row(perm[v]) = m.positions.row(v);
  s.faces = m.faces;
  for (int f = 0; f < m.NumFaces(); ++f)
    for (int c = 0; c < m.FaceSize(f); ++c) s.faces.Mutable()(f, c) = perm[m.faces(f, c)];
  if (perm_out) *perm_out = std::move(perm);
  return s;
}

}  // namespace geomfit::testing_util
