// The session's checkpoint (EstimationSession::ExportCheckpoint, FromCheckpoint): everything
// needed to resume bit for bit, as a versioned vector of doubles. The server stores these values
// and restores them, so the order below is a storage format: a written version must not change.
#include "estimator/session.h"

#include <cmath>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/types/span.h"
#include "estimator/ekf.h"
#include "estimator/session_internal.h"

namespace esg::estimator {

using Eigen::MatrixXd;
using Eigen::VectorXd;

// Checkpoint layout, all doubles; a time is three values (1, unix seconds, nanoseconds), or
// (-1, 0, 0) for absl::InfinitePast().
// Version 1 (read only):
//   initialized, use_star_tracker, last_time, last_update_time, start_time,
//   convergence_mark_time, working_pair (2), reserve_pair (2), state, steps_without_star_tracker,
//   consecutive_rejections, converged, m, convergence_mark_sigma (m);
//   the number of running gyros, then per gyro: id, h_in (3), t1 (3), residual_drift (2),
//   theta (13), phi_b (3), faulty, has_reading, h_k_last (3);
//   n (the state size, StateLayout::size()), P (n x n, row by row), P0 (n x n, row by row).
//   A session restored from it starts the consistency monitor with empty windows and counts the
//   star tracker as accepted (star_tracker_voted_faulty = 0, star_tracker_accepted = 1,
//   consecutive_accepted = 0).
// Version 2 (read only): version 1's values in the same order (so every index above is
//   unchanged), then
//   star_tracker_voted_faulty, star_tracker_accepted, consecutive_accepted,
//   c (a count), the consistency monitor's state (c values, ConsistencyMonitor::ExportState).
//   A session restored from it runs with the process noise as configured (not widened).
// Version 3 (written): version 2's values, then w (a count) and the process-noise widening's
//   state (w values, NoiseWidening::ExportState), then suspect_gyro and suspect_time (3) of the
//   isolation's confirmation (D24).
// Version 4 (written): version 3's values, then latency_s (the star-tracker latency the samples
//   are corrected with: the configured one, or the filter's estimate), previous_mean_rate_b (3)
//   and previous_interval_s of the body-rate extrapolation, then d (a count) and the per-gyro
//   accumulated star-tracker test's state (d values, GyroChangeDetector::ExportState). A session
//   restored from an earlier version corrects with the configured latency and starts the
//   extrapolation and the accumulated test afresh.
// Version 5 (written): version 4's values, then the star-tracker mount correction (D34): shift_b
//   (3), its variance about the body axes (3), the part of that counted as star-tracker noise
//   (3) and the number of corrections, then s (a count) and
//   the mount-shift test's window (s values, StarTrackerMountMonitor::ExportState). A session
//   restored from an earlier version has no mount correction.
// Version 6 (written): version 5's values, then per running gyro (in the order above): b (its
//   number of basis terms, that of its GyroConfig::basis_terms), the terms' current values (b,
//   [rad/s per unit of s]), then has_u and u_k_v (3, zeros when has_u is 0), the held suspension
//   voltages [V]. A session restored from an earlier version starts the terms at their configured
//   values, without voltages.
// Version 7 (written): version 6's values, then per running gyro (in the order above) its
//   exclusion (D94): reason (ExclusionReason), time (3), value, threshold, source; then r (a count) and
//   the reading-fault monitor's state (r values, ReadingFaultMonitor::ExportState); then a (a
//   count) and per recent verdict: gyro id, time (3), verdict (ReadingVerdict), source, value,
//   threshold, statistic; then unverified_gyro and unverified_time (3), drift_change_gyro and
//   drift_change_named (3); then per running gyro
//   the columns m of its motion since the last update (0 or its driver count) and the 3 x m
//   values, row by row. A session restored from an earlier version gives each excluded gyro
//   the reason kEarlier at its last update time, starts the monitor afresh, and one that was
//   FAULTED with a usable pair left resumes in its progress state (degraded).
// Version 8 (written): version 7's values, except that each gyro's theta is preceded by its
//   length t (kNumDriftCoefficients: the fixed terms of estimator/model_terms.h, 13 today), so a
//   checkpoint says how many fixed drift coefficients it holds: one written before a fixed term
//   was added to (or removed from) the model no longer restores (DataLoss naming the counts; the
//   server rebuilds the session from its archive) instead of reading the next field as a
//   coefficient. Versions 1-7 hold 13.
//   A field added to the session later goes after these, with a new version.
// The state layout itself is not stored: it follows from the configuration and the model.
SessionCheckpoint EstimationSession::ExportCheckpoint() const {
  SessionCheckpoint c;
  c.version = 8;
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
    v.push_back(static_cast<double>(g.theta.size()));  // version 8
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
  // Version 2.
  v.push_back(star_tracker_voted_faulty_ ? 1 : 0);
  v.push_back(star_tracker_accepted_ ? 1 : 0);
  v.push_back(consecutive_accepted_);
  const std::vector<double> monitor = consistency_.ExportState();
  v.push_back(static_cast<double>(monitor.size()));
  v.insert(v.end(), monitor.begin(), monitor.end());
  // Version 3.
  const std::vector<double> widening = widening_.ExportState();
  v.push_back(static_cast<double>(widening.size()));
  v.insert(v.end(), widening.begin(), widening.end());
  v.push_back(suspect_gyro_);
  put_time(suspect_time_);
  // Version 4.
  v.push_back(latency_s_);
  put_vec(previous_mean_rate_b_);
  v.push_back(previous_interval_s_);
  const std::vector<double> detector = change_detector_.ExportState();
  v.push_back(static_cast<double>(detector.size()));
  v.insert(v.end(), detector.begin(), detector.end());
  // Version 5.
  put_vec(st_mount_b_);
  put_vec(st_mount_var_b_);
  put_vec(st_mount_noise_var_b_);
  v.push_back(st_realignments_);
  const std::vector<double> mount = mount_monitor_.ExportState();
  v.push_back(static_cast<double>(mount.size()));
  v.insert(v.end(), mount.begin(), mount.end());
  // Version 6.
  for (const GyroState& g : gyros_) {
    v.push_back(static_cast<double>(g.basis.size()));
    for (const BasisTerm& t : g.basis) v.push_back(t.value);
    v.push_back(g.u_k_v.has_value() ? 1 : 0);
    put_vec(g.u_k_v.value_or(Eigen::Vector3d::Zero()));
  }
  // Version 7.
  for (const GyroState& g : gyros_) {
    v.push_back(static_cast<double>(g.exclusion.reason));
    put_time(g.exclusion.time);
    v.push_back(g.exclusion.value);
    v.push_back(g.exclusion.threshold);
    v.push_back(g.exclusion.source);
  }
  const std::vector<double> reading = reading_monitor_.ExportState();
  v.push_back(static_cast<double>(reading.size()));
  v.insert(v.end(), reading.begin(), reading.end());
  v.push_back(static_cast<double>(abrupt_.size()));
  for (const auto& [id, a] : abrupt_) {
    v.push_back(id);
    put_time(a.time);
    v.push_back(static_cast<double>(a.verdict));
    v.push_back(static_cast<double>(a.source));
    v.push_back(a.value);
    v.push_back(a.threshold);
    v.push_back(a.statistic);
  }
  v.push_back(unverified_gyro_);
  put_time(unverified_time_);
  v.push_back(drift_change_gyro_);
  put_time(drift_change_named_);
  for (const GyroState& g : gyros_) {
    v.push_back(static_cast<double>(g.motion_in.cols()));
    for (int r = 0; r < g.motion_in.rows(); ++r) {
      for (int c2 = 0; c2 < g.motion_in.cols(); ++c2) v.push_back(g.motion_in(r, c2));
    }
  }
  return c;
}

absl::StatusOr<EstimationSession> EstimationSession::FromCheckpoint(
    const SpacecraftConfig& config, const SessionOptions& options,
    const SessionCheckpoint& checkpoint) {
  if (checkpoint.version < 1 || checkpoint.version > 8) {
    return absl::DataLossError(
        absl::StrCat("checkpoint version ", checkpoint.version, " is unknown"));
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
  // The first value that is not what its field allows; it marks the checkpoint corrupt. An
  // integer field must hold a finite integer in int's range (a plain cast of anything else
  // would be undefined behaviour), a flag 0 or 1, a real a finite number.
  std::string bad_value;
  auto mark_bad = [&](double x, const char* what) {
    if (bad_value.empty()) {
      bad_value = absl::StrFormat("checkpoint: value %d = %.10g: %s", pos - 1, x, what);
    }
  };
  auto get_int = [&]() {
    const double x = get();
    if (!(std::abs(x) <= session_internal::kMaxCount) || x != std::floor(x)) {
      mark_bad(x, "an integer field is not an integer in [-1e9, 1e9]");
      return 0;
    }
    return static_cast<int>(x);
  };
  auto get_flag = [&]() {
    const double x = get();
    if (x != 0.0 && x != 1.0) mark_bad(x, "a flag field is not 0 or 1 (an integer)");
    return x == 1.0;
  };
  auto get_real = [&]() {
    const double x = get();
    if (!std::isfinite(x)) mark_bad(x, "a real field is not finite");
    return x;
  };
  auto get_time = [&]() {
    const double flag = get();
    if (flag != -1.0 && flag != 1.0) mark_bad(flag, "a time's flag is not -1 or 1 (an integer)");
    const double sec = get();
    if (!(std::abs(sec) <= 1e12) || sec != std::floor(sec)) {
      mark_bad(sec, "a time's seconds are not an integer in range");
    }
    const double nsec = get();
    if (!(std::abs(nsec) < 1e9) || nsec != std::floor(nsec)) {
      mark_bad(nsec, "a time's nanoseconds are not an integer in (-1e9, 1e9)");
    }
    if (flag != 1.0 || !bad_value.empty()) return absl::InfinitePast();
    return absl::FromUnixSeconds(static_cast<int64_t>(sec)) +
           absl::Nanoseconds(static_cast<int64_t>(nsec));
  };
  auto get_vec = [&](auto& x) {
    for (int i = 0; i < x.size(); ++i) x(i) = get_real();
  };
  s.initialized_ = get_flag();
  s.use_star_tracker_ = get_flag();
  s.last_time_ = get_time();
  s.last_update_time_ = get_time();
  s.start_time_ = get_time();
  s.convergence_mark_time_ = get_time();
  s.working_pair_ = {get_int(), get_int()};
  s.reserve_pair_ = {get_int(), get_int()};
  s.state_ = static_cast<SessionState>(get_int());
  s.steps_without_star_tracker_ = get_int();
  s.consecutive_rejections_ = get_int();
  s.converged_ = get_flag();
  const int n_mark = get_int();
  if (n_mark < 0 || n_mark > 1000) return absl::DataLossError("checkpoint: bad convergence record");
  s.convergence_mark_sigma_ = VectorXd::Zero(n_mark);
  get_vec(s.convergence_mark_sigma_);
  const int n_gyros = get_int();
  if (n_gyros < 0 || n_gyros > kMaxGyros) return absl::DataLossError("checkpoint: bad gyro count");
  for (int i = 0; i < n_gyros; ++i) {
    GyroState g;
    g.id = get_int();
    const GyroConfig* gc = config.FindGyro(g.id);
    if (gc == nullptr) {
      return absl::DataLossError(absl::StrCat("checkpoint: gyro ", g.id, " is not in the configuration"));
    }
    g.C_b_k_config = gc->C_b_k;
    g.basis = gc->basis_terms;  // values from version 6 on
    get_vec(g.h_in);
    get_vec(g.t1);
    get_vec(g.residual_drift);
    // Versions 1-7 hold the 13 coefficients of eq. (1), (10); version 8 says how many.
    const int theta_count = checkpoint.version >= 8 ? get_int() : 13;
    if (bad_value.empty() && !short_read && theta_count != g.theta.size()) {
      return absl::DataLossError(absl::StrFormat(
          "checkpoint: gyro %d holds %d fixed drift coefficients, this build's model has %d "
          "(a fixed term added or removed since it was written, estimator/model_terms.h)",
          g.id, theta_count, static_cast<int>(g.theta.size())));
    }
    get_vec(g.theta);
    get_vec(g.phi_b);
    g.faulty = get_flag();
    g.has_reading = get_flag();
    get_vec(g.h_k_last);
    s.gyros_.push_back(std::move(g));
  }
  s.layout_ = LayoutFor(config, options.model, s.gyros_);
  const int n = get_int();
  if (n != s.layout_.size()) {
    return absl::DataLossError(absl::StrFormat(
        "checkpoint: covariance size %d does not fit the configuration and model %s (%d states)", n,
        options.model.Name(), s.layout_.size()));
  }
  s.P_ = MatrixXd::Zero(n, n);
  s.P0_ = MatrixXd::Zero(n, n);
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) s.P_(i, j) = get_real();
  }
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) s.P0_(i, j) = get_real();
  }
  if (checkpoint.version >= 2) {
    s.star_tracker_voted_faulty_ = get_flag();
    s.star_tracker_accepted_ = get_flag();
    s.consecutive_accepted_ = get_int();
    const int n_monitor = get_int();
    if (short_read || n_monitor < 0 || static_cast<size_t>(n_monitor) > v.size() - pos) {
      return absl::DataLossError("checkpoint: truncated (consistency monitor)");
    }
    if (absl::Status st =
            s.consistency_.RestoreState(absl::MakeConstSpan(v).subspan(pos, n_monitor));
        !st.ok()) {
      return absl::DataLossError(absl::StrCat("checkpoint: consistency monitor: ", st.message()));
    }
    pos += n_monitor;
  }
  if (checkpoint.version >= 3) {
    const int n_widening = get_int();
    if (short_read || n_widening < 0 || static_cast<size_t>(n_widening) > v.size() - pos) {
      return absl::DataLossError("checkpoint: truncated (process-noise widening)");
    }
    if (absl::Status st =
            s.widening_.RestoreState(absl::MakeConstSpan(v).subspan(pos, n_widening));
        !st.ok()) {
      return absl::DataLossError(absl::StrCat("checkpoint: ", st.message()));
    }
    pos += n_widening;
    s.suspect_gyro_ = get_int();
    s.suspect_time_ = get_time();
  }
  if (checkpoint.version >= 4) {
    s.latency_s_ = get_real();
    get_vec(s.previous_mean_rate_b_);
    s.previous_interval_s_ = get_real();
    if (s.previous_interval_s_ < 0.0) mark_bad(s.previous_interval_s_, "an interval is negative");
    const int n_detector = get_int();
    if (short_read || n_detector < 0 || static_cast<size_t>(n_detector) > v.size() - pos) {
      return absl::DataLossError("checkpoint: truncated (gyro change detector)");
    }
    if (absl::Status st =
            s.change_detector_.RestoreState(absl::MakeConstSpan(v).subspan(pos, n_detector));
        !st.ok()) {
      return absl::DataLossError(absl::StrCat("checkpoint: ", st.message()));
    }
    pos += n_detector;
  }
  if (checkpoint.version >= 5) {
    get_vec(s.st_mount_b_);
    get_vec(s.st_mount_var_b_);
    get_vec(s.st_mount_noise_var_b_);
    for (const Eigen::Vector3d& var : {s.st_mount_var_b_, s.st_mount_noise_var_b_}) {
      if (!(var.minCoeff() >= 0.0)) mark_bad(var.minCoeff(), "a variance is negative");
    }
    s.st_realignments_ = get_int();
    if (s.st_realignments_ < 0) mark_bad(s.st_realignments_, "a count is negative");
    const int n_mount = get_int();
    if (short_read || n_mount < 0 || static_cast<size_t>(n_mount) > v.size() - pos) {
      return absl::DataLossError("checkpoint: truncated (star-tracker mount)");
    }
    if (absl::Status st =
            s.mount_monitor_.RestoreState(absl::MakeConstSpan(v).subspan(pos, n_mount));
        !st.ok()) {
      return absl::DataLossError(absl::StrCat("checkpoint: ", st.message()));
    }
    pos += n_mount;
  }
  if (checkpoint.version >= 6) {
    for (GyroState& g : s.gyros_) {
      const int b = get_int();
      if (short_read || b != static_cast<int>(g.basis.size())) {
        return absl::DataLossError(absl::StrFormat(
            "checkpoint: gyro %d has %d basis terms, the configuration %d", g.id, b,
            g.basis.size()));
      }
      for (BasisTerm& t : g.basis) t.value = get_real();
      const bool has_u = get_flag();
      Eigen::Vector3d u_k_v;
      get_vec(u_k_v);
      if (has_u) g.u_k_v = u_k_v;
    }
  }
  if (checkpoint.version >= 7) {
    for (GyroState& g : s.gyros_) {
      const int reason = get_int();
      if (reason < static_cast<int>(ExclusionReason::kNone) ||
          reason > static_cast<int>(ExclusionReason::kEarlier)) {
        mark_bad(reason, "an exclusion reason is unknown");
      }
      g.exclusion.reason = static_cast<ExclusionReason>(reason);
      g.exclusion.time = get_time();
      g.exclusion.value = get_real();
      g.exclusion.threshold = get_real();
      g.exclusion.source = get_int();
      if (g.exclusion.source < -1 || g.exclusion.source > 1) {
        mark_bad(g.exclusion.source, "an exclusion's track is not -1, 0 or 1");
      }
      if ((g.exclusion.reason != ExclusionReason::kNone) != g.faulty) {
        mark_bad(reason, "an exclusion reason does not match the gyro's excluded flag");
      }
    }
    const int n_reading = get_int();
    if (short_read || n_reading < 0 || static_cast<size_t>(n_reading) > v.size() - pos) {
      return absl::DataLossError("checkpoint: truncated (reading-fault monitor)");
    }
    if (absl::Status st =
            s.reading_monitor_.RestoreState(absl::MakeConstSpan(v).subspan(pos, n_reading));
        !st.ok()) {
      return absl::DataLossError(absl::StrCat("checkpoint: ", st.message()));
    }
    pos += n_reading;
    const int n_abrupt = get_int();
    if (short_read || n_abrupt < 0 || n_abrupt > kMaxGyros) {
      return absl::DataLossError("checkpoint: bad count of reading verdicts");
    }
    for (int k = 0; k < n_abrupt; ++k) {
      const int id = get_int();
      AbruptRecord a;
      a.time = get_time();
      const int verdict = get_int();
      const int source = get_int();
      if (verdict < static_cast<int>(ReadingVerdict::kJump) ||
          verdict > static_cast<int>(ReadingVerdict::kErratic)) {
        mark_bad(verdict, "a reading verdict is unknown");
      }
      if (source != 0 && source != 1) mark_bad(source, "a reading source is not 0 or 1");
      a.verdict = static_cast<ReadingVerdict>(verdict);
      a.source = static_cast<ReadingFaultMonitor::Source>(source);
      a.value = get_real();
      a.threshold = get_real();
      a.statistic = get_real();
      if (s.Find(id) == nullptr) mark_bad(id, "a reading verdict names a gyro not running");
      s.abrupt_[id] = a;
    }
    s.unverified_gyro_ = get_int();
    s.unverified_time_ = get_time();
    s.drift_change_gyro_ = get_int();
    s.drift_change_named_ = get_time();
    if (s.drift_change_gyro_ != 0 && s.Find(s.drift_change_gyro_) == nullptr) {
      mark_bad(s.drift_change_gyro_, "the drift change being measured names a gyro not running");
    }
    for (int i = 0; i < s.gyro_count(); ++i) {
      const int cols = get_int();
      if (short_read || (cols != 0 && cols != s.layout_.SpinAxisDriverCount(i))) {
        return absl::DataLossError(absl::StrFormat(
            "checkpoint: gyro %d's motion has %d drivers, the layout %d", s.gyros_[i].id, cols,
            s.layout_.SpinAxisDriverCount(i)));
      }
      s.gyros_[i].motion_in = MatrixXd::Zero(cols == 0 ? 0 : 3, cols);
      for (int r = 0; r < s.gyros_[i].motion_in.rows(); ++r) {
        for (int c2 = 0; c2 < cols; ++c2) s.gyros_[i].motion_in(r, c2) = get_real();
      }
    }
  } else {
    for (GyroState& g : s.gyros_) {
      if (!g.faulty) continue;
      g.exclusion.reason = ExclusionReason::kEarlier;
      g.exclusion.time = s.last_update_time_;
    }
  }
  if (short_read || pos != v.size()) {
    return absl::DataLossError("checkpoint: truncated or oversized");
  }
  // An uninitialised session (no valid star-tracker attitude yet) has no state to check.
  if (s.initialized_) {
    if (absl::Status st = CheckCovariance(s.P_); !st.ok()) {
      return absl::DataLossError(absl::StrCat("checkpoint: ", st.message()));
    }
    if (absl::Status st = CheckCovariance(s.P0_); !st.ok()) {
      return absl::DataLossError(absl::StrCat("checkpoint: initial ", st.message()));
    }
    // The prior variances: every state has one, from a prior sigma that is positive with a normal
    // square (ValidateConfig). The relative sigma sqrt(P)/sqrt(P0) (convergence, RelativeSigma)
    // divides by their roots: a zero let a restored session write a checkpoint with inf in it,
    // and a subnormal one can make the quotient overflow. A positive normal P0 keeps it finite
    // for every finite P (EstimationSession::RelativeSigmaOf), whatever a step does to P.
    for (int i = 0; i < s.P0_.rows(); ++i) {
      if (!(s.P0_(i, i) > 0.0) || !std::isnormal(s.P0_(i, i))) {
        return absl::DataLossError(absl::StrFormat(
            "checkpoint: initial covariance diagonal %d is not a positive normal number (%g)", i,
            s.P0_(i, i)));
      }
    }
  }
  // Every index the session dereferences must name a gyro it has: a corrupt checkpoint is
  // DataLoss, never a crash.
  if (!bad_value.empty()) return absl::DataLossError(bad_value);
  const int state_value = static_cast<int>(s.state_);
  if (state_value < static_cast<int>(SessionState::kNoData) ||
      state_value > static_cast<int>(SessionState::kFaulted)) {
    return absl::DataLossError(absl::StrCat("checkpoint: unknown session state ", state_value));
  }
  if (checkpoint.version < 7 && s.state_ == SessionState::kFaulted) {
    // Before version 7 FAULTED also meant "a gyro of the working pair was isolated and the
    // output moved to a clean pair" (docs/decisions.md D30, D94): with a usable pair left the
    // session resumes in its progress state, degraded.
    int usable = 0;
    for (const GyroState& g : s.gyros_) usable += g.faulty ? 0 : 1;
    if (usable >= 2) {
      s.state_ = s.steps_without_star_tracker_ >= 3 ? SessionState::kAutonomous
                 : s.converged_                     ? SessionState::kConverged
                                                    : SessionState::kCalibrating;
    }
  }
  if (s.steps_without_star_tracker_ < 0 || s.consecutive_rejections_ < 0 ||
      s.consecutive_accepted_ < 0) {
    return absl::DataLossError("checkpoint: negative step counter");
  }
  // An initialised session's pairs name two of its running gyros; an uninitialised one starts on
  // its pairs at the first star-tracker fix, so they name two configured gyros (a pair naming
  // gyro 0 indexed a frame's gyros at -1 there).
  for (const auto& [name, pair] : {std::pair<const char*, std::array<int, 2>>{"working", s.working_pair_},
                                   {"reserve", s.reserve_pair_}}) {
    const bool named = s.initialized_
                           ? s.Find(pair[0]) != nullptr && s.Find(pair[1]) != nullptr
                           : config.FindGyro(pair[0]) != nullptr && config.FindGyro(pair[1]) != nullptr;
    if (pair[0] == pair[1] || !named) {
      return absl::DataLossError(absl::StrCat("checkpoint: ", name, " pair [", pair[0], ",",
                                              pair[1], "] does not name two of its gyros"));
    }
  }
  return s;
}

}  // namespace esg::estimator
