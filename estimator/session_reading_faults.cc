// The session's side of the reading-fault judgement (reading_fault_monitor.h, docs/decisions.md
// D94): the tracks of every gyro's rebuilt spin axis fed at each measurement step, the drift
// bound each interval allows, the verdicts that alone let a gyro be excluded, the exclusion
// records, and the re-opening of a gyro's coefficients after a drift change below the limit.
#include <algorithm>
#include <cmath>
#include <optional>
#include <string>
#include <vector>

#include "Eigen/Eigenvalues"
#include "absl/strings/str_format.h"
#include "estimator/basis_term.h"
#include "estimator/measurements.h"
#include "estimator/rotation.h"
#include "estimator/session.h"
#include "estimator/session_internal.h"
#include "estimator/units.h"
#include "estimator/utc_time.h"

namespace esg::estimator {

using Eigen::Matrix2d;
using Eigen::Matrix3d;
using Eigen::MatrixXd;
using Eigen::Quaterniond;
using Eigen::Vector3d;
using Source = ReadingFaultMonitor::Source;

using session_internal::kJ;
using session_internal::kNoiseFloor;

namespace {

// A verdict lets the gyro be excluded for this many measurement steps after it (the three-pair
// isolation may name the gyro a step or two after its reading jumped: D24's confirmation).
constexpr int kAbruptMemorySteps = 3;

// The difference [rad, frame in, in the tangent plane of T] between a gyro's spin axis rebuilt
// with the attitude q_in_b of the pair of the two other gyros (its reading h_k turned to inertial
// space) and the axis h_in the model carries.
Vector3d PairRebuildResidualIn(const Quaterniond& q_in_b, const Matrix3d& C_b_k,
                               const Vector3d& h_k, const Vector3d& h_in,
                               const Eigen::Matrix<double, 3, 2>& T) {
  const Vector3d rebuilt_in = q_in_b.toRotationMatrix() * C_b_k * h_k;
  return T * T.transpose() * (rebuilt_in - h_in);
}

}  // namespace

const char* ExclusionReasonName(ExclusionReason r) {
  switch (r) {
    case ExclusionReason::kNone:
      return "NONE";
    case ExclusionReason::kReadingJump:
      return "READING_JUMP";
    case ExclusionReason::kBeyondAnyDrift:
      return "READING_BEYOND_ANY_DRIFT";
    case ExclusionReason::kErratic:
      return "READINGS_ERRATIC";
    case ExclusionReason::kDriftBeyondLimit:
      return "DRIFT_CHANGE_BEYOND_LIMIT";
    case ExclusionReason::kEarlier:
      return "EXCLUDED_BEFORE_UPGRADE";
  }
  return "?";
}

std::string Exclusion::Describe() const {
  const std::string at = FormatUtc(time) +
                         (source == 0   ? " (its star-tracker rebuild)"
                          : source == 1 ? " (its rebuild from the two other gyros)"
                                        : "");
  switch (reason) {
    case ExclusionReason::kNone:
      return "";
    case ExclusionReason::kReadingJump:
      return absl::StrFormat(
          "its readings jumped by %.0f arcsec at %s (a jump beats a drift change by chi-square "
          "%.1f)",
          value, at, threshold);
    case ExclusionReason::kBeyondAnyDrift:
      return absl::StrFormat(
          "its readings moved at %.3g deg/h at %s, beyond any drift change within the bound "
          "%.3g deg/h (a jump, or a reading frozen while the spacecraft turns)",
          value, at, threshold);
    case ExclusionReason::kErratic:
      return absl::StrFormat(
          "its readings scatter far beyond their noise at %s (chi-square %.1f > %.1f)", at, value,
          threshold);
    case ExclusionReason::kDriftBeyondLimit:
      return absl::StrFormat("its drift changed by %.3g deg/h at %s, beyond the limit %.3g deg/h",
                             value, at, threshold);
    case ExclusionReason::kEarlier:
      return absl::StrFormat(
          "excluded by the service before version 7 of its checkpoint, which kept no reason "
          "(at or before %s)",
          at);
  }
  return "";
}

bool EstimationSession::degraded() const {
  return std::any_of(gyros_.begin(), gyros_.end(), [](const GyroState& g) { return g.faulty; });
}

Eigen::Matrix2d EstimationSession::ModelRateCovariance(int i) const {
  const GyroState& g = gyros_[i];
  const int drivers = layout_.SpinAxisDriverCount(i);
  if (drivers <= 0) return Eigen::Matrix2d::Zero();
  {
    // The rate error of the spin axis against its drivers (the propagation's E over a unit
    // interval): residual drift, free coefficients, free basis terms.
    Eigen::MatrixXd R = Eigen::MatrixXd::Zero(2, drivers);
    const Eigen::Matrix<double, 3, 2> Tt = g.T();
    const Matrix3d minus_hx = -Skew(g.h_in);
    Matrix3d C_in_b = Matrix3d::Identity();
    const std::array<int, 2> pair = AttitudePair();
    const GyroState* a = Find(pair[0]);
    const GyroState* b = Find(pair[1]);
    if (a != nullptr && b != nullptr) {
      if (auto q = PairQuaternion(a->id, b->id, a->h_k_last, b->h_k_last, nullptr)) {
        C_in_b = q->toRotationMatrix();
      }
    }
    const Matrix3d C_in_k = C_in_b * g.C_b_k();
    if (layout_.has_drift()) R.leftCols<2>() = kJ;
    const DriftRegressorMatrix B = DriftRegressor(g.h_k_last);
    const std::vector<int>& free = layout_.FreeCoefficients(i);
    for (int j = 0; j < layout_.ThetaCount(i); ++j) {
      R.col(layout_.DriftSize() + j) = Tt.transpose() * minus_hx * C_in_k * B.col(free[j]);
    }
    if (layout_.BasisCount(i) > 0) {
      BasisInputs in;
      in.time = last_time_;
      in.h_k = g.h_k_last;
      in.w_k = g.C_b_k().transpose() * body_rate_b_;
      in.u_k_v = g.u_k_v;
      in.channels = &channel_signals_;
      const Matrix3d C_in_k_perp =
          C_in_k * (Matrix3d::Identity() - g.h_k_last * g.h_k_last.transpose());
      const std::vector<int>& free_basis = layout_.FreeBasisTerms(i);
      for (int j = 0; j < layout_.BasisCount(i); ++j) {
        R.col(layout_.DriftSize() + layout_.ThetaCount(i) + j) =
            Tt.transpose() * minus_hx * C_in_k_perp * BasisRegressor_k(g.basis[free_basis[j]], in);
      }
    }
    const int d0 = layout_.SpinAxisDrivers(i);
    const Matrix2d cov = R * P_.block(d0, d0, drivers, drivers) * R.transpose();
    return 0.5 * (cov + cov.transpose());
  }
}

double EstimationSession::DriftBound(int i) const {
  const Eigen::SelfAdjointEigenSolver<Matrix2d> eig(ModelRateCovariance(i));
  const double sigma_rate = std::sqrt(std::max(eig.eigenvalues().maxCoeff(), 0.0));
  const double widened =
      widening_.widened() ? DegPerHourToRadPerSec(widening_.EquivalentDriftDegH()) : 0.0;
  return config_.filter.drift_change_limit + 3.0 * sigma_rate + widened;
}

MismatchLocation EstimationSession::LocateModelMismatch() const {
  std::vector<int> running;  // indices of the gyros not excluded
  for (int i = 0; i < static_cast<int>(gyros_.size()); ++i) {
    if (!gyros_[i].faulty) running.push_back(i);
  }
  std::vector<Matrix2d> rate_cov;
  std::vector<double> rate_var_max;  // largest eigenvalue of each [(rad/s)^2]
  for (int i : running) {
    rate_cov.push_back(ModelRateCovariance(i));
    const Eigen::SelfAdjointEigenSolver<Matrix2d> eig(rate_cov.back());
    rate_var_max.push_back(std::max(eig.eigenvalues().maxCoeff(), 0.0));
  }
  std::vector<TrackMisfit> misfits;
  for (size_t k = 0; k < running.size(); ++k) {
    const GyroState& g = gyros_[running[k]];
    TrackMisfit m;
    m.gyro_id = g.id;
    m.star_tracker = reading_monitor_.ModelMisfit(g.id, Source::kStarTracker, rate_cov[k]);
    if (running.size() == 3) {
      // The pair rebuild moves with the two other gyros' rate errors as well, as its drift bound
      // does (TrackReadings): the reference gyro's, and the second's over sin(theta), taken
      // isotropically at their largest.
      const size_t ka = (k + 1) % 3, kb = (k + 2) % 3;
      const double sin_theta = std::max(
          gyros_[running[ka]].h_in.cross(gyros_[running[kb]].h_in).norm(), 0.1);
      const Matrix2d pair_cov =
          rate_cov[k] + (rate_var_max[ka] + rate_var_max[kb] / (sin_theta * sin_theta)) *
                            Matrix2d::Identity();
      m.pair = reading_monitor_.ModelMisfit(g.id, Source::kPair, pair_cov);
    }
    misfits.push_back(m);
  }
  return LocateMismatch(misfits);
}

Eigen::VectorXd EstimationSession::DriverValues(int i) const {
  const GyroState& g = gyros_[i];
  Eigen::VectorXd d(layout_.SpinAxisDriverCount(i));
  int k = 0;
  if (layout_.has_drift()) d.segment<2>(k) = g.residual_drift, k += 2;
  for (int free : layout_.FreeCoefficients(i)) d(k++) = g.theta(free);
  for (int free : layout_.FreeBasisTerms(i)) d(k++) = g.basis[free].value;
  return d;
}

void EstimationSession::TrackReadings(const TelemetryFrame& frame, bool st_present,
                                      const Quaterniond& q_st, const std::vector<int>& fresh) {
  const double sigma_r = std::max(config_.readout_noise, kNoiseFloor);
  const double dt = last_update_time_ == absl::InfinitePast()
                        ? 0.0
                        : session_internal::Seconds(frame.time - last_update_time_);
  const double turn_measured = body_rate_b_.norm() * dt;
  const bool turn_kept = turn_measured <= kMaxTurnRad;  // false for inf and NaN too
  const double turn = turn_kept ? turn_measured : kMaxTurnRad;
  // The turn as a rotation vector in inertial axes (its axis tells a change of the turn's
  // direction at the same rate, reading_fault_monitor.h DriftChange): the body rate carried by
  // the star tracker's attitude, or the working pair's without it.
  std::optional<Quaterniond> q_in_b;
  if (st_present) {
    q_in_b = q_st;
  } else if (const GyroState* a = Find(working_pair_[0]), *b = Find(working_pair_[1]);
             a != nullptr && b != nullptr) {
    q_in_b = PairQuaternion(a->id, b->id, a->h_k_last, b->h_k_last, nullptr);
  }
  if (!turn_kept) q_in_b.reset();  // the axis of a turn not kept is not known either
  const Vector3d turn_in =
      q_in_b.has_value() ? Vector3d(q_in_b->toRotationMatrix() * body_rate_b_ * dt) : Vector3d::Zero();
  std::vector<double> bound(gyros_.size(), 0.0);
  for (int id : fresh) bound[IndexOf(id)] = DriftBound(IndexOf(id));
  std::vector<ReadingFaultMonitor::Sample> samples;
  if (st_present) {
    const Matrix3d C_in_b_st = q_st.toRotationMatrix();
    const Vector3d st_var = StarTrackerVarianceB();
    for (int id : fresh) {
      const int i = IndexOf(id);
      const GyroState& g = gyros_[i];
      const StarTrackerDifference d =
          MakeStarTrackerDifference(g.h_in, g.T(), C_in_b_st, g.C_b_k(), g.h_k_last);
      const Matrix2d N = d.G_st * st_var.asDiagonal() * d.G_st.transpose() +
                         sigma_r * sigma_r * d.G_readout * d.G_readout.transpose();
      ReadingFaultMonitor::Sample s;
      s.gyro_id = id;
      s.source = Source::kStarTracker;
      s.T = g.T();
      s.prior_residual_in = s.T * d.z;
      s.noise_in = s.T * N * s.T.transpose();
      s.drivers = DriverValues(i);
      s.motion_jacobian_in = g.motion_in;
      s.drift_bound = bound[i];
      s.turn = turn;
      s.turn_in = turn_in;
      s.turn_in_known = q_in_b.has_value();
      samples.push_back(s);
    }
  }
  // The rebuild from the pair of the two other gyros: free of the star tracker (its 30 arcsec
  // boresight noise hides a jump of a minute or two in some directions; the pair's readout noise
  // of a few arcsec does not), and the only one without it.
  if (fresh.size() == 3) {
    for (int k = 0; k < 3; ++k) {
      const int id = fresh[k];
      const int i = IndexOf(id);
      const GyroState& g = gyros_[i];
      const GyroState& a = *Find(fresh[(k + 1) % 3]);
      const GyroState& b = *Find(fresh[(k + 2) % 3]);
      const auto q = PairQuaternion(a.id, b.id, a.h_k_last, b.h_k_last, nullptr);
      if (!q.has_value()) continue;
      const Eigen::Matrix<double, 3, 2> T = g.T();
      // Its noise, bounded isotropically (a test never stronger than with the exact one): the
      // TRIAD attitude of the pair turns by the reference gyro's readout noise about two axes and
      // by the second gyro's over sin(theta) about the reference axis, and the gyro's own readout
      // adds its noise: sigma^2 (2 + 1 / sin^2(theta) + 1) about each tangent axis.
      const double sin_theta = std::max(a.h_in.cross(b.h_in).norm(), 0.1);
      const double var = sigma_r * sigma_r * (3.0 + 1.0 / (sin_theta * sin_theta));
      ReadingFaultMonitor::Sample s;
      s.gyro_id = id;
      s.source = Source::kPair;
      s.T = T;
      s.prior_residual_in = PairRebuildResidualIn(*q, g.C_b_k(), g.h_k_last, g.h_in, T);
      s.noise_in = var * T * T.transpose();
      // The rebuild's pair moves with its own drivers too; the track measures against gyro g's
      // model as it started, the pair's model corrections part of the bound: the reference
      // gyro's drift by its rate, the second's about the reference axis by its rate over
      // sin(theta).
      s.drivers = DriverValues(i);
      s.motion_jacobian_in = g.motion_in;
      s.drift_bound = bound[i] + bound[IndexOf(a.id)] + bound[IndexOf(b.id)] / sin_theta;
      s.turn = turn;
      s.turn_in = turn_in;
      s.turn_in_known = q_in_b.has_value();
      samples.push_back(s);
    }
  }
  const std::vector<ReadingFaultMonitor::Result> results = reading_monitor_.AddStep(frame.time, samples);
  // The motion since this update starts afresh.
  for (GyroState& g : gyros_) g.motion_in.setZero();
  for (const ReadingFaultMonitor::Result& r : results) {
    if (r.verdict == ReadingVerdict::kNone) continue;
    AbruptRecord a;
    a.time = frame.time;
    a.verdict = r.verdict;
    a.source = r.source;
    a.value = r.value;
    a.threshold = r.threshold;
    a.statistic = r.statistic;
    // The star tracker's verdict is the gyro's own; keep it over the pair's at the same step.
    auto it = abrupt_.find(r.gyro_id);
    if (it != abrupt_.end() && it->second.time == frame.time &&
        it->second.source == Source::kStarTracker) {
      continue;
    }
    abrupt_[r.gyro_id] = a;
  }
}

void EstimationSession::TrackPosteriors(const TelemetryFrame& frame, bool st_present) {
  std::vector<int> fresh;
  for (const GyroState& g : gyros_) {
    if (!g.faulty && frame.gyros[g.id - 1].has_value()) fresh.push_back(g.id);
  }
  if (st_present) {
    const Matrix3d C_in_b_st = StarTrackerCorrected(frame.star_tracker->q_in_b).toRotationMatrix();
    for (int id : fresh) {
      const GyroState& g = *Find(id);
      const StarTrackerDifference d =
          MakeStarTrackerDifference(g.h_in, g.T(), C_in_b_st, g.C_b_k(), g.h_k_last);
      reading_monitor_.SetPosterior(id, Source::kStarTracker, g.T() * d.z);
    }
  }
  if (fresh.size() == 3) {
    for (int k = 0; k < 3; ++k) {
      const GyroState& g = *Find(fresh[k]);
      const GyroState& a = *Find(fresh[(k + 1) % 3]);
      const GyroState& b = *Find(fresh[(k + 2) % 3]);
      const auto q = PairQuaternion(a.id, b.id, a.h_k_last, b.h_k_last, nullptr);
      if (!q.has_value()) continue;
      reading_monitor_.SetPosterior(
          g.id, Source::kPair, PairRebuildResidualIn(*q, g.C_b_k(), g.h_k_last, g.h_in, g.T()));
    }
  }
}

bool EstimationSession::WithholdUnverified(int id, absl::Time now) {
  const bool again = unverified_gyro_ == id && unverified_time_ == last_update_time_;
  unverified_gyro_ = id;
  unverified_time_ = now;
  return !again;
}

std::optional<EstimationSession::AbruptRecord> EstimationSession::RecentAbrupt(
    int id, absl::Time now) const {
  auto it = abrupt_.find(id);
  if (it == abrupt_.end()) return std::nullopt;
  const absl::Duration memory =
      absl::Seconds(kAbruptMemorySteps * config_.filter.measurement_step + 1e-3);
  if (now - it->second.time > memory) return std::nullopt;
  return it->second;
}

Exclusion EstimationSession::ExclusionFrom(const AbruptRecord& a) {
  Exclusion e;
  e.time = a.time;
  e.source = static_cast<int>(a.source);
  switch (a.verdict) {
    case ReadingVerdict::kJump:
      e.reason = ExclusionReason::kReadingJump;
      e.value = RadToArcsec(a.value);
      e.threshold = a.statistic;
      break;
    case ReadingVerdict::kBeyond:
      e.reason = ExclusionReason::kBeyondAnyDrift;
      e.value = RadPerSecToDegPerHour(a.value);
      e.threshold = RadPerSecToDegPerHour(a.threshold);
      break;
    case ReadingVerdict::kErratic:
    case ReadingVerdict::kNone:
      e.reason = ExclusionReason::kErratic;
      e.value = a.value;
      e.threshold = a.threshold;
      break;
  }
  return e;
}

void EstimationSession::MarkExcluded(int id, const Exclusion& why) {
  GyroState* g = Find(id);
  if (g == nullptr || g->faulty) return;
  g->faulty = true;
  g->exclusion = why;
  change_detector_.Clear();
  if (drift_change_gyro_ == id) drift_change_gyro_ = 0;
}

absl::Status EstimationSession::ReadmitGyro(int gyro_id) {
  if (config_.FindGyro(gyro_id) == nullptr) {
    std::string configured;
    for (const GyroConfig& gc : config_.gyros) {
      configured += absl::StrFormat("%s%d", configured.empty() ? "" : ", ", gc.id);
    }
    return absl::NotFoundError(absl::StrFormat(
        "gyro_id: gyro %d is not configured (configured: %s)", gyro_id, configured));
  }
  const int i = IndexOf(gyro_id);
  if (i < 0 || !gyros_[i].faulty) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "gyro_id: gyro %d is not excluded (%s); only a gyro the filter excluded is readmitted",
        gyro_id, i < 0 ? "it is not running" : "it is running in the filter"));
  }
  if (working_pair_[0] == gyro_id || working_pair_[1] == gyro_id) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "gyro_id: gyro %d is in the output pair [%d,%d]: no clean pair is left to carry the "
        "output until it rejoins",
        gyro_id, working_pair_[0], working_pair_[1]));
  }
  // Its block leaves the state (state_layout.h: the blocks are contiguous in gyros_ order, so the
  // others keep their order and the latency its index); StartSwitchedOnGyros appends it again at
  // the next measurement step where it reports, with the configured prior.
  const int begin = layout_.GyroBegin(i);
  const int size = layout_.GyroSize(i);
  const int n = state_size();
  std::vector<int> keep;
  keep.reserve(n - size);
  for (int k = 0; k < n; ++k) {
    if (k < begin || k >= begin + size) keep.push_back(k);
  }
  const int m = static_cast<int>(keep.size());
  MatrixXd P(m, m), P0(m, m);
  for (int r = 0; r < m; ++r) {
    for (int c = 0; c < m; ++c) {
      P(r, c) = P_(keep[r], keep[c]);
      P0(r, c) = P0_(keep[r], keep[c]);
    }
  }
  P_ = std::move(P);
  P0_ = std::move(P0);
  gyros_.erase(gyros_.begin() + i);
  layout_ = LayoutFor(config_, options_.model, gyros_);
  if (reserve_pair_[0] == gyro_id || reserve_pair_[1] == gyro_id) reserve_pair_ = working_pair_;
  // What the filter held about the gyro's readings and drift ends with its block.
  abrupt_.erase(gyro_id);
  if (suspect_gyro_ == gyro_id) suspect_gyro_ = 0;
  if (unverified_gyro_ == gyro_id) unverified_gyro_ = 0;
  if (drift_change_gyro_ == gyro_id) drift_change_gyro_ = 0;
  change_detector_.Clear();
  reading_monitor_.Clear();
  return absl::OkStatus();
}

void EstimationSession::ReopenDrift(int id, double change_rad_s) {
  const int i = IndexOf(id);
  if (i < 0) return;
  const int t0 = layout_.Theta(i);
  for (int j = 0; j < layout_.ThetaCount(i) + layout_.BasisCount(i); ++j) {
    P_(t0 + j, t0 + j) += P0_(t0 + j, t0 + j);
  }
  if (layout_.has_drift()) {
    const int d = layout_.Drift(i);
    for (int k = 0; k < StateLayout::kDriftSize; ++k) P_(d + k, d + k) += change_rad_s * change_rad_s;
  }
  converged_ = false;
  convergence_mark_time_ = absl::InfinitePast();
}

}  // namespace esg::estimator
