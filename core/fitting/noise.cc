#include "core/fitting/noise.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "core/fitting/wls.h"
#include "core/surfaces/analytic.h"
#include "core/util/parallel.h"

namespace geomfit {

Positions ProjectOntoFits(const SurfaceFits& fits, const Positions& positions, int num_threads,
                          const double* step) {
  Positions out = positions;
  ParallelFor(fits.num_vertices(), num_threads, [&](int64_t v) {
    if (fits.diagnostics(static_cast<int>(v)).degree_used < 1) return;
    const Eigen::Vector3d x = fits.Jet(static_cast<int>(v)).x;
    if (!step) out.row(v) = x.transpose();
    else if (step[v] != 0) out.row(v) += step[v] * (x.transpose() - positions.row(v));
  });
  return out;
}

bool SmoothingBiasDominates(const Positions& before, const Positions& after, const Mesh& mesh, double noise_over_h) {
  const int n = static_cast<int>(before.rows());
  const double noise = noise_over_h * AverageEdgeLength(mesh);
  if (n == 0 || !(noise > 0)) return false;
  std::vector<double> moved(n);
  for (int v = 0; v < n; ++v) moved[v] = (after.row(v) - before.row(v)).norm();
  const auto q90 = moved.begin() + n * 9 / 10, q50 = moved.begin() + n / 2;
  std::nth_element(moved.begin(), q90, moved.end());
  std::nth_element(moved.begin(), q50, q90);
  return *q90 > kSmoothingBiasQuantile90 * noise && *q90 > kSmoothingBiasSpread * *q50;
}

NoiseSchedule NoiseScheduleFor(int degree, double residual_ratio, double cubic_ratio) {
  // Degree 2: noise below the cubic fits' truncation (a sphere's) gets the slope tier (noise.h).
  const bool symmetric = degree == 2 && residual_ratio >= kModerateNoiseResidualRatio && cubic_ratio < kHeavyNoiseCubicRatio;
  if (symmetric) residual_ratio = 0;
  NoiseSchedule s;
  if (residual_ratio >= kHeavyNoiseResidualRatio) {
    s.smoothing_degree = 3;
    s.final_weight_epsilon = degree >= 4 ? kNoiseWeightEpsilon : 0.01;
    s.final_clean_stencils = degree == 3 && residual_ratio < kVeryHeavyNoiseResidualRatio;
    if (degree >= 3 && residual_ratio < kModerateNoiseResidualRatio)
      s.smoothing_degree = std::min(degree + 2, 5), s.smoothing_passes = 4, s.cubic_near_boundary = true;
    if (residual_ratio >= kVeryHeavyNoiseResidualRatio) s.smoothing_passes = 3, s.local_passes = 1;
  } else {
    s.smoothing_degree = std::min(degree + 2, 5);
    s.final_clean_stencils = true;
    if (degree >= 4) s.final_weight_epsilon = 0.1, s.final_points_factor = 2;
    if (degree == 3) s.final_rings = 1.5, s.final_points_factor = 1;
    if (degree >= 3 && residual_ratio >= kLocalSmoothingResidualRatio) s.local_passes = 2;
  }
  if (degree == 2 && residual_ratio >= kModerateNoiseResidualRatio) s.normal_points_factor = kHeavyNoiseNormalPointsFactor;
  if (degree == 3 && residual_ratio >= kModerateNoiseResidualRatio)  // noise.h, TwoScaleFinalFit
    s.final_clean_stencils = s.two_scale_final = s.curvature_steps = true, s.smoothing_passes = 2,
    s.local_passes = residual_ratio >= kVeryHeavyNoiseResidualRatio ? kVeryHeavyCurvatureLocalPasses
                                                                    : kCurvatureLocalPasses;
  if (degree >= 4 && residual_ratio >= kModerateNoiseResidualRatio)  // noise.h, kCurvatureLocalPasses
    s.curvature_steps = true, s.local_passes = kCurvatureLocalPasses;
  if (degree == 3 && s.final_rings > 0) s.two_scale_final = true;  // light: noise.h, TwoScaleFinalFit
  if (degree >= 4 && residual_ratio >= kHeavyNoiseResidualRatio && residual_ratio < kModerateNoiseResidualRatio)
    s.final_clean_stencils = s.two_scale_final = true, s.final_points_factor = kModerateNoiseFinalPointsFactor;
  if (degree >= 3 && residual_ratio >= kModerateNoiseResidualRatio) s.unshrink_passes = kUnshrinkPasses;
  if ((degree == 3 || degree == 4) && residual_ratio < kLocalSmoothingResidualRatio) {  // nearly clean, noise.h
    s.smoothing_degree_high = kMaxDegree, s.local_passes = kNearlyCleanLocalPasses;
    if (degree == 4)
      s.final_interpolates = true, s.final_rings = (degree + 1) / 2.0, s.final_points_factor = 1.5,
      s.tangent_weight_epsilon = kNearlyCleanTangentEpsilon;
    if (degree == 3)  // the default fit on the smoothed mesh (noise.h, hermite_final)
      s.hermite_final = true, s.final_rings = 0, s.final_points_factor = 0, s.two_scale_final = false;
  }
  if (degree == 2 && residual_ratio < kSlopeRefinementResidualRatio)  // noise.h, slope_passes
    s.smoothing_degree = 5, s.slope_passes = kNoiseSlopePasses;
  if (symmetric) s.smoothing_passes = kSymmetricSmoothingPasses;
  return s;
}

double NoiseSmoothingPointsFactor(const NoiseEstimate& est, int degree, int smoothing_degree) {
  if (degree != 2 || smoothing_degree != 3 || !(est.curvature_h > 0) || !(est.noise_over_h > 0)) return 0;
  const double q = est.noise_over_h / (est.curvature_h * est.curvature_h);  // (R / h)^4, up to a constant
  const double f = std::min(kGrownSmoothingPointsScale * std::sqrt(q),
                            static_cast<double>(kMaxStencil) / NumCoefficients(smoothing_degree));
  FitOptions noise;
  noise.noise = NoiseMode::kOn;
  return f > noise.MinPointsFactor() ? f : 0;  // the noise mode's own factor (3) otherwise
}

FitOptions NoiseSmoothingOptions(const FitOptions& options, const NoiseSchedule& schedule) {
  FitOptions o = options;
  o.noise = NoiseMode::kOn;
  o.interpolate = false;
  o.weight_epsilon = kNoiseWeightEpsilon;
  o.degree = schedule.smoothing_degree;
  o.rings = o.min_points_factor = 0;
  o.normal_degree = 0;
  o.two_pass = false;
  return o;
}

Positions BlendFootPoints(const SurfaceFits& low, const SurfaceFits& high, const Positions& positions,
                          const Mesh& mesh, double noise_over_h, double spread, const double* step, int num_threads) {
  Positions out = positions;
  const double tau = spread * noise_over_h * AverageEdgeLength(mesh);
  ParallelFor(low.num_vertices(), num_threads, [&](int64_t v) {
    const int i = static_cast<int>(v);
    const bool has_low = low.diagnostics(i).degree_used >= 1, has_high = high.diagnostics(i).degree_used >= 1;
    if (!has_low && !has_high) return;
    Eigen::Vector3d x;
    if (!has_low || !has_high) {
      x = (has_high ? high : low).Jet(i).x;
    } else {
      const Eigen::Vector3d xl = low.Jet(i).x, xh = high.Jet(i).x;
      const double d = (xh - xl).norm();
      const double w = d == 0 ? 0 : tau > 0 ? d * d / (d * d + tau * tau) : 1;
      x = xl + w * (xh - xl);
    }
    if (!step) out.row(v) = x.transpose();
    else if (step[v] != 0) out.row(v) += step[v] * (x.transpose() - positions.row(v));
  });
  return out;
}

std::vector<double> LocalSmoothingSteps(const SurfaceFits& fits, const Mesh& mesh, double noise_over_h,
                                        int num_threads) {
  const double h = AverageEdgeLength(mesh), noise = noise_over_h * h;
  std::vector<double> out(fits.num_vertices(), 0);
  if (fits.dims() != 1 || !(noise > 0)) return out;
  ParallelFor(fits.num_vertices(), num_threads, [&](int64_t v) {
    const int p = fits.diagnostics(static_cast<int>(v)).degree_used;
    if (p < 1) return;
    const double* c = fits.coefficients(static_cast<int>(v));
    double sum = 0, fjk = std::tgamma(p + 1.0);  // j! k! for j = p - k
    for (int k = 0; k <= p; ++k) {
      if (k > 0) fjk = fjk / (p - k + 1) * k;
      const double a = c[TaylorIndex(p - k, k)] / fjk;
      sum += a * a;
    }
    const double q = std::sqrt(sum) * std::pow(h, p) / (kLocalSmoothingSignal * noise);
    out[v] = 1 / (1 + q * q);
  });
  return out;
}

void BlendLargeStencilNormals(const SurfaceFits& large, const std::vector<uint8_t>& adopted, Positions* normals,
                              int num_threads) {
  const int nv = large.num_vertices();
  Positions nl = *normals;
  std::vector<double> d(nv, -1);
  ParallelFor(nv, num_threads, [&](int64_t v) {
    if (!adopted[v] || large.diagnostics(static_cast<int>(v)).degree_used < 1) return;
    const SurfaceJet jet = large.Jet(static_cast<int>(v));
    Eigen::Vector3d n = jet.J.col(0).cross(jet.J.col(1));
    if (n.dot(normals->row(v)) < 0) n = -n;
    if (n.norm() == 0) return;
    nl.row(v) = n.normalized().transpose();
    d[v] = (nl.row(v) - normals->row(v)).norm();
  });
  std::vector<double> x;
  for (double a : d)
    if (a >= 0) x.push_back(a);
  if (x.empty()) return;
  std::nth_element(x.begin(), x.begin() + x.size() / 2, x.end());
  const double tau = kNormalBlendSpread * x[x.size() / 2];
  ParallelFor(nv, num_threads, [&](int64_t v) {
    if (d[v] < 0) return;
    const double w = tau > 0 ? 1 / (1 + (d[v] / tau) * (d[v] / tau)) : 1;
    const Eigen::Vector3d n = w * nl.row(v).transpose() + (1 - w) * normals->row(v).transpose();
    normals->row(v) = n.normalized().transpose();
  });
}

namespace {

// |Hessian| of an LHF fit (-1 where unfitted or below degree 2).
double HessianNorm(const SurfaceFits& fits, int v) {
  if (fits.diagnostics(v).degree_used < 2) return -1;
  const double* a = fits.coefficients(v);
  const double uu = a[TaylorIndex(2, 0)], uv = a[TaylorIndex(1, 1)], vv = a[TaylorIndex(0, 2)];
  return std::sqrt(uu * uu + 2 * uv * uv + vv * vv);
}

// 1 / (1 + (x / (spread x median x))^2) per entry, 0 where x < 0.
std::vector<double> RelativeWeights(std::vector<double> x, double spread) {
  std::vector<double> y;
  for (double a : x)
    if (a >= 0) y.push_back(a);
  if (y.empty()) return std::vector<double>(x.size(), 0);
  std::nth_element(y.begin(), y.begin() + y.size() / 2, y.end());
  const double tau = spread * y[y.size() / 2];
  for (double& a : x) a = a < 0 ? 0 : tau > 0 ? 1 / (1 + (a / tau) * (a / tau)) : 1;
  return x;
}

}  // namespace

std::vector<double> CurvatureSmoothingSteps(const SurfaceFits& fits, double spread, int num_threads) {
  std::vector<double> c(fits.num_vertices(), -1);
  if (fits.dims() != 1) return std::vector<double>(c.size(), 0);
  ParallelFor(fits.num_vertices(), num_threads, [&](int64_t v) { c[v] = HessianNorm(fits, static_cast<int>(v)); });
  return RelativeWeights(std::move(c), spread);
}

std::vector<double> UnshrinkSteps(const SurfaceFits& fits, int num_threads) {
  std::vector<double> w = CurvatureSmoothingSteps(fits, kUnshrinkSpread, num_threads);
  ParallelFor(fits.num_vertices(), num_threads, [&](int64_t v) {
    w[v] = fits.diagnostics(static_cast<int>(v)).degree_used < 2 ? 0 : -kUnshrinkStep * (1 - w[v]);
  });
  return w;
}

void TwoScaleFinalFit(const SurfaceFits& own, const SurfaceFits& other, const Neighborhoods& other_nb,
                      double spread, double* coefficients, int num_threads) {
  const int nv = own.num_vertices(), nc = own.num_coefficients();
  if (own.dims() != 1 || other.dims() != 1) return;
  // D = other - own, orders 0-2 in ambient form: offset along the normal, gradient vector, Hessian tensor.
  struct Diff {
    double d0 = 0;
    Eigen::Vector3d d1 = Eigen::Vector3d::Zero();
    Eigen::Matrix3d d2 = Eigen::Matrix3d::Zero();
    bool ok = false;
  };
  std::vector<Diff> diff(nv);
  std::vector<double> hess(nv, -1);
  const int i00 = TaylorIndex(0, 0), i10 = TaylorIndex(1, 0), i01 = TaylorIndex(0, 1), i20 = TaylorIndex(2, 0),
            i11 = TaylorIndex(1, 1), i02 = TaylorIndex(0, 2);
  ParallelFor(nv, num_threads, [&](int64_t v) {
    const int i = static_cast<int>(v);
    const LocalFrame &fr = own.frame(i), &fo = other.frame(i);
    if (own.diagnostics(i).degree_used < 2 || other.diagnostics(i).degree_used != own.diagnostics(i).degree_used ||
        fr.normal != fo.normal || fr.t1 != fo.t1 || fr.origin != fo.origin)
      return;
    const double *a = own.coefficients(i), *b = other.coefficients(i);
    Diff& e = diff[v];
    e.d0 = b[i00] - a[i00];
    e.d1 = (b[i10] - a[i10]) * fr.t1 + (b[i01] - a[i01]) * fr.t2;
    Eigen::Matrix<double, 3, 2> T;
    T << fr.t1, fr.t2;
    Eigen::Matrix2d h;
    h << b[i20] - a[i20], b[i11] - a[i11], b[i11] - a[i11], b[i02] - a[i02];
    e.d2 = T * h * T.transpose();
    e.ok = true;
    hess[v] = HessianNorm(own, i);
  });
  const std::vector<double> w = RelativeWeights(std::move(hess), spread);
  ParallelFor(nv, num_threads, [&](int64_t v) {
    const int i = static_cast<int>(v);
    if (!diff[v].ok) return;
    Diff m;  // S(D): the mean over the noise stencil
    int count = 0;
    for (int k = 0; k < other_nb.Size(i); ++k) {
      const Diff& e = diff[other_nb.Points(i)[k]];
      if (!e.ok) continue;
      m.d0 += e.d0, m.d1 += e.d1, m.d2 += e.d2, ++count;
    }
    if (count == 0) return;
    const Diff& d = diff[v];
    const double e0 = w[v] * (d.d0 - m.d0 / count);
    const Eigen::Vector3d e1 = w[v] * (d.d1 - m.d1 / count);
    const Eigen::Matrix3d e2 = w[v] * (d.d2 - m.d2 / count);
    const LocalFrame& fr = own.frame(i);
    double* a = coefficients + v * nc;
    a[i00] += e0;
    a[i10] += fr.t1.dot(e1), a[i01] += fr.t2.dot(e1);
    a[i20] += fr.t1.dot(e2 * fr.t1), a[i11] += fr.t1.dot(e2 * fr.t2), a[i02] += fr.t2.dot(e2 * fr.t2);
  });
}

namespace {

// rms of the residual of an approximating fit of `degree` (0 if it could not be solved);
// with `hessian`, also the fit's |Hessian|.
double ResidualRms(const WlsProblem& P, int degree, double* hessian = nullptr) {
  WlsSettings S;
  S.degree = degree;
  S.interpolate = false;
  S.weight_epsilon = 1;  // nearly flat weights: the residual of the whole stencil counts
  static constexpr double kNoCutoff[kMaxDegree + 1] = {0, 1e12, 1e12, 1e12, 1e12, 1e12, 1e12};
  S.cond_threshold = kNoCutoff;
  double c[kMaxCoefficients];
  const WlsSolution sol = SolveWls(P, S, c, nullptr);
  if (sol.degree_used != degree) return 0;
  if (hessian) {
    const double uu = c[TaylorIndex(2, 0)], uv = c[TaylorIndex(1, 1)], vv = c[TaylorIndex(0, 2)];
    *hessian = std::sqrt(uu * uu + 2 * uv * uv + vv * vv);
  }
  double sum = 0;
  for (int r = 0; r < P.rows; ++r) {
    double f;
    EvalTaylor(c, degree, P.u[r], P.v[r], &f, nullptr, nullptr);
    sum += (P.rhs[0][r] - f) * (P.rhs[0][r] - f);
  }
  return std::sqrt(sum / P.rows);
}

}  // namespace

RingSpec NoiseStencilSpec() {
  RingSpec spec;
  spec.rings = 2.5;
  spec.min_points = 40;
  spec.min_points_boundary = 40;
  spec.max_points = 80;
  return spec;
}

absl::StatusOr<NoiseEstimate> EstimateNoise(const Mesh& mesh, const Topology& topo, const Positions& normals,
                                            const RunContext& ctx, const Neighborhoods* all_stencils) {
  constexpr int kMaxSamples = 2000;
  const int nv = mesh.NumVertices();
  const int stride = std::max(1, nv / kMaxSamples);
  const int samples = (nv + stride - 1) / stride;
  std::vector<int32_t> sample(samples), rank;
  const bool by_source = static_cast<int>(topo.vertex_source.size()) == nv;  // relabelled: source indices
  if (by_source) {
    rank.resize(nv);
    for (int v = 0; v < nv; ++v) rank[topo.vertex_source[v]] = v;
  }
  for (int i = 0; i < samples; ++i) sample[i] = by_source ? rank[i * stride] : i * stride;
  // The sample's stencils alone (row i: sample[i]'s), or row v of every vertex's.
  const Neighborhoods own =
      all_stencils ? Neighborhoods{} : BuildNeighborhoodsOf(topo, mesh, NoiseStencilSpec(), sample, ctx.threads());
  std::vector<double> ratio(samples, -1), level(samples, -1), sextic(samples, -1), cubic(samples, -1),
      hess(samples, -1);
  const double h = AverageEdgeLength(mesh);
  absl::Status s = ParallelFor(samples, ctx, [&](int64_t i) {
    const int v = sample[i];
    const int row = all_stencils ? v : static_cast<int>(i);
    const Neighborhoods& nb = all_stencils ? *all_stencils : own;
    const Eigen::Vector3d m0 = normals.row(v).transpose();
    if (topo.is_boundary[v] || m0.squaredNorm() == 0 || nb.Size(row) < 30) return;
    const LocalFrame fr = FrameFromNormal(mesh.positions.row(v).transpose(), m0);
    WlsProblem P;
    P.rows = 0;
    for (int k = 0; k < nb.Size(row); ++k) {
      const int p = nb.Points(row)[k];
      if (normals.row(p).dot(m0) < 0.5) continue;  // folded parts of coarse stencils
      const Eigen::Vector3d d = mesh.positions.row(p).transpose() - fr.origin;
      P.u[P.rows] = d.dot(fr.t1);
      P.v[P.rows] = d.dot(fr.t2);
      P.gamma[P.rows] = 1;
      P.rhs[0][P.rows++] = d.dot(fr.normal);
    }
    if (P.rows < 30) return;
    double hq = 0;
    const double r2 = ResidualRms(P, 2, &hq), r4 = ResidualRms(P, 4);
    if (r2 > 0) ratio[i] = r4 / r2, level[i] = r4 / h, hess[i] = hq * h;
    const double r3 = ResidualRms(P, 3);
    if (r3 > 0) cubic[i] = r4 / r3;
    // The sextic's residual against the quartic's, both per remaining degree of freedom.
    constexpr int c4 = NumCoefficients(4), c6 = NumCoefficients(6);
    const double r6 = r4 > 0 && P.rows > c6 ? ResidualRms(P, 6) : 0;
    if (r6 > 0) sextic[i] = r6 / r4 * std::sqrt((P.rows - c4) / double(P.rows - c6));
  }, 64, "noise test");
  if (!s.ok()) return s;
  NoiseEstimate est;
  auto median = [](std::vector<double> x) {
    x.erase(std::remove_if(x.begin(), x.end(), [](double a) { return a < 0; }), x.end());
    if (x.empty()) return 0.0;
    std::nth_element(x.begin(), x.begin() + x.size() / 2, x.end());
    return x[x.size() / 2];
  };
  est.samples = static_cast<int>(std::count_if(ratio.begin(), ratio.end(), [](double a) { return a >= 0; }));
  est.residual_ratio = median(ratio);
  est.noise_over_h = median(level);
  est.sextic_ratio = median(sextic);
  est.cubic_ratio = median(cubic);
  est.curvature_h = median(hess);
  est.noisy = est.residual_ratio > kNoisyResidualRatio || est.sextic_ratio > kNoisySexticRatio;
  return est;
}

}  // namespace geomfit
