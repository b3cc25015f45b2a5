// Filter start (EstimationSession::Initialize): the running gyros and their state layout, the
// tangent bases from the `int` frame of the working pair, the prior covariance of the drift
// coefficients of eq. (1)/(10) and of the free basis terms (basis_term.h), the residual drifts of
// eq. (11) and the misalignments; and the spin axes rebuilt from the star tracker,
// h_in = C_in_b(star tracker) C_b_k h_k (the h_et of eq. (13)), with the covariance that rebuild
// implies (also used by the filter reset).
#include "estimator/session.h"

#include <algorithm>
#include <utility>
#include <vector>

#include "absl/strings/str_format.h"
#include "estimator/calibration_model.h"
#include "estimator/ekf.h"
#include "estimator/measurements.h"
#include "estimator/rotation.h"
#include "estimator/session_internal.h"
#include "estimator/triad.h"
#include "estimator/units.h"

namespace esg::estimator {

using Eigen::Matrix2d;
using Eigen::Matrix3d;
using Eigen::MatrixXd;
using Eigen::Vector3d;
using Matrix23 = Eigen::Matrix<double, 2, 3>;

using session_internal::kNoiseFloor;

absl::Status EstimationSession::Initialize(const TelemetryFrame& frame) {
  const auto& st = frame.star_tracker;
  if (!st.has_value() || !st->valid) return absl::OkStatus();  // wait for a star-tracker fix
  const auto& wa = frame.gyros[working_pair_[0] - 1];
  const auto& wb = frame.gyros[working_pair_[1] - 1];
  if (!wa.has_value() || !wb.has_value()) return absl::OkStatus();  // wait for the working pair

  // Running gyros: the configured gyros that report in this frame, working pair first.
  std::vector<int> order = {working_pair_[0], working_pair_[1]};
  for (const GyroConfig& gc : config_.gyros) {
    if (gc.id != working_pair_[0] && gc.id != working_pair_[1] &&
        frame.gyros[gc.id - 1].has_value()) {
      order.push_back(gc.id);
    }
  }
  const Matrix3d C_in_b = st->q_in_b.normalized().toRotationMatrix();
  gyros_.clear();
  for (int id : order) {
    const GyroConfig& gc = *config_.FindGyro(id);
    GyroState g;
    g.id = id;
    g.C_b_k_config = gc.C_b_k;
    g.theta = ModelCoefficients(options_.model, gc);
    g.basis = gc.basis_terms;
    g.has_reading = true;
    g.h_k_last = frame.gyros[id - 1]->h_k.normalized();
    if (const auto& u_mv = frame.gyros[id - 1]->u_k_mv) g.u_k_v = *u_mv * kVoltsPerMv;
    g.h_in = (C_in_b * g.C_b_k_config * g.h_k_last).normalized();  // bases below need it
    gyros_.push_back(std::move(g));
  }
  layout_ = LayoutFor(config_, options_.model, gyros_);
  // Tangent bases from e1 = unit(h_a x h_b) of the working pair (conventions.h).
  auto C_int_in = QuasiInertialFrame(gyros_[0].h_in, gyros_[1].h_in);
  if (!C_int_in.ok()) return C_int_in.status();
  const Vector3d e1 = C_int_in->row(0).transpose();
  for (GyroState& g : gyros_) {
    Vector3d t1 = e1 - e1.dot(g.h_in) * g.h_in;
    g.t1 = t1.norm() > 0.1 ? t1.normalized() : AnyPerpendicular(g.h_in);
  }

  // Prior covariance of the coefficients, residual drifts and misalignments, then the spin axes.
  const int n = layout_.size();
  P_ = MatrixXd::Zero(n, n);
  for (int i = 0; i < gyro_count(); ++i) SetDriftAndMisalignmentPrior(i, P_);
  if (layout_.has_latency()) {
    const double sigma_tau = config_.star_tracker.latency_sigma;
    P_(layout_.Latency(), layout_.Latency()) = sigma_tau * sigma_tau;
  }
  SpinAxesFromStarTracker(C_in_b);
  P0_ = P_;
  initialized_ = true;
  start_time_ = frame.time;
  last_update_time_ = frame.time;
  state_ = SessionState::kCalibrating;
  return CheckCovariance(P_);
}

void EstimationSession::SetDriftAndMisalignmentPrior(int i, MatrixXd& P) const {
  const GyroConfig& gc = *config_.FindGyro(gyros_[i].id);
  if (layout_.has_drift()) {
    const double sigma_rw0 = InitialResidualDriftSigma(options_);
    const int d = layout_.Drift(i);
    P.block<2, 2>(d, d) = sigma_rw0 * sigma_rw0 * Matrix2d::Identity();
  }
  const DriftVector sigma_theta = gc.model_sigma.AsVector();
  const std::vector<int>& free = layout_.FreeCoefficients(i);
  for (int j = 0; j < layout_.ThetaCount(i); ++j) {
    const int idx = layout_.Theta(i) + j;
    P(idx, idx) = sigma_theta(free[j]) * sigma_theta(free[j]);
  }
  const std::vector<int>& free_basis = layout_.FreeBasisTerms(i);
  for (int j = 0; j < layout_.BasisCount(i); ++j) {
    const int idx = layout_.Basis(i) + j;
    const double sigma = gc.basis_terms[free_basis[j]].sigma;
    P(idx, idx) = sigma * sigma;
  }
  if (layout_.HasPhi(i)) {
    const int po = layout_.Phi(i);
    P.block<3, 3>(po, po) = gc.misalignment_sigma * gc.misalignment_sigma * Matrix3d::Identity();
  }
}

void EstimationSession::StartSwitchedOnGyros(const TelemetryFrame& frame, StepReport& report) {
  if (!initialized_ || !report.measurement_step) return;
  // The attitude the new spin axis is rebuilt with: the star tracker when this step accepted it,
  // otherwise the output pair's.
  const auto& st = frame.star_tracker;
  const bool from_star_tracker = report.star_tracker_used && st.has_value() && st->valid;
  if (!from_star_tracker && !report.attitude.valid) return;
  // The star tracker's sample corrected for its latency, as in MeasurementUpdate.
  const Matrix3d C_in_b = from_star_tracker ? StarTrackerCorrected(st->q_in_b).toRotationMatrix()
                                            : report.attitude.q_in_b.toRotationMatrix();
  const Vector3d sigma_att_b = from_star_tracker
                                   ? config_.star_tracker.noise.cwiseMax(kNoiseFloor)
                                   : report.attitude.sigma_b.cwiseMax(kNoiseFloor);
  const double sigma_r = std::max(config_.readout_noise, kNoiseFloor);
  for (const GyroConfig& gc : config_.gyros) {
    if (Find(gc.id) != nullptr || !frame.gyros[gc.id - 1].has_value()) continue;
    GyroState g;
    g.id = gc.id;
    g.C_b_k_config = gc.C_b_k;
    g.theta = ModelCoefficients(options_.model, gc);
    g.basis = gc.basis_terms;
    g.has_reading = true;
    g.h_k_last = frame.gyros[gc.id - 1]->h_k.normalized();
    if (const auto& u_mv = frame.gyros[gc.id - 1]->u_k_mv) g.u_k_v = *u_mv * kVoltsPerMv;
    g.h_in = (C_in_b * g.C_b_k_config * g.h_k_last).normalized();
    const Vector3d e1 = gyros_[0].t1;  // the reference gyro's t1 is e1 of the int frame
    const Vector3d t1 = e1 - e1.dot(g.h_in) * g.h_in;
    g.t1 = t1.norm() > 0.1 ? t1.normalized() : AnyPerpendicular(g.h_in);
    const int old_n = state_size();
    gyros_.push_back(g);
    layout_ = LayoutFor(config_, options_.model, gyros_);
    const int n = layout_.size();
    const int i = gyro_count() - 1;
    // Appending a gyro appends its block (state_layout.h): the old indices hold.
    MatrixXd P = MatrixXd::Zero(n, n), P0 = MatrixXd::Zero(n, n);
    P.topLeftCorner(old_n, old_n) = P_;
    P0.topLeftCorner(old_n, old_n) = P0_;
    // The prior of a gyro that starts uncalibrated: that of Initialize for its coefficients,
    // residual drift and misalignment; its spin axis errs by the misalignment, the attitude it
    // was rebuilt with and the readout (a diagonal bound: its correlation with the other gyros
    // through that attitude is left out).
    SetDriftAndMisalignmentPrior(i, P);
    const double var_h = gc.misalignment_sigma * gc.misalignment_sigma +
                         sigma_att_b.squaredNorm() + sigma_r * sigma_r;
    P.block<2, 2>(layout_.SpinAxis(i), layout_.SpinAxis(i)) = var_h * Matrix2d::Identity();
    for (int k = old_n; k < n; ++k) P0(k, k) = P(k, k);
    P_ = std::move(P);
    P0_ = std::move(P0);
    // The new gyro forms the reserve pair with the reference gyro of the output pair.
    reserve_pair_ = {working_pair_[0], g.id};
    report.events.push_back(Event{
        Event::Kind::kGyroStarted, frame.time, absl::StrFormat("gyro %d", g.id),
        static_cast<double>(gyro_count()), 3.0, "running gyros",
        absl::StrFormat("gyro %d reports (switched on): its spin axis initialised from the %s, "
                        "its drift model calibrated from the configured prior; %d gyros in use, "
                        "reserve pair [%d,%d]",
                        g.id, from_star_tracker ? "star tracker" : "output pair's attitude",
                        gyro_count(), reserve_pair_[0], reserve_pair_[1])});
  }
}

void EstimationSession::SpinAxesFromStarTracker(const Matrix3d& C_in_b) {
  // The spin axes rebuilt from the star tracker, h_in = C_in_b(st) C_b_k h_k, err by the
  // misalignment, the star-tracker noise (shared by all gyros), its latency's error (when a state)
  // and the readout noise: dh_g = -H_phi,g phi_g - G_st,g (n_st - w_b dtau) - G_r,g r_g with the
  // Jacobians of the star-tracker measurement (MeasurementUpdate).
  const Matrix3d Sigma_st = StarTrackerVarianceB().asDiagonal();
  const double sigma_r = std::max(config_.readout_noise, kNoiseFloor);
  std::vector<Matrix23> G_st(gyros_.size());
  for (int i = 0; i < gyro_count(); ++i) {
    GyroState& g = gyros_[i];
    g.h_in = (C_in_b * g.C_b_k() * g.h_k_last).normalized();
    g.t1 = (g.t1 - g.t1.dot(g.h_in) * g.h_in).normalized();
    P_.middleRows(layout_.SpinAxis(i), 2).setZero();
    P_.middleCols(layout_.SpinAxis(i), 2).setZero();
  }
  // A maps the state to the spin-axis errors through the misalignments (zero on the spin axes).
  const int n = state_size();
  MatrixXd A = MatrixXd::Zero(n, n);
  MatrixXd noise = MatrixXd::Zero(n, n);
  for (int i = 0; i < gyro_count(); ++i) {
    GyroState& g = gyros_[i];
    const int h = layout_.SpinAxis(i);
    const Matrix23 Tt = g.T().transpose();
    const Vector3d h_b = g.C_b_k() * g.h_k_last;
    G_st[i] = -Tt * C_in_b * Skew(h_b);
    if (layout_.HasPhi(i)) A.block<2, 3>(h, layout_.Phi(i)) = -Tt * C_in_b * Skew(h_b);
    // The latency-corrected star tracker errs by the body rotation -w_b dtau (session.h).
    if (layout_.has_latency()) A.block<2, 1>(h, layout_.Latency()) = G_st[i] * body_rate_b_;
    const Matrix2d G_r = Tt * C_in_b * g.C_b_k() * TangentBasis(g.h_k_last);
    noise.block<2, 2>(h, h) += sigma_r * sigma_r * G_r * G_r.transpose();
  }
  for (int i = 0; i < gyro_count(); ++i) {
    for (int j = 0; j < gyro_count(); ++j) {
      noise.block<2, 2>(layout_.SpinAxis(i), layout_.SpinAxis(j)) +=
          G_st[i] * Sigma_st * G_st[j].transpose();
    }
  }
  // dh = A x + n: P_dh,x = A P (for x not a spin axis), P_dh,dh = A P A^T + N.
  const MatrixXd AP = A * P_;
  const MatrixXd APAt = AP * A.transpose();
  for (int i = 0; i < gyro_count(); ++i) {
    const int h = layout_.SpinAxis(i);
    P_.middleRows(h, 2) = AP.middleRows(h, 2);
    P_.middleCols(h, 2) = AP.middleRows(h, 2).transpose();
  }
  for (int i = 0; i < gyro_count(); ++i) {
    for (int j = 0; j < gyro_count(); ++j) {
      const int hi = layout_.SpinAxis(i), hj = layout_.SpinAxis(j);
      P_.block<2, 2>(hi, hj) = APAt.block<2, 2>(hi, hj) + noise.block<2, 2>(hi, hj);
    }
  }
  P_ = (0.5 * (P_ + P_.transpose())).eval();
}

}  // namespace esg::estimator
