// The batched SIMD kernel (wls_batch.h) against the scalar SolveWls: the same fits,
// normals, curvatures and stencil rows to 1e-12 relative, the safeguard lanes left to the
// scalar path, and the normal equations' lanes (fits without stencils) equal to the QR's.
#include <cmath>
#include <memory>
#include <random>
#include <string>

#include <gtest/gtest.h>

#include "core/fitting/fit.h"
#include "core/fitting/wls_batch.h"
#include "core/quantities/differentials.h"
#include "core/surfaces/analytic.h"
#include "tests/mesh/make_mesh.h"

namespace geomfit {
namespace {

// |a - b| <= 1e-12 max(|b|, scale): relative, with `scale` the size of the quantity
// (a curvature that vanishes by symmetry is compared at the size of the others).
::testing::AssertionResult Near(double a, double b, double scale) {
  if (std::abs(a - b) <= 1e-12 * std::max(std::abs(b), scale)) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << a << " vs " << b << " (scale " << scale << ")";
}

// Calls fn(o) for every degree 1..kMaxDegree, LHF and LOP, interpolating or not (traced
// with the mesh's name).
template <typename Fn>
void ForEachFitOptions(const char* mesh, Fn fn) {
  for (int degree = 1; degree <= kMaxDegree; ++degree)
    for (FitMethod method : {FitMethod::kLHF, FitMethod::kLOP})
      for (bool interpolate : {true, false}) {
        SCOPED_TRACE(::testing::Message() << mesh << " degree " << degree << " " << FitMethodName(method)
                                          << " interpolate " << interpolate);
        FitOptions o;
        o.degree = degree;
        o.method = method;
        o.interpolate = interpolate;
        fn(o);
      }
}

// Degree used, rank, flags and points equal; conditions within `condition_tolerance` relative.
::testing::AssertionResult SameDiagnostics(const VertexDiagnostics& a, const VertexDiagnostics& b,
                                           double condition_tolerance) {
  if (a.degree_used != b.degree_used)
    return ::testing::AssertionFailure() << "degree " << a.degree_used << " vs " << b.degree_used;
  if (a.rank != b.rank) return ::testing::AssertionFailure() << "rank " << a.rank << " vs " << b.rank;
  if (a.flags != b.flags) return ::testing::AssertionFailure() << "flags " << a.flags << " vs " << b.flags;
  if (a.points != b.points) return ::testing::AssertionFailure() << "points " << a.points << " vs " << b.points;
  const double ca = a.condition, cb = b.condition;
  if (!(std::abs(ca - cb) <= condition_tolerance * cb))
    return ::testing::AssertionFailure() << "condition " << a.condition << " vs " << b.condition;
  return ::testing::AssertionSuccess();
}

// Normals, H, K, k1 and k2 of vertex v equal to 1e-12 relative (Near), the curvatures at
// the scale `kscale`.
::testing::AssertionResult SameQuantities(const Differentials& a, const Differentials& b, int v, double kscale) {
  for (int k = 0; k < 3; ++k)
    if (auto r = Near(a.normals(v, k), b.normals(v, k), 1); !r) return r << " normal";
  if (auto r = Near(a.mean(v), b.mean(v), kscale); !r) return r << " H";
  if (auto r = Near(a.gaussian(v), b.gaussian(v), kscale * kscale); !r) return r << " K";
  if (auto r = Near(a.k1(v), b.k1(v), kscale); !r) return r << " k1";
  if (auto r = Near(a.k2(v), b.k2(v), kscale); !r) return r << " k2";
  return ::testing::AssertionSuccess();
}

struct Case {
  const char* name;
  Mesh mesh;
};

std::vector<Case> Meshes() {
  GeneratorOptions g;
  g.n = 10;
  std::vector<Case> cases;
  cases.push_back({"torus", GenerateTorusMesh(g)});
  cases.push_back({"bump", GenerateBumpMesh(g)});  // open: boundary stencils
  g.n = 6;
  cases.push_back({"sphere", GenerateSphereMesh(g)});  // quads
  return cases;
}

// Each test runs with every kernel this CPU runs (WlsBatchIsas: AVX-512, AVX2,
// portable), then goes back to the default.
class WlsBatchIsaTest : public ::testing::TestWithParam<std::string> {
 protected:
  void SetUp() override {
    default_ = WlsBatchIsa();
    ASSERT_TRUE(SetWlsBatchIsa(GetParam()));
  }
  void TearDown() override { ASSERT_TRUE(SetWlsBatchIsa(default_)); }
  std::string default_;
};

TEST(WlsBatchTest, TheDefaultKernelIsTheBestSupported) {
  const std::vector<std::string> isas = WlsBatchIsas();
  ASSERT_FALSE(isas.empty());
  EXPECT_EQ(isas.front(), WlsBatchIsa());
  EXPECT_EQ(isas.back(), "portable");
  EXPECT_FALSE(SetWlsBatchIsa("sse9"));
  EXPECT_EQ(isas.front(), WlsBatchIsa());
}

TEST_P(WlsBatchIsaTest, FitsNormalsCurvaturesAndStencilsEqualTheScalarPath) {
  int batched_vertices = 0, total = 0;
  for (const Case& c : Meshes()) {
    const Topology t = BuildTopology(c.mesh).value();
    ForEachFitOptions(c.name, [&](const FitOptions& o) {
      const int degree = o.degree;
      FitRequest scalar_req, batch_req;
      scalar_req.stencils = batch_req.stencils = true;
      scalar_req.batched_kernel = false;
      const auto scalar = FitSurface(c.mesh, t, o, nullptr, scalar_req).value();
      const auto batch = FitSurface(c.mesh, t, o, nullptr, batch_req).value();
      const Differentials ds = ComputeDifferentials(*scalar);
      const Differentials db = ComputeDifferentials(*batch);
      const double kscale = std::max(ds.k1.cwiseAbs().maxCoeff(), ds.k2.cwiseAbs().maxCoeff());
      for (int v = 0; v < c.mesh.NumVertices(); ++v) {
        const VertexDiagnostics& b = scalar->diagnostics(v);
        ASSERT_TRUE(SameDiagnostics(batch->diagnostics(v), b, 1e-12)) << "vertex " << v;
        // Taylor coefficients as heights at the stencil radius h (c_jk h^(j+k)), at the
        // size of the largest: their rounding error grows with the condition of R (2.4).
        const int nc = scalar->num_coefficients();
        const double cond = std::max(1.0, static_cast<double>(b.condition));
        double h = 0;
        for (int k = 0; k < scalar->neighborhoods().Size(v); ++k)
          h = std::max(h, (c.mesh.positions.row(scalar->neighborhoods().Points(v)[k]) - c.mesh.positions.row(v)).norm());
        auto height = [&](const SurfaceFits& f, int d, int p, int i) { return f.coefficients(v)[d * nc + i] * std::pow(h, p); };
        double cscale = 0;
        for (int d = 0; d < scalar->dims(); ++d)
          for (int p = 0; p <= degree; ++p)
            for (int i = NumCoefficients(p - 1); i < NumCoefficients(p); ++i)
              cscale = std::max(cscale, std::abs(height(*scalar, d, p, i)));
        for (int d = 0; d < scalar->dims(); ++d)
          for (int p = 0; p <= degree; ++p)
            for (int i = NumCoefficients(p - 1); i < NumCoefficients(p); ++i)
              ASSERT_LE(std::abs(height(*batch, d, p, i) - height(*scalar, d, p, i)), 1e-11 * cond * cscale)
                  << "coefficient " << i << " at vertex " << v;
        ASSERT_TRUE(SameQuantities(db, ds, v, kscale)) << "vertex " << v;
        // Stencil rows likewise: row i of order p in units of h^-p.
        const int n = scalar->neighborhoods().Size(v);
        auto entry = [&](const SurfaceFits& f, int p, int i, int k) { return f.stencil(v)[i * n + k] * std::pow(h, p); };
        double sscale = 0;
        for (int p = 0; NumCoefficients(p - 1) < scalar->stencil_rows(); ++p)
          for (int i = NumCoefficients(p - 1); i < NumCoefficients(p); ++i)
            for (int k = 0; k < n; ++k) sscale = std::max(sscale, std::abs(entry(*scalar, p, i, k)));
        for (int p = 0; NumCoefficients(p - 1) < scalar->stencil_rows(); ++p)
          for (int i = NumCoefficients(p - 1); i < NumCoefficients(p); ++i)
            for (int k = 0; k < n; ++k)
              ASSERT_LE(std::abs(entry(*batch, p, i, k) - entry(*scalar, p, i, k)), 1e-11 * cond * sscale)
                  << "stencil row " << i << " at vertex " << v;
        total++;
        batched_vertices += b.degree_used == degree;
      }
    });
  }
  // Most vertices take the batched path (no degree drop); the rest were compared too.
  EXPECT_GT(batched_vertices, total * 3 / 4);
}

// Fits without stencil rows take the normal equations (wls_batch.cc SolveNormal) in the
// well-conditioned lanes: normals and curvatures equal the scalar QR's to 1e-12 relative,
// diagnostics equal (the condition, stored as a float, to its rounding), on the test
// meshes and a shuffled irregular torus.
// (The default kernel only: the kernels' arithmetic is the same per lane, see above.)
TEST(WlsBatchTest, NormalEquationsGiveTheScalarPathsNormalsAndCurvatures) {
  std::vector<Case> cases = Meshes();
  GeneratorOptions g;
  g.n = 12;
  g.jitter = 0.4;
  cases.push_back({"shuffled torus", testing_util::ShuffleVertices(GenerateTorusMesh(g), 11)});
  int differ = 0, total = 0;
  for (const Case& c : cases) {
    const Topology t = BuildTopology(c.mesh).value();
    ForEachFitOptions(c.name, [&](const FitOptions& o) {
      FitRequest scalar_req;
      scalar_req.batched_kernel = false;
      const auto scalar = FitSurface(c.mesh, t, o, nullptr, scalar_req).value();
      const auto batch = FitSurface(c.mesh, t, o, nullptr, {}).value();
      const Differentials ds = ComputeDifferentials(*scalar);
      const Differentials db = ComputeDifferentials(*batch);
      const double kscale = std::max(ds.k1.cwiseAbs().maxCoeff(), ds.k2.cwiseAbs().maxCoeff());
      const int nc = scalar->num_coefficients() * scalar->dims();
      for (int v = 0; v < c.mesh.NumVertices(); ++v) {
        ASSERT_TRUE(SameDiagnostics(batch->diagnostics(v), scalar->diagnostics(v), 1e-6)) << "vertex " << v;
        ASSERT_TRUE(SameQuantities(db, ds, v, kscale)) << "vertex " << v;
        bool same = true;
        for (int i = 0; i < nc; ++i) same &= batch->coefficients(v)[i] == scalar->coefficients(v)[i];
        differ += !same;
        total++;
      }
    });
  }
  // The QR lanes are the scalar path's bit for bit: most vertices were solved otherwise.
  EXPECT_GT(differ, total / 2);
}

// Height fits set up in the kernel's lanes (FitRequest::lane_setup, FitHeightsBatch)
// against the same fits set up vertex by vertex (SetUpVertex, SolveWlsBatch): frames,
// coefficients and diagnostics bit for bit, on the test meshes and a jittered torus with
// shuffled numbering, with the default safeguard angle and a narrow one (rows dropped
// inside stencils: gamma 0 rows are not compacted in the lanes), every kernel.
TEST_P(WlsBatchIsaTest, LaneSetUpGivesTheSameFitsBitForBit) {
  std::vector<Case> cases = Meshes();
  GeneratorOptions g;
  g.n = 12;
  g.jitter = 0.4;
  cases.push_back({"shuffled torus", testing_util::ShuffleVertices(GenerateTorusMesh(g), 11)});
  int dropped = 0;
  for (const Case& c : cases) {
    const Topology t = BuildTopology(c.mesh).value();
    for (const double angle : {70.0, 25.0})
      for (int degree = 1; degree <= kMaxDegree; ++degree)
        for (const bool interpolate : {true, false}) {
          SCOPED_TRACE(::testing::Message() << c.name << " degree " << degree << " interpolate " << interpolate
                                            << " angle " << angle);
          FitOptions o;
          o.degree = degree;
          o.interpolate = interpolate;
          o.safeguard_angle_deg = angle;
          FitRequest problems;
          problems.lane_setup = false;
          const auto a = FitSurface(c.mesh, t, o, nullptr, {}).value();
          const auto b = FitSurface(c.mesh, t, o, nullptr, problems).value();
          const int nc = a->num_coefficients();
          for (int v = 0; v < c.mesh.NumVertices(); ++v) {
            const VertexDiagnostics &da = a->diagnostics(v), &db = b->diagnostics(v);
            ASSERT_EQ(da.degree_requested, db.degree_requested) << "vertex " << v;
            ASSERT_TRUE(SameDiagnostics(da, db, 0)) << "vertex " << v;
            ASSERT_EQ(da.condition, db.condition) << "vertex " << v;
            for (int i = 0; i < nc; ++i) ASSERT_EQ(a->coefficients(v)[i], b->coefficients(v)[i]) << "vertex " << v;
            const LocalFrame &fa = a->frame(v), &fb = b->frame(v);
            ASSERT_TRUE(fa.origin == fb.origin && fa.t1 == fb.t1 && fa.t2 == fb.t2 && fa.normal == fb.normal)
                << "vertex " << v;
            dropped += da.points < a->neighborhoods().Size(v);
          }
        }
  }
  EXPECT_GT(dropped, 0);  // the narrow angle dropped rows
}

// A random stencil of `rows` points on a paraboloid, every row with weight 1.
WlsProblem RandomProblem(int rows, std::mt19937& rng) {
  std::uniform_real_distribution<double> uni(-1, 1);
  WlsProblem P;
  P.rows = rows;
  P.dims = 1;
  for (int r = 0; r < rows; ++r) {
    P.u[r] = uni(rng);
    P.v[r] = uni(rng);
    P.gamma[r] = r % 5 == 4 ? 0.0 : 1.0;  // some rows dropped by the angle safeguard
    P.rhs[0][r] = 0.3 * P.u[r] * P.u[r] - 0.2 * P.u[r] * P.v[r] + 0.1 * P.v[r] * P.v[r] + 0.01 * uni(rng);
  }
  return P;
}

TEST_P(WlsBatchIsaTest, LanesLeavingThePlainPathAreLeftToTheScalarSolver) {
  std::mt19937 rng(7);
  WlsSettings S;
  S.degree = 2;
  const double thresholds[kMaxDegree + 1] = {0, 1e3, 1e3, 3.3e3, 1e4, 1e5, 1e6};
  S.cond_threshold = thresholds;
  // Lanes 0-3 and again 4-7 (the second group of 4 on AVX2): lane 1 (5) has 4 rows (3
  // kept) for 5 columns; lane 3 (7) has all its points on the line v = 0, which makes R
  // singular (a zero pivot).
  WlsProblem P[kWlsLanes];
  for (int l = 0; l < kWlsLanes; ++l) {
    P[l] = RandomProblem(l % 4 == 0 ? 20 : l % 4 == 1 ? 4 : l % 4 == 2 ? 30 : 12, rng);
    if (l % 4 == 3)
      for (int r = 0; r < P[l].rows; ++r) P[l].v[r] = 0;
  }
  const WlsProblem* p[kWlsLanes];
  auto coef = std::make_unique<double[]>(kWlsLanes * kMaxCoefficients);
  auto op = std::make_unique<double[]>(kWlsLanes * kMaxCoefficients * kMaxStencil);
  double *c[kWlsLanes], *o[kWlsLanes];
  for (int l = 0; l < kWlsLanes; ++l) {
    p[l] = &P[l];
    c[l] = coef.get() + l * kMaxCoefficients;
    o[l] = op.get() + l * kMaxCoefficients * kMaxStencil;
  }
  WlsSolution sol[kWlsLanes];
  auto work = std::make_unique<WlsBatchWorkspace>();
  EXPECT_EQ(SolveWlsBatch(p, kWlsLanes, S, c, o, sol, *work), 0b01010101);
  EXPECT_EQ(SolveWlsBatch(p, 6, S, c, o, sol, *work), 0b010101);  // a partial batch
  for (int l : {0, 2, 4}) {
    double ref[kMaxCoefficients], ref_op[kMaxCoefficients * kMaxStencil];
    const WlsSolution s = SolveWls(P[l], S, ref, ref_op);
    EXPECT_EQ(sol[l].degree_used, s.degree_used);
    EXPECT_NEAR(sol[l].condition, s.condition, 1e-12 * s.condition);
    for (int i = 0; i < NumCoefficients(2); ++i) EXPECT_NEAR(c[l][i], ref[i], 1e-12 * std::abs(ref[i]) + 1e-15);
    for (int i = 0; i < NumCoefficients(2) * P[l].rows; ++i) EXPECT_NEAR(o[l][i], ref_op[i], 1e-12);
  }
  // The oscillation safeguard is never batched.
  S.oscillation_safeguard = true;
  EXPECT_EQ(SolveWlsBatch(p, kWlsLanes, S, c, o, sol, *work), 0);
  EXPECT_EQ(std::string(WlsBatchIsa()), GetParam());
}

// SolveWlsBatch without operator rows: a well-conditioned lane is solved by the normal
// equations (equal to SolveWls to round-off, not bit for bit), a lane with a condition
// above the normal equations' limit (1e3) but below the cut-off by the QR (SolveWls's
// result bit for bit), a lane above the cut-off not at all; with the normal equations
// off every solved lane is SolveWls's bit for bit; and a lane solved alone gives the bits
// it gets in the batch.
TEST_P(WlsBatchIsaTest, NormalEquationsLeaveIllConditionedLanesToTheQr) {
  std::mt19937 rng(3);
  WlsSettings S;
  S.degree = 2;
  const double thresholds[kMaxDegree + 1] = {0, 1e3, 1e6, 3.3e3, 1e4, 1e5, 1e6};
  S.cond_threshold = thresholds;
  WlsProblem P[kWlsLanes];
  for (int l = 0; l < kWlsLanes; ++l) P[l] = RandomProblem(16, rng);
  // Lanes 2, 5 and 6: the points close to the parabola v = u^2 / 2, so that the columns
  // v and u^2 / 2 are nearly parallel (column scaling does not help): condition ~4e3,
  // above the cut-off 1e6, and ~1e2 (normal equations with a refinement step).
  for (int l : {2, 5, 6})
    for (int r = 0; r < P[l].rows; ++r)
      P[l].v[r] = 0.5 * P[l].u[r] * P[l].u[r] + (l == 2 ? 2e-4 : l == 5 ? 1e-7 : 1e-2) * P[l].v[r];
  const WlsProblem* p[kWlsLanes];
  double coef[kWlsLanes][kMaxCoefficients], *c[kWlsLanes], *o[kWlsLanes] = {};
  for (int l = 0; l < kWlsLanes; ++l) p[l] = &P[l], c[l] = coef[l];
  WlsSolution sol[kWlsLanes], ref[kWlsLanes];
  double ref_coef[kWlsLanes][kMaxCoefficients];
  for (int l = 0; l < kWlsLanes; ++l) ref[l] = SolveWls(P[l], S, ref_coef[l]);
  ASSERT_GT(ref[2].condition, 1e3);
  ASSERT_LT(ref[2].condition, 1e6);
  ASSERT_TRUE(ref[5].condition_downgraded);  // to degree 1
  ASSERT_GT(ref[6].condition, 30);
  ASSERT_LT(ref[6].condition, 1e3);
  auto work = std::make_unique<WlsBatchWorkspace>();
  for (bool normal : {true, false}) {
    SCOPED_TRACE(normal ? "normal equations" : "QR only");
    SetWlsBatchNormalEquations(normal);
    EXPECT_EQ(SolveWlsBatch(p, kWlsLanes, S, c, o, sol, *work), 0b11011111);
    int bit_equal = 0;
    for (int l = 0; l < kWlsLanes; ++l) {
      if (l == 5) continue;
      EXPECT_EQ(sol[l].degree_used, 2);
      EXPECT_NEAR(sol[l].condition, ref[l].condition, 1e-12 * ref[l].condition);
      bool same = true;
      for (int i = 0; i < NumCoefficients(2); ++i) {
        EXPECT_NEAR(c[l][i], ref_coef[l][i], 1e-12 * std::abs(ref_coef[l][i]) + 1e-15) << "lane " << l;
        same &= c[l][i] == ref_coef[l][i];
      }
      if (l == 2 || !normal) {
        EXPECT_TRUE(same) << "lane " << l;
      }
      bit_equal += same;
    }
    if (normal) {
      EXPECT_LT(bit_equal, 4);
    }
    // A lane's result does not depend on the other lanes of its batch (lane 6 makes its
    // group compute a refinement step): each lane solved alone gives the same bits.
    for (int l = 0; l < kWlsLanes; ++l) {
      if (l == 5) continue;
      double alone[kMaxCoefficients], *a[1] = {alone}, *no_op[1] = {nullptr};
      WlsSolution s;
      ASSERT_EQ(SolveWlsBatch(p + l, 1, S, a, no_op, &s, *work), 1) << "lane " << l;
      for (int i = 0; i < NumCoefficients(2); ++i) EXPECT_EQ(alone[i], c[l][i]) << "lane " << l;
    }
  }
  SetWlsBatchNormalEquations(true);
}

INSTANTIATE_TEST_SUITE_P(Kernels, WlsBatchIsaTest, ::testing::ValuesIn(WlsBatchIsas()),
                         [](const ::testing::TestParamInfo<std::string>& info) { return info.param; });

}  // namespace
}  // namespace geomfit
