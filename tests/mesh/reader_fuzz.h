#pragma once
// A seeded mutation corpus for the mesh readers, shared by tests/mesh/reader_fuzz_test.cc
// (small and fast) and bench/reader_fuzz.cc (long runs). No gtest here.
//
// Property checked for every mutation and every reader: ParseMesh returns, and either
//  - fails with INVALID_ARGUMENT (or RESOURCE_EXHAUSTED) and a message that starts with
//    the source name, or
//  - returns a mesh whose connectivity is valid (each face 3 or 4 indices of existing
//    vertices, -1 only in a triangle's fourth slot) and which ValidateMesh either accepts
//    or rejects only for what readers deliberately pass on: non-finite coordinates,
//    zero-area faces, repeated corners, non-manifold or inconsistently oriented faces,
//    an empty mesh. ValidateMesh never finds an index out of range, and a mesh it
//    accepts is written back by the same format's writer and read back identically.
#include <array>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/mesh/io.h"
#include "core/mesh/topology.h"

namespace geomfit::reader_fuzz {

struct SeedFile {
  std::string name;
  MeshFormat format;
  std::string bytes;
};

inline void AppendLe(std::string* out, uint64_t bits, int n) {
  for (int i = 0; i < n; ++i) out->push_back(static_cast<char>((bits >> (8 * i)) & 0xff));
}
inline void AppendF32(std::string* out, float f) {
  uint32_t u;
  std::memcpy(&u, &f, 4);
  AppendLe(out, u, 4);
}

/// A closed square pyramid: one quad and four triangles, outward orientation.
inline Mesh Pyramid() {
  Mesh m;
  m.positions.resize(5, 3);
  m.positions << 0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, 0.5, 0.5, 0.75;
  m.faces.Mutable().resize(5, 4);
  m.faces.Mutable() << 0, 3, 2, 1,  //
      0, 1, 4, -1,        //
      1, 2, 4, -1,        //
      2, 3, 4, -1,        //
      3, 0, 4, -1;
  return m;
}

/// Small valid files: OBJ, OFF, PLY ascii, PLY binary (doubles; floats with extra
/// properties), STL ascii, STL binary. Each passes ValidateMesh.
inline std::vector<SeedFile> SeedFiles() {
  const Mesh m = Pyramid();
  std::vector<SeedFile> seeds;
  seeds.push_back({"pyramid.obj", MeshFormat::kObj,
                   "# pyramid\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0.5 0.5 0.75\nvn 0 0 1\n"
                   "f 1//1 4//1 3//1 2//1\nf 1 2 5\nf -4/1 -3/2 -1/3\nf 3 4 5\nf 4 1 5\n"});
  seeds.push_back({"pyramid.off", MeshFormat::kOff,
                   "OFF\n# comment\n5 5 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n0.5 0.5 0.75\n"
                   "4 0 3 2 1\n3 0 1 4\n3 1 2 4\n3 2 3 4\n3 3 0 4\n"});
  seeds.push_back({"pyramid_ascii.ply", MeshFormat::kPly,
                   "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\n"
                   "property float z\nproperty uchar red\nelement face 5\n"
                   "property list uchar int vertex_indices\nend_header\n"
                   "0 0 0 1\n1 0 0 2\n1 1 0 3\n0 1 0 4\n0.5 0.5 0.75 5\n"
                   "4 0 3 2 1\n3 0 1 4\n3 1 2 4\n3 2 3 4\n3 3 0 4\n"});
  seeds.push_back({"pyramid_double.ply", MeshFormat::kPly, *FormatMesh(m, MeshFormat::kPly)});
  {
    std::string s =
        "ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty float x\n"
        "property float y\nproperty float z\nproperty short id\nelement face 5\n"
        "property list int uint vertex_indices\nproperty float area\nend_header\n";
    for (int v = 0; v < m.NumVertices(); ++v) {
      for (int c = 0; c < 3; ++c) AppendF32(&s, static_cast<float>(m.positions(v, c)));
      AppendLe(&s, v, 2);
    }
    for (int f = 0; f < m.NumFaces(); ++f) {
      AppendLe(&s, m.FaceSize(f), 4);
      for (int i = 0; i < m.FaceSize(f); ++i) AppendLe(&s, m.faces(f, i), 4);
      AppendF32(&s, 0.5f);
    }
    seeds.push_back({"pyramid_float.ply", MeshFormat::kPly, s});
  }
  {
    const auto tri = [](int a, int b, int c) { return std::array<int, 3>{a, b, c}; };
    std::string s = "solid pyramid\n";
    for (const auto& t :
         {tri(0, 3, 2), tri(0, 2, 1), tri(0, 1, 4), tri(1, 2, 4), tri(2, 3, 4), tri(3, 0, 4)}) {
      s += "  facet normal 0 0 0\n    outer loop\n";
      for (int i : t)
        s += absl::StrFormat("      vertex %g %g %g\n", m.positions(i, 0), m.positions(i, 1),
                             m.positions(i, 2));
      s += "    endloop\n  endfacet\n";
    }
    seeds.push_back({"pyramid_ascii.stl", MeshFormat::kStl, s + "endsolid pyramid\n"});
  }
  seeds.push_back({"pyramid.stl", MeshFormat::kStl, *FormatMesh(m, MeshFormat::kStl)});
  return seeds;
}

/// Text that replaces a whitespace-separated token: counts, indices and coordinates
/// that are huge, negative, off by one or not finite.
inline const std::vector<std::string>& SpecialTokens() {
  static const std::vector<std::string> tokens = {
      "-1", "0", "4", "5", "6", "7", "999", "-2147483648", "2147483647", "2147483648",
      "4294967295", "4294967296", "99999999999999999999", "-99999999999", "nan", "-nan",
      "inf", "-inf", "1e309", "-1e309", "1e-400", "1e300", "0x10", "1.5", "-0", "+3", "",
      "3 3 3 3", "\n", "#", "/", "//", "1/2/3", "end_header", "element vertex 3", "endloop",
      "solid", "facet normal 0 0 0", "OFF", "f", "v", "vertex"};
  return tokens;
}

/// 32- and 64-bit patterns written over binary data: huge and negative indices and
/// counts, NaN and infinities (float and double).
inline const std::vector<uint64_t>& SpecialWords() {
  static const std::vector<uint64_t> words = {
      0xffffffffu, 0x80000000u, 0x7fffffffu, 0x7fc00000u /*NaN f32*/, 0x7f800000u /*inf*/,
      0xff800000u, 5, 6, 4, 0, 1u << 30, 0x7ff8000000000000ull /*NaN f64*/,
      0x7ff0000000000000ull /*inf f64*/, 0xfff0000000000000ull, 0x7fefffffffffffffull};
  return words;
}

/// One to three seeded mutations of `bytes`.
inline std::string Mutate(std::string b, std::mt19937_64& rng) {
  const auto pick = [&](size_t n) { return n == 0 ? size_t{0} : static_cast<size_t>(rng() % n); };
  for (int k = 1 + pick(3); k > 0; --k) {
    const size_t at = pick(b.size());
    switch (pick(9)) {
      case 0:  // bit flip
        if (!b.empty()) b[at] = static_cast<char>(b[at] ^ (1 << pick(8)));
        break;
      case 1:  // truncation
        b.resize(pick(b.size() + 1));
        break;
      case 2: {  // inserted garbage
        std::string g(1 + pick(16), '\0');
        for (char& c : g) c = static_cast<char>(rng());
        b.insert(at, g);
        break;
      }
      case 3:  // deleted or repeated chunk
        if (rng() % 2)
          b.erase(at, 1 + pick(24));
        else
          b.insert(at, b.substr(at, 1 + pick(32)));
        break;
      case 4:
      case 5:
      case 6: {  // a token replaced by a special value (counts, indices, coordinates)
        std::vector<std::pair<size_t, size_t>> tokens;  // [begin, end)
        for (size_t i = 0; i < b.size();) {
          while (i < b.size() && std::isspace(static_cast<unsigned char>(b[i]))) ++i;
          const size_t begin = i;
          while (i < b.size() && !std::isspace(static_cast<unsigned char>(b[i]))) ++i;
          if (i > begin) tokens.emplace_back(begin, i);
        }
        if (tokens.empty()) break;
        const auto [begin, end] = tokens[pick(tokens.size())];
        const std::vector<std::string>& special = SpecialTokens();
        b.replace(begin, end - begin, special[pick(special.size())]);
        break;
      }
      default: {  // a 4- or 8-byte word overwritten (binary counts, indices, coordinates)
        const std::vector<uint64_t>& words = SpecialWords();
        const uint64_t w = words[pick(words.size())];
        const int n = w > 0xffffffffull ? 8 : 4;
        if (b.size() < static_cast<size_t>(n)) break;
        // Aligned to the record layout half of the time (STL records are 4-aligned).
        size_t pos = pick(b.size() - n + 1);
        if (rng() % 2) pos &= ~size_t{3};
        for (int i = 0; i < n; ++i) b[pos + i] = static_cast<char>((w >> (8 * i)) & 0xff);
        break;
      }
    }
  }
  return b;
}

/// Connectivity as the readers promise it, checked independently of the library.
inline bool ConnectivityOk(const Mesh& m, std::string* why) {
  if (m.positions.cols() != 3 || m.faces.cols() != 4) {
    *why = "bad array shapes";
    return false;
  }
  for (int f = 0; f < m.NumFaces(); ++f) {
    const int n = m.faces(f, 3) == -1 ? 3 : 4;
    for (int i = 0; i < n; ++i)
      if (m.faces(f, i) < 0 || m.faces(f, i) >= m.NumVertices()) {
        *why = absl::StrFormat("face %d corner %d is %d with %d vertices", f, i, m.faces(f, i),
                               m.NumVertices());
        return false;
      }
  }
  return true;
}

/// ValidateMesh's messages for what readers pass on by design.
inline bool IsPassedOnProblem(const absl::Status& s) {
  for (const char* what : {"not finite", "zero area", "too large", "appears twice", "non-manifold",
                           "inconsistent orientation", "no vertices", "no faces"})
    if (absl::StrContains(s.message(), what)) return true;
  return false;
}

struct Stats {
  int64_t parses = 0;
  int64_t rejected = 0;   ///< reader said INVALID_ARGUMENT / RESOURCE_EXHAUSTED
  int64_t valid = 0;      ///< parsed and ValidateMesh accepted
  int64_t passed_on = 0;  ///< parsed; ValidateMesh rejected a passed-on problem
  std::vector<std::string> failures;  ///< property violations (first few)
};

inline std::string Escape(const std::string& bytes, size_t max_bytes = 160) {
  std::string out;
  for (size_t i = 0; i < bytes.size() && i < max_bytes; ++i) {
    const unsigned char c = static_cast<unsigned char>(bytes[i]);
    if (c == '\n')
      out += "\\n";
    else if (c >= 32 && c < 127 && c != '\\')
      out += static_cast<char>(c);
    else
      absl::StrAppendFormat(&out, "\\x%02x", c);
  }
  if (bytes.size() > max_bytes) out += "...";
  return out;
}

/// Parses `bytes` as `format` and checks the property above; failures are appended to
/// stats->failures (at most 20 kept) with `label`.
inline void CheckOne(const std::string& bytes, MeshFormat format, const std::string& label,
                     Stats* stats) {
  ++stats->parses;
  const std::string source = "fuzz." + absl::AsciiStrToLower(MeshFormatName(format));
  const auto fail = [&](const std::string& what) {
    if (stats->failures.size() < 20)
      stats->failures.push_back(absl::StrCat(label, " as ", MeshFormatName(format), ": ", what,
                                             "\n  input: \"", Escape(bytes), "\""));
    else
      stats->failures.back() = "... more failures";
  };
  absl::StatusOr<Mesh> m = ParseMesh(bytes, format, source);
  if (!m.ok()) {
    const absl::StatusCode code = m.status().code();
    if (code != absl::StatusCode::kInvalidArgument && code != absl::StatusCode::kResourceExhausted)
      fail(absl::StrCat("unexpected status ", m.status().ToString()));
    else if (!absl::StartsWith(m.status().message(), source))
      fail(absl::StrCat("error does not name the source: ", m.status().message()));
    ++stats->rejected;
    return;
  }
  std::string why;
  if (!ConnectivityOk(*m, &why)) return fail("reader returned broken connectivity: " + why);
  const absl::Status valid = ValidateMesh(*m).status();
  if (!valid.ok()) {
    if (!IsPassedOnProblem(valid)) return fail("ValidateMesh: " + valid.ToString());
    ++stats->passed_on;
    return;
  }
  ++stats->valid;
  // What is valid is written back and read back identically (STL: float32, welded).
  absl::StatusOr<std::string> again = FormatMesh(*m, format);
  if (!again.ok()) return fail("writer refused a valid mesh: " + again.status().ToString());
  absl::StatusOr<Mesh> back = ParseMesh(*again, format, source);
  if (!back.ok()) return fail("re-reading the written mesh: " + back.status().ToString());
  if (format != MeshFormat::kStl &&
      (back->faces != m->faces || back->positions.rows() != m->positions.rows() ||
       std::memcmp(back->positions.data(), m->positions.data(),
                   sizeof(double) * m->positions.size()) != 0))
    fail("round trip through the writer changed the mesh");
}

/// `iterations` mutations of every seed file, each parsed by all four readers.
inline Stats Run(int64_t iterations, uint64_t seed) {
  Stats stats;
  const std::vector<SeedFile> seeds = SeedFiles();
  std::mt19937_64 rng(seed);
  for (const SeedFile& s : seeds)
    CheckOne(s.bytes, s.format, absl::StrCat(s.name, " (unmutated)"), &stats);
  for (int64_t i = 0; i < iterations; ++i)
    for (const SeedFile& s : seeds) {
      const std::string bytes = Mutate(s.bytes, rng);
      for (MeshFormat f : {MeshFormat::kObj, MeshFormat::kOff, MeshFormat::kPly, MeshFormat::kStl})
        CheckOne(bytes, f, absl::StrCat(s.name, " mutation ", i, " (seed ", seed, ")"), &stats);
    }
  return stats;
}

}  // namespace geomfit::reader_fuzz
