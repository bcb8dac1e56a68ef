// Wavefront OBJ: `v` and `f` lines; everything else is ignored.
#include <charconv>
#include <cmath>
#include <cstring>
#include <system_error>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/mesh/formats/common.h"
#include "core/mesh/formats/formats.h"
#include "core/util/status_macros.h"

namespace geomfit::mesh_io {
namespace {

// The fast path: lines in the plain form writers produce ("v X Y Z", "f I J K [L]" with
// positive indices, blanks between fields, LF or CRLF) are read straight from the bytes.
// Each function returns where the next line starts, or nullptr for anything else, which
// the general path (LineReader tokens) then reads with its checks and error messages:
// the fast path accepts only lines the general path reads to the same values.

bool IsBlank(char c) { return c == ' ' || c == '\t'; }

/// Where the next line starts if only blanks and the line's end ("\n", "\r\n" or the
/// end of the text) follow p; else nullptr.
const char* LineEnd(const char* p, const char* end) {
  while (p < end && IsBlank(*p)) ++p;
  if (p == end) return end;
  if (*p == '\n') return p + 1;
  if (*p == '\r' && p + 1 < end && p[1] == '\n') return p + 2;
  return nullptr;
}

/// A vertex line after its "v" (at p): three blank-separated finite numbers that
/// std::from_chars reads whole (ParseDouble's answer for them: the token ends where
/// from_chars stops), then the line's end.
const char* FastVertex(const char* p, const char* end, double xyz[3]) {
  for (int c = 0; c < 3; ++c) {
    if (p == end || !IsBlank(*p)) return nullptr;
    do ++p;
    while (p < end && IsBlank(*p));
    const std::from_chars_result r = std::from_chars(p, end, xyz[c]);
    if (r.ec != std::errc() || !std::isfinite(xyz[c])) return nullptr;
    p = r.ptr;
  }
  return LineEnd(p, end);
}

/// Ends a token for LineReader(..., '#'): its separators, the line's end, a comment.
bool EndsToken(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v' || c == '\n' || c == '#';
}

/// The value of the decimal digits at p (at least one) and, in *len, their count, if
/// fewer than 8: one 8-byte load, no branch per digit (SWAR: the digits moved to the
/// word's top bytes, bytes below them read as leading zeros, then the usual
/// eight-digit multiply-shift). *len = 8: more digits may follow, the value is unset.
uint64_t ShortDecimal(const char* p, int* len) {
  uint64_t w;
  std::memcpy(&w, p, 8);  // little-endian: p[0] in the low byte
  const uint64_t t = w ^ 0x3030303030303030ull;  // digits: bytes 0-9
  const uint64_t non_digit = (((t & 0x7f7f7f7f7f7f7f7full) + 0x7676767676767676ull) | t) & 0x8080808080808080ull;
  const int n = non_digit == 0 ? 8 : __builtin_ctzll(non_digit) / 8;
  *len = n;
  if (n == 0 || n == 8) return 0;
  uint64_t d = t << (8 * (8 - n));
  d = d * 10 + (d >> 8);
  return (((d & 0x000000ff000000ffull) * (100 + (1000000ull << 32))) +
          (((d >> 16) & 0x000000ff000000ffull) * (1 + (10000ull << 32)))) >>
         32;
}

/// A face line after its "f" (at p): 3 or 4 decimal indices in [1, num_vertices] (no
/// sign, at most 10 digits), each alone or followed by "/..." (texture and normal
/// indices: ignored, as the general path ignores them), then the line's end.
const char* FastFace(const char* p, const char* end, int64_t num_vertices, int32_t v[4], int* n) {
  int count = 0;
  while (p < end && IsBlank(*p)) {
    do ++p;
    while (p < end && IsBlank(*p));
    if (p == end || static_cast<unsigned>(*p - '0') > 9) break;  // LineEnd decides
    if (count == 4) return nullptr;
    uint64_t k = 0;
    int len = 8;
    if (end - p >= 8) k = ShortDecimal(p, &len);
    if (len < 8) {
      p += len;
    } else {
      const char* const first = p;
      while (p < end && static_cast<unsigned>(*p - '0') <= 9 && p - first < 10) k = 10 * k + (*p++ - '0');
    }
    if (k == 0 || k > static_cast<uint64_t>(num_vertices)) return nullptr;  // also forward references
    if (p < end && *p == '/')
      while (p < end && !EndsToken(*p)) ++p;
    v[count++] = static_cast<int32_t>(k - 1);
  }
  if (count < 3) return nullptr;
  *n = count;
  return LineEnd(p, end);
}

/// A line the general path ignores without looking into it: a comment, an empty line,
/// or one whose first token (at the line's start) is neither "v" nor "f". Returns
/// where the next line starts, else nullptr.
const char* SkippedLine(const char* p, const char* end) {
  if (*p != '\n' && *p != '#') {
    if (EndsToken(*p)) return nullptr;  // leading blanks: the general path
    const char* q = p + 1;
    while (q < end && !EndsToken(*q)) ++q;
    if (q == p + 1 && (*p == 'v' || *p == 'f')) return nullptr;
  }
  const void* nl = std::memchr(p, '\n', static_cast<size_t>(end - p));
  return nl != nullptr ? static_cast<const char*>(nl) + 1 : end;
}

}  // namespace

absl::StatusOr<Mesh> ParseObj(absl::string_view bytes, absl::string_view source, bool fast_path) {
  LineReader lines(bytes, source, '#');
  MeshBuilder b;
  // Room for a typical file's vertices and faces (~60 and ~20 bytes a line): reserved
  // address space, touched only as far as it is used.
  b.ReserveVertices(static_cast<int64_t>(bytes.size() / 32));
  b.ReserveFaces(static_cast<int64_t>(bytes.size() / 32));
  std::vector<absl::string_view> tok;
  // Faces naming a vertex not defined yet: checked once all vertices are read.
  struct ForwardReference {
    int64_t line, face, index;
  };
  std::vector<ForwardReference> forward;
  const char* const end = lines.end();
  for (;;) {
    if (fast_path) {
      const char* const p = lines.cursor();
      if (p == end) break;
      const char* next = nullptr;
      if (*p == 'v') {
        double xyz[3];
        if ((next = FastVertex(p + 1, end, xyz)) != nullptr) b.AddVertex(xyz);
      } else if (*p == 'f') {
        int32_t v[4];
        int n;
        if ((next = FastFace(p + 1, end, b.NumVertices(), v, &n)) != nullptr) b.AddFace(v, n);
      }
      if (next == nullptr) next = SkippedLine(p, end);
      if (next != nullptr) {
        lines.SkipLine(next);
        continue;
      }
    }
    if (!lines.NextTokens(&tok)) break;
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
