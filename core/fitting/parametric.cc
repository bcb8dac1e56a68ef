#include "core/fitting/parametric.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/SVD>

#include "core/fitting/fit.h"

namespace geomfit {
namespace {

// Xu's 1-ring parametrization (2.2; [67]).
bool XuParameters(const Mesh& mesh, const Topology& topo, const int32_t* pts, int n_pts, int first,
                  const LocalFrame& fr, WlsProblem* P) {
  const int v = pts[0];
  if (topo.is_boundary[v] || n_pts < 4) return false;
  const int32_t* nbr = topo.Neighbors(v);
  const int valence = topo.NumNeighbors(v);
  for (int k = 1; k < n_pts; ++k)  // the 1-ring only: Xu's construction stops there
    if (!std::binary_search(nbr, nbr + valence, pts[k])) return false;
  std::vector<int> order(n_pts - 1);
  std::vector<Eigen::Vector3d> d(n_pts);
  std::vector<double> angle(n_pts);
  for (int k = 1; k < n_pts; ++k) {
    d[k] = mesh.positions.row(pts[k]).transpose() - fr.origin;
    angle[k] = std::atan2(d[k].dot(fr.t2), d[k].dot(fr.t1));
    order[k - 1] = k;
  }
  std::sort(order.begin(), order.end(), [&](int a, int b) { return angle[a] < angle[b]; });
  // Angles at the centre between consecutive neighbours, scaled to sum to 2 pi.
  std::vector<double> theta(order.size());
  double total = 0;
  for (size_t i = 0; i < order.size(); ++i) {
    const Eigen::Vector3d &a = d[order[i]], &b = d[order[(i + 1) % order.size()]];
    total += theta[i] = std::atan2(a.cross(b).norm(), a.dot(b));
  }
  if (!(total > 0)) return false;
  double phi = angle[order[0]];
  for (size_t i = 0; i < order.size(); ++i) {
    const int k = order[i], r = k - first;
    const double len = d[k].norm();
    P->u[r] = len * std::cos(phi);
    P->v[r] = len * std::sin(phi);
    phi += theta[i] * (2 * M_PI / total);
  }
  if (first == 0) P->u[0] = P->v[0] = 0;
  return true;
}

// Least-squares conformal map of the stencil's faces (2.2; Levy et al. [43]).
bool LscmParameters(const Mesh& mesh, const Topology& topo, const int32_t* pts, int n_pts, int first,
                    const LocalFrame& fr, WlsProblem* P) {
  std::vector<std::pair<int32_t, int>> local(n_pts);  // (vertex, stencil index), sorted
  for (int k = 0; k < n_pts; ++k) local[k] = {pts[k], k};
  std::sort(local.begin(), local.end());
  auto index_of = [&](int32_t p) {
    auto it = std::lower_bound(local.begin(), local.end(), std::make_pair(p, -1));
    return it != local.end() && it->first == p ? it->second : -1;
  };
  std::vector<int32_t> faces;
  for (int k = 0; k < n_pts; ++k)
    for (int i = 0; i < topo.NumVertexFaces(pts[k]); ++i) faces.push_back(topo.VertexFaces(pts[k])[i]);
  std::sort(faces.begin(), faces.end());
  faces.erase(std::unique(faces.begin(), faces.end()), faces.end());
  // Normal equations of the conformality residuals, unknowns (u_k, v_k) at 2k, 2k + 1.
  const int n = 2 * n_pts;
  Eigen::MatrixXd N = Eigen::MatrixXd::Zero(n, n);
  int triangles = 0;
  for (int32_t f : faces) {
    int c[4];
    bool inside = true;
    for (int j = 0; j < mesh.FaceSize(f) && inside; ++j) inside = (c[j] = index_of(mesh.faces(f, j))) >= 0;
    if (!inside) continue;
    for (int t = 0; t + 2 < mesh.FaceSize(f); ++t) {  // quads as (0, 1, 2), (0, 2, 3)
      const int tri[3] = {c[0], c[t + 1], c[t + 2]};
      Eigen::Vector3d p[3];
      for (int j = 0; j < 3; ++j) p[j] = mesh.positions.row(pts[tri[j]]).transpose();
      const Eigen::Vector3d nrm = (p[1] - p[0]).cross(p[2] - p[0]);
      const double area2 = nrm.norm();
      if (!(area2 > 0)) continue;
      const Eigen::Vector3d e1 = (p[1] - p[0]).normalized(), e2 = nrm.normalized().cross(e1);
      // Orientation: conformal with respect to the frame's normal (t1, t2) side.
      const double s = nrm.dot(fr.normal) >= 0 ? 1.0 : -1.0;
      Eigen::Vector2d q[3];
      for (int j = 0; j < 3; ++j) q[j] = {(p[j] - p[0]).dot(e1), (p[j] - p[0]).dot(e2)};
      // grad phi_j = perp(q_{j+2} - q_{j+1}) / (2A); conformal: grad v = s perp(grad u).
      double gx[3], gy[3];
      for (int j = 0; j < 3; ++j) {
        const Eigen::Vector2d e = q[(j + 2) % 3] - q[(j + 1) % 3];
        gx[j] = -e.y() / area2;
        gy[j] = e.x() / area2;
      }
      const double w = std::sqrt(0.5 * area2);
      double row[2][6];  // over u_0..u_2, v_0..v_2
      for (int j = 0; j < 3; ++j) {
        row[0][j] = s * w * gy[j], row[0][3 + j] = w * gx[j];   // v_x + s u_y = 0
        row[1][j] = -s * w * gx[j], row[1][3 + j] = w * gy[j];  // v_y - s u_x = 0
      }
      for (const auto& r : row)
        for (int a = 0; a < 6; ++a)
          for (int b = 0; b < 6; ++b)
            N(2 * tri[a % 3] + a / 3, 2 * tri[b % 3] + b / 3) += r[a] * r[b];
      ++triangles;
    }
  }
  if (triangles == 0) return false;
  // Pin the centre at the origin and its nearest neighbour at its tangent projection.
  int near = -1;
  double best = 0;
  for (int k = 1; k < n_pts; ++k) {
    const double dist = (mesh.positions.row(pts[k]) - mesh.positions.row(pts[0])).squaredNorm();
    if (near < 0 || dist < best) near = k, best = dist;
  }
  if (near < 0) return false;
  const Eigen::Vector3d dn = mesh.positions.row(pts[near]).transpose() - fr.origin;
  Eigen::VectorXd x = Eigen::VectorXd::Zero(n);
  x(2 * near) = dn.dot(fr.t1), x(2 * near + 1) = dn.dot(fr.t2);
  std::vector<int> free_vars;
  for (int i = 0; i < n; ++i)
    if (i / 2 != 0 && i / 2 != near) free_vars.push_back(i);
  const int m = static_cast<int>(free_vars.size());
  Eigen::MatrixXd A(m, m);
  Eigen::VectorXd b(m);
  for (int i = 0; i < m; ++i) {
    b(i) = -(N(free_vars[i], 2 * near) * x(2 * near) + N(free_vars[i], 2 * near + 1) * x(2 * near + 1));
    for (int j = 0; j < m; ++j) A(i, j) = N(free_vars[i], free_vars[j]);
  }
  // Stencil points in no interior face would make A singular: regularize them to stay put.
  const double reg = 1e-12 * std::max(1.0, A.diagonal().cwiseAbs().maxCoeff());
  A.diagonal().array() += reg;
  const Eigen::VectorXd y = A.ldlt().solve(b);
  if (!y.allFinite()) return false;
  for (int i = 0; i < m; ++i) x(free_vars[i]) = y(i);
  for (int k = first; k < n_pts; ++k) P->u[k - first] = x(2 * k), P->v[k - first] = x(2 * k + 1);
  return true;
}

}  // namespace

bool ParametrizeStencil(FitMethod method, const Mesh& mesh, const Topology& topo, const int32_t* pts, int n_pts,
                        int first, const LocalFrame& frame, WlsProblem* P) {
  switch (method) {
    case FitMethod::kXu: return XuParameters(mesh, topo, pts, n_pts, first, frame, P);
    case FitMethod::kLSCM: return LscmParameters(mesh, topo, pts, n_pts, first, frame, P);
    default: return false;
  }
}

WlsSolution SolveWlsSvd(const WlsProblem& P, const WlsSettings& S, double* coefficients, double* op) {
  WlsSolution sol;
  const int ncoef = NumCoefficients(S.degree), first_col = S.interpolate ? 1 : 0, cols = ncoef - first_col;
  std::fill(coefficients, coefficients + P.dims * ncoef, 0.0);
  if (op) std::fill(op, op + static_cast<size_t>(ncoef) * P.rows, 0.0);
  std::vector<int> keep;
  double radius2 = 0;
  for (int r = 0; r < P.rows; ++r)
    if (P.gamma[r] > 0) keep.push_back(r), radius2 = std::max(radius2, P.u[r] * P.u[r] + P.v[r] * P.v[r]);
  if (keep.empty() || radius2 == 0) return sol;
  const double h = sol.radius = std::sqrt(radius2);
  const int rows = static_cast<int>(keep.size());
  // Columns in TaylorIndex order (minus c00 when interpolating); weights of (2.2.1).
  Eigen::MatrixXd A(rows, cols), B(rows, P.dims);
  Eigen::VectorXd w(rows);
  static constexpr double kFact[] = {1, 1, 2, 6, 24, 120, 720};
  for (int i = 0; i < rows; ++i) {
    const int r = keep[i];
    const double u = P.u[r] / h, v = P.v[r] / h;
    w(i) = P.gamma[r] * std::pow(u * u + v * v + S.weight_epsilon, -S.degree / 4.0);
    for (int p = first_col; p <= S.degree; ++p)
      for (int k = 0; k <= p; ++k)
        A(i, TaylorIndex(p - k, k) - first_col) =
            w(i) * std::pow(u, p - k) * std::pow(v, k) / (kFact[p - k] * kFact[k]);
    for (int d = 0; d < P.dims; ++d) B(i, d) = w(i) * P.rhs[d][r];
  }
  const Eigen::VectorXd scale = A.colwise().norm().cwiseMax(1e-300).cwiseInverse().transpose();
  A = A * scale.asDiagonal();
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(A, Eigen::ComputeThinU | Eigen::ComputeThinV);
  const Eigen::VectorXd& sigma = svd.singularValues();
  const double cutoff = sigma(0) / S.cond_threshold[S.degree];
  int rank = 0;
  while (rank < sigma.size() && sigma(rank) > cutoff) ++rank;
  if (rank < NumCoefficients(1) - first_col) return sol;
  sol.degree_used = S.degree;
  sol.rank = rank + first_col;
  sol.condition = sigma(0) / sigma(rank - 1);
  sol.condition_downgraded = rank < cols;
  // pinv = V_r diag(1 / sigma_r) U_r^T; coefficients c = S pinv W b / h^p.
  const Eigen::MatrixXd pinv = svd.matrixV().leftCols(rank) * sigma.head(rank).cwiseInverse().asDiagonal() *
                               svd.matrixU().leftCols(rank).transpose();
  const Eigen::MatrixXd y = pinv * B;
  for (int p = first_col; p <= S.degree; ++p)
    for (int k = 0; k <= p; ++k) {
      const int t = TaylorIndex(p - k, k), c = t - first_col;
      const double factor = scale(c) / std::pow(h, p);
      for (int d = 0; d < P.dims; ++d) coefficients[d * ncoef + t] = factor * y(c, d);
      if (op && (S.op_rows < 0 || t < S.op_rows))
        for (int i = 0; i < rows; ++i) op[static_cast<size_t>(t) * P.rows + keep[i]] = factor * pinv(c, i) * w(i);
    }
  return sol;
}

}  // namespace geomfit
