#pragma once
// CGAL Jet_fitting_3 (CGAL::Monge_via_jet_fitting, d_fitting = d, d_monge = 2) on given
// stencils, converted to the project's conventions: shared by cgal_compare and noise_study.
//
// CGAL's Monge form z = (k1 x^2 + k2 y^2)/2 + ... lives in the direct frame (d1, d2, n)
// whose normal n is oriented by its PCA. We orient it like `orient` (comply_wrt_given_normal,
// which also swaps/negates the coefficients) and convert (H = +1/R on a sphere with outward
// normals): a surface bending away from n has negative Monge curvatures, so
// k1 = -k2_cgal, k2 = -k1_cgal, H = (k1 + k2)/2, K = k1 k2.
#include <algorithm>
#include <cmath>
#include <vector>

#include <CGAL/Monge_via_jet_fitting.h>
#include <CGAL/Simple_cartesian.h>

#include "core/fitting/neighborhood.h"
#include "core/quantities/differentials.h"

namespace geomfit {

using CgalKernel = CGAL::Simple_cartesian<double>;
using CgalMongeVia = CGAL::Monge_via_jet_fitting<CgalKernel>;

/// Normals, H, K, k1, k2 of CGAL's jet fits of every vertex over `nb`'s stencils; vertices
/// with fewer points than coefficients (CGAL's precondition) get NaN and count in *too_few.
inline Differentials CgalDifferentials(const Mesh& mesh, const Neighborhoods& nb, int degree,
                                const Positions& orient, int* too_few) {
  const int nv = mesh.NumVertices();
  Differentials d;
  d.normals.resize(nv, 3);
  d.mean.resize(nv), d.gaussian.resize(nv), d.k1.resize(nv), d.k2.resize(nv);
  int few = 0;
#pragma omp parallel reduction(+ : few)
  {
    CgalMongeVia fitter;
    std::vector<CgalKernel::Point_3> pts;
#pragma omp for schedule(dynamic, 64)
    for (int v = 0; v < nv; ++v) {
      pts.clear();
      for (int i = 0; i < nb.Size(v); ++i) {
        const auto p = mesh.positions.row(nb.Points(v)[i]);
        pts.emplace_back(p(0), p(1), p(2));
      }
      if (static_cast<int>(pts.size()) < NumCoefficients(degree)) {  // CGAL precondition
        ++few;
        d.normals.row(v).setConstant(NAN);
        d.mean(v) = d.gaussian(v) = d.k1(v) = d.k2(v) = NAN;
        continue;
      }
      // CGAL's precondition d_monge <= d_fitting: a degree-1 jet has a normal only (with
      // d_monge = 2 CGAL read the curvature coefficients past the degree-1 solution).
      const int monge = std::min(degree, 2);
      CgalMongeVia::Monge_form m = fitter(pts.begin(), pts.end(), degree, monge);
      m.comply_wrt_given_normal(CgalKernel::Vector_3(orient(v, 0), orient(v, 1), orient(v, 2)));
      const auto n = m.normal_direction();
      d.normals.row(v) << n.x(), n.y(), n.z();
      d.normals.row(v).normalize();
      if (monge < 2) {
        d.mean(v) = d.gaussian(v) = d.k1(v) = d.k2(v) = NAN;
        continue;
      }
      const double c1 = m.principal_curvatures(0), c2 = m.principal_curvatures(1);
      d.k1(v) = std::max(-c1, -c2);
      d.k2(v) = std::min(-c1, -c2);
      d.mean(v) = 0.5 * (d.k1(v) + d.k2(v));
      d.gaussian(v) = d.k1(v) * d.k2(v);
    }
  }
  *too_few = few;
  return d;
}

}  // namespace geomfit
