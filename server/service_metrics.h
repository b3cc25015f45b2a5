// The metrics esgd exposes on `--metrics-listen` (docs/service.md "Metrics" documents each: name,
// type, labels, unit). One instance per EstimationCore; the ingest path (telemetry_reactor.cc),
// the committer, the apply workers and the diagnosis update it; the sessions, storage and
// backlog gauges are read from the core at each scrape (EstimationCore::Start adds the collector).
// The process_* metrics and esgd_build_info (server/metrics_process.h) are in the same registry.
#ifndef ESG_SERVER_SERVICE_METRICS_H_
#define ESG_SERVER_SERVICE_METRICS_H_

#include <string>

#include "absl/strings/string_view.h"
#include "server/metrics.h"

namespace esg::server {

struct ServiceMetrics {
  ServiceMetrics();

  MetricsRegistry registry;
  // Ingest (StreamTelemetry), counted when the frame is read and when its ack is written.
  Family<Counter>& frames_received;        // esg_frames_received_total{station}
  Family<Counter>& frames_acknowledged;    // esg_frames_acknowledged_total{station,outcome}
  Family<Counter>& frames_refused;         // esg_frames_refused_total{station,reason,field}
  Family<Counter>& frames_unacknowledged;  // esg_frames_unacknowledged_total{reason}
  Histogram& ack_latency;                  // esg_ack_latency_seconds
  // Storage.
  Family<Histogram>& storage_commit;  // esg_storage_commit_seconds{transaction}
  Histogram& commit_batch_frames;     // esg_commit_batch_frames
  Gauge& storage_healthy;             // esg_storage_healthy
  Gauge& commit_backlog_bytes;        // esg_commit_backlog_bytes
  // Sessions and the filter.
  Family<Gauge>& sessions;                // esg_sessions{state}
  Gauge& sessions_degraded;               // esg_sessions_degraded
  Family<Gauge>& gyros_excluded;          // esg_gyros_excluded{reason}
  Family<Histogram>& filter_step;         // esg_filter_step_seconds{step}
  Family<Counter>& alerts_raised;         // esg_alerts_raised_total{reason,severity}
  Family<Counter>& alerts_cleared;        // esg_alerts_cleared_total{reason,severity}
  Counter& revisions;                     // esg_revisions_total
  // Several servers on one database.
  Family<Counter>& lease_events;  // esg_session_lease_events_total{event}
  // Diagnosis.
  Family<Counter>& diagnoses;          // esg_diagnoses_total{result}
  Histogram& diagnosis_duration;       // esg_diagnosis_duration_seconds
};

// The station label of a frame's station_id: "default" when empty (the archive's name for it),
// the id when it is a valid identifier, "" otherwise (a refused frame; its text is not exposed).
std::string StationLabel(absl::string_view station_id);

// The field label of a refusal: indices dropped ("gyros[2].gyro_id" -> "gyros[].gyro_id"),
// characters outside [A-Za-z0-9_.[]] removed, at most 64 characters.
std::string FieldLabel(absl::string_view field);

}  // namespace esg::server

#endif  // ESG_SERVER_SERVICE_METRICS_H_
