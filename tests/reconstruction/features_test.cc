// Sharp features (4.1.4): detection, virtual splitting, ridge curves, and refinement
// that keeps a cylinder's sharp rims and flat caps.
#include <cstdio>

#include <gtest/gtest.h>

#include "core/reconstruction/features.h"
#include "core/reconstruction/meshing.h"
#include "core/surfaces/analytic.h"
#include "core/surfaces/errors.h"

namespace geomfit {
namespace {

TEST(FeaturesTest, CylinderRimsAreTwoClosedRidgeCurves) {
  const int n = 4;
  const Mesh mesh = GenerateCylinderMesh(n);
  const Topology topo = ValidateMesh(mesh).value();
  EXPECT_EQ(topo.num_boundary_edges, 0);
  const Features f = DetectFeatures(mesh, topo, FeatureOptions()).value();
  EXPECT_EQ(static_cast<int>(f.edges.size()), 2 * 4 * n);
  ASSERT_EQ(f.curves.size(), 2u);
  for (const auto& c : f.curves) {
    EXPECT_EQ(static_cast<int>(c.size()), 4 * n + 1);
    EXPECT_EQ(c.front(), c.back());
  }
  // The split mesh duplicates every rim vertex once and cuts the mesh along the rims.
  EXPECT_EQ(f.split.NumVertices(), mesh.NumVertices() + 2 * 4 * n);
  const Topology split = ValidateMesh(f.split).value();
  EXPECT_EQ(split.num_boundary_edges, 2 * 2 * 4 * n);
  for (int v = mesh.NumVertices(); v < f.split.NumVertices(); ++v)
    EXPECT_EQ(f.split.positions.row(v), mesh.positions.row(f.split_to_original[v]));
}

TEST(FeaturesTest, MarkedEdgesAndBadInput) {
  GeneratorOptions g;
  g.n = 24;
  const Mesh mesh = GenerateTorusMesh(g);
  const Topology topo = BuildTopology(mesh).value();
  FeatureOptions o;
  EXPECT_TRUE(DetectFeatures(mesh, topo, o).value().edges.empty());  // smooth
  o.marked = {{mesh.faces(0, 0), mesh.faces(0, 1)}};
  EXPECT_EQ(DetectFeatures(mesh, topo, o).value().edges.size(), 1u);
  o.marked = {{0, mesh.NumVertices() / 2}};
  EXPECT_EQ(DetectFeatures(mesh, topo, o).status().code(), absl::StatusCode::kInvalidArgument);
  o.marked.clear();
  o.angle_deg = 0;
  EXPECT_EQ(DetectFeatures(mesh, topo, o).status().code(), absl::StatusCode::kInvalidArgument);
}

// Refined with features, vertices stay on the cylinder (caps exactly flat, rims on the
// circle to high order); without, the fits straddle the rims and round them off.
TEST(FeaturesTest, RefinementKeepsSharpEdges) {
  std::vector<double> h, with, rim_err;
  for (int n : {4, 8, 16}) {
    const Mesh mesh = GenerateCylinderMesh(n);
    const Topology topo = BuildTopology(mesh).value();
    auto features = std::make_shared<Features>(DetectFeatures(mesh, topo, FeatureOptions()).value());
    FitOptions o;
    o.degree = 3;
    const Topology split_topo = BuildTopology(features->split).value();
    auto fits = FitSurface(features->split, split_topo, o).value();
    FeatureSurface surface(mesh, features, MakeSurface(ReconstructionMethod::kWalf, features->split, fits), o.degree);
    const Mesh refined = RefineMesh(surface, topo, 2).value();
    ASSERT_TRUE(ValidateMesh(refined).ok());
    double worst = 0, rim = 0, cap = 0;
    for (int v = 0; v < refined.NumVertices(); ++v) {
      const Eigen::Vector3d p = refined.positions.row(v).transpose();
      worst = std::max(worst, CylinderDistance(p));
      if (std::abs(std::abs(p.z()) - 1) < 1e-9 && std::hypot(p.x(), p.y()) > 1 - 0.25 / n) rim = std::max(rim, std::abs(std::hypot(p.x(), p.y()) - 1));
      if (std::hypot(p.x(), p.y()) < 0.99 && std::abs(p.z()) > 0.5) cap = std::max(cap, std::abs(std::abs(p.z()) - 1));
    }
    EXPECT_LT(cap, 1e-12) << "cap vertices must stay on the plane";
    h.push_back(AverageEdgeLength(mesh));
    with.push_back(worst);
    rim_err.push_back(rim);

    // The same refinement without features rounds the rims off.
    auto smooth_fits = FitSurface(mesh, topo, o).value();
    WalfSurface smooth(mesh, smooth_fits);
    const Mesh rounded = RefineMesh(smooth, topo, 2).value();
    double smooth_worst = 0;
    for (int v = 0; v < rounded.NumVertices(); ++v)
      smooth_worst = std::max(smooth_worst, CylinderDistance(rounded.positions.row(v).transpose()));
    std::printf("n=%d: with features %.2e (rim %.2e), without %.2e\n", n, worst, rim, smooth_worst);
    EXPECT_GT(smooth_worst, 10 * worst);
  }
  EXPECT_GE(ConvergenceOrder(h, with), 3.5);     // degree-3 curve and surface fits: O(h^4)
  // The rim's order from the resolved levels: at n = 4 (16 nodes per rim) the ridge-curve
  // windows stop at 60 degrees of arc, which brought that level's rim error from 9.2e-3
  // to 2.1e-3 (it no longer reads as the start of an O(h^4) sequence).
  EXPECT_LT(rim_err[0], 3e-3);
  EXPECT_GE(ConvergenceOrder({h[1], h[2]}, {rim_err[1], rim_err[2]}), 3.5);
}

// Inside faces along a ridge the feature surface follows the ridge curve (a curved-edge
// map), so interior points of rim faces converge to the cylinder like the rest, and its
// Jacobian is the derivative of its positions (what integration uses, 4.3).
TEST(FeaturesTest, RimFacesFollowTheRidgeWithConsistentJacobians) {
  std::vector<double> h, err;
  for (int n : {4, 8, 16, 32}) {
    const Mesh mesh = GenerateCylinderMesh(n);
    const Topology topo = BuildTopology(mesh).value();
    auto features = std::make_shared<Features>(DetectFeatures(mesh, topo, FeatureOptions()).value());
    FitOptions o;
    o.degree = 3;
    const Topology split_topo = BuildTopology(features->split).value();
    auto fits = FitSurface(features->split, split_topo, o).value();
    FeatureSurface surface(mesh, features, MakeSurface(ReconstructionMethod::kWalf, features->split, fits), o.degree);
    double worst = 0, jac = 0;
    for (const FacePoint& p : RandomFacePoints(mesh, 6, 7)) {
      bool rim_face = false;
      for (int c = 0; c < 3; ++c) rim_face |= features->IsFeature(mesh.faces(p.face, c), mesh.faces(p.face, (c + 1) % 3));
      if (!rim_face) continue;
      const SurfacePoint s = surface.Evaluate(p);
      worst = std::max(worst, CylinderDistance(s.position));
      const double eps = 1e-6;
      for (int k = 0; k < 2; ++k) {  // central differences, kept inside the triangle
        FacePoint a = p, b = p;
        (k == 0 ? a.xi : a.eta) -= eps;
        (k == 0 ? b.xi : b.eta) += eps;
        if (a.xi < 0 || a.eta < 0 || b.xi + b.eta > 1) continue;
        const Eigen::Vector3d fd = (surface.Evaluate(b).position - surface.Evaluate(a).position) / (2 * eps);
        jac = std::max(jac, (fd - s.jacobian.col(k)).norm() / s.jacobian.col(k).norm());
      }
    }
    std::printf("n=%d: rim faces' interior points within %.2e of the cylinder; Jacobian vs FD %.1e\n", n, worst, jac);
    EXPECT_LT(jac, 1e-6);
    // 16 nodes on each rim: the ridge-curve windows stop at 60 degrees of arc (they
    // spanned 90 and missed the rim by 8.5e-3).
    if (n == 4) EXPECT_LT(worst, 3e-3);
    if (n == 4) continue;  // the order from the resolved levels
    h.push_back(AverageEdgeLength(mesh));
    err.push_back(worst);
  }
  EXPECT_GE(ConvergenceOrder(h, err), 3.5);  // degree 3: O(h^4); the flat chord would be O(h^2)
}

}  // namespace
}  // namespace geomfit
