#pragma once
#include <array>
#include <vector>

#include "core/mesh/mesh.h"

namespace geomfit::testing_util {

/// A mesh from a vertex list and faces of 3 or 4 indices (tests).
inline Mesh MakeMesh(const std::vector<std::array<double, 3>>& verts, const std::vector<std::vector<int>>& faces) {
  Mesh m;
  m.positions.resize(verts.size(), 3);
  for (size_t v = 0; v < verts.size(); ++v)
    for (int c = 0; c < 3; ++c) m.positions(v, c) = verts[v][c];
  m.faces.setConstant(faces.size(), 4, -1);
  for (size_t f = 0; f < faces.size(); ++f)
    for (size_t i = 0; i < faces[f].size(); ++i) m.faces(f, i) = faces[f][i];
  return m;
}

}  // namespace geomfit::testing_util
