#include "core/surfaces/errors.h"

#include <cmath>

namespace geomfit {
namespace {

// Accumulates one scalar quantity's relative error norms.
struct ScalarAccumulator {
  double err2 = 0, ref2 = 0, errmax = 0, refmax = 0;
  void Add(double got, double want) {
    const double e = std::abs(got - want);
    err2 += e * e;
    ref2 += want * want;
    errmax = std::max(errmax, std::isfinite(e) ? e : HUGE_VAL);
    refmax = std::max(refmax, std::abs(want));
  }
  ErrorNorms Norms() const {
    return {ref2 > 0 ? std::sqrt(err2 / ref2) : std::sqrt(err2), refmax > 0 ? errmax / refmax : errmax};
  }
};

}  // namespace

DifferentialErrors MeasureErrors(const Mesh& mesh, const AnalyticSurface& surface,
                                 const Differentials& d, const std::vector<uint8_t>& mask) {
  DifferentialErrors out;
  out.h = AverageEdgeLength(mesh);
  ScalarAccumulator mean, gauss, k1, k2;
  double n2 = 0, nmax = 0;
  int count = 0;
  for (int v = 0; v < mesh.NumVertices(); ++v) {
    if (!mask.empty() && !mask[v]) continue;
    const ExactDifferentials e = surface.At(mesh.positions.row(v).transpose());
    const double en = (d.normals.row(v).transpose() - e.normal).norm();
    n2 += en * en;
    nmax = std::max(nmax, std::isfinite(en) ? en : HUGE_VAL);
    ++count;
    mean.Add(d.mean(v), e.mean);
    gauss.Add(d.gaussian(v), e.gaussian);
    k1.Add(d.k1(v), e.k1);
    k2.Add(d.k2(v), e.k2);
  }
  out.normal = {count ? std::sqrt(n2 / count) : 0, nmax};
  out.mean = mean.Norms();
  out.gaussian = gauss.Norms();
  out.k1 = k1.Norms();
  out.k2 = k2.Norms();
  return out;
}

double ConvergenceOrder(const std::vector<double>& h, const std::vector<double>& err) {
  const size_t n = std::min(h.size(), err.size());
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  for (size_t i = 0; i < n; ++i) {
    const double x = std::log(h[i]), y = std::log(err[i]);
    sx += x, sy += y, sxx += x * x, sxy += x * y;
  }
  return (n * sxy - sx * sy) / (n * sxx - sx * sx);
}

}  // namespace geomfit
