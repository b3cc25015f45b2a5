// EstimationSession's coordinator (session.h): creation, the transactional step AddFrame
// (propagation, then the measurement update at a measurement step, then the state machine of
// session.h), the convergence test and the read-only views. The equations live one file away:
//   state_layout.h             the filter's state indices
//   session_initialization.cc  filter start; spin axes rebuilt from the star tracker
//   session_propagation.cc     drift of eq. (1)/(10), random walk of eq. (11), covariance
//                              transition; prediction across a gap
//   session_update.cc          eq. (12) mismatch test, eq. (13) measurements, eq. (14) test,
//                              filter reset, Joseph update
//   session_attitude.cc        pair attitude (TRIAD) and its covariance, the output
//   session_checkpoint.cc      the checkpoint values (versions 1 to 6)
#include "estimator/session.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <optional>
#include <utility>
#include <vector>

#include "Eigen/LU"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/calibration_model.h"
#include "estimator/session_internal.h"
#include "estimator/units.h"
#include "estimator/utc_time.h"

namespace esg::estimator {

using Eigen::VectorXd;

using session_internal::Seconds;

namespace {

// Feeds the step's innovations to the consistency monitor and reports a failing test as an
// event (consistency_monitor.h). While the filter runs widened (noise_widening.h) the monitor
// sees the widened filter; the model as configured is then reported inconsistent at each test
// step on the evidence of the window that widened it (D20).
void MonitorConsistency(ConsistencyMonitor& monitor, const NoiseWidening& widening,
                        const std::function<MismatchLocation()>& located, StepReport& report) {
  using Channel = ConsistencyMonitor::Channel;
  std::vector<ConsistencyMonitor::TestResult> results;
  if (report.star_tracker_innovation.size() > 0) {
    if (auto r = monitor.Add(Channel::kStarTracker, report.time, report.star_tracker_nis,
                             static_cast<int>(report.star_tracker_innovation.size()))) {
      results.push_back(*r);
    }
  }
  if (report.autonomous_innovation.size() > 0 && report.autonomous_innovation_sigma(0) > 0.0) {
    const double n = report.autonomous_innovation(0) / report.autonomous_innovation_sigma(0);
    if (auto r = monitor.Add(Channel::kAutonomous, report.time, n * n, 1)) results.push_back(*r);
  }
  const bool monitor_failed =
      std::any_of(results.begin(), results.end(), [](const auto& r) { return r.inconsistent; });
  if (!results.empty() && !monitor_failed && widening.trigger().has_value()) {
    const NoiseWidening::Decision& t = *widening.trigger();
    const MismatchLocation where = located();
    report.events.push_back(Event{
        Event::Kind::kModelInconsistent, report.time, where.Subsystem(), t.nis_sum,
        t.widen_threshold, "chi-square",
        absl::StrFormat("star-tracker NIS of the filter as configured was %.1f > %.1f over %d "
                        "steps (chi-square, %d degrees of freedom, twice in a row) and the "
                        "filter runs widened since (as an unmodelled drift of %.3g deg/h): the "
                        "configured model does not explain the data; %s; run esg diagnose to "
                        "find what the model leaves out",
                        t.nis_sum, t.widen_threshold, t.steps, t.dof,
                        widening.EquivalentDriftDegH(), where.Describe())});
  }
  for (const ConsistencyMonitor::TestResult& r : results) {
    if (!r.inconsistent) continue;
    const MismatchLocation where = located();
    report.events.push_back(Event{
        Event::Kind::kModelInconsistent, report.time, where.Subsystem(), r.nis_sum, r.threshold,
        "chi-square",
        absl::StrFormat("%s over the last %d measurement steps is %.1f > %.1f (chi-square, %d "
                        "degrees of freedom), and %.1f over the %d steps before: the configured "
                        "model does not explain the data (false-alarm level %.2g); %s; run esg "
                        "diagnose to find what the model leaves out",
                        ConsistencyChannelName(r.channel), r.steps, r.nis_sum, r.threshold, r.dof,
                        r.previous_nis_sum, r.steps, monitor.options().false_alarm_per_test,
                        where.Describe())});
  }
}

// Feeds the step's star-tracker NIS to the process-noise widening and reports its decision
// (noise_widening.h): a change, or a window that ends still widened (so that the service's alert
// stays active while the filter runs widened).
void WidenOnInconsistency(NoiseWidening& widening, StepReport& report) {
  const auto& sigma = report.star_tracker_innovation_sigma;
  if (sigma.size() == 0) return;
  const auto d = widening.Add(report.star_tracker_nis, static_cast<int>(sigma.size()),
                              sigma.squaredNorm() / static_cast<double>(sigma.size()));
  if (!d.has_value()) return;
  using Change = NoiseWidening::Decision::Change;
  if (d->change == Change::kNone && !widening.widened()) return;
  std::string what;
  switch (d->change) {
    case Change::kWidened:
      what = "widened";
      break;
    case Change::kNarrowed:
      what = "narrowed";
      break;
    case Change::kNone:
      what = "kept widened";
      break;
  }
  report.events.push_back(Event{
      Event::Kind::kFilterWidened, report.time, "filter", d->nis_sum, d->widen_threshold,
      "chi-square",
      absl::StrFormat(
          "star-tracker NIS over the last %d steps %.1f (chi-square, %d degrees of freedom: "
          "%.1f at the widening level %.2g); process noise of the spin axes %s to that of an "
          "unmodelled drift of %.3g deg/h: the configured model does not explain the data; run "
          "esg diagnose to find what it leaves out",
          d->steps, d->nis_sum, d->dof, d->widen_threshold, widening.options().alpha, what,
          widening.EquivalentDriftDegH())});
}

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
    case Event::Kind::kModelInconsistent:
      return "MODEL_INCONSISTENT";
    case Event::Kind::kFaultAmbiguous:
      return "FAULT_AMBIGUOUS";
    case Event::Kind::kFilterWidened:
      return "FILTER_WIDENED";
    case Event::Kind::kGyroReadingMissing:
      return "GYRO_READING_MISSING";
    case Event::Kind::kGyroStarted:
      return "GYRO_STARTED";
    case Event::Kind::kStarTrackerRealigned:
      return "STAR_TRACKER_REALIGNED";
    case Event::Kind::kDriftChanged:
      return "DRIFT_CHANGED";
  }
  return "?";
}

absl::StatusOr<EstimationSession> EstimationSession::Create(const SpacecraftConfig& config,
                                                            const SessionOptions& options) {
  if (absl::Status s = ValidateConfig(config); !s.ok()) return s;
  const ModelSpec& m = options.model;
  if (!m.HasFixedTerms() && !m.random_walk) {
    return absl::InvalidArgumentError("model: no term selected (use 1, 10, 11 or e.g. 10+11)");
  }
  if (options.substeps == SessionOptions::Substeps::kMotionBounded &&
      !(options.max_substep_turn_deg > 0.0 && options.max_substep_turn_deg <= 10.0)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "max_substep_turn_deg: %g deg is outside (0, 10] deg", options.max_substep_turn_deg));
  }
  EstimationSession session;
  session.config_ = config;
  session.options_ = options;
  session.working_pair_ = config.working_pair;
  session.reserve_pair_ = config.reserve_pair;
  session.latency_s_ = config.star_tracker.latency;
  ConsistencyMonitorOptions monitor;
  monitor.window_steps = options.consistency_window_steps;
  monitor.test_every_steps = options.consistency_test_every_steps;
  monitor.warmup_steps = options.consistency_window_steps;
  monitor.false_alarm_per_test =
      PerTestLevel(config.filter.measurement_step, std::max(options.consistency_test_every_steps, 1),
                   ConsistencyMonitor::kChannels, 30.0 * 86400.0, 0.1);
  session.consistency_ = ConsistencyMonitor(monitor);
  session.widening_ = NoiseWidening(config.filter.measurement_step, options.widening);
  session.change_detector_ = GyroChangeDetector(options.drift_change);
  session.mount_monitor_ = StarTrackerMountMonitor(options.star_tracker_mount);
  std::vector<BasisTerm> terms;
  for (const GyroConfig& g : config.gyros) {
    terms.insert(terms.end(), g.basis_terms.begin(), g.basis_terms.end());
  }
  session.channel_signals_ = ChannelSignals(config.channels, terms);
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
  StateLayout layout(model.random_walk, config.star_tracker.latency_sigma > 0.0);
  for (const GyroState& g : gyros) {
    const GyroConfig& gc = *config.FindGyro(g.id);
    layout.AddGyro(FreeCoefficients(model, gc), gc.misalignment_sigma > 0.0, FreeBasisTerms(gc));
  }
  return layout;
}

void EstimationSession::ReportMissingReadings(StepReport& report) const {
  int with_reading = 0;
  for (const GyroState& g : gyros_) with_reading += !g.faulty && g.has_reading ? 1 : 0;
  for (const GyroState& g : gyros_) {
    if (g.faulty || g.has_reading) continue;
    report.events.push_back(Event{
        Event::Kind::kGyroReadingMissing, report.time, absl::StrFormat("gyro %d", g.id),
        static_cast<double>(with_reading), 2.0, "gyros with a reading",
        absl::StrFormat(
            "gyro %d has no reading in this frame: none of its measurements formed, its drift "
            "mapped with the attitude of pair [%d,%d]; %s",
            g.id, report.attitude.pair[0], report.attitude.pair[1],
            report.attitude.valid
                ? absl::StrFormat("output on pair [%d,%d]", report.attitude.pair[0],
                                  report.attitude.pair[1])
                : absl::StrCat("output not valid: ", report.attitude.invalid_reason))});
  }
}

AttitudeEstimate EstimationSession::CurrentAttitude() const { return OutputAttitude(last_time_); }

LatencyEstimate EstimationSession::StarTrackerLatency() const {
  LatencyEstimate e;
  e.latency_s = latency_s_;
  e.estimated = layout_.has_latency() && initialized_;
  e.sigma_s = e.estimated ? std::sqrt(P_(layout_.Latency(), layout_.Latency())) : 0.0;
  return e;
}

StarTrackerMount EstimationSession::StarTrackerMountShift() const {
  return StarTrackerMount{st_mount_b_, st_mount_var_b_.cwiseMax(0.0).cwiseSqrt(), st_realignments_};
}

void EstimationSession::UpdateState(const StepReport& report) {
  if (!report.measurement_step) return;
  // Convergence: every free coefficient's (and free basis term's) relative sigma changed < 5%
  // over the last hour (a 1/sqrt(t) information law alone changes it by 1/(2 t) per hour: 2% at
  // 24 h).
  std::vector<double> ratios;
  for (int i = 0; i < gyro_count(); ++i) {
    for (int j = 0; j < layout_.ThetaCount(i) + layout_.BasisCount(i); ++j) {
      ratios.push_back(RelativeSigmaOf(layout_.Theta(i) + j));
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
  // FAULTED only when no usable pair remains; an exclusion with a pair left is sensor health
  // (degraded()), not a state (session.h).
  int usable = 0;
  for (const GyroState& g : gyros_) usable += g.faulty ? 0 : 1;
  if (usable < 2) {
    state_ = SessionState::kFaulted;
  } else if (steps_without_star_tracker_ >= 3) {
    state_ = SessionState::kAutonomous;
  } else {
    state_ = converged_ ? SessionState::kConverged : SessionState::kCalibrating;
  }
}

TelemetryFrame EstimationSession::CorrectedForReadout(const TelemetryFrame& frame) const {
  TelemetryFrame out = frame;
  for (const GyroConfig& gc : config_.gyros) {
    std::optional<GyroReading>& r = out.gyros[gc.id - 1];
    if (!r.has_value() || gc.readout_distortion.isZero(0.0)) continue;
    r->h_k = CorrectReadout(gc, r->h_k);
  }
  return out;
}

Eigen::Vector3d CorrectReadout(const GyroConfig& gc, const Eigen::Vector3d& h_meas) {
  if (gc.readout_distortion.isZero(0.0)) return h_meas.normalized();
  // h_meas = normalise((I + D) h_k): the inverse up to the norm (|D_ij| <= 0.01, so I + D is
  // well conditioned).
  const Eigen::Matrix3d I_plus_D = Eigen::Matrix3d::Identity() + gc.readout_distortion;
  return I_plus_D.partialPivLu().solve(h_meas).normalized();
}

absl::StatusOr<StepReport> EstimationSession::AddFrame(const TelemetryFrame& raw_frame) {
  // Readings enter here, and only here, corrected for the readout distortion.
  const TelemetryFrame frame = CorrectedForReadout(raw_frame);
  if (initialized_ || last_time_ != absl::InfinitePast()) {
    if (frame.time <= last_time_) {
      return absl::OutOfRangeError(absl::StrCat("frame time ", FormatUtc(frame.time),
                                                " is not after the previous frame ",
                                                FormatUtc(last_time_)));
    }
  }
  StepReport report;
  report.time = frame.time;
  if (!initialized_) {
    if (absl::Status s = Initialize(frame); !s.ok()) return s;
    star_tracker_accepted_ = false;  // anchored on this one sample so far (docs/decisions.md D19)
    last_time_ = frame.time;
    channel_signals_.Advance(frame);
    report.state = state_;
    report.attitude = OutputAttitude(frame.time);
    return report;
  }
  // Transactional step: work on a copy, commit only on success.
  EstimationSession next = *this;
  next.ApplyCoefficientReleases(frame.time);
  // The frame's channel values end the lines the interval's channel terms read (channel_signal.h).
  next.channel_signals_.Ahead(frame);
  if (absl::Status s = next.Propagate(frame); !s.ok()) return s;
  next.last_time_ = frame.time;
  next.channel_signals_.Advance(frame);
  const double since_update = Seconds(frame.time - next.last_update_time_);
  if (since_update >= config_.filter.measurement_step - 1e-3) {
    if (absl::Status s = next.MeasurementUpdate(frame, report); !s.ok()) return s;
    if (options_.detect_drift_change) {
      next.TrackPosteriors(frame, next.use_star_tracker_ && frame.star_tracker.has_value() &&
                                      frame.star_tracker->valid);
    }
    next.last_update_time_ = frame.time;
    MonitorConsistency(next.consistency_, next.widening_,
                       [&next] { return next.LocateModelMismatch(); }, report);
    if (options_.adaptive_noise) WidenOnInconsistency(next.widening_, report);
  }
  next.UpdateState(report);
  report.state = next.state_;
  report.attitude = next.OutputAttitude(frame.time);
  if (!report.attitude.valid) {
    // The attitude error estimate belongs to an output attitude (StepReport).
    report.attitude_error_b_arcsec.reset();
    report.attitude_error_sigma_b_arcsec.reset();
  }
  next.ReportMissingReadings(report);
  next.StartSwitchedOnGyros(frame, report);
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
    e.basis_terms = g.basis;
    e.basis_sigma.assign(g.basis.size(), 0.0);
    const std::vector<int>& free_basis = layout_.FreeBasisTerms(i);
    for (int j = 0; j < layout_.BasisCount(i); ++j) {
      const int idx = layout_.Basis(i) + j;
      e.basis_sigma[free_basis[j]] = std::sqrt(std::max(P_(idx, idx), 0.0));
    }
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
    e.exclusion = g.exclusion;
    out.push_back(e);
  }
  return out;
}

Eigen::MatrixXd EstimationSession::CoefficientCovariance(int id) const {
  const int i = IndexOf(id);
  if (i < 0) return {};
  Eigen::MatrixXd out = Eigen::MatrixXd::Zero(kNumDriftCoefficients, kNumDriftCoefficients);
  const std::vector<int>& free = layout_.FreeCoefficients(i);
  const int t = layout_.Theta(i);
  for (int a = 0; a < layout_.ThetaCount(i); ++a) {
    for (int b = 0; b < layout_.ThetaCount(i); ++b) out(free[a], free[b]) = P_(t + a, t + b);
  }
  return out;
}

std::vector<std::pair<int, double>> EstimationSession::RelativeSigma(int id) const {
  std::vector<std::pair<int, double>> out;
  const int i = IndexOf(id);
  if (i < 0) return out;
  for (int j = 0; j < layout_.ThetaCount(i); ++j) {
    out.emplace_back(layout_.FreeCoefficients(i)[j], RelativeSigmaOf(layout_.Theta(i) + j));
  }
  return out;
}

double EstimationSession::RelativeSigmaOf(int idx) const {
  return std::sqrt(P_(idx, idx)) / std::sqrt(P0_(idx, idx));
}

void EstimationSession::ApplyCoefficientReleases(absl::Time frame_time) {
  for (const SessionOptions::CoefficientRelease& r : options_.coefficient_releases) {
    if (!(r.time > last_time_ && r.time <= frame_time)) continue;
    const int i = IndexOf(r.gyro_id);
    if (i < 0) continue;
    if (r.misalignment) {
      if (!layout_.HasPhi(i)) continue;
      const int p = layout_.Phi(i);
      for (int k = 0; k < StateLayout::kPhiSize; ++k) P_(p + k, p + k) += r.sigma * r.sigma;
      continue;
    }
    const std::vector<int>& free = layout_.FreeCoefficients(i);
    for (size_t j = 0; j < free.size(); ++j) {
      if (free[j] < r.first || free[j] >= r.first + r.count) continue;
      const int s = layout_.Theta(i) + static_cast<int>(j);
      P_(s, s) += r.sigma * r.sigma;
    }
  }
}

double ResidualRandomWalk(const SpacecraftConfig& config, const SessionOptions& options,
                          int gyro_id) {
  for (const auto& [gyro, q] : options.random_walk_by_gyro) {
    if (gyro == gyro_id) return q;
  }
  return config.random_walk;
}

double InitialResidualDriftSigma(const SessionOptions& options) {
  if (options.residual_drift_sigma >= 0.0) return options.residual_drift_sigma;
  // 0.1 deg/h with model (11) alone, 0.01 deg/h on top of a calibrated model.
  return DegPerHourToRadPerSec(options.model.HasFixedTerms() ? 0.01 : 0.1);
}

double EstimationSession::RandomWalkOf(int id) const {
  return ResidualRandomWalk(config_, options_, id);
}

}  // namespace esg::estimator
