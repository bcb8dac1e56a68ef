#include "core/fitting/options.h"

#include <cmath>
#include <cstring>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace geomfit {

const char* FitMethodName(FitMethod m) {
  switch (m) {
    case FitMethod::kLHF: return "lhf";
    case FitMethod::kLOP: return "lop";
    case FitMethod::kXu: return "xu";
    case FitMethod::kLSCM: return "lscm";
  }
  return "?";
}

const char* WlsSolverName(WlsSolver s) { return s == WlsSolver::kSVD ? "svd" : "qr"; }

const char* NoiseModeName(NoiseMode m) {
  return m == NoiseMode::kOn ? "on" : m == NoiseMode::kAuto ? "auto" : "off";
}

absl::Status ValidateFitOptions(const FitOptions& o) {
  auto bad = [](auto&&... args) { return absl::InvalidArgumentError(absl::StrCat(args...)); };
  if (o.degree < 1 || o.degree > kMaxDegree)
    return bad("fit option degree = ", o.degree, " is out of range [1, ", kMaxDegree, "]");
  if (o.rings != 0 && (o.rings < 1 || o.rings > 10 || std::fmod(2 * o.rings, 1.0) != 0))
    return bad("fit option rings = ", o.rings,
               " must be 0 (automatic) or a multiple of 0.5 in [1, 10]");
  if (!(o.max_rings >= o.StartRings() && o.max_rings <= 10))
    return bad("fit option max_rings = ", o.max_rings, " must be in [rings, 10]");
  if (!(o.min_points_factor == 0 || (o.min_points_factor >= 1 && o.min_points_factor <= 10)))
    return bad("fit option min_points_factor = ", o.min_points_factor, " must be 0 (automatic) or in [1, 10]");
  if (!(o.boundary_points_factor >= 1 && o.boundary_points_factor <= 10))
    return bad("fit option boundary_points_factor = ", o.boundary_points_factor,
               " must be in [1, 10]");
  if (o.max_points < NumCoefficients(o.degree) || o.max_points > kMaxStencil)
    return bad("fit option max_points = ", o.max_points, " must be in [",
               NumCoefficients(o.degree), ", ", kMaxStencil, "] for degree ", o.degree);
  if (!(o.safeguard_angle_deg > 0 && o.safeguard_angle_deg <= 180))
    return bad("fit option safeguard_angle_deg = ", o.safeguard_angle_deg,
               " must be in (0, 180]");
  if (!(o.weight_epsilon > 0 && o.weight_epsilon <= 1))
    return bad("fit option weight_epsilon = ", o.weight_epsilon, " must be in (0, 1]");
  for (int d = 1; d <= kMaxDegree; ++d)
    if (!(o.cond_threshold[d] >= 1))
      return bad("fit option cond_threshold[", d, "] = ", o.cond_threshold[d], " must be >= 1");
  if (o.smoothing_passes < -1 || o.smoothing_passes > 5)
    return bad("fit option smoothing_passes = ", o.smoothing_passes, " must be -1 (automatic) or in [0, 5]");
  if (o.normal_degree != 0 && (o.normal_degree < o.degree || o.normal_degree > kMaxDegree))
    return bad("fit option normal_degree = ", o.normal_degree, " must be 0 (off) or in [degree, ",
               kMaxDegree, "]");
  if (o.slope_refinement < 0 || o.slope_refinement > 3)
    return bad("fit option slope_refinement = ", o.slope_refinement, " must be 0 (off) or in [1, 3]");
  return absl::OkStatus();
}

namespace {
uint64_t Bits(double x) {
  uint64_t b;
  std::memcpy(&b, &x, sizeof b);
  return b;
}
}  // namespace

FitOptionsBits FitOptionsIdentity(const FitOptions& o) {
  FitOptionsBits b{static_cast<uint64_t>(o.degree),
                   Bits(o.StartRings()),
                   o.adaptive,
                   Bits(o.MinPointsFactor()),
                   Bits(o.boundary_points_factor),
                   Bits(o.max_rings),
                   static_cast<uint64_t>(o.max_points),
                   static_cast<uint64_t>(o.method),
                   Bits(o.safeguard_angle_deg),
                   o.Interpolates(),
                   o.two_pass,
                   static_cast<uint64_t>(o.frame_normals),
                   Bits(o.weight_epsilon),
                   o.oscillation_safeguard};
  for (int d = 1; d <= kMaxDegree; ++d) b[13 + d] = Bits(o.cond_threshold[d]);
  b[14 + kMaxDegree] = static_cast<uint64_t>(o.noise);
  b[15 + kMaxDegree] = static_cast<uint64_t>(o.SmoothingPasses());
  b[16 + kMaxDegree] = static_cast<uint64_t>(o.solver);
  b[17 + kMaxDegree] = static_cast<uint64_t>(o.NormalDegree());
  b[18 + kMaxDegree] = o.HermiteHessian();
  b[19 + kMaxDegree] = static_cast<uint64_t>(o.SlopePasses());
  b[20 + kMaxDegree] = o.CubicHermite();
  b[21 + kMaxDegree] = o.JetHermite();
  b[22 + kMaxDegree] = o.PlaneHermite();
  b[23 + kMaxDegree] = o.QuadraticHermite();
  return b;
}

std::string FitOptionsKey(const FitOptions& o) {
  std::string key = absl::StrFormat(
      "d%d r%g a%d f%g b%g mr%g mp%d %s s%g i%d t%d w%d e%g o%d", o.degree, o.StartRings(),
      o.adaptive, o.MinPointsFactor(), o.boundary_points_factor, o.max_rings, o.max_points,
      FitMethodName(o.method), o.safeguard_angle_deg, o.Interpolates(), o.two_pass,
      static_cast<int>(o.frame_normals), o.weight_epsilon, o.oscillation_safeguard);
  for (int d = 1; d <= kMaxDegree; ++d) absl::StrAppendFormat(&key, " c%g", o.cond_threshold[d]);
  absl::StrAppendFormat(&key, " n%s sp%d %s nd%d hh%d", NoiseModeName(o.noise), o.SmoothingPasses(),
                        WlsSolverName(o.solver), o.NormalDegree(), o.HermiteHessian());
  if (o.SlopePasses() > 0) absl::StrAppendFormat(&key, " sr%d", o.SlopePasses());
  if (o.QuadraticHermite()) absl::StrAppend(&key, " qh1");
  if (o.degree == 3 && !o.CubicHermite()) absl::StrAppend(&key, " ch0");
  if (o.degree == 1 && !o.PlaneHermite()) absl::StrAppend(&key, " ph0");
  // The Hermite jets when they differ from the default (on at degree 5, off at degree 4).
  if ((o.degree == 4 || o.degree == 5) && o.JetHermite() != (o.degree == 5))
    absl::StrAppendFormat(&key, " jh%d", o.JetHermite());
  return key;
}

}  // namespace geomfit
