#include "estimator/session.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/attitude_profile.h"
#include "estimator/ekf.h"
#include "estimator/fault_detection.h"
#include "estimator/measurements.h"
#include "estimator/rotation.h"
#include "estimator/spin_axis.h"
#include "estimator/triad.h"
#include "estimator/units.h"

namespace esg::estimator {

using Eigen::Matrix2d;
using Eigen::Matrix3d;
using Eigen::MatrixXd;
using Eigen::Quaterniond;
using Eigen::Vector2d;
using Eigen::Vector3d;
using Eigen::VectorXd;
using Matrix32 = Eigen::Matrix<double, 3, 2>;
using Matrix23 = Eigen::Matrix<double, 2, 3>;

namespace {

// Floors keep R positive definite when a configuration sets a noise to zero.
constexpr double kNoiseFloor = 0.01 * kRadPerArcsec;
// Floor of the eq. (12) allowed angle.
constexpr double kMismatchFloor = 2.0 * kRadPerArcsec;
// Numerical-Jacobian step for the pair attitude [rad]: TRIAD is smooth, central differences
// have truncation error ~eps^2 (1e-14 rad) and rounding ~1e-16/eps (1e-9 relative).
constexpr double kJacobianStep = 1e-7;
// d(dh)/dt = J dw_int in the tangent basis: (T w) x h = w2 t1 - w1 t2.
const Matrix2d kJ = (Matrix2d() << 0.0, 1.0, -1.0, 0.0).finished();

double Seconds(absl::Duration d) { return absl::ToDoubleSeconds(d); }

}  // namespace

const char* SessionStateName(SessionState s) {
  switch (s) {
    case SessionState::kNoData:
      return "NO_DATA";
    case SessionState::kCalibrating:
      return "CALIBRATING";
    case SessionState::kConverged:
      return "CONVERGED";
    case SessionState::kAutonomous:
      return "AUTONOMOUS";
    case SessionState::kFaulted:
      return "FAULTED";
  }
  return "?";
}

const char* EventKindName(Event::Kind kind) {
  switch (kind) {
    case Event::Kind::kStarTrackerInnovation:
      return "STAR_TRACKER_INNOVATION";
    case Event::Kind::kStarTrackerFault:
      return "STAR_TRACKER_FAULT";
    case Event::Kind::kWorkingPairFault:
      return "WORKING_PAIR_FAULT";
    case Event::Kind::kReservePairFault:
      return "RESERVE_PAIR_FAULT";
    case Event::Kind::kGyroDataRejected:
      return "GYRO_DATA_REJECTED";
    case Event::Kind::kStarTrackerInvalid:
      return "STAR_TRACKER_INVALID";
    case Event::Kind::kFilterReset:
      return "FILTER_RESET";
  }
  return "?";
}

Eigen::Matrix<double, 3, 2> EstimationSession::GyroState::T() const {
  Matrix32 T;
  T.col(0) = t1;
  T.col(1) = t2();
  return T;
}

Matrix3d EstimationSession::GyroState::C_b_k() const {
  return ExpMatrix(phi_b) * C_b_k_config;
}

absl::StatusOr<EstimationSession> EstimationSession::Create(const SpacecraftConfig& config,
                                                            const SessionOptions& options) {
  if (absl::Status s = ValidateConfig(config); !s.ok()) return s;
  const ModelSpec& m = options.model;
  if (!m.k0 && !m.c1c2 && !m.mu_nu && !m.random_walk) {
    return absl::InvalidArgumentError("model: no term selected (use 1, 10, 11 or e.g. 10+11)");
  }
  EstimationSession session;
  session.config_ = config;
  session.options_ = options;
  session.working_pair_ = config.working_pair;
  session.reserve_pair_ = config.reserve_pair;
  return session;
}

EstimationSession::GyroState* EstimationSession::Find(int id) {
  for (GyroState& g : gyros_) {
    if (g.id == id) return &g;
  }
  return nullptr;
}

const EstimationSession::GyroState* EstimationSession::Find(int id) const {
  for (const GyroState& g : gyros_) {
    if (g.id == id) return &g;
  }
  return nullptr;
}

int EstimationSession::IndexOf(int id) const {
  for (int i = 0; i < gyro_count(); ++i) {
    if (gyros_[i].id == id) return i;
  }
  return -1;
}

StateLayout EstimationSession::LayoutFor(const SpacecraftConfig& config, const ModelSpec& model,
                                         const std::vector<GyroState>& gyros) {
  StateLayout layout(model.random_walk);
  for (const GyroState& g : gyros) {
    const GyroConfig& gc = *config.FindGyro(g.id);
    layout.AddGyro(FreeCoefficients(model, gc), gc.misalignment_sigma > 0.0);
  }
  return layout;
}

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
    g.has_reading = true;
    g.h_k_last = frame.gyros[id - 1]->h_k.normalized();
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
  const double sigma_rw0 =
      options_.residual_drift_sigma >= 0.0
          ? options_.residual_drift_sigma
          : DegPerHourToRadPerSec((options_.model.k0 || options_.model.c1c2) ? 0.01 : 0.1);
  for (int i = 0; i < gyro_count(); ++i) {
    const GyroConfig& gc = *config_.FindGyro(gyros_[i].id);
    if (layout_.has_drift()) {
      const int d = layout_.Drift(i);
      P_.block<2, 2>(d, d) = sigma_rw0 * sigma_rw0 * Matrix2d::Identity();
    }
    const DriftVector sigma_theta = gc.model_sigma.AsVector();
    const std::vector<int>& free = layout_.FreeCoefficients(i);
    for (int j = 0; j < layout_.ThetaCount(i); ++j) {
      const int idx = layout_.Theta(i) + j;
      P_(idx, idx) = sigma_theta(free[j]) * sigma_theta(free[j]);
    }
    if (layout_.HasPhi(i)) {
      const int po = layout_.Phi(i);
      P_.block<3, 3>(po, po) = gc.misalignment_sigma * gc.misalignment_sigma * Matrix3d::Identity();
    }
  }
  SpinAxesFromStarTracker(C_in_b);
  P0_ = P_;
  initialized_ = true;
  start_time_ = frame.time;
  last_update_time_ = frame.time;
  state_ = SessionState::kCalibrating;
  return CheckCovariance(P_);
}

void EstimationSession::SpinAxesFromStarTracker(const Matrix3d& C_in_b) {
  // The spin axes rebuilt from the star tracker, h_in = C_in_b(st) C_b_k h_k, err by the
  // misalignment, the star-tracker noise (shared by all gyros) and the readout noise:
  // dh_g = -H_phi,g phi_g - G_st,g n_st - G_r,g r_g with the Jacobians of the star-tracker
  // measurement (MeasurementUpdate).
  const Vector3d st_noise = config_.star_tracker.noise.cwiseMax(kNoiseFloor);
  const Matrix3d Sigma_st = st_noise.cwiseAbs2().asDiagonal();
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

std::optional<Quaterniond> EstimationSession::PairQuaternion(int a, int b, const Vector3d& h_k_a,
                                                             const Vector3d& h_k_b,
                                                             Matrix3d* covariance_in) const {
  const int ia = IndexOf(a);
  const int ib = IndexOf(b);
  if (ia < 0 || ib < 0) return std::nullopt;
  const GyroState* ga = &gyros_[ia];
  const GyroState* gb = &gyros_[ib];
  auto attitude = [&](const Vector3d& h_in_a, const Vector3d& h_in_b, const Matrix3d& C_a,
                      const Matrix3d& C_b, const Vector3d& hk_a,
                      const Vector3d& hk_b) -> std::optional<Quaterniond> {
    auto q = PairAttitude(h_in_a, h_in_b, C_a * hk_a, C_b * hk_b);
    if (!q.ok()) return std::nullopt;
    return *q;
  };
  const Matrix3d C_a = ga->C_b_k(), C_b = gb->C_b_k();
  const auto q0 = attitude(ga->h_in, gb->h_in, C_a, C_b, h_k_a, h_k_b);
  if (!q0.has_value() || covariance_in == nullptr) return q0;

  // Attitude error dtheta_in (q_true = Exp(dtheta_in) q_est) against the state errors of the two
  // gyros and their readout noise, by one-sided differences (error ~ step, 1e-7 relative: this
  // feeds a 1-sigma envelope; prediction evaluates it at every output sample).
  const int n = state_size();
  MatrixXd J = MatrixXd::Zero(3, n);
  Eigen::Matrix<double, 3, 4> J_r = Eigen::Matrix<double, 3, 4>::Zero();
  const double e = kJacobianStep;
  const Quaterniond q0_conj = q0->conjugate();
  auto diff = [&](const std::optional<Quaterniond>& qp) {
    if (!qp) return Vector3d::Zero().eval();
    return (LogQuaternion(*qp * q0_conj) / e).eval();
  };
  const Matrix32 Ta = ga->T(), Tb = gb->T();
  for (int i = 0; i < 2; ++i) {
    J.col(layout_.SpinAxis(ia) + i) =
        diff(attitude((ga->h_in + e * Ta.col(i)).normalized(), gb->h_in, C_a, C_b, h_k_a, h_k_b));
    J.col(layout_.SpinAxis(ib) + i) =
        diff(attitude(ga->h_in, (gb->h_in + e * Tb.col(i)).normalized(), C_a, C_b, h_k_a, h_k_b));
  }
  for (int i = 0; i < 3; ++i) {
    const Matrix3d R = ExpMatrix(e * Vector3d::Unit(i));
    if (layout_.HasPhi(ia)) {
      J.col(layout_.Phi(ia) + i) = diff(attitude(ga->h_in, gb->h_in, R * C_a, C_b, h_k_a, h_k_b));
    }
    if (layout_.HasPhi(ib)) {
      J.col(layout_.Phi(ib) + i) = diff(attitude(ga->h_in, gb->h_in, C_a, R * C_b, h_k_a, h_k_b));
    }
  }
  const Matrix32 Ua = TangentBasis(h_k_a), Ub = TangentBasis(h_k_b);
  for (int i = 0; i < 2; ++i) {
    J_r.col(i) = diff(attitude(ga->h_in, gb->h_in, C_a, C_b, (h_k_a + e * Ua.col(i)).normalized(), h_k_b));
    J_r.col(2 + i) = diff(attitude(ga->h_in, gb->h_in, C_a, C_b, h_k_a, (h_k_b + e * Ub.col(i)).normalized()));
  }
  // Only the columns of the two gyros are nonzero: J P J^T over those blocks.
  std::vector<int> cols;
  for (int g : {ia, ib}) {
    for (int k = 0; k < 2; ++k) cols.push_back(layout_.SpinAxis(g) + k);
    if (layout_.HasPhi(g)) {
      for (int k = 0; k < 3; ++k) cols.push_back(layout_.Phi(g) + k);
    }
  }
  const int m = static_cast<int>(cols.size());
  Eigen::MatrixXd Js(3, m), Ps(m, m);
  for (int i = 0; i < m; ++i) {
    Js.col(i) = J.col(cols[i]);
    for (int j = 0; j < m; ++j) Ps(i, j) = P_(cols[i], cols[j]);
  }
  const double sigma_r = std::max(config_.readout_noise, kNoiseFloor);
  *covariance_in = Js * Ps * Js.transpose() + sigma_r * sigma_r * J_r * J_r.transpose();
  return q0;
}

absl::Status EstimationSession::Propagate(const TelemetryFrame& frame) {
  const double span = Seconds(frame.time - last_time_);
  const bool rw = layout_.has_drift();

  // Readings at both ends (a gyro missing in the new frame holds its last reading).
  std::vector<Vector3d> h_k_begin(gyros_.size()), h_k_end(gyros_.size());
  double max_turn = 0.0;  // largest angle a reading turns over the interval [rad]
  for (size_t i = 0; i < gyros_.size(); ++i) {
    const auto& reading = frame.gyros[gyros_[i].id - 1];
    h_k_begin[i] = gyros_[i].h_k_last;
    h_k_end[i] = reading.has_value() ? reading->h_k.normalized() : gyros_[i].h_k_last;
    max_turn = std::max(max_turn, std::acos(std::clamp(h_k_begin[i].dot(h_k_end[i]), -1.0, 1.0)));
  }
  // The configured integration rate (the paper's 8 Hz); prediction instead sizes substeps to
  // the motion of the readings (one per 0.1 deg): the drift depends on time only through them.
  // Counted in double: the span is the caller's (a library user may send a frame years after the
  // previous one, or at absl::InfiniteFuture), so the count is checked before it becomes an int.
  const double substeps_wanted =
      adaptive_integration_ ? std::ceil(max_turn / (0.1 * kRadPerDeg))
                            : std::ceil(span * config_.filter.integration_rate_hz - 1e-9);
  if (!(substeps_wanted <= static_cast<double>(std::numeric_limits<int>::max()))) {
    return absl::OutOfRangeError(absl::StrFormat(
        "frame time %s: propagating %g s at filter.integrationRateHz %g needs %g steps, more "
        "than %d",
        absl::FormatTime(frame.time), span, config_.filter.integration_rate_hz, substeps_wanted,
        std::numeric_limits<int>::max()));
  }
  const int substeps = std::max(1, static_cast<int>(substeps_wanted));
  const double dt = span / substeps;
  // Output pair for the body attitude used to carry case-frame drift to inertial axes.
  const std::array<int, 2> pair = working_pair_;
  int ia = -1, ib = -1;
  for (size_t i = 0; i < gyros_.size(); ++i) {
    if (gyros_[i].id == pair[0]) ia = static_cast<int>(i);
    if (gyros_[i].id == pair[1]) ib = static_cast<int>(i);
  }
  std::vector<Matrix3d> C_b_k(gyros_.size());
  std::vector<Eigen::Matrix<double, 3, kNumDriftCoefficients>> M(
      gyros_.size(), Eigen::Matrix<double, 3, kNumDriftCoefficients>::Zero());
  for (size_t i = 0; i < gyros_.size(); ++i) C_b_k[i] = gyros_[i].C_b_k();
  std::vector<Vector3d> h_k(gyros_.size());
  Matrix3d C_in_b = Matrix3d::Identity();
  for (int step = 0; step < substeps; ++step) {
    // Midpoint of the substep: second order in dt for the slowly varying drift.
    const double s = (step + 0.5) / substeps;
    for (size_t i = 0; i < gyros_.size(); ++i) h_k[i] = SlerpUnit(h_k_begin[i], h_k_end[i], s);
    auto q = PairAttitude(gyros_[ia].h_in, gyros_[ib].h_in, C_b_k[ia] * h_k[ia],
                          C_b_k[ib] * h_k[ib]);
    if (q.ok()) C_in_b = q->toRotationMatrix();
    for (size_t i = 0; i < gyros_.size(); ++i) {
      GyroState& g = gyros_[i];
      const DriftRegressorMatrix B = DriftRegressor(h_k[i]);
      const Matrix3d C_in_k = C_in_b * C_b_k[i];
      const Eigen::Matrix<double, 3, kNumDriftCoefficients> CB = C_in_k * B;
      Vector3d dw_in = CB * g.theta;  // DESIGN §3: dh_in/dt = (C_in_k dw_k) x h_in
      if (rw) dw_in += g.T() * g.residual_drift;
      g.h_in = StepSpinAxis(g.h_in, dw_in, dt);
      M[i] += CB * dt;
    }
  }
  // Transition over the interval: only the spin-axis errors move,
  // d(dh)/dt = T^T [(C_in_k B dtheta) x h] + J dw_int  (tangent basis held over the interval).
  // Phi = I + E, where E is nonzero only in the spin-axis rows of each gyro, in the columns of its
  // own residual drifts and free coefficients, which follow the spin-axis pair contiguously. So
  // P <- P + E P + P E^T + E P E^T + Q costs O(n k) instead of O(n^3).
  std::vector<MatrixXd> E(gyros_.size());
  const double q_rw = config_.random_walk;
  for (int i = 0; i < gyro_count(); ++i) {
    GyroState& g = gyros_[i];
    // Keep the tangent basis perpendicular to the moved axis (a change of order 1e-5 rad).
    g.t1 = (g.t1 - g.t1.dot(g.h_in) * g.h_in).normalized();
    const Matrix23 Tt = g.T().transpose();
    const Matrix3d minus_hx = -Skew(g.h_in);  // v x h = -h x v
    // Columns: the spin-axis drivers of state_layout.h, residual drift then free coefficients.
    E[i] = MatrixXd::Zero(2, layout_.SpinAxisDriverCount(i));
    if (rw) E[i].leftCols<2>() = kJ * span;
    const std::vector<int>& free = layout_.FreeCoefficients(i);
    for (int j = 0; j < layout_.ThetaCount(i); ++j) {
      E[i].col(layout_.DriftSize() + j) = Tt * minus_hx * M[i].col(free[j]);
    }
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
      const double q2 = q_rw * q_rw;
      const int h = layout_.SpinAxis(i), d = layout_.Drift(i);
      P_.block<2, 2>(d, d) += q2 * span * Matrix2d::Identity();
      P_.block<2, 2>(h, d) += q2 * span * span / 2.0 * kJ;
      P_.block<2, 2>(d, h) += q2 * span * span / 2.0 * kJ.transpose();
      P_.block<2, 2>(h, h) += q2 * span * span * span / 3.0 * Matrix2d::Identity();
    }
  }
  // The rows that changed: spin axis, then residual drift (contiguous, state_layout.h).
  const int rows = StateLayout::kSpinAxisSize + layout_.DriftSize();
  for (int i = 0; i < gyro_count(); ++i) {
    const int h = layout_.SpinAxis(i);
    if (!P_.middleRows(h, rows).allFinite()) {
      return absl::InternalError(absl::StrFormat("covariance of gyro %d is not finite after propagation", gyros_[i].id));
    }
    for (int k = 0; k < rows; ++k) {
      if (P_(h + k, h + k) < 0.0) {
        return absl::InternalError(absl::StrFormat("covariance of gyro %d has a negative variance", gyros_[i].id));
      }
    }
  }
  return absl::OkStatus();
}

absl::Status EstimationSession::MeasurementUpdate(const TelemetryFrame& frame, StepReport& report) {
  report.measurement_step = true;
  const int n = state_size();
  const double kd = config_.filter.innovation_kd;
  const double sigma_r = std::max(config_.readout_noise, kNoiseFloor);
  const Vector3d st_noise = config_.star_tracker.noise.cwiseMax(kNoiseFloor);

  const auto& st = frame.star_tracker;
  const bool st_present = use_star_tracker_ && st.has_value() && st->valid;
  bool st_available = st_present;
  const Quaterniond q_st = st_available ? st->q_in_b.normalized() : Quaterniond::Identity();

  auto has_reading = [&](const GyroState& g) {
    return !g.faulty && frame.gyros[g.id - 1].has_value();
  };

  // eq. (12): working pair, reserve pair, star tracker.
  {
    Matrix3d S1, S2;
    std::optional<Quaterniond> q1, q2;
    const GyroState* a1 = Find(working_pair_[0]);
    const GyroState* b1 = Find(working_pair_[1]);
    const GyroState* a2 = Find(reserve_pair_[0]);
    const GyroState* b2 = Find(reserve_pair_[1]);
    const bool reserve_usable = reserve_pair_ != working_pair_ && a2 && b2 && has_reading(*a2) &&
                                has_reading(*b2) && state_ != SessionState::kFaulted;
    if (a1 && b1 && has_reading(*a1) && has_reading(*b1)) {
      q1 = PairQuaternion(a1->id, b1->id, a1->h_k_last, b1->h_k_last, &S1);
    }
    if (reserve_usable) q2 = PairQuaternion(a2->id, b2->id, a2->h_k_last, b2->h_k_last, &S2);
    const Matrix3d C_in_b_st = q_st.toRotationMatrix();
    const Matrix3d S_st = C_in_b_st * Matrix3d(st_noise.cwiseAbs2().asDiagonal()) * C_in_b_st.transpose();
    // Allowed angle of each mismatch (eq. (12)): the configured one, or k_d times the mismatch's
    // sigma along its direction. The two pairs share the reference gyro; the sum of their
    // covariances bounds that of their mismatch.
    auto allowed = [&](const std::optional<Quaterniond>& a, const Quaterniond* b, const Matrix3d& S) {
      if (!a.has_value() || b == nullptr) return 0.0;
      if (config_.filter.fault_threshold > 0.0) return config_.filter.fault_threshold;
      return DirectionalAllowedAngle(LogQuaternion(*a * b->conjugate()), S, kd, kMismatchFloor);
    };
    const std::array<double, 3> allowed_angles = {
        allowed(q1, q2 ? &*q2 : nullptr, S1 + S2), allowed(q1, st_available ? &q_st : nullptr, S1 + S_st),
        allowed(q2, st_available ? &q_st : nullptr, S2 + S_st)};
    const MismatchTest mt = TestMismatch(q1 ? &*q1 : nullptr, q2 ? &*q2 : nullptr,
                                         st_available ? &q_st : nullptr, allowed_angles);
    auto event = [&](Event::Kind kind, std::string subsystem, int m, std::string message) {
      Event ev{kind, frame.time, std::move(subsystem), RadToArcsec(mt.angle[m]),
               RadToArcsec(mt.allowed[m]), "arcsec", std::move(message)};
      report.events.push_back(std::move(ev));
    };
    if (mt.faulty == Subsystem::kWorkingPair) {
      // The gyro of the working pair that is not in the reserve pair is the suspect.
      int suspect = working_pair_[1];
      if (working_pair_[1] == reserve_pair_[0] || working_pair_[1] == reserve_pair_[1]) {
        suspect = working_pair_[0];
      }
      if (GyroState* g = Find(suspect)) g->faulty = true;
      event(Event::Kind::kWorkingPairFault,
            absl::StrFormat("working_pair[%d,%d]", working_pair_[0], working_pair_[1]), 0,
            absl::StrFormat("eq. (12): working pair disagrees with reserve pair and star tracker; "
                            "output switched to reserve pair [%d,%d], gyro %d excluded",
                            reserve_pair_[0], reserve_pair_[1], suspect));
      working_pair_ = reserve_pair_;
      state_ = SessionState::kFaulted;
    } else if (mt.faulty == Subsystem::kReservePair) {
      int suspect = reserve_pair_[1];
      if (reserve_pair_[1] == working_pair_[0] || reserve_pair_[1] == working_pair_[1]) {
        suspect = reserve_pair_[0];
      }
      if (GyroState* g = Find(suspect)) g->faulty = true;
      event(Event::Kind::kReservePairFault,
            absl::StrFormat("reserve_pair[%d,%d]", reserve_pair_[0], reserve_pair_[1]), 0,
            absl::StrFormat("eq. (12): reserve pair disagrees with working pair and star tracker; "
                            "gyro %d excluded",
                            suspect));
    } else if (mt.faulty == Subsystem::kStarTracker) {
      event(Event::Kind::kStarTrackerFault, "star_tracker", 1,
            "eq. (12): star tracker disagrees with both gyro pairs; its measurements are rejected");
      st_available = false;
    }
  }

  // Measurements (eq. (13)): z_st (2 per healthy gyro) then z_avt (per healthy pair).
  std::vector<int> healthy;  // gyro indices
  for (int i = 0; i < gyro_count(); ++i) {
    if (has_reading(gyros_[i])) healthy.push_back(i);
  }
  const int n_st = st_available ? 2 * static_cast<int>(healthy.size()) : 0;
  const int n_avt = options_.use_autonomous_measurements
                        ? static_cast<int>(healthy.size() * (healthy.size() - 1) / 2)
                        : 0;
  const int m = n_st + n_avt;
  if (m == 0) return absl::OkStatus();
  // Noise sources: star-tracker rotation (3, body axes), readout (2 per gyro, case tangent plane).
  const int n_noise = 3 + 2 * static_cast<int>(gyros_.size());
  MatrixXd H = MatrixXd::Zero(m, n);
  VectorXd z = VectorXd::Zero(m);
  MatrixXd G = MatrixXd::Zero(m, n_noise);
  VectorXd noise_var(n_noise);
  noise_var.head<3>() = st_noise.cwiseAbs2();
  noise_var.tail(n_noise - 3).setConstant(sigma_r * sigma_r);
  auto noise_col = [](int gyro_index) { return 3 + 2 * gyro_index; };

  // Body attitude for the star-tracker rebuild is the star tracker's own.
  const Matrix3d C_in_b_st = q_st.toRotationMatrix();
  int row = 0;
  for (int i : healthy) {
    if (!st_available) break;
    const GyroState& g = gyros_[i];
    const StarTrackerDifference d =
        MakeStarTrackerDifference(g.h_in, g.T(), C_in_b_st, g.C_b_k(), g.h_k_last);
    z.segment<2>(row) = d.z;
    H.block<2, 2>(row, layout_.SpinAxis(i)) = d.H_h;
    if (layout_.HasPhi(i)) H.block<2, 3>(row, layout_.Phi(i)) = d.H_phi;
    G.block<2, 3>(row, 0) = d.G_st;
    G.block<2, 2>(row, noise_col(i)) = d.G_readout;
    row += 2;
  }
  std::vector<std::pair<int, int>> avt_pairs;  // gyro ids
  for (size_t ka = 0; ka < healthy.size() && n_avt > 0; ++ka) {
    for (size_t kb = ka + 1; kb < healthy.size(); ++kb) {
      const int ia = healthy[ka], ib = healthy[kb];
      const GyroState& a = gyros_[ia];
      const GyroState& b = gyros_[ib];
      const AutonomousDifference d = MakeAutonomousDifference(
          a.h_in, a.T(), a.C_b_k(), a.h_k_last, b.h_in, b.T(), b.C_b_k(), b.h_k_last);
      z(row) = d.z;
      H.block<1, 2>(row, layout_.SpinAxis(ia)) = d.H_h_a;
      H.block<1, 2>(row, layout_.SpinAxis(ib)) = d.H_h_b;
      if (layout_.HasPhi(ia)) H.block<1, 3>(row, layout_.Phi(ia)) = d.H_phi_a;
      if (layout_.HasPhi(ib)) H.block<1, 3>(row, layout_.Phi(ib)) = d.H_phi_b;
      G.block<1, 2>(row, noise_col(ia)) = d.G_readout_a;
      G.block<1, 2>(row, noise_col(ib)) = d.G_readout_b;
      avt_pairs.emplace_back(a.id, b.id);
      ++row;
    }
  }
  MatrixXd R = G * noise_var.asDiagonal() * G.transpose();
  MatrixXd S = H * P_ * H.transpose() + R;

  std::vector<int> keep;
  report.autonomous_innovation = z.tail(n_avt);
  report.autonomous_innovation_sigma = S.diagonal().tail(n_avt).cwiseSqrt();
  if (n_st > 0) {
    report.star_tracker_innovation = z.head(n_st);
    report.star_tracker_innovation_sigma = S.diagonal().head(n_st).cwiseSqrt();
    // eq. (14) on z2..z5.
    const InnovationTest t = TestInnovation(z.head(n_st), S.topLeftCorner(n_st, n_st), kd);
    report.star_tracker_test_ratio = t.worst_ratio;
    report.star_tracker_nis = t.nis;
    report.star_tracker_log_det_s = t.log_det_s;
    if (t.passed) {
      for (int i = 0; i < n_st; ++i) keep.push_back(i);
      report.star_tracker_used = true;
    } else {
      const GyroState* g = &gyros_[healthy[t.worst_index / 2]];
      report.events.push_back(Event{
          Event::Kind::kStarTrackerInnovation, frame.time, "star_tracker",
          RadToArcsec(t.worst_value), RadToArcsec(t.worst_threshold), "arcsec",
          absl::StrFormat("eq. (14): star-tracker difference for gyro %d exceeds k_d sigma_z "
                          "(|z| = %.1f arcsec > %.1f); star-tracker data rejected, output autonomous",
                          g->id, RadToArcsec(t.worst_value), RadToArcsec(t.worst_threshold))});
    }
  }
  // With the star-tracker differences applied, z_avt adds nothing: the angle between the rebuilt
  // axes h_et equals the measured theta_S, so z_avt = -(h_et_a - h_a).h_b - h_a.(h_et_b - h_b) to
  // first order, a linear function of z_st with the same noise, and the joint S would be singular.
  // It is tested by eq. (14) every step and applied only when the output runs autonomous.
  const bool apply_avt = !report.star_tracker_used;
  for (int k = 0; k < n_avt; ++k) {
    const int i = n_st + k;
    const double sigma = std::sqrt(S(i, i));
    // eq. (14) on z_avt.
    if (std::abs(z(i)) <= kd * sigma) {
      if (apply_avt) keep.push_back(i);
    } else {
      report.events.push_back(Event{
          Event::Kind::kGyroDataRejected, frame.time,
          absl::StrFormat("gyros %d,%d", avt_pairs[k].first, avt_pairs[k].second),
          std::abs(z(i)), kd * sigma, "1",
          absl::StrFormat("eq. (14): autonomous measurement z_avt = %.3g exceeds k_d sigma_z = %.3g",
                          z(i), kd * sigma)});
    }
  }
  if (report.star_tracker_used) {
    steps_without_star_tracker_ = 0;
    consecutive_rejections_ = 0;
  } else {
    ++steps_without_star_tracker_;
    if (st_present) ++consecutive_rejections_;
  }
  if (consecutive_rejections_ >= kResetAfterRejections) {
    // The star tracker has been present and rejected for kResetAfterRejections steps: a star
    // tracker that is wrong that long flags itself invalid, a filter whose model misses part of
    // the drift does not, so the filter is taken to be wrong (docs/decisions.md).
    SpinAxesFromStarTracker(C_in_b_st);
    report.events.push_back(Event{
        Event::Kind::kFilterReset, frame.time, "filter",
        static_cast<double>(consecutive_rejections_), static_cast<double>(kResetAfterRejections),
        "steps",
        absl::StrFormat("star-tracker data rejected for %d steps in a row: spin axes "
                        "re-initialised from the star tracker (is the drift model missing a term?)",
                        consecutive_rejections_)});
    consecutive_rejections_ = 0;
    steps_without_star_tracker_ = 0;
    return CheckCovariance(P_);
  }
  if (keep.empty()) return absl::OkStatus();
  const int mk = static_cast<int>(keep.size());
  MatrixXd Hk(mk, n), Rk(mk, mk);
  VectorXd zk(mk);
  for (int i = 0; i < mk; ++i) {
    Hk.row(i) = H.row(keep[i]);
    zk(i) = z(keep[i]);
    for (int j = 0; j < mk; ++j) Rk(i, j) = R(keep[i], keep[j]);
  }
  VectorXd dx;
  if (absl::Status s = JosephUpdate(Hk, zk, Rk, P_, dx); !s.ok()) return s;
  ApplyCorrection(dx);
  return absl::OkStatus();
}

void EstimationSession::ApplyCorrection(const VectorXd& dx) {
  // Feedback of the error estimate into the nominal state, then the error state is zero.
  for (int i = 0; i < gyro_count(); ++i) {
    GyroState& g = gyros_[i];
    g.h_in = (g.h_in + g.T() * dx.segment<2>(layout_.SpinAxis(i))).normalized();
    g.t1 = (g.t1 - g.t1.dot(g.h_in) * g.h_in).normalized();
    if (layout_.has_drift()) g.residual_drift += dx.segment<2>(layout_.Drift(i));
    const std::vector<int>& free = layout_.FreeCoefficients(i);
    for (int j = 0; j < layout_.ThetaCount(i); ++j) g.theta(free[j]) += dx(layout_.Theta(i) + j);
    if (layout_.HasPhi(i)) {
      // C_b_k(true) = Exp(dphi) Exp(phi) C_b_k(config): compose the rotations.
      g.phi_b = LogQuaternion(ExpQuaternion(dx.segment<3>(layout_.Phi(i))) * ExpQuaternion(g.phi_b));
    }
  }
}

AttitudeEstimate EstimationSession::OutputAttitude(absl::Time time) const {
  AttitudeEstimate out;
  out.time = time;
  out.pair = working_pair_;
  const GyroState* a = Find(working_pair_[0]);
  const GyroState* b = Find(working_pair_[1]);
  if (!initialized_ || a == nullptr || b == nullptr) return out;
  Matrix3d S_in;
  const auto q = PairQuaternion(a->id, b->id, a->h_k_last, b->h_k_last, &S_in);
  if (!q.has_value()) return out;
  out.q_in_b = *q;
  const Matrix3d C_b_in = q->toRotationMatrix().transpose();
  const Matrix3d S_b = C_b_in * S_in * C_b_in.transpose();
  out.sigma_b = S_b.diagonal().cwiseMax(0.0).cwiseSqrt();
  out.valid = true;
  return out;
}

AttitudeEstimate EstimationSession::CurrentAttitude() const { return OutputAttitude(last_time_); }

void EstimationSession::UpdateState(const StepReport& report) {
  if (!report.measurement_step) return;
  // Convergence: every free coefficient's relative sigma changed < 5% over the last hour (a
  // 1/sqrt(t) information law alone changes it by 1/(2 t) per hour: 2% at 24 h).
  std::vector<double> ratios;
  for (int i = 0; i < gyro_count(); ++i) {
    for (int j = 0; j < layout_.ThetaCount(i); ++j) {
      const int idx = layout_.Theta(i) + j;
      ratios.push_back(std::sqrt(P_(idx, idx) / P0_(idx, idx)));
    }
  }
  const VectorXd r = Eigen::Map<VectorXd>(ratios.data(), static_cast<int>(ratios.size()));
  if (convergence_mark_time_ == absl::InfinitePast() || convergence_mark_sigma_.size() != r.size()) {
    convergence_mark_time_ = report.time;
    convergence_mark_sigma_ = r;
  } else if (report.time - convergence_mark_time_ >= absl::Hours(1)) {
    const double change = r.size() == 0 ? 0.0
                                        : ((convergence_mark_sigma_ - r).cwiseAbs().array() /
                                           convergence_mark_sigma_.array())
                                              .maxCoeff();
    if (change < 0.05 && report.time - start_time_ >= absl::Hours(2)) converged_ = true;
    convergence_mark_time_ = report.time;
    convergence_mark_sigma_ = r;
  }
  if (state_ == SessionState::kFaulted) return;
  if (steps_without_star_tracker_ >= 3) {
    state_ = SessionState::kAutonomous;
  } else {
    state_ = converged_ ? SessionState::kConverged : SessionState::kCalibrating;
  }
}

absl::StatusOr<StepReport> EstimationSession::AddFrame(const TelemetryFrame& frame) {
  if (initialized_ || last_time_ != absl::InfinitePast()) {
    if (frame.time <= last_time_) {
      return absl::OutOfRangeError(absl::StrCat("frame time ", absl::FormatTime(frame.time),
                                                " is not after the previous frame ",
                                                absl::FormatTime(last_time_)));
    }
  }
  StepReport report;
  report.time = frame.time;
  if (!initialized_) {
    if (absl::Status s = Initialize(frame); !s.ok()) return s;
    last_time_ = frame.time;
    report.state = state_;
    report.attitude = OutputAttitude(frame.time);
    return report;
  }
  // Transactional step: work on a copy, commit only on success.
  EstimationSession next = *this;
  if (absl::Status s = next.Propagate(frame); !s.ok()) return s;
  next.last_time_ = frame.time;
  const double since_update = Seconds(frame.time - next.last_update_time_);
  if (since_update >= config_.filter.measurement_step - 1e-3) {
    if (absl::Status s = next.MeasurementUpdate(frame, report); !s.ok()) return s;
    next.last_update_time_ = frame.time;
  }
  next.UpdateState(report);
  report.state = next.state_;
  report.attitude = next.OutputAttitude(frame.time);
  *this = std::move(next);
  return report;
}

std::vector<GyroEstimate> EstimationSession::Gyros() const {
  std::vector<GyroEstimate> out;
  for (int i = 0; i < gyro_count(); ++i) {
    const GyroState& g = gyros_[i];
    GyroEstimate e;
    e.id = g.id;
    e.coefficients = DriftCoefficients::FromVector(g.theta);
    DriftVector sigma = DriftVector::Zero();
    const std::vector<int>& free = layout_.FreeCoefficients(i);
    for (int j = 0; j < layout_.ThetaCount(i); ++j) {
      const int idx = layout_.Theta(i) + j;
      sigma(free[j]) = std::sqrt(std::max(P_(idx, idx), 0.0));
    }
    e.sigma = DriftCoefficients::FromVector(sigma);
    e.misalignment_b = g.phi_b;
    if (layout_.HasPhi(i)) {
      const int p = layout_.Phi(i);
      e.misalignment_sigma_b = P_.block<3, 3>(p, p).diagonal().cwiseSqrt();
    }
    if (layout_.has_drift()) {
      const int d = layout_.Drift(i);
      e.residual_drift = g.residual_drift;
      e.residual_drift_sigma = P_.block<2, 2>(d, d).diagonal().cwiseSqrt();
    }
    e.h_in = g.h_in;
    const int h = layout_.SpinAxis(i);
    e.spin_axis_sigma = P_.block<2, 2>(h, h).diagonal().cwiseSqrt();
    e.faulty = g.faulty;
    out.push_back(e);
  }
  return out;
}

std::vector<std::pair<int, double>> EstimationSession::RelativeSigma(int id) const {
  std::vector<std::pair<int, double>> out;
  const int i = IndexOf(id);
  if (i < 0) return out;
  for (int j = 0; j < layout_.ThetaCount(i); ++j) {
    const int idx = layout_.Theta(i) + j;
    out.emplace_back(layout_.FreeCoefficients(i)[j], std::sqrt(P_(idx, idx) / P0_(idx, idx)));
  }
  return out;
}

absl::StatusOr<std::vector<PredictedSample>> EstimationSession::Predict(
    const std::vector<absl::Time>& times, const AttitudeProfile* planned,
    absl::Time planned_start) const {
  if (!initialized_) {
    return absl::FailedPreconditionError("prediction needs an initialised session (no star-tracker fix yet)");
  }
  EstimationSession s = *this;
  s.use_star_tracker_ = false;
  s.adaptive_integration_ = true;
  const Quaterniond q_hold = CurrentAttitude().q_in_b;
  std::vector<PredictedSample> out;
  out.reserve(times.size());
  for (absl::Time t : times) {
    if (t <= s.last_time_) {
      return absl::OutOfRangeError(absl::StrCat("prediction time ", absl::FormatTime(t),
                                                " is not after the last frame ",
                                                absl::FormatTime(s.last_time_)));
    }
    const Quaterniond q_in_b = planned != nullptr
                                   ? planned->Attitude(Seconds(t - planned_start))
                                   : q_hold;
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

// Checkpoint layout (version 1), all doubles: header, then per gyro, then P.
SessionCheckpoint EstimationSession::ExportCheckpoint() const {
  SessionCheckpoint c;
  std::vector<double>& v = c.values;
  auto put_time = [&](absl::Time t) {
    if (t == absl::InfinitePast()) {
      v.push_back(-1.0);
      v.push_back(0.0);
      v.push_back(0.0);
      return;
    }
    const int64_t ns = absl::ToUnixNanos(t);
    v.push_back(1.0);
    v.push_back(static_cast<double>(ns / 1000000000));
    v.push_back(static_cast<double>(ns % 1000000000));
  };
  auto put_vec = [&](const auto& x) {
    for (int i = 0; i < x.size(); ++i) v.push_back(x(i));
  };
  v.push_back(initialized_ ? 1 : 0);
  v.push_back(use_star_tracker_ ? 1 : 0);
  put_time(last_time_);
  put_time(last_update_time_);
  put_time(start_time_);
  put_time(convergence_mark_time_);
  v.push_back(working_pair_[0]);
  v.push_back(working_pair_[1]);
  v.push_back(reserve_pair_[0]);
  v.push_back(reserve_pair_[1]);
  v.push_back(static_cast<double>(state_));
  v.push_back(steps_without_star_tracker_);
  v.push_back(consecutive_rejections_);
  v.push_back(converged_ ? 1 : 0);
  v.push_back(static_cast<double>(convergence_mark_sigma_.size()));
  put_vec(convergence_mark_sigma_);
  v.push_back(static_cast<double>(gyros_.size()));
  for (const GyroState& g : gyros_) {
    v.push_back(g.id);
    put_vec(g.h_in);
    put_vec(g.t1);
    put_vec(g.residual_drift);
    put_vec(g.theta);
    put_vec(g.phi_b);
    v.push_back(g.faulty ? 1 : 0);
    v.push_back(g.has_reading ? 1 : 0);
    put_vec(g.h_k_last);
  }
  v.push_back(static_cast<double>(P_.rows()));
  for (int i = 0; i < P_.rows(); ++i) {
    for (int j = 0; j < P_.cols(); ++j) v.push_back(P_(i, j));
  }
  for (int i = 0; i < P0_.rows(); ++i) {
    for (int j = 0; j < P0_.cols(); ++j) v.push_back(P0_(i, j));
  }
  return c;
}

absl::StatusOr<EstimationSession> EstimationSession::FromCheckpoint(
    const SpacecraftConfig& config, const SessionOptions& options,
    const SessionCheckpoint& checkpoint) {
  if (checkpoint.version != 1) {
    return absl::DataLossError(absl::StrCat("checkpoint version ", checkpoint.version, " is unknown"));
  }
  auto created = Create(config, options);
  if (!created.ok()) return created.status();
  EstimationSession s = std::move(*created);
  const std::vector<double>& v = checkpoint.values;
  size_t pos = 0;
  bool short_read = false;
  auto get = [&]() {
    if (pos >= v.size()) {
      short_read = true;
      return 0.0;
    }
    return v[pos++];
  };
  auto get_time = [&]() {
    const double flag = get();
    const double sec = get();
    const double nsec = get();
    if (flag < 0) return absl::InfinitePast();
    return absl::FromUnixNanos(static_cast<int64_t>(sec) * 1000000000 + static_cast<int64_t>(nsec));
  };
  auto get_vec = [&](auto& x) {
    for (int i = 0; i < x.size(); ++i) x(i) = get();
  };
  s.initialized_ = get() != 0;
  s.use_star_tracker_ = get() != 0;
  s.last_time_ = get_time();
  s.last_update_time_ = get_time();
  s.start_time_ = get_time();
  s.convergence_mark_time_ = get_time();
  s.working_pair_ = {static_cast<int>(get()), static_cast<int>(get())};
  s.reserve_pair_ = {static_cast<int>(get()), static_cast<int>(get())};
  s.state_ = static_cast<SessionState>(static_cast<int>(get()));
  s.steps_without_star_tracker_ = static_cast<int>(get());
  s.consecutive_rejections_ = static_cast<int>(get());
  s.converged_ = get() != 0;
  const int n_mark = static_cast<int>(get());
  if (n_mark < 0 || n_mark > 1000) return absl::DataLossError("checkpoint: bad convergence record");
  s.convergence_mark_sigma_ = VectorXd::Zero(n_mark);
  get_vec(s.convergence_mark_sigma_);
  const int n_gyros = static_cast<int>(get());
  if (n_gyros < 0 || n_gyros > kMaxGyros) return absl::DataLossError("checkpoint: bad gyro count");
  for (int i = 0; i < n_gyros; ++i) {
    GyroState g;
    g.id = static_cast<int>(get());
    const GyroConfig* gc = config.FindGyro(g.id);
    if (gc == nullptr) {
      return absl::DataLossError(absl::StrCat("checkpoint: gyro ", g.id, " is not in the configuration"));
    }
    g.C_b_k_config = gc->C_b_k;
    get_vec(g.h_in);
    get_vec(g.t1);
    get_vec(g.residual_drift);
    get_vec(g.theta);
    get_vec(g.phi_b);
    g.faulty = get() != 0;
    g.has_reading = get() != 0;
    get_vec(g.h_k_last);
    s.gyros_.push_back(std::move(g));
  }
  s.layout_ = LayoutFor(config, options.model, s.gyros_);
  const int n = static_cast<int>(get());
  if (n != s.layout_.size()) {
    return absl::DataLossError(absl::StrFormat(
        "checkpoint: covariance size %d does not fit the configuration and model %s (%d states)", n,
        options.model.Name(), s.layout_.size()));
  }
  s.P_ = MatrixXd::Zero(n, n);
  s.P0_ = MatrixXd::Zero(n, n);
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) s.P_(i, j) = get();
  }
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) s.P0_(i, j) = get();
  }
  if (short_read || pos != v.size()) return absl::DataLossError("checkpoint: truncated or oversized");
  // An uninitialised session (no valid star-tracker attitude yet) has no state to check.
  if (s.initialized_) {
    if (absl::Status st = CheckCovariance(s.P_); !st.ok()) {
      return absl::DataLossError(absl::StrCat("checkpoint: ", st.message()));
    }
  }
  return s;
}

}  // namespace esg::estimator
