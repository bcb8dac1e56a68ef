#pragma once
// Eight 64-byte records (x y z nx ny nz and two more doubles, each an aligned cache
// line) transposed into components across 8 lanes: shared by the lane kernel's AVX-512
// row set-up (wls_batch.cc) and the slope refinement's batches (slopes.cc).

namespace geomfit {

/// q[c] = (at[0][c], ..., at[7][c]) for c = 0..5, `V` a GCC vector of 8 doubles and
/// every at[l] 64-byte aligned. Unpacks of lane pairs give (x, z, ny, pad) and (y, nx,
/// nz, pad) in pairs of lanes; two-source permutes put lanes 0-3 and 4-7 of two
/// components side by side, 256-bit joins finish. Data movement only: exact. (Generic
/// shuffles, compiled for the caller's instruction set: GCC 12 warns on the intrinsics'
/// undefined sources.)
template <class V>
__attribute__((always_inline)) inline void TransposeRecords8(const double* const* at, V* q) {
  V lo[4], hi[4];
  for (int k = 0; k < 4; ++k) {
    const V a = *reinterpret_cast<const V*>(at[2 * k]), b = *reinterpret_cast<const V*>(at[2 * k + 1]);
    lo[k] = __builtin_shufflevector(a, b, 0, 8, 2, 10, 4, 12, 6, 14);
    hi[k] = __builtin_shufflevector(a, b, 1, 9, 3, 11, 5, 13, 7, 15);
  }
  for (int h = 0; h < 2; ++h) {
    const V* t = h ? hi : lo;
    const V a = __builtin_shufflevector(t[0], t[1], 0, 1, 8, 9, 2, 3, 10, 11);
    const V b = __builtin_shufflevector(t[2], t[3], 0, 1, 8, 9, 2, 3, 10, 11);
    const V c = __builtin_shufflevector(t[0], t[1], 4, 5, 12, 13, 6, 7, 14, 15);
    const V d = __builtin_shufflevector(t[2], t[3], 4, 5, 12, 13, 6, 7, 14, 15);
    q[h] = __builtin_shufflevector(a, b, 0, 1, 2, 3, 8, 9, 10, 11);
    q[h + 2] = __builtin_shufflevector(a, b, 4, 5, 6, 7, 12, 13, 14, 15);
    q[h + 4] = __builtin_shufflevector(c, d, 0, 1, 2, 3, 8, 9, 10, 11);
  }
}

}  // namespace geomfit
