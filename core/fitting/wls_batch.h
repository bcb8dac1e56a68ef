#pragma once
#include <memory>

#include "core/fitting/wls.h"

namespace geomfit {

/// Problems solved together by SolveWlsBatch, one per SIMD lane.
inline constexpr int kWlsLanes = 4;

/// Scratch space of SolveWlsBatch (about 225 KB): allocate once per thread or block of
/// vertices, never per call.
struct WlsBatchWorkspace {
  static constexpr int kDoubles =
      kWlsLanes * ((kMaxCoefficients + 3 + 8) * kMaxStencil + kMaxCoefficients * kMaxCoefficients);
  alignas(64) double data[kDoubles];
};

/// SolveWls for up to kWlsLanes problems with the same settings and dims at once: the
/// problems sit side by side in SIMD lanes (row i of every problem in one vector, rows
/// padded with zero weight), with the degree fixed at compile time. Same steps and
/// safeguards as SolveWls (weights (2.2.1), column scaling (2.6.6), Householder QR,
/// condition cut-off (2.4), operator rows), equal results to round-off.
///
/// A lane whose fit leaves the plain path (too few rows, a zero pivot, a condition above
/// the cut-off, so a degree drop, or the oscillation safeguard, which is never batched)
/// is not written: the returned bit mask has bit l set iff problem l was solved, and the
/// caller solves the others with SolveWls. `ops[l]` may be null (no operator rows).
/// Runs AVX2 code when the CPU has it, portable code otherwise (one binary).
int SolveWlsBatch(const WlsProblem* const problems[], int count, const WlsSettings& settings,
                  double* const coefficients[], double* const ops[], WlsSolution solutions[],
                  WlsBatchWorkspace& work);

/// The instruction set SolveWlsBatch runs with on this CPU: "avx2" or "portable".
const char* WlsBatchIsa();

}  // namespace geomfit
