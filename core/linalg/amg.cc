#include "core/linalg/amg.h"

#include <algorithm>
#include <cmath>

#include <Eigen/LU>

#include "absl/strings/str_format.h"
#include "core/util/status_macros.h"

namespace geomfit {
namespace {

using Matrix = Amg::Matrix;

constexpr double kStall = 0.85;  // a coarse level with more rows than this fraction is no coarsening

// The symmetrized strength graph in CSR: j is a strong neighbour of i when
// |a_ij| >= theta sqrt(|a_ii a_jj|) or |a_ji| >= theta sqrt(|a_ii a_jj|); `weight` holds
// the larger of the two relative strengths.
struct StrengthGraph {
  std::vector<int> offsets, neighbors;
  std::vector<double> weight;
  int Degree(int i) const { return offsets[i + 1] - offsets[i]; }
};

StrengthGraph Strength(const Matrix& A, const Eigen::VectorXd& diagonal, double theta) {
  const int n = static_cast<int>(A.rows());
  const int* outer = A.outerIndexPtr();
  const int* inner = A.innerIndexPtr();
  const double* values = A.valuePtr();
  auto strength = [&](int i, int p) {
    const double d = std::sqrt(std::abs(diagonal(i) * diagonal(inner[p])));
    return d > 0 ? std::abs(values[p]) / d : 1.0;
  };
  std::vector<int> count(n + 1, 0);
  for (int i = 0; i < n; ++i)
    for (int p = outer[i]; p < outer[i + 1]; ++p)
      if (inner[p] != i && strength(i, p) >= theta) ++count[i + 1], ++count[inner[p] + 1];
  StrengthGraph g;
  g.offsets.assign(n + 1, 0);
  for (int i = 0; i < n; ++i) g.offsets[i + 1] = g.offsets[i] + count[i + 1];
  std::vector<std::pair<int, double>> edges(g.offsets[n]);
  std::vector<int> fill(g.offsets.begin(), g.offsets.end() - 1);
  for (int i = 0; i < n; ++i)
    for (int p = outer[i]; p < outer[i + 1]; ++p) {
      const int j = inner[p];
      if (j == i) continue;
      const double s = strength(i, p);
      if (s < theta) continue;
      edges[fill[i]++] = {j, s};
      edges[fill[j]++] = {i, s};
    }
  // Sort each row and merge the two directions of an edge.
  g.neighbors.reserve(edges.size());
  g.weight.reserve(edges.size());
  std::vector<int> offsets(n + 1, 0);
  for (int i = 0; i < n; ++i) {
    auto begin = edges.begin() + g.offsets[i], end = edges.begin() + g.offsets[i + 1];
    std::sort(begin, end);
    for (auto e = begin; e != end; ++e) {
      if (static_cast<int>(g.neighbors.size()) > offsets[i] && g.neighbors.back() == e->first) {
        g.weight.back() = std::max(g.weight.back(), e->second);
      } else {
        g.neighbors.push_back(e->first);
        g.weight.push_back(e->second);
      }
    }
    offsets[i + 1] = static_cast<int>(g.neighbors.size());
  }
  g.offsets = std::move(offsets);
  return g;
}

// Greedy aggregation (Vanek et al.'s three passes). Returns the aggregate of each row,
// -1 for rows without strong neighbours (left to the smoother), and the count.
int Aggregate(const StrengthGraph& g, std::vector<int>* aggregate) {
  const int n = static_cast<int>(g.offsets.size()) - 1;
  std::vector<int>& agg = *aggregate;
  agg.assign(n, -1);
  int count = 0;
  // 1: a row whose strong neighbours are all free seeds an aggregate of itself and them.
  for (int i = 0; i < n; ++i) {
    if (agg[i] >= 0 || g.Degree(i) == 0) continue;
    bool free = true;
    for (int p = g.offsets[i]; p < g.offsets[i + 1] && free; ++p) free = agg[g.neighbors[p]] < 0;
    if (!free) continue;
    agg[i] = count;
    for (int p = g.offsets[i]; p < g.offsets[i + 1]; ++p) agg[g.neighbors[p]] = count;
    ++count;
  }
  // 2: the rest join the aggregate of their strongest neighbour from pass 1.
  const std::vector<int> first = agg;
  for (int i = 0; i < n; ++i) {
    if (agg[i] >= 0) continue;
    double best = -1;
    for (int p = g.offsets[i]; p < g.offsets[i + 1]; ++p)
      if (first[g.neighbors[p]] >= 0 && g.weight[p] > best) best = g.weight[p], agg[i] = first[g.neighbors[p]];
  }
  // 3: what is left (strong neighbours, none aggregated in pass 1) groups with its free
  // neighbours.
  for (int i = 0; i < n; ++i) {
    if (agg[i] >= 0 || g.Degree(i) == 0) continue;
    agg[i] = count;
    for (int p = g.offsets[i]; p < g.offsets[i + 1]; ++p)
      if (agg[g.neighbors[p]] < 0) agg[g.neighbors[p]] = count;
    ++count;
  }
  return count;
}

// Estimate of the spectral radius of D^{-1} A: a few power iterations from a fixed
// start (deterministic), the largest growth factor seen. Stops early when ctx is cancelled.
double SpectralRadius(const Matrix& A, const Eigen::VectorXd& inverse_diagonal, const RunContext& ctx) {
  const int n = static_cast<int>(A.rows());
  Eigen::VectorXd x(n), y;
  for (int i = 0; i < n; ++i) x(i) = 1 + 0.5 * std::sin(1.7 * i + 0.3);
  x.normalize();
  double rho = 0;
  for (int it = 0; it < 15 && !ctx.cancelled(); ++it) {
    MultiplySerial(A, x, &y);
    y = y.cwiseProduct(inverse_diagonal);
    const double norm = y.norm();
    if (!(norm > 0)) break;
    rho = std::max(rho, norm);
    x = y / norm;
  }
  return rho;
}

// P = (I - w D^{-1} A) T, T the aggregates' piecewise constants.
Matrix SmoothedProlongator(const Matrix& A, const Eigen::VectorXd& inverse_diagonal, const std::vector<int>& agg,
                           int coarse, double w) {
  const int n = static_cast<int>(A.rows());
  const int* outer = A.outerIndexPtr();
  const int* inner = A.innerIndexPtr();
  const double* values = A.valuePtr();
  std::vector<double> accumulator(coarse, 0);
  std::vector<int> touched;
  std::vector<char> seen(coarse, 0);
  std::vector<Eigen::Triplet<double, int>> triplets;
  triplets.reserve(A.nonZeros());
  for (int i = 0; i < n; ++i) {
    touched.clear();
    auto add = [&](int c, double v) {
      if (!seen[c]) seen[c] = 1, touched.push_back(c);
      accumulator[c] += v;
    };
    if (agg[i] >= 0) add(agg[i], 1);
    const double f = w * inverse_diagonal(i);
    for (int p = outer[i]; p < outer[i + 1]; ++p)
      if (agg[inner[p]] >= 0) add(agg[inner[p]], -f * values[p]);
    for (int c : touched) {
      if (accumulator[c] != 0) triplets.emplace_back(i, c, accumulator[c]);
      accumulator[c] = 0;
      seen[c] = 0;
    }
  }
  Matrix P(n, coarse);
  P.setFromTriplets(triplets.begin(), triplets.end());
  return P;
}

Matrix Tentative(const std::vector<int>& agg, int coarse) {
  std::vector<Eigen::Triplet<double, int>> triplets;
  for (int i = 0; i < static_cast<int>(agg.size()); ++i)
    if (agg[i] >= 0) triplets.emplace_back(i, agg[i], 1.0);
  Matrix T(static_cast<Eigen::Index>(agg.size()), coarse);
  T.setFromTriplets(triplets.begin(), triplets.end());
  return T;
}

}  // namespace

void MultiplySerial(const Matrix& A, const Eigen::VectorXd& x, Eigen::VectorXd* y) {
  y->resize(A.rows());
  const int* outer = A.outerIndexPtr();
  const int* inner = A.innerIndexPtr();
  const double* values = A.valuePtr();
  for (Eigen::Index i = 0; i < A.rows(); ++i) {
    double acc = 0;
    for (int p = outer[i]; p < outer[i + 1]; ++p) acc += values[p] * x(inner[p]);
    (*y)(i) = acc;
  }
}

absl::Status ValidateAmgOptions(const AmgOptions& o) {
  if (!(o.strength >= 0 && o.strength < 1))
    return absl::InvalidArgumentError(absl::StrFormat("amg.strength %g is out of range [0, 1)", o.strength));
  if (!(o.jacobi_weight > 0 && o.jacobi_weight <= 1))
    return absl::InvalidArgumentError(absl::StrFormat("amg.jacobi_weight %g is out of range (0, 1]", o.jacobi_weight));
  if (o.sweeps < 1) return absl::InvalidArgumentError(absl::StrFormat("amg.sweeps %d must be >= 1", o.sweeps));
  if (o.coarse_size < 1 || o.coarse_size > 5000)
    return absl::InvalidArgumentError(absl::StrFormat("amg.coarse_size %d is out of range [1, 5000]", o.coarse_size));
  if (o.max_levels < 1) return absl::InvalidArgumentError(absl::StrFormat("amg.max_levels %d must be >= 1", o.max_levels));
  return absl::OkStatus();
}

// A row far from diagonal dominance at the finest level and its local problem: the
// unknowns of its stencil (the row itself first), the rows whose residual they touch, and
// the LU of A restricted to the stencil.
struct Patch {
  std::vector<int> cols, affected;
  Eigen::FullPivLU<Eigen::MatrixXd> lu;
};

struct Amg::Level {
  Matrix A;
  Eigen::VectorXd diagonal, inverse_diagonal;  // a_ii; the relaxation's 1 / d_i
  std::vector<Patch> patches;  // the finest level's rows far from diagonal dominance
  Matrix P, R;  // to and from the next level (empty at the coarsest)
  Eigen::FullPivLU<Eigen::MatrixXd> lu;  // the coarsest level's, when small enough
  bool direct = false;
  mutable Eigen::VectorXd b, x, r;  // the cycle's work vectors (b, x: this level's problem)

  /// `finest`: rows far from diagonal dominance get patches (BuildPatches).
  absl::Status SetMatrix(const Matrix& m, bool finest) {
    A = m;
    A.makeCompressed();
    std::vector<int> weak_rows;
    inverse_diagonal.resize(A.rows());
    diagonal.resize(A.rows());
    for (int i = 0; i < A.rows(); ++i) {
      double d = 0, off = 0;
      for (Matrix::InnerIterator it(A, i); it; ++it) {
        if (it.col() == i) {
          d += it.value();
        } else {
          off += std::abs(it.value());
        }
      }
      diagonal(i) = d;
      if (!(std::isfinite(d) && std::isfinite(off) && (d != 0 || off != 0)))
        return absl::InvalidArgumentError(absl::StrFormat("amg: row %d: diagonal %g, off-diagonal sum %g", i, d, off));
      // A row whose diagonal is small against its couplings (GFD stencils at valence-3
      // vertices: a_ii ~ 0 or < 0) would blow relaxation and the prolongator up: there the
      // l1 diagonal |a_ii| + sum |a_ij| damps instead.
      const bool weak = d < 0.5 * off;
      inverse_diagonal(i) = 1 / (weak ? std::abs(d) + off : d);
      if (weak && finest) weak_rows.push_back(i);
    }
    BuildPatches(weak_rows);
    return absl::OkStatus();
  }

  // Rows with |a_ii| < sum |a_ij| / 2 at the finest level are ill-conditioned stencils
  // (on a 1M-vertex cubed sphere: a_ii = -456 against couplings summing to 3498, typical
  // rows 200 / 230). Their error mode is local and neither a pointwise relaxation (even
  // with the l1 diagonal) nor the coarse levels reduce it: the V-cycle amplified it by
  // 1.15-1.46 per cycle. Such a row is relaxed by solving A on its stencil's unknowns
  // exactly (a multiplicative Schwarz step on that patch). At coarse levels such rows are
  // Galerkin sums, smooth couplings that the l1 diagonal handles.
  void BuildPatches(const std::vector<int>& rows) {
    patches.clear();
    const int n = static_cast<int>(A.rows());
    const int* outer = A.outerIndexPtr();
    const int* inner = A.innerIndexPtr();
    const double* values = A.valuePtr();
    std::vector<int> position(n, -1);
    for (int i : rows) {
      Patch patch;
      patch.cols.push_back(i);
      position[i] = 0;
      for (int p = outer[i]; p < outer[i + 1]; ++p)
        if (position[inner[p]] < 0) position[inner[p]] = static_cast<int>(patch.cols.size()), patch.cols.push_back(inner[p]);
      const int m = static_cast<int>(patch.cols.size());
      Eigen::MatrixXd local = Eigen::MatrixXd::Zero(m, m);
      for (int a = 0; a < m; ++a)
        for (int p = outer[patch.cols[a]]; p < outer[patch.cols[a] + 1]; ++p)
          if (position[inner[p]] >= 0) local(a, position[inner[p]]) = values[p];
      for (int c : patch.cols) position[c] = -1;
      patch.lu.compute(local);
      if (patch.lu.isInvertible()) patches.push_back(std::move(patch));  // else: the l1 relaxation alone
    }
    if (patches.empty()) return;
    // affected: the rows with a coupling to a patch's unknowns (one pass over A).
    std::vector<int> start(n + 1, 0), member, last(patches.size(), -1);
    for (const Patch& patch : patches)
      for (int c : patch.cols) ++start[c + 1];
    for (int i = 0; i < n; ++i) start[i + 1] += start[i];
    member.resize(start[n]);
    std::vector<int> fill(start.begin(), start.end() - 1);
    for (int q = 0; q < static_cast<int>(patches.size()); ++q)
      for (int c : patches[q].cols) member[fill[c]++] = q;
    for (int k = 0; k < n; ++k)
      for (int p = outer[k]; p < outer[k + 1]; ++p)
        for (int e = start[inner[p]]; e < start[inner[p] + 1]; ++e)
          if (last[member[e]] != k) last[member[e]] = k, patches[member[e]].affected.push_back(k);
  }
};

Amg::Amg() = default;
Amg::~Amg() = default;
Amg::Amg(Amg&&) noexcept = default;
Amg& Amg::operator=(Amg&&) noexcept = default;

int Amg::rows(int level) const { return static_cast<int>(levels_[level]->A.rows()); }

double Amg::operator_complexity() const {
  if (levels_.empty()) return 0;
  double nnz = 0;
  for (const auto& l : levels_) nnz += static_cast<double>(l->A.nonZeros());
  return nnz / static_cast<double>(levels_[0]->A.nonZeros());
}

absl::Status Amg::Build(const Matrix& A, const AmgOptions& options, const RunContext& ctx) {
  levels_.clear();
  absl::Status status = BuildLevels(A, options, ctx);
  if (!status.ok()) levels_.clear();  // no half-built hierarchy
  return status;
}

absl::Status Amg::BuildLevels(const Matrix& A, const AmgOptions& options, const RunContext& ctx) {
  GF_RETURN_IF_ERROR(ValidateAmgOptions(options));
  if (A.rows() != A.cols() || A.rows() == 0) return absl::InvalidArgumentError("amg: the matrix is not square");
  options_ = options;
  auto first = std::make_unique<Level>();
  GF_RETURN_IF_ERROR(first->SetMatrix(A, true));
  levels_.push_back(std::move(first));
  std::vector<int> agg;
  // ctx is polled between the set-up's phases (each one O(nnz) of a level; the longest
  // stretch without a poll is one sparse product of the finest level).
  while (levels_.back()->A.rows() > options_.coarse_size && num_levels() < options_.max_levels) {
    GF_RETURN_IF_ERROR(ctx.Check());
    Level& fine = *levels_.back();
    int coarse = Aggregate(Strength(fine.A, fine.diagonal, options_.strength), &agg);
    // Coarsening stalls when the diagonal dominates (weak couplings everywhere): then
    // every coupling counts.
    if (coarse == 0 || coarse > kStall * fine.A.rows()) {
      GF_RETURN_IF_ERROR(ctx.Check());
      coarse = Aggregate(Strength(fine.A, fine.diagonal, 0), &agg);
    }
    if (coarse == 0 || coarse > kStall * fine.A.rows()) break;
    GF_RETURN_IF_ERROR(ctx.Check());
    if (options_.smooth_prolongator) {
      const double rho = SpectralRadius(fine.A, fine.inverse_diagonal, ctx);
      GF_RETURN_IF_ERROR(ctx.Check());
      fine.P = SmoothedProlongator(fine.A, fine.inverse_diagonal, agg, coarse, rho > 0 ? 4 / (3 * rho) : 0);
    } else {
      fine.P = Tentative(agg, coarse);
    }
    GF_RETURN_IF_ERROR(ctx.Check());
    fine.R = fine.P.transpose();
    GF_RETURN_IF_ERROR(ctx.Check());
    const Matrix AP = fine.A * fine.P;
    GF_RETURN_IF_ERROR(ctx.Check());
    Matrix Ac = fine.R * AP;
    GF_RETURN_IF_ERROR(ctx.Check());
    auto next = std::make_unique<Level>();
    GF_RETURN_IF_ERROR(next->SetMatrix(Ac, false));
    levels_.push_back(std::move(next));
  }
  GF_RETURN_IF_ERROR(ctx.Check());
  Level& last = *levels_.back();
  last.direct = last.A.rows() <= options_.coarse_size;
  if (last.direct) {
    last.lu.compute(Eigen::MatrixXd(last.A));
    if (!last.lu.isInvertible())
      return absl::FailedPreconditionError(
          absl::StrFormat("amg: the coarsest operator (%d rows) is singular", static_cast<int>(last.A.rows())));
  }
  for (auto& l : levels_) {
    l->b.resize(l->A.rows());
    l->x.resize(l->A.rows());
    l->r.resize(l->A.rows());
  }
  return absl::OkStatus();
}

absl::Status Amg::UpdateFinest(const Matrix& A) {
  if (levels_.empty()) return absl::FailedPreconditionError("amg: UpdateFinest before Build");
  if (A.rows() != levels_[0]->A.rows() || A.cols() != A.rows())
    return absl::InvalidArgumentError("amg: UpdateFinest with a matrix of another size");
  if (levels_.size() == 1) return Build(A, options_);
  return levels_[0]->SetMatrix(A, true);
}

void Amg::Smooth(const Level& l, const Eigen::VectorXd& b, Eigen::VectorXd* x, bool forward, bool from_zero) const {
  const int n = static_cast<int>(l.A.rows());
  const int* outer = l.A.outerIndexPtr();
  const int* inner = l.A.innerIndexPtr();
  const double* values = l.A.valuePtr();
  double* xv = x->data();
  if (options_.smoother == AmgSmoother::kJacobi) {
    MultiplySerial(l.A, *x, &l.r);
    *x += options_.jacobi_weight * (b - l.r).cwiseProduct(l.inverse_diagonal);
    return;
  }
  auto relax = [&](int i) {
    double acc = b(i);
    for (int p = outer[i]; p < outer[i + 1]; ++p) acc -= values[p] * xv[inner[p]];
    xv[i] += acc * l.inverse_diagonal(i);
  };
  if (from_zero && forward) {  // x_j = 0 for j >= i: only the (sorted) columns below i count
    for (int i = 0; i < n; ++i) {
      double acc = b(i);
      for (int p = outer[i]; p < outer[i + 1] && inner[p] < i; ++p) acc -= values[p] * xv[inner[p]];
      xv[i] = acc * l.inverse_diagonal(i);
    }
  } else if (forward) {
    for (int i = 0; i < n; ++i) relax(i);
  } else {
    for (int i = n - 1; i >= 0; --i) relax(i);
  }
}

void Amg::SolvePatches(const Level& l, const Eigen::VectorXd& b, Eigen::VectorXd* x, Eigen::VectorXd* r) const {
  const int* outer = l.A.outerIndexPtr();
  const int* inner = l.A.innerIndexPtr();
  const double* values = l.A.valuePtr();
  double* xv = x->data();
  auto residual = [&](int k) {
    double acc = b(k);
    for (int p = outer[k]; p < outer[k + 1]; ++p) acc -= values[p] * xv[inner[p]];
    return acc;
  };
  Eigen::VectorXd local, delta;
  for (const Patch& patch : l.patches) {
    const int m = static_cast<int>(patch.cols.size());
    local.resize(m);
    for (int a = 0; a < m; ++a) local(a) = r ? (*r)(patch.cols[a]) : residual(patch.cols[a]);
    delta = patch.lu.solve(local);
    for (int a = 0; a < m; ++a) xv[patch.cols[a]] += delta(a);
    if (r)
      for (int k : patch.affected) (*r)(k) = residual(k);
  }
}

void Amg::Cycle(int level, const Eigen::VectorXd& b, Eigen::VectorXd* x) const {
  const Level& l = *levels_[level];
  if (level + 1 == num_levels()) {
    if (l.direct) {
      *x = l.lu.solve(b);
      return;
    }
    x->setZero(b.size());
    for (int s = 0; s < 4 * options_.sweeps; ++s) {
      Smooth(l, b, x, s % 2 == 0, s == 0);
      SolvePatches(l, b, x, nullptr);
    }
    return;
  }
  x->setZero(b.size());
  for (int s = 0; s < options_.sweeps; ++s) Smooth(l, b, x, true, s == 0);
  if (options_.sweeps == 1 && options_.smoother == AmgSmoother::kGaussSeidel) {
    // After one forward sweep from zero, b_i - sum_{j <= i} a_ij x_j = (d_i - a_ii) x_i (d_i
    // the relaxation's diagonal), so r_i = (d_i - a_ii) x_i - sum_{j > i} a_ij x_j: half a product.
    const int* outer = l.A.outerIndexPtr();
    const int* inner = l.A.innerIndexPtr();
    const double* values = l.A.valuePtr();
    for (Eigen::Index i = 0; i < l.A.rows(); ++i) {
      double acc = (1 / l.inverse_diagonal(i) - l.diagonal(i)) * (*x)(i);
      for (int p = outer[i + 1] - 1; p >= outer[i] && inner[p] > i; --p) acc -= values[p] * (*x)(inner[p]);
      l.r(i) = acc;
    }
  } else {
    MultiplySerial(l.A, *x, &l.r);
    l.r = b - l.r;
  }
  SolvePatches(l, b, x, &l.r);
  const Level& c = *levels_[level + 1];
  MultiplySerial(l.R, l.r, &c.b);
  Cycle(level + 1, c.b, &c.x);
  MultiplySerial(l.P, c.x, &l.r);
  *x += l.r;
  SolvePatches(l, b, x, nullptr);
  for (int s = 0; s < options_.sweeps; ++s) Smooth(l, b, x, false, false);
}

void Amg::Apply(const Eigen::VectorXd& b, Eigen::VectorXd* x) const {
  if (levels_.empty()) {
    *x = b;
    return;
  }
  Cycle(0, b, x);
}

}  // namespace geomfit
