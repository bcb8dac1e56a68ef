#pragma once
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "core/fitting/frames.h"
#include "core/fitting/wls.h"
#include "core/mesh/mesh.h"

namespace geomfit {

/// Problems solved together by SolveWlsBatch, one per SIMD lane: 8 lanes of one
/// AVX-512 vector, or two groups of 4 (AVX2, portable).
inline constexpr int kWlsLanes = 8;

/// Scratch space of SolveWlsBatch (about 450 KB): allocate once per thread or block of
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
/// condition cut-off (2.4), operator rows), equal results to round-off. Without
/// operator rows (every `ops[l]` null), lanes whose scaled condition is small (<= 1e3
/// and half the cut-off) are solved by the normal equations instead (Cholesky of the
/// column-scaled Gram matrix built from weighted moments, wls_batch.cc SolveNormal):
/// the same condition and degree, normals and curvatures equal to the QR's to ~1e-14
/// relative, but not bit for bit; the other lanes take the QR.
///
/// A lane whose fit leaves the plain path (too few rows, a zero pivot, a condition above
/// the cut-off, so a degree drop, or the oscillation safeguard, which is never batched)
/// is not written: the returned bit mask has bit l set iff problem l was solved, and the
/// caller solves the others with SolveWls. `ops[l]` may be null (no operator rows).
/// Runs AVX-512 code (8 lanes) when the CPU has it, else AVX2 (4 lanes), else portable
/// code (one binary); every lane performs the same operations in the same order.
int SolveWlsBatch(const WlsProblem* const problems[], int count, const WlsSettings& settings,
                  double* const coefficients[], double* const ops[], WlsSolution solutions[],
                  WlsBatchWorkspace& work);

/// Position and normal of one point as FitHeightsBatch reads them: one aligned 64-byte
/// cache line (two doubles of padding, zero), loaded whole and transposed in registers
/// across the lanes (no per-component gathers).
struct alignas(64) PointRecord {
  double p[3];
  double n[3];
  double pad[2];
};
using PointRecords = std::vector<PointRecord>;

/// records[k] = (positions row order[k], normals row order[k]) for every vertex k (order
/// null: row k): the copy in fit order whose slots FitHeightsBatch and the fit loop read.
PointRecords MakePointRecords(const Positions& positions, const Positions& normals, const int32_t* order,
                              int threads);

/// Where FitHeightsBatch reads its stencils: the point in slot s is points[s].
struct HeightLanesInput {
  const PointRecord* points;
  double cos_cut;  ///< cos(safeguard angle): rows whose normals turn further get gamma 0 (2.2.1)
};

/// One vertex of FitHeightsBatch: its slot, its stencil's slots (centre first) and where
/// its fit goes.
struct HeightLane {
  int slot;
  const int32_t* points;
  int size;
  LocalFrame* frame;     ///< written for every lane
  double* coefficients;  ///< NumCoefficients(degree) doubles, written for solved lanes
};

/// Height-function fits (LHF) without operator rows for up to kWlsLanes non-isolated
/// vertices, set up in the SIMD lanes themselves: frame (FrameFromNormal), the stencil
/// points' (u, v, height) and safeguard factors (2.2.1) as fit.cc's SetUpVertex computes
/// them, 8 (or 4) vertices per vector, then solved by the normal equations as
/// SolveWlsBatch does (its SolveNormal: the same bits). `used[l]` gets the vertex's count
/// of rows with a positive safeguard factor (the centre counted); frames are written for
/// every lane. Returns the mask of lanes solved; the others (too few rows, a condition
/// the normal equations leave to the QR, ...) are for SolveWlsBatch / SolveWls. Returns 0
/// with the normal equations off (SetWlsBatchNormalEquations) or a degree above 6.
int FitHeightsBatch(const HeightLanesInput& in, const HeightLane lanes[], int count, const WlsSettings& settings,
                    WlsSolution solutions[], int used[], WlsBatchWorkspace& work);

/// Whether SolveWlsBatch and FitHeightsBatch use the normal equations (the default).
bool WlsBatchNormalEquations();

/// Tests and benchmarks: whether SolveWlsBatch may solve well-conditioned lanes without
/// operator rows by the normal equations (the default) or always by the QR (not
/// thread-safe: call before fitting).
void SetWlsBatchNormalEquations(bool enabled);

/// The instruction set SolveWlsBatch runs with: "avx512", "avx2" or "portable" (the
/// best this CPU has unless SetWlsBatchIsa chose another).
const char* WlsBatchIsa();

/// The kernels this CPU and build run, best (the default) first, "portable" last.
std::vector<std::string> WlsBatchIsas();

/// Tests and benchmarks: run SolveWlsBatch with `isa` from now on (not thread-safe:
/// call before fitting). False, and nothing changes, if this CPU or build lacks it.
bool SetWlsBatchIsa(std::string_view isa);

}  // namespace geomfit
