// WALF and CMF (4.1): distance to the exact surface O(h^(d+1)) at random points per
// face, normal jumps O(h^d), the oscillation safeguard, point validation.
#include <array>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "core/reconstruction/surface.h"
#include "core/surfaces/analytic.h"
#include "core/surfaces/errors.h"
#include "tests/mesh/make_mesh.h"

namespace geomfit {
namespace {

struct Errors {
  double distance = 0, normal = 0;
};

Errors MeasureOn(const Mesh& mesh, const AnalyticSurface& exact, ReconstructionMethod method, int degree,
                 bool safeguard, int per_face, int* downgraded = nullptr) {
  const Topology topo = BuildTopology(mesh).value();
  FitOptions o;
  o.degree = degree;
  o.oscillation_safeguard = safeguard;
  auto fits = FitSurface(mesh, topo, o).value();
  if (downgraded) {
    *downgraded = 0;
    for (const VertexDiagnostics& dg : fits->diagnostics()) *downgraded += (dg.flags & kFlagOscillation) != 0;
  }
  auto surface = MakeSurface(method, mesh, fits);
  std::vector<SurfacePoint> out;
  EXPECT_TRUE(EvaluatePoints(*surface, RandomFacePoints(mesh, per_face, 42), &out).ok());
  Errors e;
  for (const SurfacePoint& s : out) {
    const Eigen::Vector3d p = exact.Project(s.position);
    e.distance = std::max(e.distance, (p - s.position).norm());
    e.normal = std::max(e.normal, (exact.At(p).normal - s.normal).norm());
  }
  return e;
}

Errors Measure(const std::string& name, int n, ReconstructionMethod method, int degree, bool safeguard = false,
               int per_face = 10) {
  GeneratorOptions g;
  g.n = n;
  return MeasureOn(GenerateNamedMesh(name, g).value(), *NamedSurface(name).value(), method, degree, safeguard,
                per_face);
}

struct Case {
  std::string surface;
  ReconstructionMethod method;
  int degree;
};
void PrintTo(const Case& c, std::ostream* os) {
  *os << c.surface << " " << ReconstructionMethodName(c.method) << " degree " << c.degree;
}

class ReconstructionOrderTest : public testing::TestWithParam<Case> {};

TEST_P(ReconstructionOrderTest, DistanceOrderDPlus1NormalOrderD) {
  const Case& c = GetParam();
  std::vector<double> h, dist, nrm;
  for (int n : {16, 32, 64}) {
    GeneratorOptions g;
    g.n = n;
    h.push_back(AverageEdgeLength(GenerateNamedMesh(c.surface, g).value()));
    const Errors e = Measure(c.surface, n, c.method, c.degree, false, c.method == ReconstructionMethod::kCmf ? 2 : 10);
    dist.push_back(e.distance);
    nrm.push_back(e.normal);
  }
  const double od = ConvergenceOrder(h, dist), on = ConvergenceOrder(h, nrm);
  std::printf("%s %s d=%d: distance Linf %.2e %.2e %.2e order %.2f | normal Linf %.2e order %.2f\n",
              c.surface.c_str(), ReconstructionMethodName(c.method), c.degree, dist[0], dist[1], dist[2],
              od, nrm[2], on);
  // WALF: O(h^(d+1) + h^6) (4.1.1); CMF: O(h^(d+1)) (4.1.2).
  const double expected = c.method == ReconstructionMethod::kWalf ? std::min(c.degree + 1, 6) : c.degree + 1;
  EXPECT_GE(od, expected - 0.5);
  EXPECT_GE(on, c.degree - 0.5);
}

std::vector<Case> Cases() {
  std::vector<Case> cases;
  for (int d = 1; d <= 6; ++d)
    for (auto m : {ReconstructionMethod::kWalf, ReconstructionMethod::kCmf}) {
      cases.push_back({"torus", m, d});
      cases.push_back({"sphere", m, d});
    }
  return cases;
}

std::string Name(const testing::TestParamInfo<Case>& info) {
  return info.param.surface + "_" + ReconstructionMethodName(info.param.method) + "_d" +
         std::to_string(info.param.degree);
}

INSTANTIATE_TEST_SUITE_P(Surfaces, ReconstructionOrderTest, testing::ValuesIn(Cases()), Name);

TEST(ReconstructionTest, LinearInterpolationIsOnlySecondOrder) {
  std::vector<double> h, dist;
  for (int n : {16, 32, 64}) {
    GeneratorOptions g;
    g.n = n;
    h.push_back(AverageEdgeLength(GenerateTorusMesh(g)));
    dist.push_back(Measure("torus", n, ReconstructionMethod::kLinear, 2).distance);
  }
  EXPECT_NEAR(ConvergenceOrder(h, dist), 2.0, 0.3);
}

// The oscillation safeguard (4.1.3) lowers degrees on coarse meshes where fits oscillate
// (compare Table 4.1) and leaves well-resolved fits alone.
TEST(OscillationSafeguardTest, DowngradesOnCoarseMeshesOnly) {
  for (int d : {4, 5, 6}) {
    int coarse = 0, fine = 0;
    for (int n : {8, 64}) {
      GeneratorOptions g;
      g.n = n;
      const Mesh mesh = GenerateTorusMesh(g);
      FitOptions o;
      o.degree = d;
      o.oscillation_safeguard = true;
      auto fits = FitSurface(mesh, BuildTopology(mesh).value(), o).value();
      int count = 0;
      for (const VertexDiagnostics& dg : fits->diagnostics()) {
        if (dg.flags & kFlagOscillation) {
          ++count;
          EXPECT_LT(dg.degree_used, d);
          EXPECT_GE(dg.degree_used, 2);
        }
      }
      (n == 8 ? coarse : fine) = count;
    }
    std::printf("degree %d: downgraded %d of 192 coarse vertices, %d of 12288 fine\n", d, coarse, fine);
    // Degree 5 is where the coarse fits blow up (distance 0.37, normals flipped; see
    // below); degrees 4 and 6 unsafeguarded stay within the linear surface's error there,
    // and the scale-free tests leave them (nearly) alone.
    if (d == 5) EXPECT_GT(coarse, 192 / 20);
    EXPECT_EQ(fine, 0);
  }
  // Degrees <= 3 on the fine mesh: nothing to downgrade.
  GeneratorOptions g;
  g.n = 64;
  const Mesh mesh = GenerateTorusMesh(g);
  FitOptions o;
  o.degree = 3;
  o.oscillation_safeguard = true;
  auto fits = FitSurface(mesh, BuildTopology(mesh).value(), o).value();
  for (const VertexDiagnostics& dg : fits->diagnostics()) ASSERT_FALSE(dg.flags & kFlagOscillation);
}

// The safeguard costs nothing on smooth, resolved meshes: WALF's max distance with it is
// within 1.5x of without it at mid resolutions, every degree (the text's absolute
// eps = 0.01 cost 2-36x on the torus and up to 290x on the sphere here). At the
// coarsest level it still prevents the blow-ups: without it degree 5 reaches 0.19 on a
// torus of tube radius 0.3 (0.37 with the plain fit, before the Hermite jets became degree 5's
// default, bench/README.md `d45m`) and normals turn by ~65 degrees.
TEST(OscillationSafeguardTest, CostsNothingOnSmoothMeshesAndBoundsCoarseOnes) {
  for (const std::string name : {"torus", "sphere"})
    for (int n : {16, 24})
      for (int d = 2; d <= 6; ++d) {
        const Errors off = Measure(name, n, ReconstructionMethod::kWalf, d, false, 4);
        const Errors on = Measure(name, n, ReconstructionMethod::kWalf, d, true, 4);
        std::printf("%s n=%d d=%d: distance off %.2e on %.2e (x%.2f)\n", name.c_str(), n, d, off.distance,
                    on.distance, on.distance / off.distance);
        EXPECT_LE(on.distance, 1.5 * off.distance) << name << " n=" << n << " d=" << d;
        EXPECT_LE(on.normal, 1.5 * off.normal) << name << " n=" << n << " d=" << d;
      }
  const double linear = Measure("torus", 8, ReconstructionMethod::kLinear, 2).distance;
  double worst_off = 0;
  for (int d = 3; d <= 6; ++d) {
    const Errors off = Measure("torus", 8, ReconstructionMethod::kWalf, d, false);
    const Errors on = Measure("torus", 8, ReconstructionMethod::kWalf, d, true);
    std::printf("torus n=8 d=%d: distance off %.2e on %.2e, normal off %.2f on %.2f (linear %.2e)\n", d,
                off.distance, on.distance, off.normal, on.normal, linear);
    worst_off = std::max(worst_off, off.distance);
    EXPECT_LT(on.normal, 0.7);  // |n - n_exact| < sqrt(2): no flipped normal, far from it
    EXPECT_LT(on.distance, 1.5 * linear);
  }
  EXPECT_GT(worst_off, 3 * linear);  // the blow-up the safeguard exists for
}

// A torus (R = 1, r = 0.3) triangulated as a structured mesher would: nu x nv jittered
// parameter cells (nu along the ring, nv around the tube), alternating diagonals. With
// nu <= nv the cells are long along the ring, so degree-6 stencils reach around the tube
// (stencil radius ~ 2x the tube radius).
Mesh StructuredTorus(int nu, int nv, double jitter, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> jit(-jitter / 2, jitter / 2);
  std::vector<std::array<double, 3>> verts;
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      const double u = 2 * M_PI * (i + jit(rng)) / nu, v = 2 * M_PI * (j + jit(rng)) / nv;
      verts.push_back({(1 + 0.3 * std::cos(v)) * std::cos(u), (1 + 0.3 * std::cos(v)) * std::sin(u), 0.3 * std::sin(v)});
    }
  auto id = [&](int i, int j) { return (i % nu) * nv + j % nv; };
  std::vector<std::vector<int>> faces;
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      const int a = id(i, j), b = id(i + 1, j), c = id(i + 1, j + 1), d = id(i, j + 1);
      if ((i + j) % 2) faces.insert(faces.end(), {{a, b, c}, {a, c, d}});
      else faces.insert(faces.end(), {{a, b, d}, {b, c, d}});
    }
  return testing_util::MakeMesh(verts, faces);
}

// Issue 16: the safeguard costs nothing on smooth meshes that are not the project's
// own. Anisotropic structured tori (stencils wrapping around the tube, where comparing
// with the degree-2 fit on half the stencil disc cost 2.9-8.6x at degree 6) and the
// coarse ellipsoid (curvature radius 0.36; the coefficient test without the (p+1)!
// factor lowered 22 of its 386 degree-6 fits, as it lowered marching-cubes tori's): no
// fit is lowered, so WALF and CMF are those of the unsafeguarded fits, degrees 3-6.
TEST(OscillationSafeguardTest, CostsNothingOnAnisotropicAndCoarseSmoothMeshes) {
  auto torus = NamedSurface("torus").value();
  auto ellipsoid = NamedSurface("ellipsoid").value();
  GeneratorOptions g;
  g.n = 8;
  const struct {
    const char* name;
    Mesh mesh;
    const AnalyticSurface* exact;
  } cases[] = {{"torus 32x32", StructuredTorus(32, 32, 0.25, 1), torus.get()},
               {"torus 24x48", StructuredTorus(24, 48, 0.25, 2), torus.get()},
               {"ellipsoid n=8", GenerateNamedMesh("ellipsoid", g).value(), ellipsoid.get()}};
  for (const auto& c : cases)
    for (auto method : {ReconstructionMethod::kWalf, ReconstructionMethod::kCmf})
      for (int d = 3; d <= 6; ++d) {
        int downgraded = 0;
        const int per_face = method == ReconstructionMethod::kCmf ? 1 : 3;
        const Errors off = MeasureOn(c.mesh, *c.exact, method, d, false, per_face);
        const Errors on = MeasureOn(c.mesh, *c.exact, method, d, true, per_face, &downgraded);
        std::printf("%s %s d=%d: distance off %.2e on %.2e, normal off %.2e on %.2e, %d lowered\n", c.name,
                    ReconstructionMethodName(method), d, off.distance, on.distance, off.normal, on.normal, downgraded);
        EXPECT_EQ(downgraded, 0) << c.name << " d=" << d;
        EXPECT_LE(on.distance, 1.5 * off.distance) << c.name << " d=" << d;
        EXPECT_LE(on.normal, 1.5 * off.normal) << c.name << " d=" << d;
      }
}

TEST(FacePointTest, RejectsPointsOutsideFacesAndBadFaces) {
  GeneratorOptions g;
  g.n = 4;
  const Mesh mesh = GenerateTorusMesh(g);
  EXPECT_TRUE(ValidateFacePoint(mesh, {0, 0.2, 0.3}, 0).ok());
  EXPECT_THAT(ValidateFacePoint(mesh, {0, 0.8, 0.3}, 5).message(), testing::HasSubstr("point 5"));
  EXPECT_THAT(ValidateFacePoint(mesh, {mesh.NumFaces(), 0.1, 0.1}, 2).message(), testing::HasSubstr("face"));
  EXPECT_FALSE(ValidateFacePoint(mesh, {-1, 0.1, 0.1}, 0).ok());
  EXPECT_FALSE(ValidateFacePoint(mesh, {0, NAN, 0.1}, 0).ok());
  std::vector<SurfacePoint> out;
  LinearSurface linear(mesh);
  EXPECT_EQ(EvaluatePoints(linear, {{0, 0.1, 0.1}, {0, -0.5, 0.1}}, &out).code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace geomfit
