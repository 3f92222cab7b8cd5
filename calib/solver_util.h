#pragma once
// Small statistics and Ceres helpers shared by the intrinsics and turntable adjustments. Internal
// to calib/.
#include <vector>

#include <ceres/ceres.h>

#include "calib/camera_model.h"
#include "engine/core/status.h"
#include "engine/math/types.h"

namespace reflcap::calib::internal {

// 1.4826 x the median absolute value: the standard deviation of Gaussian data, robust to outliers.
double RobustSigma(std::vector<double> values);
double Median(std::vector<double> values);
double Rms(const std::vector<double>& values);

// Covariance of the listed parameter blocks (each block's full size, in the order given) from the
// problem's Jacobian at its current point (no loss function), over every free parameter of the
// problem, multiplied by `variance` (the residual variance: the residuals are in pixels, not in
// units of their standard deviation). Blocks held constant get zero rows and columns; a parameter
// a manifold holds gets zero variance. The normal matrix is scaled to unit diagonal before it is
// inverted, so that its condition number compares directions, not units (pixels against
// radians against metres); FailedPrecondition when a direction is numerically undetermined.
StatusOr<Eigen::MatrixXd> BlockCovariance(ceres::Problem* problem, const std::vector<double*>& blocks,
                                          const std::vector<int>& sizes, double variance);

// An affine subspace of R^n as a Ceres manifold: x + A delta. Holds parameters (columns of the
// identity for the free ones) and ties them (a column with several ones: fx = fy share a step).
class LinearManifold : public ceres::Manifold {
 public:
  explicit LinearManifold(Eigen::MatrixXd basis);
  int AmbientSize() const override { return int(a_.rows()); }
  int TangentSize() const override { return int(a_.cols()); }
  bool Plus(const double* x, const double* delta, double* x_plus_delta) const override;
  bool PlusJacobian(const double* x, double* jacobian) const override;
  bool Minus(const double* y, const double* x, double* y_minus_x) const override;
  bool MinusJacobian(const double* x, double* jacobian) const override;

 private:
  Eigen::MatrixXd a_;       // ambient x tangent
  Eigen::MatrixXd a_pinv_;  // tangent x ambient
};

// Sets the intrinsics block's manifold for `model` (or holds the block when nothing is free).
void SetIntrinsicsManifold(const IntrinsicsModel& model, double* block, ceres::Problem* problem);

// Ceres options for the small dense problems of calibration.
// `schur`: eliminate the many small pose blocks first (intrinsics); otherwise dense normal
// equations (the turntable problem has no such structure).
ceres::Solver::Options SolverOptions(int threads, int max_iterations, bool schur);

}  // namespace reflcap::calib::internal
