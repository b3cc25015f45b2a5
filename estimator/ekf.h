// Generic extended-Kalman-filter algebra, no physics: covariance propagation and the Joseph-form
// measurement update, both transactional: the candidate (dx, P) is committed only
// when it is finite and P stays symmetric with a non-negative diagonal; otherwise the inputs are
// untouched and Internal is returned with the diagnostic.
#ifndef ESG_ESTIMATOR_EKF_H_
#define ESG_ESTIMATOR_EKF_H_

#include "Eigen/Core"
#include "absl/status/status.h"

namespace esg::estimator {

// Symmetrises the candidate covariance and commits it to P when CheckCovariance passes.
absl::Status CommitCovariance(Eigen::MatrixXd candidate, Eigen::MatrixXd& P);

// P <- Phi P Phi^T + Q, then symmetrised.
absl::Status PropagateCovariance(const Eigen::MatrixXd& Phi, const Eigen::MatrixXd& Q,
                                 Eigen::MatrixXd& P);

// Joseph form: K = P H^T S^-1, S = H P H^T + R, dx = K z,
// P <- (I - K H) P (I - K H)^T + K R K^T, symmetrised. dx is the error-state correction
// (true - estimate, conventions.h) to feed back into the nominal state.
absl::Status JosephUpdate(const Eigen::MatrixXd& H, const Eigen::VectorXd& z,
                          const Eigen::MatrixXd& R, Eigen::MatrixXd& P, Eigen::VectorXd& dx);

// Checks P: finite, symmetric to rel. 1e-9, diagonal >= 0. Internal with the reason otherwise.
absl::Status CheckCovariance(const Eigen::MatrixXd& P);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_EKF_H_
