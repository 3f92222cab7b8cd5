#include "calib/solver_util.h"

#include <algorithm>
#include <cmath>
#include <map>

#include <Eigen/Eigenvalues>

namespace reflcap::calib::internal {

double Median(std::vector<double> values) {
  if (values.empty()) return 0;
  const size_t mid = values.size() / 2;
  std::nth_element(values.begin(), values.begin() + mid, values.end());
  if (values.size() % 2 == 1) return values[mid];
  const double upper = values[mid];
  return 0.5 * (upper + *std::max_element(values.begin(), values.begin() + mid));
}

double RobustSigma(std::vector<double> values) {
  for (double& v : values) v = std::abs(v);
  return 1.4826 * Median(std::move(values));
}

double Rms(const std::vector<double>& values) {
  if (values.empty()) return 0;
  double s = 0;
  for (double v : values) s += v * v;
  return std::sqrt(s / values.size());
}

namespace {
// Normal matrices are formed in double precision (relative rounding ~1e-16); after scaling to unit
// diagonal, an eigenvalue below 1e-12 of the largest is within rounding of zero: undetermined.
constexpr double kMinScaledEigenvalue = 1e-12;
}  // namespace

StatusOr<Eigen::MatrixXd> BlockCovariance(ceres::Problem* problem, const std::vector<double*>& blocks,
                                          const std::vector<int>& sizes, double variance) {
  std::vector<double*> all;
  problem->GetParameterBlocks(&all);
  std::vector<double*> active;
  std::map<const double*, int> tangent_offset;
  int n = 0;
  for (double* b : all) {
    if (problem->IsParameterBlockConstant(b)) continue;
    active.push_back(b);
    tangent_offset[b] = n;
    n += problem->ParameterBlockTangentSize(b);
  }
  int total = 0;
  std::vector<int> offset;
  for (int s : sizes) {
    offset.push_back(total);
    total += s;
  }
  Eigen::MatrixXd cov = Eigen::MatrixXd::Zero(total, total);
  if (n == 0) return cov;
  ceres::Problem::EvaluateOptions eval;
  eval.parameter_blocks = active;
  eval.apply_loss_function = false;
  ceres::CRSMatrix jac;
  if (!problem->Evaluate(eval, nullptr, nullptr, nullptr, &jac)) {
    return InternalError("the Jacobian of the adjustment could not be evaluated");
  }
  Eigen::MatrixXd normal = Eigen::MatrixXd::Zero(n, n);
  for (int r = 0; r < jac.num_rows; ++r) {
    for (int a = jac.rows[r]; a < jac.rows[r + 1]; ++a) {
      for (int b = a; b < jac.rows[r + 1]; ++b) {
        normal(jac.cols[a], jac.cols[b]) += jac.values[a] * jac.values[b];
      }
    }
  }
  normal = normal.selfadjointView<Eigen::Upper>();
  const Eigen::VectorXd diag = normal.diagonal();
  Eigen::VectorXd scale(n);
  for (int i = 0; i < n; ++i) {
    if (!(diag[i] > 0)) return FailedPreconditionError("a parameter does not affect any residual");
    scale[i] = 1 / std::sqrt(diag[i]);
  }
  const Eigen::MatrixXd scaled = scale.asDiagonal() * normal * scale.asDiagonal();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(scaled);
  if (eig.info() != Eigen::Success) return InternalError("eigen-decomposition of the normal matrix failed");
  const Eigen::VectorXd& lambda = eig.eigenvalues();
  if (!(lambda[0] > kMinScaledEigenvalue * lambda[n - 1])) {
    return FailedPreconditionError("the adjustment's normal matrix is singular (scaled eigenvalues ",
                                   lambda[0], " / ", lambda[n - 1], ")");
  }
  const Eigen::MatrixXd inv = eig.eigenvectors() * lambda.cwiseInverse().asDiagonal() * eig.eigenvectors().transpose();
  const Eigen::MatrixXd tangent_cov = scale.asDiagonal() * inv * scale.asDiagonal() * variance;
  // Tangent -> ambient through each block's manifold.
  std::vector<Eigen::MatrixXd> plus(blocks.size());
  for (size_t i = 0; i < blocks.size(); ++i) {
    if (problem->IsParameterBlockConstant(blocks[i])) continue;
    const int t = problem->ParameterBlockTangentSize(blocks[i]);
    const ceres::Manifold* m = problem->GetManifold(blocks[i]);
    if (m == nullptr) {
      plus[i] = Eigen::MatrixXd::Identity(sizes[i], t);
    } else {
      Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> j(sizes[i], t);
      m->PlusJacobian(blocks[i], j.data());
      plus[i] = j;
    }
  }
  for (size_t a = 0; a < blocks.size(); ++a) {
    if (plus[a].size() == 0) continue;
    const int ta = tangent_offset.at(blocks[a]);
    for (size_t b = 0; b < blocks.size(); ++b) {
      if (plus[b].size() == 0) continue;
      const int tb = tangent_offset.at(blocks[b]);
      cov.block(offset[a], offset[b], sizes[a], sizes[b]) =
          plus[a] * tangent_cov.block(ta, tb, plus[a].cols(), plus[b].cols()) * plus[b].transpose();
    }
  }
  return cov;
}

void SetIntrinsicsManifold(const IntrinsicsModel& model, double* block, ceres::Problem* problem) {
  if (model.TangentSize() == 0) {
    problem->SetParameterBlockConstant(block);
  } else if (model.TangentSize() < kIntrinsicCount) {
    problem->SetManifold(block, new LinearManifold(model.Basis()));
  }
}

LinearManifold::LinearManifold(Eigen::MatrixXd basis) : a_(std::move(basis)) {
  a_pinv_ = a_.completeOrthogonalDecomposition().pseudoInverse();
}

bool LinearManifold::Plus(const double* x, const double* delta, double* x_plus_delta) const {
  Eigen::Map<const Eigen::VectorXd> xv(x, a_.rows()), d(delta, a_.cols());
  Eigen::Map<Eigen::VectorXd>(x_plus_delta, a_.rows()) = xv + a_ * d;
  return true;
}

bool LinearManifold::PlusJacobian(const double*, double* jacobian) const {
  Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(jacobian, a_.rows(), a_.cols()) = a_;
  return true;
}

bool LinearManifold::Minus(const double* y, const double* x, double* y_minus_x) const {
  Eigen::Map<const Eigen::VectorXd> yv(y, a_.rows()), xv(x, a_.rows());
  Eigen::Map<Eigen::VectorXd>(y_minus_x, a_.cols()) = a_pinv_ * (yv - xv);
  return true;
}

bool LinearManifold::MinusJacobian(const double*, double* jacobian) const {
  Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(jacobian, a_.cols(), a_.rows()) = a_pinv_;
  return true;
}

ceres::Solver::Options SolverOptions(int threads, int max_iterations, bool schur) {
  ceres::Solver::Options options;
  options.linear_solver_type = schur ? ceres::DENSE_SCHUR : ceres::SPARSE_NORMAL_CHOLESKY;
  options.max_num_iterations = max_iterations;
  options.num_threads = threads > 0 ? threads : 1;
  // Pixel residuals of ~0.1 px: a relative cost change of 1e-12 is far below anything that moves a
  // parameter by a fraction of its sigma.
  options.function_tolerance = 1e-12;
  options.gradient_tolerance = 1e-12;
  options.parameter_tolerance = 1e-12;
  options.logging_type = ceres::SILENT;
  options.minimizer_progress_to_stdout = false;
  return options;
}

}  // namespace reflcap::calib::internal
