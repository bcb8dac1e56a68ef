// OFF (Geomview): optional [ST][C][N]OFF keyword, counts, one vertex or face per line.
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

/// The fast path (common.h) of a face line "N I J K [L]": N = 3 or 4 and that many
/// indices in [0, num_vertices), then the line's end (a line with colours goes to the
/// general path).
const char* FastFace(const char* p, const char* end, int64_t num_vertices, int32_t v[4], int* n) {
  uint64_t k;
  p = SkipBlanks(p, end);
  if (p == end || !IsDigit(*p) || (p = FastDigits(p, end, &k)) == nullptr || k < 3 || k > 4) return nullptr;
  *n = static_cast<int>(k);
  for (int i = 0; i < *n; ++i) {
    if (p == end || !IsBlank(*p)) return nullptr;
    p = SkipBlanks(p, end);
    if (p == end || !IsDigit(*p) || (p = FastDigits(p, end, &k)) == nullptr || k >= static_cast<uint64_t>(num_vertices))
      return nullptr;
    v[i] = static_cast<int32_t>(k);
  }
  return LineEnd(p, end);
}

}  // namespace

absl::StatusOr<Mesh> ParseOff(absl::string_view bytes, absl::string_view source, bool fast_path) {
  LineReader lines(bytes, source, '#');
  std::vector<absl::string_view> tok;
  if (!lines.NextTokens(&tok)) return lines.Error("empty file");
  size_t first = 0;
  if (absl::EndsWith(tok[0], "OFF")) {
    const absl::string_view prefix = tok[0].substr(0, tok[0].size() - 3);
    if (prefix != "" && prefix != "C" && prefix != "N" && prefix != "CN" && prefix != "NC" &&
        prefix != "ST" && prefix != "STC" && prefix != "STN" && prefix != "STCN")
      return lines.Error(absl::StrCat("unsupported OFF variant '", tok[0], "'"));
    if (tok.size() > 1 && absl::AsciiStrToLower(tok[1]) == "binary")
      return lines.Error("binary OFF is not supported");
    first = 1;
    if (tok.size() == 1) {  // the counts are on the next line
      if (!lines.NextTokens(&tok)) return lines.Error("missing counts line");
      first = 0;
    }
  }
  if (tok.size() < first + 2) return lines.Error("counts line needs #vertices and #faces");
  int64_t nv, nf;
  if (!ParseInteger(tok[first], &nv) || !ParseInteger(tok[first + 1], &nf) || nv < 0 || nf < 0)
    return lines.Error(absl::StrCat("bad counts '", tok[first], " ", tok[first + 1],
                                    "' (expected non-negative integers)"));
  // Every vertex line holds at least "x y z\n" (6 bytes), every face "3 a b c\n" (8).
  if (nv > static_cast<int64_t>(lines.remaining() / 6) || nv > kMaxInt32)
    return CountError(source, "vertices", nv, lines.remaining());
  if (nf > static_cast<int64_t>(lines.remaining() / 8) || nf > kMaxInt32)
    return CountError(source, "faces", nf, lines.remaining());

  MeshBuilder b;
  b.ReserveVertices(nv);
  b.ReserveFaces(nf);
  const char* const end = lines.end();
  for (int64_t i = 0; i < nv; ++i) {
    double xyz[3];
    const char* next = fast_path ? FastCoordinates(SkipBlanks(lines.cursor(), end), end, xyz) : nullptr;
    if (next != nullptr) {  // common.h
      lines.SkipLine(next);
      b.AddVertex(xyz);
      continue;
    }
    if (!lines.NextTokens(&tok))
      return lines.Error(absl::StrFormat("unexpected end of file after %d of %d vertices", i, nv));
    double p[3];
    GF_RETURN_IF_ERROR(ParseCoordinates(lines, tok, 0, p));
    b.AddVertex(p);
  }
  for (int64_t f = 0; f < nf; ++f) {
    int32_t corners[4];
    int n_fast;
    const char* next = fast_path ? FastFace(lines.cursor(), end, nv, corners, &n_fast) : nullptr;
    if (next != nullptr) {
      lines.SkipLine(next);
      b.AddFace(corners, n_fast);
      continue;
    }
    if (!lines.NextTokens(&tok))
      return lines.Error(absl::StrFormat("unexpected end of file after %d of %d faces", f, nf));
    int64_t n;
    if (!ParseInteger(tok[0], &n))
      return lines.Error(absl::StrCat("'", tok[0], "' is not a face size"));
    GF_RETURN_IF_ERROR(CheckFaceSize(lines, f, n));
    if (static_cast<int64_t>(tok.size()) < n + 1)
      return lines.Error(
          absl::StrFormat("face %d needs %d indices, found %d", f, n, tok.size() - 1));
    int32_t v[4];
    for (int i = 0; i < n; ++i) {
      int64_t k;
      if (!ParseInteger(tok[i + 1], &k))
        return lines.Error(absl::StrCat("'", tok[i + 1], "' is not a vertex index"));
      if (k < 0 || k >= nv) return lines.Error(IndexRangeMessage(f, k, nv));
      v[i] = static_cast<int32_t>(k);
    }
    b.AddFace(v, static_cast<int>(n));
  }
  return b.Build();
}

std::string FormatOff(const Mesh& mesh) {
  std::string out = absl::StrFormat("OFF\n%d %d 0\n", mesh.NumVertices(), mesh.NumFaces());
  AppendTextBody(&out, mesh, TextDialect::kOff);
  return out;
}

}  // namespace geomfit::mesh_io
