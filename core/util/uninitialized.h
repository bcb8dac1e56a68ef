#pragma once
#include <memory>
#include <type_traits>
#include <utility>
#include <vector>

namespace geomfit {

/// A std::allocator whose value-less construct() leaves the storage as allocated: a
/// vector sized with resize() costs no serial pass over its memory, and its owner writes
/// every element before reading it (e.g. each thread its own part: first touch in
/// parallel). For trivially destructible types only.
template <typename T>
struct UninitializedAllocator : std::allocator<T> {
  static_assert(std::is_trivially_destructible_v<T>);
  template <typename U>
  struct rebind {
    using other = UninitializedAllocator<U>;
  };
  UninitializedAllocator() = default;
  template <typename U>
  UninitializedAllocator(const UninitializedAllocator<U>&) noexcept {}
  template <typename U>
  void construct(U*) noexcept {}
  template <typename U, typename... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};

/// A vector whose resize() leaves the new elements unwritten (UninitializedAllocator).
template <typename T>
using UninitializedVector = std::vector<T, UninitializedAllocator<T>>;

}  // namespace geomfit
