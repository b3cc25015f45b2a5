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

namespace {

// Appends a checkpoint's values: a time as (1, unix seconds, nanoseconds), or (-1, 0, 0) for
// absl::InfinitePast(); a vector's components; a monitor's exported state after its count.
class CheckpointWriter {
 public:
  explicit CheckpointWriter(std::vector<double>& values) : v_(values) {}

  void Put(double x) { v_.push_back(x); }
  void Time(absl::Time t) {
    if (t == absl::InfinitePast()) {
      v_.push_back(-1.0);
      v_.push_back(0.0);
      v_.push_back(0.0);
      return;
    }
    const int64_t ns = absl::ToUnixNanos(t);
    v_.push_back(1.0);
    v_.push_back(static_cast<double>(ns / 1000000000));
    v_.push_back(static_cast<double>(ns % 1000000000));
  }
  template <typename Vector>
  void Vec(const Vector& x) {
    for (int i = 0; i < x.size(); ++i) v_.push_back(x(i));
  }
  void Block(const std::vector<double>& state) {
    v_.push_back(static_cast<double>(state.size()));
    v_.insert(v_.end(), state.begin(), state.end());
  }
  // The block's values, then their count: the checkpoint's last field, so that cutting it off
  // (its count is the last value) leaves the previous version's values.
  void TrailingBlock(const std::vector<double>& state) {
    v_.insert(v_.end(), state.begin(), state.end());
    v_.push_back(static_cast<double>(state.size()));
  }

 private:
  std::vector<double>& v_;
};

// Reads a checkpoint's values in order. A read past the end gives 0 and marks the read short; the
// first value that is not what its field allows is kept as bad_value(), which marks the
// checkpoint corrupt: an integer field must hold a finite integer in int's range (a plain cast of
// anything else would be undefined behaviour), a flag 0 or 1, a real a finite number, a time
// (1, seconds, nanoseconds) or (-1, 0, 0).
class CheckpointReader {
 public:
  explicit CheckpointReader(const std::vector<double>& values) : v_(values) {}

  double Get() {
    if (pos_ >= v_.size()) {
      short_read_ = true;
      return 0.0;
    }
    return v_[pos_++];
  }
  // Keeps the first bad value, naming the index of the value read last.
  void MarkBad(double x, const char* what) {
    if (bad_value_.empty()) {
      bad_value_ = absl::StrFormat("checkpoint: value %d = %.10g: %s", pos_ - 1, x, what);
    }
  }
  int Int() {
    const double x = Get();
    if (!(std::abs(x) <= session_internal::kMaxCount) || x != std::floor(x)) {
      MarkBad(x, "an integer field is not an integer in [-1e9, 1e9]");
      return 0;
    }
    return static_cast<int>(x);
  }
  bool Flag() {
    const double x = Get();
    if (x != 0.0 && x != 1.0) MarkBad(x, "a flag field is not 0 or 1 (an integer)");
    return x == 1.0;
  }
  double Real() {
    const double x = Get();
    if (!std::isfinite(x)) MarkBad(x, "a real field is not finite");
    return x;
  }
  absl::Time Time() {
    const double flag = Get();
    if (flag != -1.0 && flag != 1.0) MarkBad(flag, "a time's flag is not -1 or 1 (an integer)");
    const double sec = Get();
    if (!(std::abs(sec) <= 1e12) || sec != std::floor(sec)) {
      MarkBad(sec, "a time's seconds are not an integer in range");
    }
    const double nsec = Get();
    if (!(std::abs(nsec) < 1e9) || nsec != std::floor(nsec)) {
      MarkBad(nsec, "a time's nanoseconds are not an integer in (-1e9, 1e9)");
    }
    if (flag != 1.0 || !bad_value_.empty()) return absl::InfinitePast();
    return absl::FromUnixSeconds(static_cast<int64_t>(sec)) +
           absl::Nanoseconds(static_cast<int64_t>(nsec));
  }
  template <typename Vector>
  void Vec(Vector& x) {
    for (int i = 0; i < x.size(); ++i) x(i) = Real();
  }
  // A block a monitor exports and restores itself (ExportState, RestoreState): its count, then
  // that many values. Refused (DataLoss) when the count runs past the end ("checkpoint: truncated
  // (`what`)") or the monitor refuses the values (`prefix` and its message).
  template <typename Monitor>
  absl::Status Block(Monitor& monitor, const char* what, const char* prefix) {
    const int n = Int();
    if (short_read_ || n < 0 || static_cast<size_t>(n) > v_.size() - pos_) {
      return absl::DataLossError(absl::StrCat("checkpoint: truncated (", what, ")"));
    }
    if (absl::Status st = monitor.RestoreState(absl::MakeConstSpan(v_).subspan(pos_, n));
        !st.ok()) {
      return absl::DataLossError(absl::StrCat(prefix, st.message()));
    }
    pos_ += n;
    return absl::OkStatus();
  }

  // A block written by CheckpointWriter::TrailingBlock, the checkpoint's last field: its count is
  // the last value. Refused (DataLoss) when that count is not an integer that fits before it and
  // after what was read ("checkpoint: truncated (`what`)") or the monitor refuses the values.
  template <typename Monitor>
  absl::Status TrailingBlock(Monitor& monitor, const char* what, const char* prefix) {
    const double count = v_.empty() ? -1.0 : v_.back();
    if (short_read_ || v_.size() <= pos_ || !(count >= 0.0) || count != std::floor(count) ||
        count > static_cast<double>(v_.size() - pos_ - 1)) {
      return absl::DataLossError(absl::StrCat("checkpoint: truncated (", what, ")"));
    }
    const size_t n = static_cast<size_t>(count);
    if (absl::Status st = monitor.RestoreState(absl::MakeConstSpan(v_).subspan(pos_, n));
        !st.ok()) {
      return absl::DataLossError(absl::StrCat(prefix, st.message()));
    }
    pos_ += n;
    Get();  // the count
    return absl::OkStatus();
  }

  bool short_read() const { return short_read_; }
  // Every value read, and no more.
  bool AtEnd() const { return !short_read_ && pos_ == v_.size(); }
  const std::string& bad_value() const { return bad_value_; }

 private:
  const std::vector<double>& v_;
  size_t pos_ = 0;
  bool short_read_ = false;
  std::string bad_value_;
};

}  // namespace

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
// Version 9 (written when the configuration has a basis term of kind channel; otherwise version 8
//   is written, unchanged): version 8's values, then c (a count) and the held channels' and
//   lags' state (c values, ChannelSignals::ExportState). A session restored from version 8 with
//   channel terms starts them without held values (s = 0 until a frame carries the channel).
// Version 10 (written): version 9's values, the channels' block always (c = 0 without channel
//   terms), then the turns' axes of the reading-fault monitor's points (x values,
//   ReadingFaultMonitor::ExportTurnAxes) and x, last (CheckpointWriter::TrailingBlock: the values
//   before it are version 9's). A session restored from an earlier version has points without
//   the turn's axis: until they leave the monitor's window, a drift change's note compares the
//   scalar turn rates (reading_fault_monitor.h DriftChange).
//   A field added to the session later goes after these, with a new version.
// The state layout itself is not stored: it follows from the configuration and the model.
SessionCheckpoint EstimationSession::ExportCheckpoint() const {
  SessionCheckpoint c;
  c.version = 10;
  CheckpointWriter w(c.values);
  w.Put(initialized_ ? 1 : 0);
  w.Put(use_star_tracker_ ? 1 : 0);
  w.Time(last_time_);
  w.Time(last_update_time_);
  w.Time(start_time_);
  w.Time(convergence_mark_time_);
  w.Put(working_pair_[0]);
  w.Put(working_pair_[1]);
  w.Put(reserve_pair_[0]);
  w.Put(reserve_pair_[1]);
  w.Put(static_cast<double>(state_));
  w.Put(steps_without_star_tracker_);
  w.Put(consecutive_rejections_);
  w.Put(converged_ ? 1 : 0);
  w.Put(static_cast<double>(convergence_mark_sigma_.size()));
  w.Vec(convergence_mark_sigma_);
  w.Put(static_cast<double>(gyros_.size()));
  for (const GyroState& g : gyros_) {
    w.Put(g.id);
    w.Vec(g.h_in);
    w.Vec(g.t1);
    w.Vec(g.residual_drift);
    w.Put(static_cast<double>(g.theta.size()));  // version 8
    w.Vec(g.theta);
    w.Vec(g.phi_b);
    w.Put(g.faulty ? 1 : 0);
    w.Put(g.has_reading ? 1 : 0);
    w.Vec(g.h_k_last);
  }
  w.Put(static_cast<double>(P_.rows()));
  for (int i = 0; i < P_.rows(); ++i) {
    for (int j = 0; j < P_.cols(); ++j) w.Put(P_(i, j));
  }
  for (int i = 0; i < P0_.rows(); ++i) {
    for (int j = 0; j < P0_.cols(); ++j) w.Put(P0_(i, j));
  }
  // Version 2.
  w.Put(star_tracker_voted_faulty_ ? 1 : 0);
  w.Put(star_tracker_accepted_ ? 1 : 0);
  w.Put(consecutive_accepted_);
  w.Block(consistency_.ExportState());
  // Version 3.
  w.Block(widening_.ExportState());
  w.Put(suspect_gyro_);
  w.Time(suspect_time_);
  // Version 4.
  w.Put(latency_s_);
  w.Vec(previous_mean_rate_b_);
  w.Put(previous_interval_s_);
  w.Block(change_detector_.ExportState());
  // Version 5.
  w.Vec(st_mount_b_);
  w.Vec(st_mount_var_b_);
  w.Vec(st_mount_noise_var_b_);
  w.Put(st_realignments_);
  w.Block(mount_monitor_.ExportState());
  // Version 6.
  for (const GyroState& g : gyros_) {
    w.Put(static_cast<double>(g.basis.size()));
    for (const BasisTerm& t : g.basis) w.Put(t.value);
    w.Put(g.u_k_v.has_value() ? 1 : 0);
    w.Vec(g.u_k_v.value_or(Eigen::Vector3d::Zero()));
  }
  // Version 7.
  for (const GyroState& g : gyros_) {
    w.Put(static_cast<double>(g.exclusion.reason));
    w.Time(g.exclusion.time);
    w.Put(g.exclusion.value);
    w.Put(g.exclusion.threshold);
    w.Put(g.exclusion.source);
  }
  w.Block(reading_monitor_.ExportState());
  w.Put(static_cast<double>(abrupt_.size()));
  for (const auto& [id, a] : abrupt_) {
    w.Put(id);
    w.Time(a.time);
    w.Put(static_cast<double>(a.verdict));
    w.Put(static_cast<double>(a.source));
    w.Put(a.value);
    w.Put(a.threshold);
    w.Put(a.statistic);
  }
  w.Put(unverified_gyro_);
  w.Time(unverified_time_);
  w.Put(drift_change_gyro_);
  w.Time(drift_change_named_);
  for (const GyroState& g : gyros_) {
    w.Put(static_cast<double>(g.motion_in.cols()));
    for (int r = 0; r < g.motion_in.rows(); ++r) {
      for (int c2 = 0; c2 < g.motion_in.cols(); ++c2) w.Put(g.motion_in(r, c2));
    }
  }
  w.Block(channel_signals_.ExportState());         // version 9
  w.TrailingBlock(reading_monitor_.ExportTurnAxes());  // version 10
  return c;
}

// The steps of FromCheckpoint, one per block of the layout above, in its order; then the checks of
// what was read as a whole. A value a field does not allow is marked in the reader (reported after
// the blocks, CheckpointReader::bad_value); what makes the rest unreadable is refused at once.
struct EstimationSession::CheckpointRestore {
  // Version 1's session fields, initialized to the convergence record. Refuses a convergence
  // record longer than 1000.
  static absl::Status ReadSessionFields(CheckpointReader& r, EstimationSession& s) {
    s.initialized_ = r.Flag();
    s.use_star_tracker_ = r.Flag();
    s.last_time_ = r.Time();
    s.last_update_time_ = r.Time();
    s.start_time_ = r.Time();
    s.convergence_mark_time_ = r.Time();
    s.working_pair_ = {r.Int(), r.Int()};
    s.reserve_pair_ = {r.Int(), r.Int()};
    s.state_ = static_cast<SessionState>(r.Int());
    s.steps_without_star_tracker_ = r.Int();
    s.consecutive_rejections_ = r.Int();
    s.converged_ = r.Flag();
    const int n_mark = r.Int();
    if (n_mark < 0 || n_mark > 1000) return absl::DataLossError("checkpoint: bad convergence record");
    s.convergence_mark_sigma_ = VectorXd::Zero(n_mark);
    r.Vec(s.convergence_mark_sigma_);
    return absl::OkStatus();
  }

  // The running gyros: their count, then per gyro its id, spin axis, tangent basis, residual
  // drift, fixed coefficients (from version 8 preceded by their count; versions 1-7 hold the 13
  // of eq. (1), (10)), misalignment, flags and last reading. Refuses a count above kMaxGyros, a
  // gyro not in the configuration, and a count of fixed coefficients other than the model's.
  static absl::Status ReadGyros(CheckpointReader& r, const SpacecraftConfig& config, int version,
                                EstimationSession& s) {
    const int n_gyros = r.Int();
    if (n_gyros < 0 || n_gyros > kMaxGyros) return absl::DataLossError("checkpoint: bad gyro count");
    for (int i = 0; i < n_gyros; ++i) {
      GyroState g;
      g.id = r.Int();
      const GyroConfig* gc = config.FindGyro(g.id);
      if (gc == nullptr) {
        return absl::DataLossError(
            absl::StrCat("checkpoint: gyro ", g.id, " is not in the configuration"));
      }
      g.C_b_k_config = gc->C_b_k;
      g.basis = gc->basis_terms;  // values from version 6 on
      r.Vec(g.h_in);
      r.Vec(g.t1);
      r.Vec(g.residual_drift);
      const int theta_count = version >= 8 ? r.Int() : 13;
      if (r.bad_value().empty() && !r.short_read() && theta_count != g.theta.size()) {
        return absl::DataLossError(absl::StrFormat(
            "checkpoint: gyro %d holds %d fixed drift coefficients, this build's model has %d "
            "(a fixed term added or removed since it was written, estimator/model_terms.h)",
            g.id, theta_count, static_cast<int>(g.theta.size())));
      }
      r.Vec(g.theta);
      r.Vec(g.phi_b);
      g.faulty = r.Flag();
      g.has_reading = r.Flag();
      r.Vec(g.h_k_last);
      s.gyros_.push_back(std::move(g));
    }
    return absl::OkStatus();
  }

  // The state layout (not stored: it follows from the configuration, the model and the gyros
  // read), then n, P and P0 (n x n each, row by row). Refuses an n other than the layout's size.
  static absl::Status ReadCovariances(CheckpointReader& r, const SpacecraftConfig& config,
                                      const ModelSpec& model, EstimationSession& s) {
    s.layout_ = LayoutFor(config, model, s.gyros_);
    const int n = r.Int();
    if (n != s.layout_.size()) {
      return absl::DataLossError(absl::StrFormat(
          "checkpoint: covariance size %d does not fit the configuration and model %s (%d states)",
          n, model.Name(), s.layout_.size()));
    }
    s.P_ = MatrixXd::Zero(n, n);
    s.P0_ = MatrixXd::Zero(n, n);
    for (int i = 0; i < n; ++i) {
      for (int j = 0; j < n; ++j) s.P_(i, j) = r.Real();
    }
    for (int i = 0; i < n; ++i) {
      for (int j = 0; j < n; ++j) s.P0_(i, j) = r.Real();
    }
    return absl::OkStatus();
  }

  // Version 2: the star tracker's anchoring (D19) and the consistency monitor. Refuses a monitor
  // block that is truncated or that the monitor refuses.
  static absl::Status ReadAnchorAndConsistency(CheckpointReader& r, EstimationSession& s) {
    s.star_tracker_voted_faulty_ = r.Flag();
    s.star_tracker_accepted_ = r.Flag();
    s.consecutive_accepted_ = r.Int();
    return r.Block(s.consistency_, "consistency monitor", "checkpoint: consistency monitor: ");
  }

  // Version 3: the process-noise widening and the isolation's suspect (D24). Refuses a widening
  // block that is truncated or that the widening refuses.
  static absl::Status ReadWideningAndSuspect(CheckpointReader& r, EstimationSession& s) {
    if (absl::Status st = r.Block(s.widening_, "process-noise widening", "checkpoint: ");
        !st.ok()) {
      return st;
    }
    s.suspect_gyro_ = r.Int();
    s.suspect_time_ = r.Time();
    return absl::OkStatus();
  }

  // Version 4: the star-tracker latency, the body-rate extrapolation (a negative interval is a bad
  // value) and the accumulated star-tracker test (D33). Refuses a test block that is truncated
  // or that the test refuses.
  static absl::Status ReadLatencyRateAndDetector(CheckpointReader& r, EstimationSession& s) {
    s.latency_s_ = r.Real();
    r.Vec(s.previous_mean_rate_b_);
    s.previous_interval_s_ = r.Real();
    if (s.previous_interval_s_ < 0.0) r.MarkBad(s.previous_interval_s_, "an interval is negative");
    return r.Block(s.change_detector_, "gyro change detector", "checkpoint: ");
  }

  // Version 5: the star-tracker mount correction (D34; a negative variance or count is a bad
  // value) and the mount-shift test. Refuses a test block that is truncated or that the test
  // refuses.
  static absl::Status ReadMount(CheckpointReader& r, EstimationSession& s) {
    r.Vec(s.st_mount_b_);
    r.Vec(s.st_mount_var_b_);
    r.Vec(s.st_mount_noise_var_b_);
    for (const Eigen::Vector3d& var : {s.st_mount_var_b_, s.st_mount_noise_var_b_}) {
      if (!(var.minCoeff() >= 0.0)) r.MarkBad(var.minCoeff(), "a variance is negative");
    }
    s.st_realignments_ = r.Int();
    if (s.st_realignments_ < 0) r.MarkBad(s.st_realignments_, "a count is negative");
    return r.Block(s.mount_monitor_, "star-tracker mount", "checkpoint: ");
  }

  // Version 9: the held channels and lags of the channel terms; refuses a count other than the
  // configuration's terms need.
  static absl::Status ReadChannelSignals(CheckpointReader& r, EstimationSession& s) {
    return r.Block(s.channel_signals_, "channel signals", "checkpoint: ");
  }

  // Version 10: the turns' axes of the reading-fault monitor's points (a trailing block),
  // restored into the monitor read with version 7's fields.
  static absl::Status ReadTurnAxes(CheckpointReader& r, EstimationSession& s) {
    struct TurnAxes {
      ReadingFaultMonitor& monitor;
      absl::Status RestoreState(absl::Span<const double> v) { return monitor.RestoreTurnAxes(v); }
    } axes{s.reading_monitor_};
    return r.TrailingBlock(axes, "turn axes", "checkpoint: ");
  }

  // Version 6: per gyro its basis terms' values and held suspension voltages. Refuses a count of
  // terms other than the configuration's.
  static absl::Status ReadBasisValues(CheckpointReader& r, EstimationSession& s) {
    for (GyroState& g : s.gyros_) {
      const int b = r.Int();
      if (r.short_read() || b != static_cast<int>(g.basis.size())) {
        return absl::DataLossError(absl::StrFormat(
            "checkpoint: gyro %d has %d basis terms, the configuration %d", g.id, b,
            g.basis.size()));
      }
      for (BasisTerm& t : g.basis) t.value = r.Real();
      const bool has_u = r.Flag();
      Eigen::Vector3d u_k_v;
      r.Vec(u_k_v);
      if (has_u) g.u_k_v = u_k_v;
    }
    return absl::OkStatus();
  }

  // Version 7: per gyro its exclusion (D94; an unknown reason or track, or a reason that does
  // not match the excluded flag, is a bad value), the reading-fault monitor, the recent verdicts,
  // the unverified gyro and the drift change being measured, and per gyro its motion since the
  // last update. Refuses a monitor block that is truncated or that the monitor refuses, a bad
  // count of verdicts, and a motion whose columns are not the layout's drivers.
  static absl::Status ReadReadingFaults(CheckpointReader& r, EstimationSession& s) {
    ReadExclusions(r, s);
    if (absl::Status st = r.Block(s.reading_monitor_, "reading-fault monitor", "checkpoint: ");
        !st.ok()) {
      return st;
    }
    if (absl::Status st = ReadVerdicts(r, s); !st.ok()) return st;
    s.unverified_gyro_ = r.Int();
    s.unverified_time_ = r.Time();
    s.drift_change_gyro_ = r.Int();
    s.drift_change_named_ = r.Time();
    if (s.drift_change_gyro_ != 0 && s.Find(s.drift_change_gyro_) == nullptr) {
      r.MarkBad(s.drift_change_gyro_, "the drift change being measured names a gyro not running");
    }
    return ReadMotion(r, s);
  }

  static void ReadExclusions(CheckpointReader& r, EstimationSession& s) {
    for (GyroState& g : s.gyros_) {
      const int reason = r.Int();
      if (reason < static_cast<int>(ExclusionReason::kNone) ||
          reason > static_cast<int>(ExclusionReason::kEarlier)) {
        r.MarkBad(reason, "an exclusion reason is unknown");
      }
      g.exclusion.reason = static_cast<ExclusionReason>(reason);
      g.exclusion.time = r.Time();
      g.exclusion.value = r.Real();
      g.exclusion.threshold = r.Real();
      g.exclusion.source = r.Int();
      if (g.exclusion.source < -1 || g.exclusion.source > 1) {
        r.MarkBad(g.exclusion.source, "an exclusion's track is not -1, 0 or 1");
      }
      if ((g.exclusion.reason != ExclusionReason::kNone) != g.faulty) {
        r.MarkBad(reason, "an exclusion reason does not match the gyro's excluded flag");
      }
    }
  }

  // The count of recent verdicts (refused above kMaxGyros), then each: gyro id (a gyro not
  // running is a bad value), time, verdict, source, value, threshold, statistic.
  static absl::Status ReadVerdicts(CheckpointReader& r, EstimationSession& s) {
    const int n_abrupt = r.Int();
    if (r.short_read() || n_abrupt < 0 || n_abrupt > kMaxGyros) {
      return absl::DataLossError("checkpoint: bad count of reading verdicts");
    }
    for (int k = 0; k < n_abrupt; ++k) {
      const int id = r.Int();
      AbruptRecord a;
      a.time = r.Time();
      const int verdict = r.Int();
      const int source = r.Int();
      if (verdict < static_cast<int>(ReadingVerdict::kJump) ||
          verdict > static_cast<int>(ReadingVerdict::kErratic)) {
        r.MarkBad(verdict, "a reading verdict is unknown");
      }
      if (source != 0 && source != 1) r.MarkBad(source, "a reading source is not 0 or 1");
      a.verdict = static_cast<ReadingVerdict>(verdict);
      a.source = static_cast<ReadingFaultMonitor::Source>(source);
      a.value = r.Real();
      a.threshold = r.Real();
      a.statistic = r.Real();
      if (s.Find(id) == nullptr) r.MarkBad(id, "a reading verdict names a gyro not running");
      s.abrupt_[id] = a;
    }
    return absl::OkStatus();
  }

  // Per gyro the columns of its motion (0, or its spin-axis driver count in the layout: refused
  // otherwise), then 3 x that many values, row by row.
  static absl::Status ReadMotion(CheckpointReader& r, EstimationSession& s) {
    for (int i = 0; i < s.gyro_count(); ++i) {
      const int cols = r.Int();
      if (r.short_read() || (cols != 0 && cols != s.layout_.SpinAxisDriverCount(i))) {
        return absl::DataLossError(absl::StrFormat(
            "checkpoint: gyro %d's motion has %d drivers, the layout %d", s.gyros_[i].id, cols,
            s.layout_.SpinAxisDriverCount(i)));
      }
      s.gyros_[i].motion_in = MatrixXd::Zero(cols == 0 ? 0 : 3, cols);
      for (int r2 = 0; r2 < s.gyros_[i].motion_in.rows(); ++r2) {
        for (int c2 = 0; c2 < cols; ++c2) s.gyros_[i].motion_in(r2, c2) = r.Real();
      }
    }
    return absl::OkStatus();
  }

  // Before version 7: each excluded gyro gets the reason kEarlier at the last update time.
  static void ExclusionsBeforeVersion7(EstimationSession& s) {
    for (GyroState& g : s.gyros_) {
      if (!g.faulty) continue;
      g.exclusion.reason = ExclusionReason::kEarlier;
      g.exclusion.time = s.last_update_time_;
    }
  }

  // An initialised session's P and P0 (an uninitialised one, no valid star-tracker attitude yet,
  // has no state to check): refuses an invalid covariance (CheckCovariance) and a prior variance
  // that is not a positive normal number.
  static absl::Status CheckCovariances(const EstimationSession& s) {
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
    return absl::OkStatus();
  }

  // The session state and the step counters: refuses an unknown state and a negative counter.
  // Before version 7 FAULTED also meant "a gyro of the working pair was isolated and the output
  // moved to a clean pair" (docs/decisions.md D30, D94): with a usable pair left the session
  // resumes in its progress state, degraded.
  static absl::Status CheckStateAndCounters(int version, EstimationSession& s) {
    const int state_value = static_cast<int>(s.state_);
    if (state_value < static_cast<int>(SessionState::kNoData) ||
        state_value > static_cast<int>(SessionState::kFaulted)) {
      return absl::DataLossError(absl::StrCat("checkpoint: unknown session state ", state_value));
    }
    if (version < 7 && s.state_ == SessionState::kFaulted) {
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
    return absl::OkStatus();
  }

  // The working and reserve pairs: an initialised session's pairs name two of its running gyros;
  // an uninitialised one starts on its pairs at the first star-tracker fix, so they name two
  // configured gyros (a pair naming gyro 0 indexed a frame's gyros at -1 there). Refused
  // otherwise.
  static absl::Status CheckPairs(const SpacecraftConfig& config, const EstimationSession& s) {
    for (const auto& [name, pair] :
         {std::pair<const char*, std::array<int, 2>>{"working", s.working_pair_},
          {"reserve", s.reserve_pair_}}) {
      const bool named =
          s.initialized_
              ? s.Find(pair[0]) != nullptr && s.Find(pair[1]) != nullptr
              : config.FindGyro(pair[0]) != nullptr && config.FindGyro(pair[1]) != nullptr;
      if (pair[0] == pair[1] || !named) {
        return absl::DataLossError(absl::StrCat("checkpoint: ", name, " pair [", pair[0], ",",
                                                pair[1], "] does not name two of its gyros"));
      }
    }
    return absl::OkStatus();
  }
};

absl::StatusOr<EstimationSession> EstimationSession::FromCheckpoint(
    const SpacecraftConfig& config, const SessionOptions& options,
    const SessionCheckpoint& checkpoint) {
  using Steps = CheckpointRestore;
  const int version = checkpoint.version;
  if (version < 1 || version > 10) {
    return absl::DataLossError(absl::StrCat("checkpoint version ", version, " is unknown"));
  }
  auto created = Create(config, options);
  if (!created.ok()) return created.status();
  EstimationSession s = std::move(*created);
  // The blocks in the layout's order, each read by its version on; a session restored from an
  // earlier version keeps what Create set for the later blocks (the layout comment above).
  CheckpointReader r(checkpoint.values);
  if (absl::Status st = Steps::ReadSessionFields(r, s); !st.ok()) return st;
  if (absl::Status st = Steps::ReadGyros(r, config, version, s); !st.ok()) return st;
  if (absl::Status st = Steps::ReadCovariances(r, config, options.model, s); !st.ok()) return st;
  if (version >= 2) {
    if (absl::Status st = Steps::ReadAnchorAndConsistency(r, s); !st.ok()) return st;
  }
  if (version >= 3) {
    if (absl::Status st = Steps::ReadWideningAndSuspect(r, s); !st.ok()) return st;
  }
  if (version >= 4) {
    if (absl::Status st = Steps::ReadLatencyRateAndDetector(r, s); !st.ok()) return st;
  }
  if (version >= 5) {
    if (absl::Status st = Steps::ReadMount(r, s); !st.ok()) return st;
  }
  if (version >= 6) {
    if (absl::Status st = Steps::ReadBasisValues(r, s); !st.ok()) return st;
  }
  if (version >= 7) {
    if (absl::Status st = Steps::ReadReadingFaults(r, s); !st.ok()) return st;
  } else {
    Steps::ExclusionsBeforeVersion7(s);
  }
  if (version >= 9) {
    if (absl::Status st = Steps::ReadChannelSignals(r, s); !st.ok()) return st;
  }
  if (version >= 10) {
    if (absl::Status st = Steps::ReadTurnAxes(r, s); !st.ok()) return st;
  }
  if (!r.AtEnd()) return absl::DataLossError("checkpoint: truncated or oversized");

  // What was read, as a whole. Every index the session dereferences must name a gyro it has: a
  // corrupt checkpoint is DataLoss, never a crash.
  if (s.initialized_) {
    if (absl::Status st = Steps::CheckCovariances(s); !st.ok()) return st;
  }
  if (!r.bad_value().empty()) return absl::DataLossError(r.bad_value());
  if (absl::Status st = Steps::CheckStateAndCounters(version, s); !st.ok()) return st;
  if (absl::Status st = Steps::CheckPairs(config, s); !st.ok()) return st;
  return s;
}

}  // namespace esg::estimator
