// Wavefront OBJ: `v` and `f` lines; everything else is ignored.
#include <cstring>
#include <cstdint>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/mesh/formats/common.h"
#include "core/mesh/formats/formats.h"
#include "core/util/status_macros.h"

namespace geomfit::mesh_io {
namespace {

// The fast path (common.h): "v X Y Z" and "f I J K [L]" lines with positive indices,
// blanks between fields, LF or CRLF, read straight from the bytes; every other line goes
// to the general path.

/// Ends a token for LineReader(..., '#'): its separators, the line's end, a comment.
bool EndsToken(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v' || c == '\n' || c == '#';
}

/// A face line after its "f" (at p): 3 or 4 decimal indices in [1, num_vertices] (no
/// sign, at most 10 digits), each alone or followed by "/..." (texture and normal
/// indices: ignored, as the general path ignores them), then the line's end.
const char* FastFace(const char* p, const char* end, int64_t num_vertices, int32_t v[4], int* n) {
  int count = 0;
  while (p < end && IsBlank(*p)) {
    do ++p;
    while (p < end && IsBlank(*p));
    if (p == end || !IsDigit(*p)) break;  // LineEnd decides
    if (count == 4) return nullptr;
    uint64_t k;
    if ((p = FastDigits(p, end, &k)) == nullptr) return nullptr;
    if (k == 0 || k > static_cast<uint64_t>(num_vertices)) return nullptr;  // also forward references
    if (p < end && *p == '/')
      while (p < end && !EndsToken(*p)) ++p;
    v[count++] = static_cast<int32_t>(k - 1);
  }
  if (count < 3) return nullptr;
  *n = count;
  return LineEnd(p, end);
}

#if defined(__SSE2__)
/// The commonest face line after its "f" (at p): spaces and 3 or 4 indices of 1-8 digits
/// each, then "\n", all within the 32 bytes at p (40 readable): the bytes classified at
/// once (two 16-byte compares), each index then read from its own offset (no chain of
/// one index's end to the next one's start). The same indices as FastFace; nullptr for
/// anything else (FastFace then reads the line).
const char* PlainFace(const char* p, const char* end, int64_t num_vertices, int32_t v[4], int* n) {
  if (end - p < 40) return nullptr;
  const __m128i lo = _mm_loadu_si128(reinterpret_cast<const __m128i*>(p));
  const __m128i hi = _mm_loadu_si128(reinterpret_cast<const __m128i*>(p + 16));
  const auto bits = [](__m128i a, __m128i b) {
    return static_cast<uint32_t>(_mm_movemask_epi8(a)) | static_cast<uint32_t>(_mm_movemask_epi8(b)) << 16;
  };
  const __m128i nl = _mm_set1_epi8('\n'), sp = _mm_set1_epi8(' '), zero = _mm_set1_epi8('0'),
                nine = _mm_set1_epi8(9);
  const uint32_t newline = bits(_mm_cmpeq_epi8(lo, nl), _mm_cmpeq_epi8(hi, nl));
  if (newline == 0) return nullptr;
  const int len = __builtin_ctz(newline);          // the line's bytes before its "\n"
  const uint32_t line = (uint32_t{1} << len) - 1;  // len <= 31
  const uint32_t space = bits(_mm_cmpeq_epi8(lo, sp), _mm_cmpeq_epi8(hi, sp)) & line;
  // '0'..'9': x - '0' <= 9 as unsigned bytes
  const __m128i dlo = _mm_sub_epi8(lo, zero), dhi = _mm_sub_epi8(hi, zero);
  const uint32_t digit =
      bits(_mm_cmpeq_epi8(_mm_min_epu8(dlo, nine), dlo), _mm_cmpeq_epi8(_mm_min_epu8(dhi, nine), dhi)) & line;
  if ((space | digit) != line || (space & 1) == 0) return nullptr;
  // Each index's first and last digit, in order.
  uint32_t first = digit & ~(digit << 1), last = digit & ~(digit >> 1);
  int count = 0;
  for (; first != 0; ++count) {
    if (count == 4) return nullptr;
    const int a = __builtin_ctz(first), b = __builtin_ctz(last);
    first &= first - 1, last &= last - 1;
    if (b - a >= 8) return nullptr;  // 9 or more digits
    const uint64_t k = EightDigitsValue(p + a, b - a + 1);
    if (k == 0 || k > static_cast<uint64_t>(num_vertices)) return nullptr;
    v[count] = static_cast<int32_t>(k - 1);
  }
  if (count < 3) return nullptr;
  *n = count;
  return p + len + 1;
}
#endif

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
  b.ReserveFaces(static_cast<int64_t>(bytes.size() / 32));
  b.ReserveVertices(static_cast<int64_t>(bytes.size() / 32));
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
        if ((next = FastCoordinates(p + 1, end, xyz, true)) != nullptr) b.AddVertex(xyz);
      } else if (*p == 'f') {
        int32_t v[4];
        int n;
#if defined(__SSE2__)
        next = PlainFace(p + 1, end, b.NumVertices(), v, &n);
        if (next == nullptr) next = FastFace(p + 1, end, b.NumVertices(), v, &n);
#else
        next = FastFace(p + 1, end, b.NumVertices(), v, &n);
#endif
        if (next != nullptr) b.AddFace(v, n);
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
