// Mapping of records and estimator values to esg.v1 messages (see proto_mapping.h).
#include "server/proto_mapping.h"

#include <algorithm>
#include <cstdint>
#include <optional>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "estimator/model_terms.h"
#include "estimator/rotation.h"
#include "estimator/units.h"
#include "proto/convert.h"
#include "server/alert_catalog.h"
#include "server/grpc_status.h"

namespace esg::server {

using estimator::Event;

const char* SeverityName(esg::v1::AlertSeverity s) {
  switch (s) {
    case esg::v1::ALERT_SEVERITY_INFO:
      return "INFO";
    case esg::v1::ALERT_SEVERITY_WARNING:
      return "WARNING";
    case esg::v1::ALERT_SEVERITY_DISTRESS:
      return "DISTRESS";
    case esg::v1::ALERT_SEVERITY_CRITICAL:
      return "CRITICAL";
    default:
      return "UNSPECIFIED";
  }
}

namespace {

esg::v1::AlertSeverity SeverityFromName(const std::string& name) {
  if (name == "INFO") return esg::v1::ALERT_SEVERITY_INFO;
  if (name == "WARNING") return esg::v1::ALERT_SEVERITY_WARNING;
  if (name == "DISTRESS") return esg::v1::ALERT_SEVERITY_DISTRESS;
  if (name == "CRITICAL") return esg::v1::ALERT_SEVERITY_CRITICAL;
  return esg::v1::ALERT_SEVERITY_UNSPECIFIED;
}

esg::v1::AlertReason ReasonFromName(const std::string& name) {
  esg::v1::AlertReason reason = esg::v1::ALERT_REASON_UNSPECIFIED;
  esg::v1::AlertReason_Parse("ALERT_REASON_" + name, &reason);
  return reason;
}

}  // namespace

esg::v1::SessionState StateToProto(estimator::SessionState s) {
  switch (s) {
    case estimator::SessionState::kNoData:
      return esg::v1::SESSION_STATE_NO_DATA;
    case estimator::SessionState::kCalibrating:
      return esg::v1::SESSION_STATE_CALIBRATING;
    case estimator::SessionState::kConverged:
      return esg::v1::SESSION_STATE_CONVERGED;
    case estimator::SessionState::kAutonomous:
      return esg::v1::SESSION_STATE_AUTONOMOUS;
    case estimator::SessionState::kFaulted:
      return esg::v1::SESSION_STATE_FAULTED;
  }
  return esg::v1::SESSION_STATE_UNSPECIFIED;
}

static void QuaternionToProto(const Eigen::Quaterniond& q_in_b,
                       google::protobuf::RepeatedField<double>* out) {
  const estimator::ScalarFirst q = estimator::ToScalarFirst(estimator::Canonical(q_in_b));
  out->Clear();
  for (double v : q) out->Add(v);
}

void FillSample(absl::Time time, const estimator::AttitudeEstimate& attitude,
                const std::vector<std::pair<int, Eigen::Vector3d>>& h_in,
                esg::v1::AttitudeSample* out) {
  *out->mutable_time() = proto_convert::TimeToProto(time);
  QuaternionToProto(attitude.q_in_b, out->mutable_q_in_b());
  for (int i = 0; i < 3; ++i) out->add_sigma_arcsec(estimator::RadToArcsec(attitude.sigma_b(i)));
  for (const auto& [id, h] : h_in) {
    esg::v1::GyroAxis* axis = out->add_spin_axes();
    axis->set_gyro_id(id);
    for (int i = 0; i < 3; ++i) axis->add_h_in(h(i));
  }
}

esg::v1::EstimateRecord EstimateToProto(const storage::EstimateRecord& r) {
  esg::v1::EstimateRecord e;
  e.set_spacecraft_id(r.spacecraft_id);
  *e.mutable_measurement_time() = proto_convert::TimeToProto(r.measurement_time);
  esg::v1::SessionState state = esg::v1::SESSION_STATE_UNSPECIFIED;
  esg::v1::SessionState_Parse("SESSION_STATE_" + r.state, &state);
  e.set_state(state);
  if (r.attitude_valid) {
    estimator::AttitudeEstimate attitude;
    attitude.q_in_b = estimator::QuaternionFromScalarFirst(r.q_in_b);
    for (int i = 0; i < 3; ++i) attitude.sigma_b(i) = r.sigma_b[i];
    FillSample(r.measurement_time, attitude, {}, e.mutable_attitude());
    for (int id : r.output_pair) e.add_output_pair(id);
  }
  e.set_attitude_invalid_reason(r.attitude_invalid_reason);
  e.set_star_tracker_used(r.star_tracker_used);
  for (const storage::GyroInnovationRecord& g : r.star_tracker_innovations) {
    esg::v1::GyroInnovation* out = e.add_star_tracker_innovations();
    out->set_gyro_id(g.gyro_id);
    for (int i = 0; i < 2; ++i) {
      out->add_innovation_arcsec(estimator::RadToArcsec(g.innovation[i]));
      out->add_sigma_arcsec(estimator::RadToArcsec(g.sigma[i]));
    }
  }
  e.set_star_tracker_test_ratio(r.star_tracker_test_ratio);
  if (r.last_star_tracker_time != absl::InfinitePast()) {
    *e.mutable_last_star_tracker_time() = proto_convert::TimeToProto(r.last_star_tracker_time);
  }
  *e.mutable_compute_time() = proto_convert::TimeToProto(r.compute_time);
  if (r.has_attitude_error) {
    for (int k = 0; k < 3; ++k) {
      e.add_attitude_error_b_arcsec(estimator::RadToArcsec(r.attitude_error_b[k]));
      e.add_attitude_error_sigma_b_arcsec(estimator::RadToArcsec(r.attitude_error_sigma_b[k]));
    }
  }
  return e;
}

esg::v1::SessionInfo SessionInfoToProto(const SessionSummary& s) {
  esg::v1::SessionInfo info;
  info.set_spacecraft_id(s.spacecraft_id);
  info.set_served_by(s.served_by);
  info.set_frames_rejected(s.frames_rejected);
  info.set_frames_duplicate(s.frames_duplicate);
  info.set_frames_conflicting(s.frames_conflicting);
  if (s.last_frame_time != absl::InfinitePast()) {
    *info.mutable_last_frame_time() = proto_convert::TimeToProto(s.last_frame_time);
  }
  // The single-station fields describe the default station; `stations` lists every one.
  auto it = s.highest_durable.find(storage::kDefaultStation);
  info.set_highest_durable_sequence(it == s.highest_durable.end() ? 0 : it->second);
  info.set_last_sequence(it == s.highest_durable.end() ? 0 : it->second);
  for (const auto& [station, sequence] : s.highest_durable) {
    esg::v1::StationSequence* out = info.add_stations();
    out->set_station_id(station);
    out->set_highest_durable_sequence(sequence);
  }
  info.set_highest_applied_sequence(s.highest_applied_sequence);
  info.set_quarantine_reason(s.quarantine_reason);
  info.set_rebuilding(s.rebuilding);
  info.set_frames_accepted(s.frames_accepted);
  info.set_frames_applied(s.frames_applied);
  info.set_frames_apply_failed(s.frames_apply_failed);
  info.set_star_tracker_rejections(s.star_tracker_rejections);
  if (s.configured.has_value()) {
    info.set_model(s.configured->model_name);
    *info.mutable_config() = s.configured->config;
    for (int id : s.configured->reserve_pair) info.add_reserve_pair(id);
  }
  if (s.last_compute_time != absl::InfinitePast()) {
    *info.mutable_last_compute_time() = proto_convert::TimeToProto(s.last_compute_time);
  }
  if (!s.quarantine_reason.empty()) info.set_state(esg::v1::SESSION_STATE_QUARANTINED);
  if (s.session.has_value()) {
    const estimator::EstimationSession& session = *s.session;
    if (s.quarantine_reason.empty()) info.set_state(StateToProto(session.state()));
    for (int id : session.working_pair()) info.add_working_pair(id);
    info.set_degraded(session.degraded());
    for (const estimator::GyroEstimate& g : session.Gyros()) {
      if (!g.faulty) continue;
      esg::v1::ExcludedGyro* x = info.add_excluded_gyros();
      x->set_gyro_id(g.id);
      x->set_reason(estimator::ExclusionReasonName(g.exclusion.reason));
      if (g.exclusion.time != absl::InfinitePast()) {
        *x->mutable_time() = proto_convert::TimeToProto(g.exclusion.time);
      }
      x->set_value(g.exclusion.value);
      x->set_threshold(g.exclusion.threshold);
      x->set_message(absl::StrCat("gyro ", g.id, " excluded: ", g.exclusion.Describe()));
    }
    const estimator::AttitudeEstimate attitude = session.CurrentAttitude();
    if (session.initialized() && attitude.valid) {
      std::vector<std::pair<int, Eigen::Vector3d>> h_in;
      for (const estimator::GyroEstimate& g : session.Gyros()) h_in.emplace_back(g.id, g.h_in);
      FillSample(attitude.time, attitude, h_in, info.mutable_latest_attitude());
    }
    const estimator::ConsistencyMonitor& monitor = session.consistency_monitor();
    std::optional<estimator::ConsistencyMonitor::TestResult> shown;
    for (auto channel : {estimator::ConsistencyMonitor::Channel::kStarTracker,
                         estimator::ConsistencyMonitor::Channel::kAutonomous}) {
      const auto& last = monitor.last(channel);
      if (!last.has_value()) continue;
      if (!shown.has_value() || (last->inconsistent && !shown->inconsistent)) shown = last;
    }
    if (session.initialized()) {
      const estimator::LatencyEstimate latency = session.StarTrackerLatency();
      esg::v1::StarTrackerLatency* l = info.mutable_star_tracker_latency();
      l->set_latency_s(latency.latency_s);
      l->set_sigma_s(latency.sigma_s);
      l->set_estimated(latency.estimated);
    }
    const double widened_drift_deg_h = session.noise_widening().EquivalentDriftDegH();
    if (shown.has_value() || widened_drift_deg_h > 0.0) {
      esg::v1::ModelConsistency* mc = info.mutable_model_consistency();
      mc->set_consistent(!monitor.inconsistent() && widened_drift_deg_h == 0.0);
      mc->set_widened_drift_deg_h(widened_drift_deg_h);
    }
    if (shown.has_value()) {
      esg::v1::ModelConsistency* mc = info.mutable_model_consistency();
      mc->set_channel(estimator::ConsistencyChannelName(shown->channel));
      mc->set_value(shown->nis_sum);
      mc->set_threshold(shown->threshold);
      mc->set_window_steps(shown->steps);
      mc->set_degrees_of_freedom(shown->dof);
      *mc->mutable_test_time() = proto_convert::TimeToProto(shown->time);
      mc->set_tests(monitor.tests());
      mc->set_failing_tests(monitor.inconsistent_tests());
      if (monitor.first_inconsistent_time() != absl::InfinitePast()) {
        *mc->mutable_first_inconsistent_time() =
            proto_convert::TimeToProto(monitor.first_inconsistent_time());
      }
    }
  }
  if (s.alerts.has_value()) {
    info.set_active_alerts(s.alerts->active);
    info.set_unacknowledged_alerts(s.alerts->unacknowledged);
  }
  return info;
}

esg::v1::DiagnosisResult DiagnosisToProto(const storage::DiagnosisRecord& r) {
  esg::v1::DiagnosisResult out;
  out.set_id(r.id);
  out.set_spacecraft_id(r.spacecraft_id);
  out.set_verdict(r.verdict);
  out.set_report_json(r.report_json);
  out.set_frames(r.frames);
  out.set_config_version(r.config_version);
  out.set_model(r.model_name);
  out.set_requested_by(r.requested_by);
  out.set_answers_alert(r.answers_alert);
  *out.mutable_first_frame_time() = proto_convert::TimeToProto(r.from_time);
  *out.mutable_last_frame_time() = proto_convert::TimeToProto(r.to_time);
  *out.mutable_compute_time() = proto_convert::TimeToProto(r.compute_time);
  return out;
}

// "field: reason" -> Rejection (proto/convert.h error contract).
esg::v1::Rejection RejectionFromStatus(const absl::Status& status) {
  esg::v1::Rejection r;
  const std::string bounded = BoundedMessage(status.message());
  const absl::string_view m = bounded;
  const size_t colon = m.find(": ");
  if (colon == absl::string_view::npos) {
    r.set_field("frame");
    r.set_reason(std::string(m));
  } else {
    r.set_field(std::string(m.substr(0, colon)));
    r.set_reason(std::string(m.substr(colon + 2)));
  }
  r.set_code(static_cast<int>(status.code()));
  // At least 1 ms: 0 is "no delay given" on the wire, and the lease may expire just now.
  if (const std::optional<int64_t> ms = RetryDelayMs(status); ms.has_value()) {
    r.set_retry_after_ms(std::max<int64_t>(*ms, 1));
  }
  return r;
}

// The alert catalog is the single source (alert_catalog.h).
esg::v1::AlertSeverity SeverityOf(Event::Kind kind) { return AlertKindOf(kind).severity; }

esg::v1::AlertReason ReasonOf(Event::Kind kind) { return AlertKindOf(kind).reason; }

esg::v1::Alert AlertToProto(const storage::AlertRecord& r) {
  esg::v1::Alert a;
  a.set_spacecraft_id(r.spacecraft_id);
  a.set_sequence(r.sequence);
  a.set_severity(SeverityFromName(r.severity));
  a.set_reason(ReasonFromName(r.reason));
  a.set_subsystem(r.subsystem);
  a.set_value(r.value);
  a.set_threshold(r.threshold);
  a.set_unit(r.unit);
  a.set_repeat_count(r.repeat_count);
  *a.mutable_measurement_time() = proto_convert::TimeToProto(r.measurement_time);
  *a.mutable_compute_time() = proto_convert::TimeToProto(r.compute_time);
  *a.mutable_first_time() = proto_convert::TimeToProto(r.first_time);
  a.set_acknowledged(r.acknowledged);
  a.set_acknowledged_by(r.acknowledged_by);
  if (r.acknowledged && r.acknowledged_time != absl::InfinitePast()) {
    *a.mutable_acknowledged_time() = proto_convert::TimeToProto(r.acknowledged_time);
  }
  a.set_cleared(r.cleared);
  if (r.revised_time != absl::InfinitePast()) {
    *a.mutable_revised_time() = proto_convert::TimeToProto(r.revised_time);
  }
  if (r.cleared && r.cleared_time != absl::InfinitePast()) {
    *a.mutable_cleared_time() = proto_convert::TimeToProto(r.cleared_time);
  }
  a.set_message(r.message);
  return a;
}

esg::v1::CoefficientSnapshot SnapshotToProto(const storage::CoefficientRecord& r) {
  esg::v1::CoefficientSnapshot s;
  s.set_spacecraft_id(r.spacecraft_id);
  s.set_gyro_id(r.gyro_id);
  *s.mutable_measurement_time() = proto_convert::TimeToProto(r.measurement_time);
  *s.mutable_compute_time() = proto_convert::TimeToProto(r.compute_time);
  if (r.revised_time != absl::InfinitePast()) {
    *s.mutable_revised_time() = proto_convert::TimeToProto(r.revised_time);
  }
  // The record is SI (storage/records.h); the message carries deg/h and arcsec.
  auto fill = [](const std::vector<double>& v, esg::v1::GyroDriftModel* m,
                 google::protobuf::RepeatedField<double>* misalignment) {
    if (v.size() != static_cast<size_t>(storage::kNumCoefficientValues)) return;
    for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
      proto_convert::SetDriftModelTermDegH(
          term, estimator::RadPerSecToDegPerHour(v[term.theta_index]), m);
    }
    for (int i = 0; i < 3; ++i) {
      misalignment->Add(estimator::RadToArcsec(v[storage::kCoefficientMisalignment + i]));
    }
  };
  fill(r.values, s.mutable_model(), s.mutable_misalignment_arcsec());
  fill(r.sigmas, s.mutable_sigma(), s.mutable_misalignment_sigma_arcsec());
  for (const estimator::BasisTerm& t : r.basis_terms) {
    *s.add_basis_terms() = proto_convert::BasisTermToProto(t);
  }
  return s;
}

absl::StatusOr<estimator::TimeInterval> IntervalFromProto(const google::protobuf::Timestamp* from,
                                                          const google::protobuf::Timestamp* to) {
  estimator::TimeInterval interval;
  if (from != nullptr) {
    absl::StatusOr<absl::Time> t = proto_convert::TimeFromProto(*from);
    if (!t.ok()) return absl::InvalidArgumentError(absl::StrCat("from: ", t.status().message()));
    interval.from = *t;
  }
  if (to != nullptr) {
    absl::StatusOr<absl::Time> t = proto_convert::TimeFromProto(*to);
    if (!t.ok()) return absl::InvalidArgumentError(absl::StrCat("to: ", t.status().message()));
    interval.to = *t;
  }
  if (interval.to < interval.from) {
    return absl::InvalidArgumentError(absl::StrCat("to: ", FormatUtc(interval.to),
                                                   " is before from ", FormatUtc(interval.from)));
  }
  return interval;
}

}  // namespace esg::server
