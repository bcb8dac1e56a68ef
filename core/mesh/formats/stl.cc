// STL: binary when the size is 84 + 50 n, else ascii; bitwise-equal corners welded.
#include <array>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/mesh/formats/common.h"
#include "core/mesh/formats/formats.h"
#include "core/util/status_macros.h"

namespace geomfit::mesh_io {
namespace {

bool LooksLikeAsciiStl(absl::string_view bytes) {
  return absl::StartsWith(absl::StripLeadingAsciiWhitespace(bytes), "solid");
}

absl::StatusOr<Mesh> ParseBinaryStl(absl::string_view bytes, int64_t n) {
  MeshBuilder b;
  VertexWelder welder(&b);
  b.ReserveFaces(n);
  for (int64_t t = 0; t < n; ++t) {
    const char* rec = bytes.data() + 84 + 50 * t + 12;  // skip the facet normal
    int32_t v[3];
    for (int i = 0; i < 3; ++i) {
      double p[3];
      for (int c = 0; c < 3; ++c) p[c] = GetFloat(rec + 12 * i + 4 * c);
      v[i] = welder.Add(p);
    }
    b.AddFace(v, 3);
  }
  return b.Build();
}

absl::StatusOr<Mesh> ParseAsciiStl(absl::string_view bytes, absl::string_view source) {
  LineReader lines(bytes, source, 0);
  MeshBuilder b;
  VertexWelder welder(&b);
  std::vector<absl::string_view> tok;
  enum { kOutside, kSolid, kFacet, kLoop } state = kOutside;
  int32_t v[3];
  int corners = 0;
  auto expect = [&](bool ok, absl::string_view keyword) {
    return ok ? absl::OkStatus() : lines.Error(absl::StrCat("unexpected '", keyword, "'"));
  };
  while (lines.NextTokens(&tok)) {
    const absl::string_view k = tok[0];
    if (k == "solid") {
      GF_RETURN_IF_ERROR(expect(state == kOutside, k));
      state = kSolid;
    } else if (k == "facet") {
      GF_RETURN_IF_ERROR(expect(state == kSolid, k));
      state = kFacet;
      corners = 0;
    } else if (k == "outer") {
      GF_RETURN_IF_ERROR(expect(state == kFacet && corners == 0, k));
      state = kLoop;
    } else if (k == "vertex") {
      GF_RETURN_IF_ERROR(expect(state == kLoop, k));
      if (corners == 3) return lines.Error("facet has more than 3 vertices");
      double p[3];
      GF_RETURN_IF_ERROR(ParseCoordinates(lines, tok, 1, p));
      v[corners++] = welder.Add(p);
    } else if (k == "endloop") {
      GF_RETURN_IF_ERROR(expect(state == kLoop, k));
      if (corners != 3) return lines.Error(absl::StrCat("facet has ", corners, " vertices, not 3"));
      state = kFacet;
    } else if (k == "endfacet") {
      GF_RETURN_IF_ERROR(expect(state == kFacet && corners == 3, k));
      b.AddFace(v, 3);
      state = kSolid;
    } else if (k == "endsolid") {
      GF_RETURN_IF_ERROR(expect(state == kSolid, k));
      state = kOutside;
    } else {
      return lines.Error(absl::StrCat("unexpected token '", k, "'"));
    }
  }
  if (state != kOutside) return lines.Error("unexpected end of file (missing 'endsolid')");
  return b.Build();
}

}  // namespace

absl::StatusOr<Mesh> ParseStl(absl::string_view bytes, absl::string_view source) {
  if (bytes.size() < 84 && !LooksLikeAsciiStl(bytes))
    return absl::InvalidArgumentError(absl::StrCat(
        source, ": not an STL file (shorter than the 84-byte binary header and no 'solid')"));
  const uint64_t n = bytes.size() >= 84 ? GetLE(bytes.data() + 80, 4) : 0;
  if (bytes.size() >= 84 && 84 + 50 * n == bytes.size()) {
    if (n > kMaxInt32 / 3)
      return absl::InvalidArgumentError(absl::StrCat(source, ": too many triangles (", n, ")"));
    return ParseBinaryStl(bytes, static_cast<int64_t>(n));
  }
  const std::string binary_error = absl::StrFormat(
      "byte 80: binary STL header claims %d triangles (%d bytes) but the file has %d bytes", n,
      84 + 50 * n, bytes.size());
  if (!LooksLikeAsciiStl(bytes))
    return absl::InvalidArgumentError(absl::StrCat(source, ": ", binary_error));
  absl::StatusOr<Mesh> ascii = ParseAsciiStl(bytes, source);
  // A binary STL may start with "solid" too: say what is wrong either way.
  if (!ascii.ok() && bytes.size() >= 84)
    return absl::InvalidArgumentError(
        absl::StrCat(ascii.status().message(), " (and as a binary STL: ", binary_error, ")"));
  return ascii;
}

std::string FormatStl(const Mesh& m) {
  std::vector<std::array<int32_t, 3>> tris;
  for (int f = 0; f < m.NumFaces(); ++f) {
    tris.push_back({m.faces(f, 0), m.faces(f, 1), m.faces(f, 2)});
    if (m.FaceSize(f) == 4) tris.push_back({m.faces(f, 0), m.faces(f, 2), m.faces(f, 3)});
  }
  std::string out = "geomfit binary STL";
  out.resize(80, ' ');
  PutLE(&out, tris.size(), 4);
  for (const auto& t : tris) {
    const Eigen::Vector3d a = m.positions.row(t[0]), b = m.positions.row(t[1]),
                          c = m.positions.row(t[2]);
    const Eigen::Vector3d n = (b - a).cross(c - a).normalized();
    for (int k = 0; k < 3; ++k) PutFloat(&out, static_cast<float>(n[k]));
    for (int i = 0; i < 3; ++i)
      for (int k = 0; k < 3; ++k) PutFloat(&out, static_cast<float>(m.positions(t[i], k)));
    PutLE(&out, 0, 2);
  }
  return out;
}

}  // namespace geomfit::mesh_io
