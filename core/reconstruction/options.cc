#include "core/reconstruction/options.h"

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace geomfit {

const char* ReconstructionMethodName(ReconstructionMethod m) {
  switch (m) {
    case ReconstructionMethod::kWalf: return "walf";
    case ReconstructionMethod::kCmf: return "cmf";
    case ReconstructionMethod::kLinear: break;
  }
  return "linear";
}

FitOptions DefaultReconstructionFit() {
  FitOptions o;
  o.degree = 3;
  o.oscillation_safeguard = true;
  return o;
}

absl::Status ReconstructionOptions::Validate() const {
  if (absl::Status s = ValidateFitOptions(fit); !s.ok()) return absl::InvalidArgumentError(absl::StrCat("fit: ", s.message()));
  if (fit.method == FitMethod::kXu || fit.method == FitMethod::kLSCM)
    return absl::InvalidArgumentError(absl::StrCat("fit: method ", FitMethodName(fit.method),
                                                   " is a comparison method for differentials; reconstruction "
                                                   "needs lhf or lop"));
  if (!(feature_angle_deg >= 0 && feature_angle_deg <= 180))
    return absl::InvalidArgumentError(
        absl::StrFormat("feature_angle_deg = %g is out of range [0, 180]", feature_angle_deg));
  for (size_t i = 0; i < feature_edges.size(); ++i)
    if (feature_edges[i].first < 0 || feature_edges[i].second < 0)
      return absl::InvalidArgumentError(absl::StrCat("feature_edges: edge ", i, " has a negative vertex id"));
  return absl::OkStatus();
}

absl::Status CheckRange(const char* field, int64_t value, int64_t lo, int64_t hi) {
  if (value >= lo && value <= hi) return absl::OkStatus();
  return absl::InvalidArgumentError(absl::StrCat(field, " = ", value, " is out of range [", lo, ", ", hi, "]"));
}

}  // namespace geomfit
