// The metrics of esgd (see service_metrics.h; documented in docs/service.md "Metrics").
#include "server/service_metrics.h"

#include "absl/strings/ascii.h"
#include "estimator/spacecraft_config.h"
#include "server/metrics_process.h"
#include "storage/records.h"

namespace esg::server {
namespace {

std::vector<double> CommitBuckets() {
  return {0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0};
}

std::vector<double> FilterStepBuckets() {
  return {0.00001, 0.000025, 0.00005, 0.0001, 0.00025, 0.0005, 0.001,
          0.0025,  0.005,    0.01,    0.025,  0.05,    0.1,    0.25};
}

}  // namespace

ServiceMetrics::ServiceMetrics()
    : frames_received(registry.AddCounter(
          "esg_frames_received_total",
          "Telemetry frames read from StreamTelemetry calls, by station.", {"station"})),
      frames_acknowledged(registry.AddCounter(
          "esg_frames_acknowledged_total",
          "Acknowledgements sent with accepted=true (outcome new: stored durably; duplicate: "
          "already stored), by station.",
          {"station", "outcome"})),
      frames_refused(registry.AddCounter(
          "esg_frames_refused_total",
          "Acknowledgements sent with accepted=false, by station, reason (the rejection's gRPC "
          "code name) and rejected field.",
          {"station", "reason", "field"})),
      frames_unacknowledged(registry.AddCounter(
          "esg_frames_unacknowledged_total",
          "Frames read but never acknowledged because their stream failed (storage unavailable, "
          "backlog full, shutdown), by the stream's gRPC code name.",
          {"reason"})),
      ack_latency(registry
                      .AddHistogram("esg_ack_latency_seconds",
                                    "Time from reading a frame to writing its acknowledgement "
                                    "(accepted or refused), seconds.",
                                    {}, LatencyBuckets())
                      .Get()),
      storage_commit(registry.AddHistogram(
          "esg_storage_commit_seconds",
          "Duration of database write transactions from BEGIN to the end of COMMIT (fsync "
          "included), seconds, by transaction: telemetry (the group commit of accepted frames), filter (an "
          "apply job's effects and checkpoint), configure.",
          {"transaction"}, CommitBuckets())),
      commit_batch_frames(registry
                              .AddHistogram("esg_commit_batch_frames",
                                            "Frames stored by one telemetry group commit.", {},
                                            {1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000})
                              .Get()),
      storage_healthy(registry
                          .AddGauge("esg_storage_healthy",
                                    "1 while storage commits (ingest and filter), 0 while a "
                                    "commit fails (health NOT_SERVING).")
                          .Get()),
      commit_backlog_bytes(registry
                               .AddGauge("esg_commit_backlog_bytes",
                                         "Bytes of accepted frames queued for the next group "
                                         "commit.")
                               .Get()),
      sessions(registry.AddGauge(
          "esg_sessions",
          "Configured spacecraft by session state (NO_DATA, CALIBRATING, CONVERGED, AUTONOMOUS, "
          "FAULTED, or QUARANTINED when the filter is stopped or rebuilding).",
          {"state"})),
      sessions_degraded(registry
                            .AddGauge("esg_sessions_degraded",
                                      "Sessions running degraded: a gyro excluded, the output "
                                      "from a clean pair (docs/service.md \"Session states\").")
                            .Get()),
      gyros_excluded(registry.AddGauge(
          "esg_gyros_excluded",
          "Excluded gyros over the sessions, by reason (READING_JUMP, READING_BEYOND_ANY_DRIFT, "
          "READINGS_ERRATIC, DRIFT_CHANGE_BEYOND_LIMIT, EXCLUDED_BEFORE_UPGRADE).",
          {"reason"})),
      filter_step(registry.AddHistogram(
          "esg_filter_step_seconds",
          "Wall time of one filter step (EstimationSession::AddFrame) on an apply worker, seconds, "
          "by step: measurement (a measurement update ran), propagation (only propagation), "
          "failed (the step returned an error).",
          {"step"}, FilterStepBuckets())),
      alerts_raised(registry.AddCounter(
          "esg_alerts_raised_total",
          "Alerts stored as new (a repeat within the collapse window is not counted), by reason "
          "and severity.",
          {"reason", "severity"})),
      alerts_cleared(registry.AddCounter("esg_alerts_cleared_total",
                                         "Alerts cleared, by reason and severity.",
                                         {"reason", "severity"})),
      revisions(registry
                    .AddCounter("esg_revisions_total",
                                "Re-runs of the filter over late frames (accepted within the "
                                "reorder window, measured before an applied frame): each one "
                                "revises the coefficient history and alerts after the window "
                                "checkpoint it starts from.")
                    .Get()),
      lease_events(registry.AddCounter(
          "esg_session_lease_events_total",
          "Session leases of this server (several servers on one PostgreSQL database), by event: "
          "taken (a new spacecraft configured here, or a session loaded here), lost (found taken "
          "over by another server), released (at a clean stop), refused (a call met a lease "
          "another server holds).",
          {"event"})),
      diagnoses(registry.AddCounter(
          "esg_diagnoses_total",
          "Diagnose runs finished, by result: ok (stored), cancelled, error.", {"result"})),
      diagnosis_duration(
          registry
              .AddHistogram("esg_diagnosis_duration_seconds",
                            "Wall time of a Diagnose run, seconds.", {},
                            {0.1, 0.25, 0.5, 1, 2.5, 5, 10, 25, 50, 100, 250, 500})
              .Get()) {
  // Series that should read 0 before their first event.
  for (const char* result : {"ok", "cancelled", "error"}) diagnoses.With({result});
  for (const char* state :
       {"NO_DATA", "CALIBRATING", "CONVERGED", "AUTONOMOUS", "FAULTED", "QUARANTINED"}) {
    sessions.With({state});
  }
  for (const char* t : {"telemetry", "filter", "configure"}) storage_commit.With({t});
  for (const char* reason : {"READING_JUMP", "READING_BEYOND_ANY_DRIFT", "READINGS_ERRATIC",
                             "DRIFT_CHANGE_BEYOND_LIMIT", "EXCLUDED_BEFORE_UPGRADE"}) {
    gyros_excluded.With({reason});
  }
  storage_healthy.Set(1);
  AddProcessMetrics(registry);
  AddBuildInfo(registry);
}

std::string StationLabel(absl::string_view station_id) {
  if (station_id.empty()) return std::string(storage::kDefaultStation);
  if (!estimator::ValidateIdentifier(station_id, "station_id").ok()) return "";
  return std::string(station_id);
}

std::string FieldLabel(absl::string_view field) {
  std::string out;
  bool in_index = false;
  for (const char c : field) {
    if (c == '[') in_index = true;
    if (c == ']') in_index = false;
    if (in_index && c != '[') continue;
    if (absl::ascii_isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '.' || c == '[' ||
        c == ']') {
      out += c;
    }
    if (out.size() >= 64) break;
  }
  return out;
}

}  // namespace esg::server
