// The attitude of a gyro pair (EstimationSession::PairQuaternion, OutputAttitude): q_in_b from
// the two predicted inertial spin axes and their measured body-frame directions (TRIAD,
// triad.h), and its covariance in inertial axes from the spin-axis and misalignment states and
// the readout noise. This is the L_in,c of each pair in eq. (12) and the session's output.
#include "estimator/session.h"

#include <algorithm>
#include <array>
#include <optional>

#include "absl/strings/str_format.h"
#include "estimator/measurements.h"
#include "estimator/rotation.h"
#include "estimator/session_internal.h"
#include "estimator/triad.h"

namespace esg::estimator {

using Eigen::Matrix3d;
using Eigen::MatrixXd;
using Eigen::Quaterniond;
using Eigen::Vector3d;
using Matrix32 = Eigen::Matrix<double, 3, 2>;

using session_internal::kNoiseFloor;

Eigen::Matrix<double, 3, 2> EstimationSession::GyroState::T() const {
  Matrix32 T;
  T.col(0) = t1;
  T.col(1) = t2();
  return T;
}

Matrix3d EstimationSession::GyroState::C_b_k() const {
  return ExpMatrix(phi_b) * C_b_k_config;
}

std::optional<Quaterniond> EstimationSession::PairQuaternion(int a, int b, const Vector3d& h_k_a,
                                                             const Vector3d& h_k_b,
                                                             Matrix3d* covariance_in,
                                                             MatrixXd* jacobian_state,
                                                             MatrixXd* jacobian_readout) const {
  const int ia = IndexOf(a);
  const int ib = IndexOf(b);
  if (ia < 0 || ib < 0) return std::nullopt;
  const GyroState* ga = &gyros_[ia];
  const GyroState* gb = &gyros_[ib];
  const Matrix3d C_a = ga->C_b_k(), C_b = gb->C_b_k();
  const auto q0 = PairAttitude(ga->h_in, gb->h_in, C_a * h_k_a, C_b * h_k_b);
  if (!q0.ok()) return std::nullopt;
  if (covariance_in == nullptr) return *q0;

  // Attitude error dtheta_in (q_true = Exp(dtheta_in) q_est) against the state errors of the two
  // gyros and their readout noise, to first order (TriadLinearisation, triad.h): a spin-axis
  // error moves the inertial triad, a misalignment or a readout error the body triad, and
  // dtheta_in = omega_in - C_in_b omega_b. Only the two gyros' columns are nonzero: at most 2 + 3
  // each (spin axis, misalignment phi when the layout has it).
  const Vector3d h_b_a = C_a * h_k_a, h_b_b = C_b * h_k_b;
  const TriadLinearisation inertial(ga->h_in, gb->h_in), body(h_b_a, h_b_b);
  const Matrix3d C_in_b = q0->toRotationMatrix();
  const Vector3d none = Vector3d::Zero();
  constexpr int kMaxColumns = 10;
  Eigen::Matrix<double, 3, kMaxColumns> J_columns;
  std::array<int, kMaxColumns> cols{};
  int m = 0;
  auto add = [&](int col, const Vector3d& dtheta_in) {
    cols[m] = col;
    J_columns.col(m++) = dtheta_in;
  };
  const Matrix32 Ta = ga->T(), Tb = gb->T();
  for (int i = 0; i < 2; ++i) add(layout_.SpinAxis(ia) + i, inertial.RotationOf(Ta.col(i), none));
  if (layout_.HasPhi(ia)) {
    for (int i = 0; i < 3; ++i) {
      add(layout_.Phi(ia) + i,
          -C_in_b * body.RotationOf(Vector3d::Unit(i).cross(h_b_a), none));
    }
  }
  for (int i = 0; i < 2; ++i) add(layout_.SpinAxis(ib) + i, inertial.RotationOf(none, Tb.col(i)));
  if (layout_.HasPhi(ib)) {
    for (int i = 0; i < 3; ++i) {
      add(layout_.Phi(ib) + i,
          -C_in_b * body.RotationOf(none, Vector3d::Unit(i).cross(h_b_b)));
    }
  }
  const Matrix32 Ua = TangentBasis(h_k_a), Ub = TangentBasis(h_k_b);
  Eigen::Matrix<double, 3, 4> J_r;
  for (int i = 0; i < 2; ++i) {
    J_r.col(i) = -C_in_b * body.RotationOf(C_a * Ua.col(i), none);
    J_r.col(2 + i) = -C_in_b * body.RotationOf(none, C_b * Ub.col(i));
  }
  const auto Js = J_columns.leftCols(m);
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, kMaxColumns, kMaxColumns> Ps(m, m);
  for (int i = 0; i < m; ++i) {
    for (int j = 0; j < m; ++j) Ps(i, j) = P_(cols[i], cols[j]);
  }
  if (jacobian_state != nullptr) {
    *jacobian_state = MatrixXd::Zero(3, state_size());
    for (int i = 0; i < m; ++i) jacobian_state->col(cols[i]) = Js.col(i);
  }
  if (jacobian_readout != nullptr) {
    *jacobian_readout = MatrixXd::Zero(3, 2 * gyro_count());
    jacobian_readout->block<3, 2>(0, 2 * ia) = J_r.leftCols<2>();
    jacobian_readout->block<3, 2>(0, 2 * ib) = J_r.rightCols<2>();
  }
  const double sigma_r = std::max(config_.readout_noise, kNoiseFloor);
  *covariance_in = Js * Ps * Js.transpose() + sigma_r * sigma_r * J_r * J_r.transpose();
  return *q0;
}

std::array<int, 2> EstimationSession::AttitudePair() const {
  const GyroState* a = Find(working_pair_[0]);
  const GyroState* b = Find(working_pair_[1]);
  if (a != nullptr && b != nullptr && a->has_reading && b->has_reading) return working_pair_;
  for (size_t i = 0; i < gyros_.size(); ++i) {
    for (size_t j = i + 1; j < gyros_.size(); ++j) {
      const GyroState& gi = gyros_[i];
      const GyroState& gj = gyros_[j];
      if (!gi.faulty && !gj.faulty && gi.has_reading && gj.has_reading) return {gi.id, gj.id};
    }
  }
  return working_pair_;
}

AttitudeEstimate EstimationSession::OutputAttitude(absl::Time time) const {
  AttitudeEstimate out;
  out.time = time;
  out.pair = AttitudePair();
  const GyroState* a = Find(out.pair[0]);
  const GyroState* b = Find(out.pair[1]);
  if (!initialized_ || a == nullptr || b == nullptr) {
    out.invalid_reason = "no star-tracker fix with the working pair's readings yet";
    return out;
  }
  if (a->faulty || b->faulty) {
    out.invalid_reason = absl::StrFormat(
        "no usable pair: gyro %d excluded (%s)", a->faulty ? a->id : b->id,
        (a->faulty ? a : b)->exclusion.Describe());
    return out;
  }
  if (!a->has_reading || !b->has_reading) {
    std::string missing;
    for (const GyroState& g : gyros_) {
      if (!g.faulty && !g.has_reading) {
        missing += absl::StrFormat("%s%d", missing.empty() ? "" : ", ", g.id);
      }
    }
    out.invalid_reason = absl::StrFormat(
        "no pair of healthy gyros has a reading in this frame (missing: gyro %s)", missing);
    return out;
  }
  Matrix3d S_in;
  const auto q = PairQuaternion(a->id, b->id, a->h_k_last, b->h_k_last, &S_in);
  if (!q.has_value()) {
    out.invalid_reason = absl::StrFormat("pair [%d,%d]: spin axes too close to form an attitude",
                                         a->id, b->id);
    return out;
  }
  out.q_in_b = *q;
  const Matrix3d C_b_in = q->toRotationMatrix().transpose();
  const Matrix3d S_b = C_b_in * S_in * C_b_in.transpose();
  out.sigma_b = S_b.diagonal().cwiseMax(0.0).cwiseSqrt();
  out.valid = true;
  return out;
}

}  // namespace esg::estimator
