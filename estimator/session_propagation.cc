// Propagation (EstimationSession::Propagate, Predict): the nominal spin axes integrated at the
// integration rate with the drift of eq. (1)/(10) (drift_model.h), the configured basis terms
// beyond them (basis_term.h) and the residual drift of eq. (11), dh_in/dt = (C_in_k dw_k) x h_in
// (docs/physics.md, spin_axis.h), and the covariance transition of the spin-axis errors with the
// integrated random walk of eq. (11) as process noise. Prediction across a gap runs the same
// propagation on the readings a planned attitude implies.
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/attitude_profile.h"
#include "estimator/basis_term.h"
#include "estimator/rotation.h"
#include "estimator/session.h"
#include "estimator/session_internal.h"
#include "estimator/spin_axis.h"
#include "estimator/triad.h"
#include "estimator/units.h"
#include "estimator/utc_time.h"

namespace esg::estimator {

using Eigen::Matrix2d;
using Eigen::Matrix3d;
using Eigen::MatrixXd;
using Eigen::Quaterniond;
using Eigen::Vector3d;
using Matrix23 = Eigen::Matrix<double, 2, 3>;

using session_internal::kJ;
using session_internal::Seconds;

absl::Status EstimationSession::Propagate(const TelemetryFrame& frame) {
  const double span = Seconds(frame.time - last_time_);
  const bool rw = layout_.has_drift();

  // Readings at both ends. The pair that carries case-frame drift to inertial axes has fresh
  // readings in this frame (AttitudePair); a gyro without a reading in the frame is not held at
  // its last reading (which the spacecraft's motion has made stale): its case-frame axis at the
  // end is the one that pair's attitude implies, h_k = C_k_b C_b_in h_in, so that neither its
  // drift nor anything else depends on a reading it did not send.
  for (GyroState& g : gyros_) {
    g.has_reading = frame.gyros[g.id - 1].has_value();
    // Suspension voltages for the basis terms: the frame's, else the last received (held).
    if (g.has_reading && frame.gyros[g.id - 1]->u_k_mv.has_value()) {
      g.u_k_v = *frame.gyros[g.id - 1]->u_k_mv * kVoltsPerMv;
    }
  }
  const std::array<int, 2> pair = AttitudePair();
  const int ia = IndexOf(pair[0]), ib = IndexOf(pair[1]);
  std::vector<Vector3d> h_k_begin(gyros_.size()), h_k_end(gyros_.size());
  for (size_t i = 0; i < gyros_.size(); ++i) {
    h_k_begin[i] = gyros_[i].h_k_last;
    if (gyros_[i].has_reading) h_k_end[i] = frame.gyros[gyros_[i].id - 1]->h_k.normalized();
  }
  body_rate_b_ = Vector3d::Zero();
  rate_extrapolation_b_ = Vector3d::Zero();
  // The body rate the basis terms see over the whole interval (their w_k = C_k_b w_b): the
  // attitude pair's mean rate over the interval, not the extrapolated end rate body_rate_b_ (the
  // drift is integrated across the interval, and the mean is what its two ends measure); zero
  // when no pair has fresh readings at both ends.
  Vector3d interval_rate_b = Vector3d::Zero();
  const double previous_interval_s = previous_interval_s_;
  previous_interval_s_ = 0.0;  // set again below when this interval's mean rate is measured
  if (!gyros_[ia].has_reading || !gyros_[ib].has_reading) {
    // No pair has fresh readings: every gyro holds its last reading (the output is then not
    // valid, OutputAttitude).
    for (size_t i = 0; i < gyros_.size(); ++i) {
      if (!gyros_[i].has_reading) h_k_end[i] = h_k_begin[i];
    }
  } else {
    const auto q_end =
        PairAttitude(gyros_[ia].h_in, gyros_[ib].h_in, gyros_[ia].C_b_k() * h_k_end[ia],
                     gyros_[ib].C_b_k() * h_k_end[ib]);
    for (size_t i = 0; i < gyros_.size(); ++i) {
      if (gyros_[i].has_reading) continue;
      h_k_end[i] = q_end.ok() ? (gyros_[i].C_b_k().transpose() *
                                 q_end->toRotationMatrix().transpose() * gyros_[i].h_in)
                                    .normalized()
                              : h_k_begin[i];
    }
    if (span > 0.0) {
      // The body rate at the end of the interval, for the star-tracker latency correction of
      // the measurement update and the mount-shift test's latency alternative (D34). The interval's
      // mean rate comes from the attitude pair's attitudes at both ends, q_end = q_begin (x)
      // Exp(w_mean T); taken at the interval's midpoint and extrapolated to its end along the line
      // through the previous interval's mean (second order for a smoothly changing rate, such as a
      // slew's).
      const auto q_begin =
          PairAttitude(gyros_[ia].h_in, gyros_[ib].h_in, gyros_[ia].C_b_k() * h_k_begin[ia],
                       gyros_[ib].C_b_k() * h_k_begin[ib]);
      if (q_begin.ok() && q_end.ok()) {
        const Vector3d mean_rate_b = LogQuaternion(q_begin->conjugate() * *q_end) / span;
        interval_rate_b = mean_rate_b;
        if (previous_interval_s > 0.0) {
          rate_extrapolation_b_ =
              (mean_rate_b - previous_mean_rate_b_) * span / (span + previous_interval_s);
        }
        body_rate_b_ = mean_rate_b + rate_extrapolation_b_;
        previous_mean_rate_b_ = mean_rate_b;
        previous_interval_s_ = span;
      }
    }
  }
  double max_turn = 0.0;  // largest angle a reading turns over the interval [rad]
  for (size_t i = 0; i < gyros_.size(); ++i) {
    max_turn = std::max(max_turn, std::acos(std::clamp(h_k_begin[i].dot(h_k_end[i]), -1.0, 1.0)));
  }
  // The configured integration rate (the paper's 8 Hz); prediction instead sizes substeps to
  // the motion of the readings (one per 0.1 deg): the drift depends on time only through them.
  // Counted in double: the span is the caller's (a library user may send a frame years after the
  // previous one, or at absl::InfiniteFuture), so the count is checked before it becomes an int.
  const double substeps_wanted = adaptive_integration_
                                     ? std::ceil(max_turn / (0.1 * kRadPerDeg))
                                     : std::ceil(span * config_.filter.integration_rate_hz - 1e-9);
  if (!(substeps_wanted <= static_cast<double>(std::numeric_limits<int>::max()))) {
    return absl::OutOfRangeError(absl::StrFormat(
        "frame time %s: propagating %g s at filter.integrationRateHz %g needs %g steps, more "
        "than %d",
        FormatUtc(frame.time), span, config_.filter.integration_rate_hz, substeps_wanted,
        std::numeric_limits<int>::max()));
  }
  const int substeps = std::max(1, static_cast<int>(substeps_wanted));
  const double dt = span / substeps;
  std::vector<Matrix3d> C_b_k(gyros_.size());
  std::vector<Eigen::Matrix<double, 3, kNumDriftCoefficients>> M(
      gyros_.size(), Eigen::Matrix<double, 3, kNumDriftCoefficients>::Zero());
  for (size_t i = 0; i < gyros_.size(); ++i) C_b_k[i] = gyros_[i].C_b_k();
  // The free basis terms' columns, carried to inertial axes like M: sum of C_in_k s e_m dt.
  std::vector<MatrixXd> M_basis(gyros_.size());
  for (int i = 0; i < gyro_count(); ++i) M_basis[i] = MatrixXd::Zero(3, layout_.BasisCount(i));
  std::vector<Vector3d> h_k(gyros_.size());
  Matrix3d C_in_b = Matrix3d::Identity();
  for (int step = 0; step < substeps; ++step) {
    // Midpoint of the substep: second order in dt for the slowly varying drift.
    const double s = (step + 0.5) / substeps;
    const absl::Time substep_time = last_time_ + absl::Seconds(s * span);
    for (size_t i = 0; i < gyros_.size(); ++i) h_k[i] = SlerpUnit(h_k_begin[i], h_k_end[i], s);
    auto q =
        PairAttitude(gyros_[ia].h_in, gyros_[ib].h_in, C_b_k[ia] * h_k[ia], C_b_k[ib] * h_k[ib]);
    if (q.ok()) C_in_b = q->toRotationMatrix();
    for (size_t i = 0; i < gyros_.size(); ++i) {
      GyroState& g = gyros_[i];
      const DriftRegressorMatrix B = DriftRegressor(h_k[i]);
      const Matrix3d C_in_k = C_in_b * C_b_k[i];
      const Eigen::Matrix<double, 3, kNumDriftCoefficients> CB = C_in_k * B;
      // eq. (1)/(10) carried to inertial axes: dh_in/dt = (C_in_k dw_k) x h_in.
      Vector3d dw_in = CB * g.theta;
      if (rw) dw_in += g.T() * g.residual_drift;
      if (!g.basis.empty()) {
        // The basis terms beyond eq. (1)/(10), held and free at their current values. Only their
        // part perpendicular to h_k moves the spin axis (basis_term.h); it is taken here, with
        // the projection I - h_k h_k^T that eq. (1)/(10)'s projected-gradient form carries
        // (drift_model.h), so that the integrator (a finite rotation per substep, which the
        // along-h part would tilt at second order in dt) treats a term as the eq. (1)/(10) term
        // it equals: -(I - h h^T) C1 is the C1 term of eq. (10).
        BasisInputs in;
        in.time = substep_time;
        in.h_k = h_k[i];
        in.w_k = C_b_k[i].transpose() * interval_rate_b;
        in.u_k_v = g.u_k_v;
        const Matrix3d C_in_k_perp = C_in_k * (Matrix3d::Identity() - h_k[i] * h_k[i].transpose());
        dw_in += C_in_k_perp * BasisDriftSum_k(g.basis, in);
        const std::vector<int>& free_basis = layout_.FreeBasisTerms(i);
        for (int j = 0; j < layout_.BasisCount(i); ++j) {
          M_basis[i].col(j) += C_in_k_perp * BasisRegressor_k(g.basis[free_basis[j]], in) * dt;
        }
      }
      g.h_in = StepSpinAxis(g.h_in, dw_in, dt);
      M[i] += CB * dt;
    }
  }
  // Transition over the interval: only the spin-axis errors move,
  // d(dh)/dt = T^T [(C_in_k (B dtheta + sum_j s_j e_m(j) dvalue_j)) x h] + J dw_int (tangent
  // basis held over the interval; the sum over the free basis terms).
  // Phi = I + E, where E is nonzero only in the spin-axis rows of each gyro, in the columns of its
  // own residual drifts and free coefficients, which follow the spin-axis pair contiguously. So
  // P <- P + E P + P E^T + E P E^T + Q costs O(n k) instead of O(n^3).
  std::vector<MatrixXd> E(gyros_.size());
  for (int i = 0; i < gyro_count(); ++i) {
    GyroState& g = gyros_[i];
    // Keep the tangent basis perpendicular to the moved axis (a change of order 1e-5 rad).
    g.t1 = (g.t1 - g.t1.dot(g.h_in) * g.h_in).normalized();
    const Matrix23 Tt = g.T().transpose();
    const Matrix3d minus_hx = -Skew(g.h_in);  // v x h = -h x v
    // Columns: the spin-axis drivers of state_layout.h, residual drift, free coefficients, then
    // free basis terms.
    E[i] = MatrixXd::Zero(2, layout_.SpinAxisDriverCount(i));
    if (rw) E[i].leftCols<2>() = kJ * span;
    const std::vector<int>& free = layout_.FreeCoefficients(i);
    for (int j = 0; j < layout_.ThetaCount(i); ++j) {
      E[i].col(layout_.DriftSize() + j) = Tt * minus_hx * M[i].col(free[j]);
    }
    for (int j = 0; j < layout_.BasisCount(i); ++j) {
      E[i].col(layout_.DriftSize() + layout_.ThetaCount(i) + j) = Tt * minus_hx * M_basis[i].col(j);
    }
    // The spin axis's motion against its drivers since the last measurement update, inertial
    // (the reading-fault tracks, session_reading_faults.cc).
    if (g.motion_in.rows() != 3 || g.motion_in.cols() != E[i].cols()) {
      g.motion_in = MatrixXd::Zero(3, E[i].cols());
    }
    g.motion_in += g.T() * E[i];
    g.h_k_last = h_k_end[i];
  }
  // In place: AddFrame and Predict work on a copy of the session, so a failure here leaves the
  // caller's session untouched. Only the spin-axis rows and columns (and the random-walk blocks)
  // change; they are symmetrised and checked, the rest of P is untouched.
  std::vector<MatrixXd> EP(gyros_.size());
  for (int i = 0; i < gyro_count(); ++i) {
    EP[i] = E[i] * P_.middleRows(layout_.SpinAxisDrivers(i), E[i].cols());  // 2 x n, from P before
  }
  std::vector<std::vector<Matrix2d>> EPEt(gyros_.size(), std::vector<Matrix2d>(gyros_.size()));
  for (int i = 0; i < gyro_count(); ++i) {
    for (int j = 0; j < gyro_count(); ++j) {
      EPEt[i][j] = EP[i].middleCols(layout_.SpinAxisDrivers(j), E[j].cols()) * E[j].transpose();
    }
  }
  for (int i = 0; i < gyro_count(); ++i) P_.middleRows(layout_.SpinAxis(i), 2) += EP[i];
  for (int i = 0; i < gyro_count(); ++i) P_.middleCols(layout_.SpinAxis(i), 2) += EP[i].transpose();
  for (int i = 0; i < gyro_count(); ++i) {
    for (int j = 0; j <= i; ++j) {
      const int oi = layout_.SpinAxis(i), oj = layout_.SpinAxis(j);
      const Matrix2d block = 0.5 * (P_.block<2, 2>(oi, oj) + P_.block<2, 2>(oj, oi).transpose()) +
                             0.5 * (EPEt[i][j] + EPEt[j][i].transpose());
      P_.block<2, 2>(oi, oj) = block;
      P_.block<2, 2>(oj, oi) = block.transpose();
    }
    if (rw) {
      // Integrated random walk (eq. (11)) over the interval.
      const double q_rw = RandomWalkOf(gyros_[i].id);  // eq. (11)
      const double q2 = q_rw * q_rw;
      const int h = layout_.SpinAxis(i), d = layout_.Drift(i);
      P_.block<2, 2>(d, d) += q2 * span * Matrix2d::Identity();
      P_.block<2, 2>(h, d) += q2 * span * span / 2.0 * kJ;
      P_.block<2, 2>(d, h) += q2 * span * span / 2.0 * kJ.transpose();
      P_.block<2, 2>(h, h) += q2 * span * span * span / 3.0 * Matrix2d::Identity();
    }
  }
  if (widening_.widened()) {
    // The adaptive process noise (noise_widening.h): white noise on the spin-axis angles adding
    // the widening's variance per measurement step.
    const double q_w = widening_.added_variance() / config_.filter.measurement_step;
    for (int i = 0; i < gyro_count(); ++i) {
      P_.block<2, 2>(layout_.SpinAxis(i), layout_.SpinAxis(i)) += q_w * span * Matrix2d::Identity();
    }
  }
  // The rows that changed: spin axis, then residual drift (contiguous, state_layout.h).
  const int rows = StateLayout::kSpinAxisSize + layout_.DriftSize();
  for (int i = 0; i < gyro_count(); ++i) {
    const int h = layout_.SpinAxis(i);
    if (!P_.middleRows(h, rows).allFinite()) {
      return absl::InternalError(
          absl::StrFormat("covariance of gyro %d is not finite after propagation", gyros_[i].id));
    }
    for (int k = 0; k < rows; ++k) {
      if (P_(h + k, h + k) < 0.0) {
        return absl::InternalError(
            absl::StrFormat("covariance of gyro %d has a negative variance", gyros_[i].id));
      }
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<std::vector<PredictedSample>> EstimationSession::Predict(
    const std::vector<absl::Time>& times, const AttitudeProfile* planned,
    absl::Time planned_start) const {
  if (!initialized_) {
    return absl::FailedPreconditionError(
        "prediction needs an initialised session (no star-tracker fix yet)");
  }
  EstimationSession s = *this;
  s.use_star_tracker_ = false;
  s.adaptive_integration_ = true;
  const Quaterniond q_hold = CurrentAttitude().q_in_b;
  std::vector<PredictedSample> out;
  out.reserve(times.size());
  for (absl::Time t : times) {
    if (t <= s.last_time_) {
      return absl::OutOfRangeError(absl::StrCat("prediction time ", FormatUtc(t),
                                                " is not after the last frame ",
                                                FormatUtc(s.last_time_)));
    }
    const Quaterniond q_in_b =
        planned != nullptr ? planned->Attitude(Seconds(t - planned_start)) : q_hold;
    const Matrix3d C_b_in = q_in_b.toRotationMatrix().transpose();
    // The readings the plan implies: h_k = C_k_b C_b_in h_in (gyros' current predicted axes).
    TelemetryFrame frame;
    frame.time = t;
    for (const GyroState& g : s.gyros_) {
      GyroReading r;
      r.h_k = (g.C_b_k().transpose() * C_b_in * g.h_in).normalized();
      frame.gyros[g.id - 1] = r;
    }
    // Propagation only (no measurement), then the output is the plan with the envelope of the
    // propagated covariance.
    if (absl::Status st = s.Propagate(frame); !st.ok()) return st;
    s.last_time_ = t;
    for (GyroState& g : s.gyros_) {
      g.h_k_last = (g.C_b_k().transpose() * C_b_in * g.h_in).normalized();
    }
    PredictedSample sample;
    sample.time = t;
    sample.attitude = s.OutputAttitude(t);
    sample.attitude.q_in_b = q_in_b;
    for (const GyroState& g : s.gyros_) sample.h_in.emplace_back(g.id, g.h_in);
    out.push_back(std::move(sample));
  }
  return out;
}

}  // namespace esg::estimator
