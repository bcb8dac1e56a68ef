#pragma once
#include <cstdint>
#include <memory>
#include <string>

#include <Eigen/Core>

#include "absl/status/statusor.h"
#include "core/mesh/mesh.h"

namespace geomfit {

/// Exact differential geometry of an analytic surface at a point on it, with the
/// project's conventions (outward / upward normal; H = +1/R on a sphere; k1 >= k2).
struct ExactDifferentials {
  Eigen::Vector3d normal;
  double mean, gaussian, k1, k2;
  Eigen::Vector3d e1, e2;  ///< principal directions (zero where umbilic / undefined)
};

/// An analytic surface that test meshes are generated on and measured against.
class AnalyticSurface {
 public:
  virtual ~AnalyticSurface() = default;
  virtual std::string Name() const = 0;
  /// Exact quantities at a point on the surface.
  virtual ExactDifferentials At(const Eigen::Vector3d& p) const = 0;
  /// Closest point on the surface (used to put noisy or refined points back on it).
  virtual Eigen::Vector3d Project(const Eigen::Vector3d& p) const = 0;
};

std::unique_ptr<AnalyticSurface> MakeSphere(double radius = 1.0);
std::unique_ptr<AnalyticSurface> MakeTorus(double R = 1.0, double r = 0.3);
std::unique_ptr<AnalyticSurface> MakeEllipsoid(double a, double b, double c);
/// z = exp(-81/16 ((x-.5)^2 + (y-.5)^2)) over [0,1]^2, the open surface of (3.3.2).
std::unique_ptr<AnalyticSurface> MakeGaussianBump();

/// Mesh generators. `n` sets the resolution (h ~ 1/n: doubling n halves h). Vertices
/// lie exactly on the surface; connectivity is irregular (each grid cell is split
/// along a random diagonal, valences 4..8) and vertices are jittered along the
/// surface by up to `jitter` x the local spacing, reproducibly from `seed`.
struct GeneratorOptions {
  int n = 16;
  double jitter = 0.25;
  uint64_t seed = 1;
  bool quads = false;  ///< keep grid cells as quads (torus and graph only)
};
Mesh GenerateSphereMesh(const GeneratorOptions& o, double radius = 1.0);  ///< cubed sphere, 6 n^2 cells
Mesh GenerateTorusMesh(const GeneratorOptions& o, double R = 1.0, double r = 0.3);  ///< 3n x n cells
Mesh GenerateEllipsoidMesh(const GeneratorOptions& o, double a, double b, double c);
Mesh GenerateBumpMesh(const GeneratorOptions& o);  ///< open graph over [0,1]^2, n x n cells

/// The open cylinder x^2 + y^2 = radius^2, |z| <= 1: 4n x 2n jittered cells (membranes, 6.3.7).
Mesh GenerateOpenCylinderMesh(const GeneratorOptions& o, double radius = 1.0);
/// The faces of the cubed sphere whose centroids have z > 0 (an open half sphere with a
/// jagged rim), vertices renumbered.
Mesh GenerateHemisphereMesh(const GeneratorOptions& o, double radius = 1.0);

/// An unstructured sphere of exactly `vertices` vertices (e.g. the text's 368 / 1450 /
/// 5804, §5.4): the convex hull, i.e. the spherical Delaunay triangulation, of the
/// golden-angle (Fibonacci) spiral, whose near-equilateral triangles (valences 5-7) are
/// what advancing-front and Delaunay meshers give. Each point is first moved along the
/// sphere by up to `jitter` x the spacing (seeded), then the hull is taken.
Mesh GenerateDelaunaySphereMesh(int vertices, double jitter = 0, uint64_t seed = 1, double radius = 1.0);

/// A closed cylinder x^2 + y^2 = 1, |z| <= 1, with flat caps: sharp circular edges
/// (4.1.4). 4n segments around, 2n rows on the side, n rings per cap.
Mesh GenerateCylinderMesh(int n);
/// Distance from p to that closed cylinder.
double CylinderDistance(const Eigen::Vector3d& p);

/// Generates by name: sphere, torus, ellipsoid (axes 1, 0.8, 0.6), bump, quadtorus,
/// cylinder (sharp rims; no jitter).
absl::StatusOr<Mesh> GenerateNamedMesh(const std::string& name, const GeneratorOptions& o);
/// The analytic surface of a named mesh (same names).
absl::StatusOr<std::unique_ptr<AnalyticSurface>> NamedSurface(const std::string& name);

/// `mesh` with every vertex moved along the surface normal by alpha_v h^power (h the
/// average edge length), alpha_v a Gaussian of standard deviation `alpha` / 2 clipped to
/// [-alpha, alpha] (the controlled-noise tests of 3.3; Figs 3.18-3.21 use alpha = 0.1
/// and power 2 or 3). Deterministic for a seed.
Mesh PerturbAlongNormals(const Mesh& mesh, const AnalyticSurface& surface, double alpha, int power,
                         uint64_t seed = 7);

/// Average edge length (the h of convergence studies).
double AverageEdgeLength(const Mesh& mesh);

}  // namespace geomfit
