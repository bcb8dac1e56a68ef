#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "absl/status/status.h"
#include "core/fitting/fit.h"
#include "core/mesh/topology.h"
#include "core/reconstruction/options.h"

namespace geomfit {

/// A point of a face by natural coordinates. Triangles: shape functions
/// N = (1 - xi - eta, xi, eta) with xi, eta >= 0, xi + eta <= 1. Quads: bilinear
/// N = ((1-xi)(1-eta), xi(1-eta), xi eta, (1-xi) eta) with xi, eta in [0, 1].
struct FacePoint {
  int32_t face = 0;
  double xi = 0, eta = 0;
};

/// Shape functions of the face at (xi, eta) and their derivatives; returns the count.
int ShapeFunctions(const Mesh& mesh, int face, double xi, double eta, double N[4], double dNdxi[4],
                   double dNdeta[4]);

/// OK, or INVALID_ARGUMENT naming point `index`: face out of range, coordinates
/// non-finite or outside the face (tolerance 1e-9).
absl::Status ValidateFacePoint(const Mesh& mesh, const FacePoint& p, int64_t index);

/// A point of a reconstructed surface with its unit normal and its Jacobian with
/// respect to the face's natural coordinates (columns d/dxi, d/deta).
struct SurfacePoint {
  Eigen::Vector3d position;
  Eigen::Vector3d normal;
  Eigen::Matrix<double, 3, 2> jacobian;
};

/// A continuous surface defined over the faces of a mesh (chapter 4).
class ReconstructedSurface {
 public:
  virtual ~ReconstructedSurface() = default;
  virtual SurfacePoint Evaluate(const FacePoint& p) const = 0;
  virtual const Mesh& mesh() const = 0;
};

/// The piecewise linear (bilinear for quads) surface: the baseline.
class LinearSurface final : public ReconstructedSurface {
 public:
  explicit LinearSurface(const Mesh& mesh) : mesh_(mesh) {}
  SurfacePoint Evaluate(const FacePoint& p) const override;
  const Mesh& mesh() const override { return mesh_; }

 private:
  const Mesh& mesh_;
};

/// WALF, weighted averaging of local fittings (4.1.1, 4.3.11-4.3.12): the vertex fits,
/// each evaluated at the projection of the linear point onto its frame, blended with
/// the shape functions; normals blended likewise. Holds the fits (cheap to evaluate).
class WalfSurface final : public ReconstructedSurface {
 public:
  WalfSurface(const Mesh& mesh, std::shared_ptr<const SurfaceFits> fits) : mesh_(mesh), fits_(std::move(fits)) {}
  SurfacePoint Evaluate(const FacePoint& p) const override;
  const Mesh& mesh() const override { return mesh_; }
  const SurfaceFits& fits() const { return *fits_; }

 private:
  const Mesh& mesh_;
  std::shared_ptr<const SurfaceFits> fits_;
};

/// CMF, continuous moving frames (4.1.2): at each point a fresh weighted fit in the
/// frame of the blended vertex normal (4.1.6), over the union of the face's vertex
/// stencils with weights (4.1.8)-(4.1.9). Vertex normals come from the vertex fits.
class CmfSurface final : public ReconstructedSurface {
 public:
  CmfSurface(const Mesh& mesh, std::shared_ptr<const SurfaceFits> fits, int threads = 0);
  SurfacePoint Evaluate(const FacePoint& p) const override;
  const Mesh& mesh() const override { return mesh_; }

 private:
  const Mesh& mesh_;
  std::shared_ptr<const SurfaceFits> fits_;
  Positions normals_;  // fitted vertex normals
};


/// Builds the surface of `method` over fits of the mesh (ignored for kLinear).
/// `threads`: for the CMF surface's vertex normals.
std::unique_ptr<ReconstructedSurface> MakeSurface(ReconstructionMethod method, const Mesh& mesh,
                                                  std::shared_ptr<const SurfaceFits> fits, int threads = 0);

/// `per_face` uniformly random points in every face, reproducible from `seed`.
std::vector<FacePoint> RandomFacePoints(const Mesh& mesh, int per_face, uint64_t seed);

/// Evaluates many points in parallel (after validating every one), polling `ctx`
/// (progress phase "evaluate points").
absl::Status EvaluatePoints(const ReconstructedSurface& surface, const std::vector<FacePoint>& points,
                            std::vector<SurfacePoint>* out, const RunContext& ctx = {});

}  // namespace geomfit
