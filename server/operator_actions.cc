// The operators' actions on a session beyond its configuration (docs/service.md "Applying a
// diagnosis", "Readmitting a gyro"): ApplyDiagnosis maps a stored diagnosis's findings onto the
// configuration it ran on (estimator/discovery/apply_findings.h) and reconfigures with replace =
// true; ReadmitGyro stores a readmission that the filter jobs apply before the next frame
// (ApplyReadmissions), in every re-run from the archive too.
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/time/clock.h"
#include "estimator/discovery/apply_findings.h"
#include "estimator/discovery/report.h"
#include "estimator/status_macros.h"
#include "proto/convert.h"
#include "proto/diagnosis_json.h"
#include "server/core_internal.h"
#include "server/estimation_core.h"
#include "server/log.h"
#include "storage/lease_store.h"

namespace esg::server {
namespace disc = estimator::discovery;

namespace {

bool Appliable(const std::string& verdict) {
  return verdict != disc::kVerdictNone && verdict != disc::kVerdictUnexplained;
}

// FailedPrecondition naming the spacecraft if it cannot take an operator's action: it is
// quarantined, or its stored configuration cannot be used (`usable` false); else OK.
absl::Status Usable(const std::string& id, const std::string& quarantine_reason, bool usable) {
  std::string reason = quarantine_reason;
  if (reason.empty() && !usable) {
    reason = "its stored configuration cannot be used";
  }
  if (reason.empty()) return absl::OkStatus();
  return absl::FailedPreconditionError(
      absl::StrCat("spacecraft_id: '", id, "' is quarantined (", reason,
                   "); ConfigureSpacecraft with replace=true ends the quarantine"));
}

}  // namespace

void ApplyReadmissions(const std::string& spacecraft_id,
                       const std::vector<storage::ReadmissionRecord>& readmissions,
                       absl::Time frame_time, bool log, estimator::EstimationSession& session) {
  for (const storage::ReadmissionRecord& r : readmissions) {
    if (r.after_time < session.last_frame_time() || r.after_time >= frame_time) continue;
    const absl::Status done = session.ReadmitGyro(r.gyro_id);
    if (!log) continue;
    if (done.ok()) {
      LogEvent(
          "INFO", "gyro_readmitted",
          absl::StrCat(spacecraft_id, ": gyro ", r.gyro_id, " readmitted by '", r.operator_name,
                       "'; it rejoins at the next measurement step"),
          {{"spacecraftId", spacecraft_id}, {"gyroId", r.gyro_id}, {"operator", r.operator_name}});
    } else {
      LogEvent("WARN", "gyro_readmission_skipped",
               absl::StrCat(spacecraft_id, ": the readmission of gyro ", r.gyro_id, " by '",
                            r.operator_name, "' changes nothing here: ", done.message()),
               {{"spacecraftId", spacecraft_id}, {"gyroId", r.gyro_id}});
    }
  }
}

void DescribeApplication(const estimator::SpacecraftConfig& config,
                         const storage::DiagnosisRecord& record, esg::v1::DiagnosisResult* result) {
  if (!Appliable(record.verdict)) return;
  absl::StatusOr<disc::DiagnosisReport> report =
      proto_convert::DiagnosisFindingsFromJson(record.report_json);
  if (!report.ok()) return;
  const disc::AppliedFindings applied = disc::WithFindings(config, *report);
  for (const std::string& line : applied.applied) result->add_applies(line);
  for (const std::string& line : applied.not_applied) result->add_does_not_apply(line);
}

absl::StatusOr<esg::v1::ApplyDiagnosisResponse> EstimationCore::ApplyDiagnosis(
    const esg::v1::ApplyDiagnosisRequest& request) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  ASSIGN_OR_RETURN(std::shared_ptr<Spacecraft> sc, Lookup(request.spacecraft_id()));
  absl::StatusOr<storage::DiagnosisRecord> record =
      storage_->diagnoses().Get(request.diagnosis_id());
  if (absl::IsNotFound(record.status()) ||
      (record.ok() && record->spacecraft_id != request.spacecraft_id())) {
    return absl::NotFoundError(absl::StrCat("diagnosis_id: diagnosis ", request.diagnosis_id(),
                                            " of spacecraft '", request.spacecraft_id(),
                                            "' does not exist"));
  }
  if (!record.ok()) return record.status();
  std::shared_ptr<const Setup> setup;
  {
    absl::MutexLock lock(&sc->state_mu);
    setup = sc->setup;
    RETURN_IF_ERROR(Usable(sc->id, sc->apply.quarantine_reason, setup != nullptr));
  }
  if (!Appliable(record->verdict)) {
    return absl::FailedPreconditionError(absl::StrCat(
        "diagnosis_id: diagnosis ", record->id, " has the verdict '", record->verdict, "': ",
        record->verdict == disc::kVerdictNone
            ? "the configured model explains the data, nothing to apply"
            : "no effect explains the mismatch, nothing to apply"));
  }
  if (record->config_version == 0 || record->model_name.empty()) {
    return absl::FailedPreconditionError(absl::StrCat(
        "diagnosis_id: diagnosis ", record->id,
        " was stored before the service recorded the configuration a diagnosis runs on; run "
        "the diagnosis again"));
  }
  // Checked before the refit and again under Configure's lock, so that a configuration stored
  // in between is never overwritten with one derived from the version before it.
  const auto unchanged = [&]() -> absl::Status {
    ASSIGN_OR_RETURN(storage::ConfigRecord current, storage_->configs().Get(sc->id));
    std::string model_name;
    {
      absl::MutexLock lock(&sc->state_mu);
      if (sc->setup != nullptr) model_name = sc->setup->model_name;
    }
    if (current.version == record->config_version && model_name == record->model_name) {
      return absl::OkStatus();
    }
    return absl::FailedPreconditionError(absl::StrCat(
        "diagnosis_id: diagnosis ", record->id, " ran on configuration version ",
        record->config_version, " with model ", record->model_name,
        "; the session now runs version ", current.version, " with model ", model_name,
        ": the configuration changed since, run the diagnosis again"));
  };
  RETURN_IF_ERROR(unchanged());
  ASSIGN_OR_RETURN(disc::DiagnosisReport report,
                   proto_convert::DiagnosisFindingsFromJson(record->report_json));
  const disc::AppliedFindings applied = disc::WithFindings(setup->config, report);
  if (applied.applied.empty()) {
    return absl::FailedPreconditionError(absl::StrCat(
        "diagnosis_id: none of diagnosis ", record->id,
        "'s findings maps to configuration: ", absl::StrJoin(applied.not_applied, "; ")));
  }
  esg::v1::ConfigureRequest configure;
  *configure.mutable_config() = proto_convert::ConfigToProto(applied.config);
  configure.set_model(setup->model_name);
  configure.set_replace(true);
  ASSIGN_OR_RETURN(esg::v1::ConfigureResponse configured, Configure(configure, unchanged));
  ASSIGN_OR_RETURN(storage::ConfigRecord stored, storage_->configs().Get(sc->id));
  LogEvent(
      "INFO", "diagnosis_applied",
      absl::StrCat("spacecraft ", sc->id, ": diagnosis ", record->id, " (", record->verdict,
                   ") applied as configuration version ", stored.version, ": ",
                   absl::StrJoin(applied.applied, "; ")),
      {{"spacecraftId", sc->id}, {"diagnosisId", record->id}, {"configVersion", stored.version}});
  esg::v1::ApplyDiagnosisResponse response;
  *response.mutable_session() = std::move(*configured.mutable_session());
  for (const std::string& line : applied.applied) response.add_applied(line);
  for (const std::string& line : applied.not_applied) response.add_not_applied(line);
  response.set_config_version(stored.version);
  return response;
}

absl::StatusOr<esg::v1::ReadmitGyroResponse> EstimationCore::ReadmitGyro(
    const esg::v1::ReadmitGyroRequest& request) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  if (request.gyro_id() < 1 || request.gyro_id() > estimator::kMaxGyros) {
    return absl::InvalidArgumentError(
        absl::StrCat("gyro_id: must be 1..", estimator::kMaxGyros, ", got ", request.gyro_id()));
  }
  if (request.operator_name().empty()) {
    return absl::InvalidArgumentError("operator_name: required (who readmits the gyro)");
  }
  ASSIGN_OR_RETURN(std::shared_ptr<Spacecraft> sc, Lookup(request.spacecraft_id()));
  // The job lock keeps the filter from moving the session while the readmission is checked
  // against it and stored.
  absl::MutexLock job(&sc->job_mu);
  storage::ReadmissionRecord record;
  record.spacecraft_id = sc->id;
  record.gyro_id = request.gyro_id();
  record.operator_name = request.operator_name();
  record.compute_time = absl::Now();
  {
    absl::MutexLock lock(&sc->state_mu);
    RETURN_IF_ERROR(Usable(sc->id, sc->apply.quarantine_reason,
                           sc->setup != nullptr && sc->session.has_value()));
    const absl::Time after = sc->session->last_frame_time();
    for (const storage::ReadmissionRecord& r : sc->readmissions) {
      if (r.gyro_id == record.gyro_id && r.after_time >= after) {
        return absl::FailedPreconditionError(
            absl::StrCat("gyro_id: gyro ", r.gyro_id, " was readmitted already by '",
                         r.operator_name, "'; it rejoins at the next measurement step"));
      }
    }
    // The session's own verdict on a copy: not configured, not excluded, of the output pair.
    estimator::EstimationSession trial = *sc->session;
    RETURN_IF_ERROR(trial.ReadmitGyro(record.gyro_id));
    record.after_time = after;
  }
  // With leases, stored only while this server still holds the session (checked inside the
  // transaction, as every write of the session is): a server that lost it stores nothing the
  // new holder would not know of.
  if (const absl::Status stored = storage_->CommitReadmission(record, FenceOf(*sc));
      !stored.ok()) {
    if (!storage::LeaseLostSpacecraft(stored).has_value()) return stored;
    MarkLeaseLost(*sc, stored.message());
    return absl::AbortedError(
        absl::StrCat("spacecraft_id: ", stored.message(), "; the readmission of gyro ",
                     record.gyro_id, " is not stored: send it again (the server holding the "
                     "session now takes it): docs/service.md \"Several servers\""));
  }
  esg::v1::ReadmitGyroResponse response;
  {
    absl::MutexLock lock(&sc->state_mu);
    sc->readmissions.push_back(record);
  }
  LogEvent(
      "INFO", "gyro_readmission_stored",
      absl::StrCat(sc->id, ": gyro ", record.gyro_id, " readmitted by '", record.operator_name,
                   "' after ", FormatUtc(record.after_time),
                   "; it rejoins at the next measurement step"),
      {{"spacecraftId", sc->id}, {"gyroId", record.gyro_id}, {"operator", record.operator_name}});
  *response.mutable_session() = SessionInfoToProto(Summarize(*sc));
  *response.mutable_after_time() = proto_convert::TimeToProto(record.after_time);
  Schedule(sc);
  return response;
}

}  // namespace esg::server
