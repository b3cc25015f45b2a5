// The queries of the service: session summaries, coefficient history, alert acknowledgement,
// and the model-discrepancy diagnosis over archived telemetry (see estimation_core.h).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "absl/strings/escaping.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "absl/time/clock.h"
#include "estimator/basis_term.h"
#include "estimator/discovery/diagnose.h"
#include "estimator/status_macros.h"
#include "proto/convert.h"
#include "proto/diagnosis_json.h"
#include "server/core_internal.h"
#include "server/estimation_core.h"
#include "server/log.h"
#include "server/operator_name.h"
#include "storage/schema.h"
#include "storage/service_queries.h"

namespace esg::server {

using estimator::TelemetryFrame;

SessionSummary EstimationCore::Summarize(Spacecraft& sc) {
  SessionSummary summary;
  summary.spacecraft_id = sc.id;
  if (shared()) summary.served_by = options_.node_id;
  {
    absl::MutexLock lock(&sc.ingest_mu);
    summary.frames_rejected = sc.frames_rejected;
    summary.frames_duplicate = sc.frames_duplicate;
    summary.frames_conflicting = sc.frames_conflicting;
    summary.last_frame_time = sc.last_accepted_time;
  }
  {
    absl::MutexLock lock(&sc.state_mu);
    summary.highest_durable = sc.highest_durable;
    summary.highest_applied_sequence = sc.apply.applied_sequence;
    summary.quarantine_reason = sc.apply.quarantine_reason;
    summary.rebuilding = sc.apply.Rebuilding();
    summary.frames_accepted = sc.frames_accepted;
    summary.frames_applied = sc.apply.frames_applied;
    summary.frames_apply_failed = sc.apply.frames_apply_failed;
    summary.star_tracker_rejections = sc.apply.star_tracker_rejections;
    if (sc.setup != nullptr) {
      summary.configured = SessionSummary::Configured{
          sc.setup->model_name, proto_convert::ConfigToProto(sc.setup->config),
          sc.setup->config.reserve_pair};
    }
    summary.last_compute_time = sc.last_compute_time;
    summary.session = sc.session;
  }
  absl::StatusOr<storage::AlertCounts> counts = storage::CountAlerts(storage_->database(), sc.id);
  if (counts.ok()) summary.alerts = *counts;
  return summary;
}

absl::StatusOr<esg::v1::SessionInfo> EstimationCore::GetSession(const std::string& spacecraft_id) {
  if (spacecraft_id.empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  absl::StatusOr<std::shared_ptr<Spacecraft>> sc = Lookup(spacecraft_id);
  if (shared() && absl::IsUnavailable(sc.status())) {
    // Another server holds the session: its state as that server last committed it.
    ASSIGN_OR_RETURN(storage::ConfigRecord record, storage_->configs().Get(spacecraft_id));
    return SummarizeFromDatabase(record);
  }
  if (!sc.ok()) return sc.status();
  return SessionInfoToProto(Summarize(**sc));
}

namespace {

// ---- Page tokens (AIP-158; docs/service.md "Paging") ----
// A token is the URL-safe base64 of "esg1;<list>;<request fingerprint>;<position>": opaque to
// clients, bound to the list and to the request's filters (a token of another request is
// refused), and carrying the position after which the next page starts (keyset paging: a page
// costs the same wherever it is, and records appended meanwhile are neither skipped nor
// repeated).

// FNV-1a, 64 bit: stable across processes and builds (absl::Hash is not).
uint64_t Fingerprint(absl::string_view text) {
  uint64_t h = 1469598103934665603ull;
  for (unsigned char c : text) {
    h ^= c;
    h *= 1099511628211ull;
  }
  return h;
}

std::string EncodePageToken(absl::string_view list, absl::string_view filters,
                            absl::string_view position) {
  return absl::WebSafeBase64Escape(
      absl::StrCat("esg1;", list, ";", absl::Hex(Fingerprint(filters)), ";", position));
}

// The position of a token of `list` for a request with `filters`; InvalidArgument naming
// page_token otherwise.
absl::StatusOr<std::string> DecodePageToken(absl::string_view token, absl::string_view list,
                                            absl::string_view filters) {
  std::string raw;
  if (!absl::WebSafeBase64Unescape(token, &raw)) {
    return absl::InvalidArgumentError("page_token: not a page token of this service");
  }
  const std::vector<std::string> parts = absl::StrSplit(raw, absl::MaxSplits(';', 3));
  if (parts.size() != 4 || parts[0] != "esg1" || parts[1] != list) {
    return absl::InvalidArgumentError(absl::StrCat("page_token: not a page token of ", list,
                                                   " (take next_page_token of the "
                                                   "previous response)"));
  }
  if (parts[2] != absl::StrCat(absl::Hex(Fingerprint(filters)))) {
    return absl::InvalidArgumentError(
        absl::StrCat("page_token: belongs to a ", list,
                     " request with other filters (spacecraft, gyro or "
                     "time span); paging must repeat the first request"));
  }
  return parts[3];
}

// AIP-158 page size: 0 -> `default_size`, above `max_size` -> `max_size`, negative refused.
absl::StatusOr<int64_t> PageSize(int32_t page_size, int64_t default_size, int64_t max_size) {
  if (page_size < 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("page_size: must be >= 0 (0: ", default_size, "), got ", page_size));
  }
  if (page_size == 0) return default_size;
  return std::min<int64_t>(page_size, max_size);
}

// Integers of a token position "a:b:c"; InvalidArgument naming page_token when malformed.
absl::StatusOr<std::vector<int64_t>> PositionIntegers(absl::string_view position, size_t count) {
  const std::vector<absl::string_view> parts = absl::StrSplit(position, ':');
  std::vector<int64_t> out(parts.size());
  bool ok = parts.size() == count;
  for (size_t i = 0; ok && i < parts.size(); ++i) ok = absl::SimpleAtoi(parts[i], &out[i]);
  if (!ok) return absl::InvalidArgumentError("page_token: damaged (its position does not parse)");
  return out;
}

}  // namespace

absl::StatusOr<esg::v1::ListSessionsResponse> EstimationCore::ListSessions(
    const esg::v1::ListSessionsRequest& request) {
  ASSIGN_OR_RETURN(const int64_t size,
                   PageSize(request.page_size(), kDefaultSessionsPageSize, kMaxSessionsPageSize));
  std::string after;
  if (!request.page_token().empty()) {
    ASSIGN_OR_RETURN(std::string position,
                     DecodePageToken(request.page_token(), "ListSessions", ""));
    if (!absl::WebSafeBase64Unescape(position, &after)) {
      return absl::InvalidArgumentError("page_token: damaged (its position does not parse)");
    }
  }
  // Ordered by spacecraft id; the page starts after the token's id.
  bool more = false;
  if (shared()) {
    // Every spacecraft of the shared database: this server's sessions from memory, the others'
    // as their servers last committed them.
    ASSIGN_OR_RETURN(std::vector<storage::ConfigRecord> configs, storage_->configs().List());
    esg::v1::ListSessionsResponse response;
    std::string last;
    for (const storage::ConfigRecord& record : configs) {
      if (!request.page_token().empty() && record.spacecraft_id <= after) continue;
      if (response.sessions_size() >= size) {
        more = true;
        break;
      }
      std::shared_ptr<Spacecraft> sc = Find(record.spacecraft_id);
      if (sc != nullptr && !sc->lease_lost) {
        *response.add_sessions() = SessionInfoToProto(Summarize(*sc));
      } else {
        ASSIGN_OR_RETURN(*response.add_sessions(), SummarizeFromDatabase(record));
      }
      last = record.spacecraft_id;
    }
    if (more) {
      response.set_next_page_token(
          EncodePageToken("ListSessions", "", absl::WebSafeBase64Escape(last)));
    }
    return response;
  }
  const std::vector<std::shared_ptr<Spacecraft>> page =
      registry_.Page(request.page_token().empty() ? std::string() : after, size, &more);
  esg::v1::ListSessionsResponse response;
  for (auto& sc : page) *response.add_sessions() = SessionInfoToProto(Summarize(*sc));
  if (more) {
    response.set_next_page_token(
        EncodePageToken("ListSessions", "", absl::WebSafeBase64Escape(page.back()->id)));
  }
  return response;
}

absl::StatusOr<esg::v1::DiagnosisResult> EstimationCore::Diagnose(
    const esg::v1::DiagnoseRequest& request,
    const std::function<void(double fraction, const std::string& stage)>& progress,
    const std::function<bool()>& cancelled, const DiagnosisOrigin& origin) {
  const std::string& id = request.spacecraft_id();
  LogEvent("INFO", "diagnosis_started", absl::StrCat("diagnosis of ", id, " started"),
           {{"spacecraftId", id}});
  const absl::Time start = absl::Now();
  absl::StatusOr<esg::v1::DiagnosisResult> result = RunDiagnosis(request, progress, cancelled, origin);
  const double seconds = absl::ToDoubleSeconds(absl::Now() - start);
  metrics_.diagnosis_duration.Observe(seconds);
  if (result.ok()) {
    metrics_.diagnoses.With({"ok"}).Increment();
    LogEvent("INFO", "diagnosis_finished",
             absl::StrCat("diagnosis #", result->id(), " of ", id, " finished in ",
                          absl::FormatDuration(absl::Seconds(seconds))),
             {{"spacecraftId", id},
              {"diagnosisId", static_cast<int64_t>(result->id())},
              {"result", "ok"},
              {"durationSeconds", seconds}});
  } else {
    const bool was_cancelled = result.status().code() == absl::StatusCode::kCancelled;
    metrics_.diagnoses.With({was_cancelled ? "cancelled" : "error"}).Increment();
    LogEvent(was_cancelled ? "INFO" : "WARN", "diagnosis_finished",
             absl::StrCat("diagnosis of ", id, was_cancelled ? " cancelled" : " failed", " after ",
                          absl::FormatDuration(absl::Seconds(seconds)), ": ",
                          result.status().ToString()),
             {{"spacecraftId", id},
              {"result", was_cancelled ? "cancelled" : "error"},
              {"durationSeconds", seconds}});
  }
  return result;
}

absl::StatusOr<esg::v1::DiagnosisResult> EstimationCore::RunDiagnosis(
    const esg::v1::DiagnoseRequest& request,
    const std::function<void(double fraction, const std::string& stage)>& progress,
    const std::function<bool()>& cancelled, const DiagnosisOrigin& origin) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  ASSIGN_OR_RETURN(std::shared_ptr<Spacecraft> sc, Lookup(request.spacecraft_id()));
  ASSIGN_OR_RETURN(const estimator::TimeInterval interval, RequestInterval(request));
  std::shared_ptr<const Setup> setup;
  std::string quarantine_reason;
  {
    absl::MutexLock state(&sc->state_mu);
    setup = sc->setup;
    // A rebuild (quarantine while the session is rebuilt from the archive) does not stop a
    // diagnosis of the archive; a stopped filter does.
    if (sc->apply.FilterStopped()) quarantine_reason = sc->apply.quarantine_reason;
  }
  if (setup == nullptr) {
    return absl::FailedPreconditionError(
        absl::StrCat("spacecraft_id: '", sc->id, "' has no usable configuration (quarantined)"));
  }
  // A quarantined spacecraft's archive holds what stopped its filter; the diagnosis waits for
  // the operator's ConfigureSpacecraft with replace=true, as the filter does.
  if (!quarantine_reason.empty()) {
    return absl::FailedPreconditionError(
        absl::StrCat("spacecraft_id: '", sc->id, "' is quarantined: ", quarantine_reason));
  }
  const double period_s = request.orbital_period_s();
  if (!(period_s == 0.0 ||
        (period_s >= estimator::kMinOrbitalPeriodS && period_s <= estimator::kMaxOrbitalPeriodS))) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "orbital_period_s: %g s is outside [%g, %g] s (or 0: the period of the recording's "
        "orbital-orientation spans)",
        period_s, estimator::kMinOrbitalPeriodS, estimator::kMaxOrbitalPeriodS));
  }
  estimator::discovery::DiagnoseOptions options;
  options.model = request.model().empty() ? setup->model_name : request.model();
  options.orbital_period_s = request.orbital_period_s();
  options.cancelled = cancelled;
  // The estimator starts no threads. A diagnosis runs on its call's worker thread and gets one
  // more here (options.threads = 2 tasks, the calling thread one of them); with the limit on
  // concurrent diagnoses (CallLimiter) this bounds the server's diagnosis threads.
  options.threads = 2;
  options.run_parallel = [](int count, const std::function<void(int)>& task) {
    std::vector<std::thread> helpers;
    for (int i = 1; i < count; ++i) helpers.emplace_back(task, i);
    task(0);
    for (std::thread& t : helpers) t.join();
  };
  // ParseModel's messages start with "model: " already.
  absl::StatusOr<estimator::ModelSpec> model_spec = estimator::ParseModel(options.model);
  if (!model_spec.ok()) return model_spec.status();
  // The configuration version the diagnosis runs on, recorded with it (ApplyDiagnosis refuses a
  // diagnosis of another version).
  ASSIGN_OR_RETURN(const storage::ConfigRecord config_record, storage_->configs().Get(sc->id));
  ASSIGN_OR_RETURN(std::vector<storage::ArchivedFrame> archived,
                   storage_->archive().ReadTimeRange(sc->id, interval.from, interval.End()));
  // An empty window is the request's window, or the spacecraft's whole archive.
  const char* window_field = request.has_from() || request.has_to() ? "from: " : "spacecraft_id: ";
  if (archived.empty()) {
    return absl::FailedPreconditionError(absl::StrCat(window_field, "no archived telemetry of '",
                                                      sc->id, "' in [", FormatUtc(interval.from),
                                                      ", ", FormatUtc(interval.to), "]"));
  }
  if (cancelled && cancelled()) return absl::CancelledError("diagnosis cancelled");
  std::vector<TelemetryFrame> frames;
  frames.reserve(archived.size());
  for (const storage::ArchivedFrame& a : archived) {
    // A frame the filter skips (archived before a bound the service checks now, or damaged) is
    // skipped here too, with the same log line (apply_worker.cc): one frame does not refuse the
    // whole window.
    absl::StatusOr<TelemetryFrame> frame = DecodeArchivedFrame(a.payload);
    if (!frame.ok()) {
      LogEvent("WARN", "frame_undecodable",
               absl::StrCat(sc->id, ": archived frame (station ", a.station_id, ", sequence ",
                            a.sequence, ") skipped by the diagnosis: ",
                            frame.status().ToString()),
               {{"spacecraftId", sc->id}, {"station", a.station_id}, {"sequence", a.sequence}});
      continue;
    }
    frames.push_back(*std::move(frame));
  }
  if (frames.empty()) {
    return absl::FailedPreconditionError(absl::StrCat(
        window_field, "no decodable archived telemetry of '", sc->id, "' in [",
        FormatUtc(interval.from), ", ", FormatUtc(interval.to), "]"));
  }
  // The spacecraft's orbit from its stored deliveries (docs/service.md "Orbits"), when they
  // cover the span: the sun's regressors then see the Earth's shadow.
  ASSIGN_OR_RETURN(const StoredOrbit stored_orbit,
                   OrbitFor(sc->id, frames.front().time, frames.back().time));
  options.orbit = stored_orbit.orbit;
  options.orbit_source = stored_orbit.note;
  ASSIGN_OR_RETURN(estimator::discovery::DiagnosisReport report,
                   estimator::discovery::Diagnose(setup->config, frames, options, progress));
  // A diagnosis cancelled while it ran is not stored, even when it completed meanwhile.
  if (cancelled && cancelled()) return absl::CancelledError("diagnosis cancelled");
  storage::DiagnosisRecord record;
  record.spacecraft_id = sc->id;
  record.from_time = frames.front().time;
  record.to_time = frames.back().time;
  record.compute_time = absl::Now();
  record.verdict = report.verdict;
  record.report_json = proto_convert::DiagnosisToJson(report);
  record.frames = static_cast<int64_t>(frames.size());
  record.config_version = config_record.version;
  record.model_name = model_spec->Name();
  record.requested_by = origin.requested_by;
  record.answers_alert = origin.answers_alert;
  ASSIGN_OR_RETURN(record.id, storage_->diagnoses().Put(record));
  esg::v1::DiagnosisResult result = DiagnosisToProto(record);
  DescribeApplication(setup->config, record, &result);
  return result;
}

absl::StatusOr<esg::v1::ListDiagnosesResponse> EstimationCore::ListDiagnoses(
    const esg::v1::ListDiagnosesRequest& request) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  RETURN_IF_ERROR(CheckConfigured(request.spacecraft_id()));
  ASSIGN_OR_RETURN(const int64_t size,
                   PageSize(request.page_size(), kDefaultDiagnosesPageSize, kMaxDiagnosesPageSize));
  int64_t after_id = 0;
  if (!request.page_token().empty()) {
    ASSIGN_OR_RETURN(std::string position, DecodePageToken(request.page_token(), "ListDiagnoses",
                                                           request.spacecraft_id()));
    ASSIGN_OR_RETURN(std::vector<int64_t> v, PositionIntegers(position, 1));
    after_id = v[0];
  }
  ASSIGN_OR_RETURN(
      std::vector<storage::DiagnosisRecord> records,
      storage_->diagnoses().ListSummaries(request.spacecraft_id(), after_id, size + 1));
  esg::v1::ListDiagnosesResponse response;
  const bool more = static_cast<int64_t>(records.size()) > size;
  if (more) records.resize(size);
  for (const storage::DiagnosisRecord& r : records) {
    *response.add_diagnoses() = DiagnosisToProto(r);
  }
  if (more) {
    response.set_next_page_token(
        EncodePageToken("ListDiagnoses", request.spacecraft_id(), absl::StrCat(records.back().id)));
  }
  return response;
}

absl::StatusOr<esg::v1::DiagnosisResult> EstimationCore::GetDiagnosis(
    const esg::v1::GetDiagnosisRequest& request) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  RETURN_IF_ERROR(CheckConfigured(request.spacecraft_id()));
  absl::StatusOr<storage::DiagnosisRecord> record = storage_->diagnoses().Get(request.id());
  if (absl::IsNotFound(record.status()) ||
      (record.ok() && record->spacecraft_id != request.spacecraft_id())) {
    return absl::NotFoundError(absl::StrCat("id: diagnosis ", request.id(), " of spacecraft '",
                                            request.spacecraft_id(), "' does not exist"));
  }
  if (!record.ok()) return record.status();
  esg::v1::DiagnosisResult result = DiagnosisToProto(*record);
  std::shared_ptr<const Setup> setup;
  if (std::shared_ptr<Spacecraft> sc = Find(request.spacecraft_id()); sc != nullptr) {
    absl::MutexLock lock(&sc->state_mu);
    setup = sc->setup;
  }
  if (setup != nullptr) DescribeApplication(setup->config, *record, &result);
  return result;
}

absl::StatusOr<esg::v1::HistoryResponse> EstimationCore::History(
    const esg::v1::HistoryRequest& request) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  ASSIGN_OR_RETURN(const int64_t size,
                   PageSize(request.page_size(), kDefaultHistoryPageSize, kMaxHistoryPageSize));
  RETURN_IF_ERROR(CheckConfigured(request.spacecraft_id()));
  if (request.gyro_id() < 0 || request.gyro_id() > estimator::kMaxGyros) {
    return absl::InvalidArgumentError(
        absl::StrCat("gyro_id: must be 0 (all) or 1..4, got ", request.gyro_id()));
  }
  ASSIGN_OR_RETURN(const estimator::TimeInterval interval, RequestInterval(request));
  // Storage queries take the half-open [from, end), end the first instant after `to`.
  const absl::Time from = interval.from;
  const absl::Time to = interval.End();
  // The filters a token is bound to (the request without its paging fields).
  const std::string filters =
      absl::StrCat(request.spacecraft_id(), "|", request.gyro_id(), "|",
                   storage::TimeToUnixNanos(from), "|", storage::TimeToUnixNanos(to),
                   request.include_revised() ? "|revised" : "");
  std::optional<storage::CoefficientCursor> after;
  if (!request.page_token().empty()) {
    ASSIGN_OR_RETURN(std::string position,
                     DecodePageToken(request.page_token(), "GetCoefficientHistory", filters));
    ASSIGN_OR_RETURN(std::vector<int64_t> v, PositionIntegers(position, 3));
    after = storage::CoefficientCursor{v[0], v[1], v[2]};
  }
  ASSIGN_OR_RETURN(storage::CoefficientPage page,
                   storage_->coefficients().HistoryPage(request.spacecraft_id(), request.gyro_id(),
                                                        from, to, after, size,
                                                        request.include_revised()));
  esg::v1::HistoryResponse response;
  for (const storage::CoefficientRecord& r : page.records) {
    *response.add_snapshots() = SnapshotToProto(r);
  }
  if (page.next.has_value()) {
    response.set_next_page_token(
        EncodePageToken("GetCoefficientHistory", filters,
                        absl::StrCat(page.next->measurement_time_unix_ns, ":", page.next->gyro_id,
                                     ":", page.next->row_id)));
  }
  return response;
}

absl::StatusOr<esg::v1::EstimateHistoryResponse> EstimationCore::EstimateHistory(
    const esg::v1::EstimateHistoryRequest& request) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  ASSIGN_OR_RETURN(const int64_t size, PageSize(request.page_size(), kDefaultEstimatesPageSize,
                                                kMaxEstimatesPageSize));
  RETURN_IF_ERROR(CheckConfigured(request.spacecraft_id()));
  ASSIGN_OR_RETURN(const estimator::TimeInterval interval, RequestInterval(request));
  // Storage queries take the half-open [from, end), end the first instant after `to`.
  const absl::Time from = interval.from;
  const absl::Time to = interval.End();
  // The filters a token is bound to (the request without its paging fields).
  const std::string filters = absl::StrCat(request.spacecraft_id(), "|",
                                           storage::TimeToUnixNanos(from), "|",
                                           storage::TimeToUnixNanos(to));
  std::optional<absl::Time> after;
  if (!request.page_token().empty()) {
    ASSIGN_OR_RETURN(std::string position,
                     DecodePageToken(request.page_token(), "GetEstimateHistory", filters));
    ASSIGN_OR_RETURN(std::vector<int64_t> v, PositionIntegers(position, 1));
    after = storage::UnixNanosToTime(v[0]);
  }
  ASSIGN_OR_RETURN(storage::EstimatePage page,
                   storage_->estimates().Page(request.spacecraft_id(), from, to, after, size));
  esg::v1::EstimateHistoryResponse response;
  for (const storage::EstimateRecord& r : page.records) {
    *response.add_estimates() = EstimateToProto(r);
  }
  if (page.next.has_value()) {
    response.set_next_page_token(EncodePageToken(
        "GetEstimateHistory", filters, absl::StrCat(storage::TimeToUnixNanos(*page.next))));
  }
  return response;
}

absl::StatusOr<esg::v1::ExportTelemetryResponse> EstimationCore::ExportTelemetryChunk(
    const esg::v1::ExportTelemetryRequest& request, absl::Time* after, bool* done) {
  *done = true;
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  RETURN_IF_ERROR(CheckConfigured(request.spacecraft_id()));
  ASSIGN_OR_RETURN(const estimator::TimeInterval interval, RequestInterval(request));
  // Frame times are unique per spacecraft, so "after the last time sent" resumes exactly.
  const absl::Time start = std::max(*after, interval.from - absl::Nanoseconds(1));
  ASSIGN_OR_RETURN(std::vector<storage::ArchivedFrame> frames,
                   storage_->archive().ReadAfter(request.spacecraft_id(), start, kExportChunkSize));
  esg::v1::ExportTelemetryResponse response;
  for (const storage::ArchivedFrame& f : frames) {
    if (f.measurement_time > interval.to) return response;  // done
    esg::v1::TelemetryFrame* frame = response.add_frames();
    if (!frame->ParseFromString(f.payload)) {
      return absl::DataLossError(absl::StrCat("archived frame ", f.sequence, " of '",
                                              request.spacecraft_id(), "' does not parse"));
    }
    frame->set_station_id(f.station_id);  // as stored ("default" for a frame that named none)
    frame->set_sequence(f.sequence);
    *after = f.measurement_time;
  }
  *done = static_cast<int64_t>(frames.size()) < kExportChunkSize;
  return response;
}

absl::StatusOr<esg::v1::Alert> EstimationCore::Acknowledge(
    const esg::v1::AcknowledgeRequest& request) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  ASSIGN_OR_RETURN(std::shared_ptr<Spacecraft> sc, Lookup(request.spacecraft_id()));
  if (request.sequence() < 1) {
    return absl::InvalidArgumentError(
        absl::StrCat("sequence: must be >= 1, got ", request.sequence()));
  }
  RETURN_IF_ERROR(ValidateOperatorName(request.operator_name(), "operator_name"));
  absl::MutexLock publish(&sc->publish_mu);
  absl::StatusOr<storage::AlertRecord> before = storage_->alerts().Get(sc->id, request.sequence());
  if (absl::IsNotFound(before.status())) {
    return absl::NotFoundError(absl::StrCat("sequence: alert ", request.sequence(),
                                            " of spacecraft '", sc->id, "' does not exist"));
  }
  ASSIGN_OR_RETURN(storage::AlertRecord record,
                   storage_->alerts().Acknowledge(sc->id, request.sequence(),
                                                  request.operator_name(), absl::Now()));
  if (before.ok() && !before->acknowledged) hub_.Publish(record);
  return AlertToProto(record);
}

}  // namespace esg::server
