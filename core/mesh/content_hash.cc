#include "core/mesh/content_hash.h"

#include <cstring>

#include "absl/strings/str_format.h"

namespace geomfit {
namespace {

inline uint64_t Mix(uint64_t x) {  // splitmix64 finalizer
  x ^= x >> 30;
  x *= 0xbf58476d1ce4e5b9ULL;
  x ^= x >> 27;
  x *= 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

}  // namespace

void ContentHash::Add(const void* data, size_t bytes) {
  const auto* p = static_cast<const unsigned char*>(data);
  size_t i = 0;
  for (; i + 8 <= bytes; i += 8) {
    uint64_t w;
    std::memcpy(&w, p + i, 8);
    a_ = Mix(a_ ^ w) + 0x9e3779b97f4a7c15ULL;
    b_ = Mix(b_ + w) ^ (a_ >> 7);
  }
  uint64_t tail = 0;
  std::memcpy(&tail, p + i, bytes - i);
  a_ = Mix(a_ ^ tail ^ (uint64_t{bytes - i} << 56));
  b_ = Mix(b_ + tail + 0x632be59bd9b4e019ULL);
  length_ += bytes;
}

std::string ContentHash::Hex() const {
  return absl::StrFormat("%016x%016x", Mix(a_ ^ length_), Mix(b_ + length_));
}

std::string MeshContentHash(const Mesh& mesh, const std::string& name,
                            const std::map<std::string, std::string>& labels) {
  ContentHash h;
  const int64_t counts[2] = {mesh.NumVertices(), mesh.NumFaces()};
  h.Add(counts, sizeof(counts));
  h.Add(mesh.faces.data(), sizeof(int32_t) * mesh.faces.size());
  h.Add(mesh.positions.data(), sizeof(double) * mesh.positions.size());
  h.AddString(name);
  for (const auto& [k, v] : labels) {  // std::map: sorted
    h.AddString(k);
    h.AddString(v);
  }
  return h.Hex();
}

std::string MeshIdOf(const std::string& content_hash) { return "m-" + content_hash.substr(0, 20); }

}  // namespace geomfit
