// The star-tracker mount-shift test (star_tracker_mount.h).
#include "estimator/star_tracker_mount.h"

#include <cmath>
#include <utility>

#include "Eigen/Cholesky"
#include "Eigen/Geometry"
#include "Eigen/LU"
#include "absl/strings/str_format.h"
#include "estimator/statistics.h"

namespace esg::estimator {

using Eigen::Matrix3d;
using Eigen::Vector3d;

StarTrackerMountMonitor::StarTrackerMountMonitor(StarTrackerMountOptions options)
    : options_(options) {
  threshold_ =
      ChiSquareQuantile(1.0 - options_.alpha, 3.0 * (options_.window_steps - 1));
  perpendicular_threshold_ = ChiSquareQuantile(1.0 - options_.alpha, 2.0);
}

std::optional<StarTrackerMountMonitor::Decision> StarTrackerMountMonitor::AddVoted(
    const Vector3d& d_b, const Matrix3d& R_b, const Vector3d& w_b) {
  if (!d_b.allFinite() || !R_b.allFinite() || !w_b.allFinite() ||
      R_b.llt().info() != Eigen::Success) {
    steps_.clear();
    return std::nullopt;
  }
  steps_.push_back(Step{d_b, R_b, w_b});
  while (static_cast<int>(steps_.size()) > options_.window_steps) steps_.pop_front();
  if (static_cast<int>(steps_.size()) < options_.window_steps) return std::nullopt;
  // Information-weighted mean of the window and its scatter about it.
  Matrix3d information = Matrix3d::Zero();
  Vector3d weighted = Vector3d::Zero();
  for (const Step& s : steps_) {
    const Matrix3d W = s.R_b.inverse();
    information += W;
    weighted += W * s.d_b;
  }
  Decision d;
  d.shift_b = information.ldlt().solve(weighted);
  for (const Step& s : steps_) {
    const Vector3d r = s.d_b - d.shift_b;
    d.scatter += r.dot(s.R_b.ldlt().solve(r));
  }
  d.threshold = threshold_;
  d.steps = options_.window_steps;
  if (!(d.scatter <= threshold_)) {
    steps_.pop_front();
    return std::nullopt;
  }
  d.covariance_b = information.inverse() + steps_.back().R_b;
  // Could a time-tag error explain the shift? (1) Along the window's mean rate w: its part
  // perpendicular to w, in the plane (u1, u2) perpendicular to it, against its covariance there.
  for (const Step& s : steps_) d.mean_rate_b += s.w_b / static_cast<double>(steps_.size());
  d.rate_before_b = d.mean_rate_b;
  for (const Vector3d& w : applied_rates_b_) {
    if ((w - d.mean_rate_b).norm() > (d.rate_before_b - d.mean_rate_b).norm()) d.rate_before_b = w;
  }
  d.perpendicular_threshold = perpendicular_threshold_;
  const double rate = d.mean_rate_b.norm();
  if (rate > 0.0 && d.shift_b.norm() <= rate * kMaxLatencyS) {
    const Vector3d w_hat = d.mean_rate_b / rate;
    const Vector3d u1 = w_hat.unitOrthogonal();
    const Vector3d u2 = w_hat.cross(u1);
    Eigen::Matrix<double, 3, 2> U;
    U << u1, u2;
    const Eigen::Vector2d p = U.transpose() * d.shift_b;
    const Eigen::Matrix2d S = U.transpose() * d.covariance_b * U;
    d.perpendicular_chi2 = p.dot(S.ldlt().solve(p));
    if (d.perpendicular_chi2 < perpendicular_threshold_) {
      d.latency_alternative = true;
      // q_st = q(t - tau) = q(t) (x) Exp(-w_b tau): m = -w tau.
      d.latency_alternative_s = -d.shift_b.dot(d.mean_rate_b) / (rate * rate);
    }
  }
  // (2) The rate changed since a recent step that applied the star tracker by enough for a
  // latency within kMaxLatencyS to make the shift: the misalignment states absorbed part of the
  // old rate's rotation (not all, and not along a known direction), so only the size is tested.
  const Vector3d change_b = d.mean_rate_b - d.rate_before_b;
  const double change = change_b.norm();
  if (!d.latency_alternative && change > 0.0 && d.shift_b.norm() <= change * kMaxLatencyS) {
    d.latency_alternative = true;
    d.latency_alternative_s = -d.shift_b.dot(change_b) / (change * change);
  }
  steps_.clear();
  return d;
}

void StarTrackerMountMonitor::NoteApplied(const Vector3d& w_b) {
  if (!w_b.allFinite()) return;
  applied_rates_b_.push_back(w_b);
  while (static_cast<int>(applied_rates_b_.size()) > kAppliedSteps) applied_rates_b_.pop_front();
}

std::vector<double> StarTrackerMountMonitor::ExportState() const {
  std::vector<double> v = {static_cast<double>(applied_rates_b_.size())};
  for (const Vector3d& w : applied_rates_b_) v.insert(v.end(), {w.x(), w.y(), w.z()});
  v.push_back(static_cast<double>(steps_.size()));
  for (const Step& s : steps_) {
    for (int i = 0; i < 3; ++i) v.push_back(s.d_b(i));
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) v.push_back(s.R_b(i, j));
    }
    for (int i = 0; i < 3; ++i) v.push_back(s.w_b(i));
  }
  return v;
}

absl::Status StarTrackerMountMonitor::RestoreState(absl::Span<const double> state) {
  if (state.empty()) return absl::DataLossError("star-tracker mount: state truncated");
  const double applied = state[0];
  if (!(applied >= 0.0 && applied <= kAppliedSteps && applied == std::floor(applied))) {
    return absl::DataLossError(absl::StrFormat(
        "star-tracker mount: applied rate count %g outside [0, %d]", applied, kAppliedSteps));
  }
  const size_t head = 1 + 3 * static_cast<size_t>(applied);
  if (state.size() < head + 1) return absl::DataLossError("star-tracker mount: state truncated");
  std::deque<Vector3d> applied_rates_b;
  for (size_t k = 0; k < static_cast<size_t>(applied); ++k) {
    const Vector3d w(state[1 + 3 * k], state[2 + 3 * k], state[3 + 3 * k]);
    if (!w.allFinite()) return absl::DataLossError("star-tracker mount: a rate is not finite");
    applied_rates_b.push_back(w);
  }
  const double n = state[head];
  if (!(n >= 0.0 && n < options_.window_steps && n == std::floor(n))) {
    return absl::DataLossError(absl::StrFormat("star-tracker mount: step count %g outside [0, %d)",
                                               n, options_.window_steps));
  }
  constexpr size_t kPerStep = 15;
  if (state.size() != head + 1 + kPerStep * static_cast<size_t>(n)) {
    return absl::DataLossError("star-tracker mount: state size does not match its step count");
  }
  std::deque<Step> steps;
  for (size_t k = 0; k < static_cast<size_t>(n); ++k) {
    const double* p = state.data() + head + 1 + kPerStep * k;
    Step s;
    for (int i = 0; i < 3; ++i) s.d_b(i) = p[i];
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) s.R_b(i, j) = p[3 + 3 * i + j];
    }
    for (int i = 0; i < 3; ++i) s.w_b(i) = p[12 + i];
    if (!s.d_b.allFinite() || !s.R_b.allFinite() || !s.w_b.allFinite() ||
        s.R_b.llt().info() != Eigen::Success) {
      return absl::DataLossError(absl::StrFormat(
          "star-tracker mount: step %d is not finite or its covariance not positive definite", k));
    }
    steps.push_back(std::move(s));
  }
  applied_rates_b_ = std::move(applied_rates_b);
  steps_ = std::move(steps);
  return absl::OkStatus();
}

}  // namespace esg::estimator
