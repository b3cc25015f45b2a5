#include "estimator/ekf.h"

#include <cmath>

#include "Eigen/Cholesky"
#include "absl/strings/str_format.h"

namespace esg::estimator {

using Eigen::MatrixXd;
using Eigen::VectorXd;

absl::Status CheckCovariance(const MatrixXd& P) {
  if (P.rows() != P.cols()) return absl::InternalError("covariance is not square");
  if (P.size() == 0) return absl::OkStatus();  // no state yet (maxCoeff of nothing is undefined)
  if (!P.allFinite()) return absl::InternalError("covariance has non-finite entries");
  const double scale = P.diagonal().cwiseAbs().maxCoeff();
  if ((P - P.transpose()).cwiseAbs().maxCoeff() > 1e-9 * std::max(scale, 1e-300)) {
    return absl::InternalError("covariance is not symmetric");
  }
  for (int i = 0; i < P.rows(); ++i) {
    if (P(i, i) < 0.0) {
      return absl::InternalError(absl::StrFormat("covariance diagonal %d is negative (%g)", i, P(i, i)));
    }
  }
  return absl::OkStatus();
}

absl::Status CommitCovariance(MatrixXd candidate, MatrixXd& P) {
  candidate = (0.5 * (candidate + candidate.transpose())).eval();
  if (absl::Status s = CheckCovariance(candidate); !s.ok()) return s;
  P = std::move(candidate);
  return absl::OkStatus();
}

absl::Status PropagateCovariance(const MatrixXd& Phi, const MatrixXd& Q, MatrixXd& P) {
  return CommitCovariance(Phi * P * Phi.transpose() + Q, P);
}

absl::Status JosephUpdate(const MatrixXd& H, const VectorXd& z, const MatrixXd& R, MatrixXd& P,
                          VectorXd& dx) {
  const MatrixXd PHt = P * H.transpose();
  const MatrixXd S = H * PHt + R;
  Eigen::LLT<MatrixXd> llt(S);
  if (llt.info() != Eigen::Success) {
    return absl::InternalError("innovation covariance S = H P H^T + R is not positive definite");
  }
  const MatrixXd K = llt.solve(PHt.transpose()).transpose();
  const MatrixXd IKH = MatrixXd::Identity(P.rows(), P.cols()) - K * H;
  MatrixXd candidate = IKH * P * IKH.transpose() + K * R * K.transpose();
  candidate = (0.5 * (candidate + candidate.transpose())).eval();
  VectorXd candidate_dx = K * z;
  if (!candidate_dx.allFinite()) return absl::InternalError("state correction is not finite");
  if (absl::Status s = CheckCovariance(candidate); !s.ok()) return s;
  P = std::move(candidate);
  dx = std::move(candidate_dx);
  return absl::OkStatus();
}

}  // namespace esg::estimator
