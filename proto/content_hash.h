#pragma once
#include <cstddef>
#include <cstdint>
#include <string>

namespace geomfit {

/// A stable (across processes and machines) 128-bit content hash for mesh identity
/// and idempotent uploads. Not cryptographic.
class ContentHash {
 public:
  void Add(const void* data, size_t bytes);
  void AddString(const std::string& s) {
    const uint64_t n = s.size();
    Add(&n, sizeof(n));
    Add(s.data(), s.size());
  }
  /// 32 lowercase hex digits.
  std::string Hex() const;

 private:
  uint64_t a_ = 0x9e3779b97f4a7c15ULL, b_ = 0xc2b2ae3d27d4eb4fULL, length_ = 0;
};

}  // namespace geomfit
