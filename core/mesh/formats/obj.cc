// Wavefront OBJ: `v` and `f` lines; everything else is ignored.
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/mesh/formats/common.h"
#include "core/mesh/formats/formats.h"
#include "core/util/status_macros.h"

namespace geomfit::mesh_io {

absl::StatusOr<Mesh> ParseObj(absl::string_view bytes, absl::string_view source) {
  LineReader lines(bytes, source, '#');
  MeshBuilder b;
  std::vector<absl::string_view> tok;
  // Faces naming a vertex not defined yet: checked once all vertices are read.
  struct ForwardReference {
    int64_t line, face, index;
  };
  std::vector<ForwardReference> forward;
  while (lines.NextTokens(&tok)) {
    if (tok[0] == "v") {
      double p[3];
      GF_RETURN_IF_ERROR(ParseCoordinates(lines, tok, 1, p));
      b.AddVertex(p);
    } else if (tok[0] == "f") {
      const int64_t n = static_cast<int64_t>(tok.size()) - 1;
      GF_RETURN_IF_ERROR(CheckFaceSize(lines, b.NumFaces(), n));
      int32_t v[4];
      for (int i = 0; i < n; ++i) {
        const absl::string_view t = tok[i + 1].substr(0, tok[i + 1].find('/'));
        int64_t k;
        if (!ParseInteger(t, &k))
          return lines.Error(absl::StrCat("'", tok[i + 1], "' is not a vertex index"));
        if (k == 0) return lines.Error("vertex index 0 (OBJ indices start at 1)");
        k = k < 0 ? b.NumVertices() + k : k - 1;  // negative: relative to the last vertex
        if (k < 0)
          return lines.Error(absl::StrCat("relative vertex index ", tok[i + 1],
                                          " points before the first vertex"));
        if (k > kMaxInt32) return lines.Error(absl::StrCat("vertex index ", t, " is too large"));
        if (k >= b.NumVertices()) forward.push_back({lines.line_number(), b.NumFaces(), k + 1});
        v[i] = static_cast<int32_t>(k);
      }
      b.AddFace(v, static_cast<int>(n));
    }
  }
  for (const ForwardReference& r : forward)
    if (r.index > b.NumVertices())
      return lines.ErrorAt(r.line, absl::StrFormat("face %d: vertex index %d is out of range "
                                                   "(the file has %d vertices)",
                                                   r.face, r.index, b.NumVertices()));
  return b.Build();
}

std::string FormatObj(const Mesh& mesh) {
  std::string out = "# geomfit\n";
  AppendTextBody(&out, mesh, TextDialect::kObj);
  return out;
}

}  // namespace geomfit::mesh_io
