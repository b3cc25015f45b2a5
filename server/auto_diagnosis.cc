// The automatic diagnosis; its rules are stated in auto_diagnosis.h.
#include "server/auto_diagnosis.h"

#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/time/clock.h"
#include "estimator/discovery/report.h"
#include "proto/convert.h"
#include "server/log.h"
#include "server/proto_mapping.h"

namespace esg::server {
namespace {

// Summaries read per page while looking for the latest automatic diagnosis.
constexpr int64_t kSummaryPage = 200;

// "answers alert #5 (MODEL_INCONSISTENT model:gyro_2 at 2019-03-01T03:00:00.000Z)".
std::string AnswersText(const storage::AlertRecord& alert) {
  return absl::StrCat("answers alert #", alert.sequence, " (", alert.reason, " ", alert.subsystem,
                      " at ", FormatUtc(alert.first_time), ")");
}

// The verdict in words and what to do about it.
std::string VerdictText(const esg::v1::DiagnosisResult& result) {
  const std::string apply = absl::StrCat("apply it with `esg model apply --spacecraft ",
                                         result.spacecraft_id(), " --diagnosis ", result.id(),
                                         "` (the session then re-runs the archive)");
  if (result.verdict() == estimator::discovery::kVerdictNone) {
    return "verdict none: no effect the model lacks was found over the span, nothing to apply; "
           "the mismatch may have been transient, or the noise settings are too tight";
  }
  if (result.verdict() == estimator::discovery::kVerdictUnexplained) {
    return "verdict unexplained: the mismatch is real but no library effect explains it, nothing "
           "to apply; look at the span with `esg diagnose --out DIR` and its plots";
  }
  std::string text = absl::StrCat("verdict ", result.verdict());
  if (result.applies_size() > 0) {
    absl::StrAppend(&text, ": the model lacks ", absl::StrJoin(result.applies(), "; "), "; ",
                    apply);
  } else {
    absl::StrAppend(&text, ": none of its findings maps to the configuration (",
                    absl::StrJoin(result.does_not_apply(), "; "),
                    "), nothing to apply; read it with `esg diagnoses show --id ", result.id(),
                    "`");
  }
  return text;
}

// "over A .. B", the span the diagnosis covered; a span whose ends cannot be read (a timestamp
// outside the range a Timestamp may hold) is stated as such rather than guessed.
std::string SpanText(const esg::v1::DiagnosisResult& result) {
  const absl::StatusOr<absl::Time> first = proto_convert::TimeFromProto(result.first_frame_time());
  const absl::StatusOr<absl::Time> last = proto_convert::TimeFromProto(result.last_frame_time());
  if (first.ok() && last.ok()) {
    return absl::StrCat("over ", FormatUtc(*first), " .. ", FormatUtc(*last));
  }
  const absl::Status& bad = first.ok() ? last.status() : first.status();
  return absl::StrCat("over a span whose ", first.ok() ? "last" : "first",
                      " frame time cannot be read (", bad.message(), ")");
}

}  // namespace

std::string FollowUpMessage(const esg::v1::DiagnosisResult& result,
                            const storage::AlertRecord& alert) {
  return absl::StrCat("automatic diagnosis #", result.id(), " of ", result.spacecraft_id(), " ",
                      AnswersText(alert), ", ", SpanText(result), " (", result.frames(),
                      " frames, configuration version ", result.config_version(),
                      "): ", VerdictText(result));
}

AutoDiagnosis::AutoDiagnosis(EstimationCore* core, CallLimiter* limiter,
                             AutoDiagnosisOptions options)
    : core_(core), limiter_(limiter), options_(options) {
  if (options_.span <= absl::ZeroDuration()) return;
  thread_ = std::thread([this] { Loop(); });
  core_->SetModelObserver([this](const storage::AlertRecord& a) { OnModelAlert(a); },
                          [this](const std::string& id) { OnConfigured(id); });
}

AutoDiagnosis::~AutoDiagnosis() { Stop(); }

void AutoDiagnosis::Stop() {
  if (!thread_.joinable()) return;
  core_->SetModelObserver({}, {});
  {
    absl::MutexLock lock(&mu_);
    stop_ = true;
    queue_.clear();
    if (running_.has_value()) CancelLocked(*running_, "the server stops");
  }
  thread_.join();
}

bool AutoDiagnosis::Busy(const std::string& spacecraft_id) const {
  if (running_.has_value() && running_->alert.spacecraft_id == spacecraft_id) return true;
  for (const Job& j : queue_) {
    if (j.alert.spacecraft_id == spacecraft_id) return true;
  }
  return false;
}

void AutoDiagnosis::OnModelAlert(const storage::AlertRecord& alert) {
  if (options_.span <= absl::ZeroDuration()) return;
  absl::MutexLock lock(&mu_);
  if (stop_ || Busy(alert.spacecraft_id)) return;
  Job job;
  job.alert = alert;
  queue_.push_back(std::move(job));
}

void AutoDiagnosis::CancelLocked(Job& job, const std::string& why) {
  job.why = why;
  job.cancelled->store(true);
}

void AutoDiagnosis::OnConfigured(const std::string& spacecraft_id) {
  absl::MutexLock lock(&mu_);
  std::erase_if(queue_, [&](const Job& j) { return j.alert.spacecraft_id == spacecraft_id; });
  if (running_.has_value() && running_->alert.spacecraft_id == spacecraft_id) {
    CancelLocked(*running_, "the configuration changed (its span is stale)");
  }
}

std::optional<int64_t> AutoDiagnosis::Cancel(const std::string& spacecraft_id) {
  absl::StatusOr<storage::ConfigRecord> config = core_->storage().configs().Get(spacecraft_id);
  std::optional<int64_t> answered;
  {
    absl::MutexLock lock(&mu_);
    for (auto it = queue_.begin(); it != queue_.end();) {
      if (it->alert.spacecraft_id != spacecraft_id) {
        ++it;
        continue;
      }
      answered = it->alert.sequence;
      LogEvent("INFO", "auto_diagnosis_cancelled",
               absl::StrCat("automatic diagnosis of ", spacecraft_id, " (", AnswersText(it->alert),
                            ") cancelled before it started: an operator cancelled it"),
               {{"spacecraftId", spacecraft_id}, {"alertSequence", it->alert.sequence}});
      it = queue_.erase(it);
    }
    if (running_.has_value() && running_->alert.spacecraft_id == spacecraft_id) {
      answered = running_->alert.sequence;
      CancelLocked(*running_, "an operator cancelled it");
    }
    if (!answered.has_value() || !config.ok()) return answered;
    suppressed_[spacecraft_id] = config->version;
  }
  // Stored, so that a restart keeps it (in memory above for this run of the server either way);
  // outside the lock, which the filter workers' alerts take.
  storage::AutoCancelRecord marker;
  marker.spacecraft_id = spacecraft_id;
  marker.config_version = config->version;
  marker.answers_alert = *answered;
  marker.cancel_time = absl::Now();
  if (const absl::Status stored = core_->storage().diagnoses().PutAutoCancel(marker);
      !stored.ok()) {
    LogEvent("WARN", "auto_diagnosis_cancel_not_stored",
             absl::StrCat("the cancel of the automatic diagnosis of ", spacecraft_id,
                          " under configuration version ", config->version,
                          " holds until this server stops, not after: ", stored.ToString()),
             {{"spacecraftId", spacecraft_id}, {"configVersion", config->version}});
  }
  return answered;
}

std::string AutoDiagnosis::WhyCancelled(const Job& job) {
  absl::MutexLock lock(&mu_);
  return running_.has_value() ? running_->why : job.why;
}

void AutoDiagnosis::Loop() {
  for (;;) {
    Job job;
    {
      absl::MutexLock lock(&mu_);
      auto ready = [this]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
        return stop_ || !queue_.empty();
      };
      mu_.Await(absl::Condition(&ready));
      if (stop_) return;
      job = std::move(queue_.front());
      queue_.pop_front();
      running_ = job;  // shares the cancellation flag
    }
    Run(job);
    absl::MutexLock lock(&mu_);
    running_.reset();
  }
}

std::string AutoDiagnosis::Debounced(const Job& job) {
  const std::string& id = job.alert.spacecraft_id;
  absl::StatusOr<storage::ConfigRecord> config = core_->storage().configs().Get(id);
  if (!config.ok()) return absl::StrCat("its configuration cannot be read: ", config.status().ToString());
  bool cancelled = false;
  {
    absl::MutexLock lock(&mu_);
    auto it = suppressed_.find(id);
    cancelled = it != suppressed_.end() && it->second == config->version;
  }
  if (!cancelled) {
    // A cancel stored before this server started.
    absl::StatusOr<bool> stored = core_->storage().diagnoses().AutoCancelled(id, config->version);
    if (!stored.ok()) {
      return absl::StrCat("its cancels cannot be read: ", stored.status().ToString());
    }
    cancelled = *stored;
  }
  if (cancelled) {
    return absl::StrCat("an operator cancelled the automatic diagnosis under configuration "
                        "version ", config->version);
  }
  int64_t after = 0;
  for (;;) {
    absl::StatusOr<std::vector<storage::DiagnosisRecord>> page =
        core_->storage().diagnoses().ListSummaries(id, after, kSummaryPage);
    if (!page.ok()) return absl::StrCat("its diagnoses cannot be read: ", page.status().ToString());
    for (const storage::DiagnosisRecord& d : *page) {
      if (d.requested_by == storage::kRequestedByService && d.config_version == config->version &&
          d.to_time > job.alert.first_time - options_.span) {
        return absl::StrCat("automatic diagnosis #", d.id, " (to ", FormatUtc(d.to_time),
                            ") answered this configuration version ", config->version,
                            " less than --auto-diagnosis-hours before the alert");
      }
    }
    if (static_cast<int64_t>(page->size()) < kSummaryPage) return "";
    after = page->back().id;
  }
}

std::optional<CallLimiter::Permit> AutoDiagnosis::WaitForSlot(const Job& job) {
  bool logged = false;
  for (;;) {
    absl::StatusOr<CallLimiter::Permit> permit =
        limiter_->Acquire(kAutoDiagnosisCaller, "automatic diagnosis");
    if (permit.ok()) return std::move(*permit);
    if (!logged) {
      logged = true;
      LogEvent("INFO", "auto_diagnosis_waiting",
               absl::StrCat("automatic diagnosis of ", job.alert.spacecraft_id,
                            " waits for a free diagnosis slot: ", permit.status().message()),
               {{"spacecraftId", job.alert.spacecraft_id},
                {"alertSequence", job.alert.sequence}});
    }
    absl::MutexLock lock(&mu_);
    auto done = [this, &job]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
      return stop_ || job.cancelled->load();
    };
    if (mu_.AwaitWithTimeout(absl::Condition(&done), options_.slot_retry)) return std::nullopt;
  }
}

void AutoDiagnosis::Run(const Job& job) {
  const std::string& id = job.alert.spacecraft_id;
  if (const std::string why = Debounced(job); !why.empty()) {
    LogEvent("INFO", "auto_diagnosis_skipped",
             absl::StrCat("no automatic diagnosis of ", id, " for alert #", job.alert.sequence,
                          ": ", why),
             {{"spacecraftId", id}, {"alertSequence", job.alert.sequence}});
    return;
  }
  std::optional<CallLimiter::Permit> permit = WaitForSlot(job);
  absl::StatusOr<absl::Time> last = core_->LastDurableTime(id);
  if (!permit.has_value() || !last.ok() || *last == absl::InfinitePast()) {
    const std::string why = !permit.has_value() ? WhyCancelled(job)
                            : last.ok()         ? std::string("no archived frame")
                                                : last.status().ToString();
    LogEvent("INFO", "auto_diagnosis_cancelled",
             absl::StrCat("automatic diagnosis of ", id, " (", AnswersText(job.alert),
                          ") cancelled before it started: ", why),
             {{"spacecraftId", id}, {"alertSequence", job.alert.sequence}});
    return;
  }
  esg::v1::DiagnoseRequest request;
  request.set_spacecraft_id(id);
  *request.mutable_from() = proto_convert::TimeToProto(*last - options_.span);
  *request.mutable_to() = proto_convert::TimeToProto(*last);
  LogEvent("INFO", "auto_diagnosis_started",
           absl::StrCat("automatic diagnosis of ", id, " started over ",
                        FormatUtc(*last - options_.span), " .. ", FormatUtc(*last), "; it ",
                        AnswersText(job.alert)),
           {{"spacecraftId", id}, {"alertSequence", job.alert.sequence}});
  const absl::Time started = absl::Now();
  const std::shared_ptr<std::atomic<bool>> flag = job.cancelled;
  absl::StatusOr<esg::v1::DiagnosisResult> result = core_->Diagnose(
      request, [](double, const std::string&) {}, [flag] { return flag->load(); },
      DiagnosisOrigin{storage::kRequestedByService, job.alert.sequence});
  permit->Release();
  Finish(job, result, started);
}

void AutoDiagnosis::Finish(const Job& job, const absl::StatusOr<esg::v1::DiagnosisResult>& result,
                           absl::Time started) {
  const std::string& id = job.alert.spacecraft_id;
  const double seconds = absl::ToDoubleSeconds(absl::Now() - started);
  if (!result.ok() && job.cancelled->load()) {
    LogEvent("INFO", "auto_diagnosis_cancelled",
             absl::StrCat("automatic diagnosis of ", id, " (", AnswersText(job.alert),
                          ") cancelled after ", absl::FormatDuration(absl::Seconds(seconds)),
                          ": ", WhyCancelled(job), "; nothing stored"),
             {{"spacecraftId", id}, {"alertSequence", job.alert.sequence}});
    return;
  }
  if (!result.ok()) {
    LogEvent("WARN", "auto_diagnosis_finished",
             absl::StrCat("automatic diagnosis of ", id, " (", AnswersText(job.alert),
                          ") failed: ", result.status().ToString()),
             {{"spacecraftId", id},
              {"alertSequence", job.alert.sequence},
              {"result", "error"},
              {"durationSeconds", seconds}});
    return;
  }
  AlertOccurrence follow_up;
  follow_up.reason = "MODEL_DIAGNOSED";
  follow_up.subsystem = "model";
  // The diagnosis's last frame; the answered alert's time if it cannot be read.
  follow_up.time = proto_convert::TimeFromProto(result->last_frame_time())
                       .value_or(job.alert.measurement_time);
  follow_up.value = static_cast<double>(result->id());
  follow_up.threshold = static_cast<double>(job.alert.sequence);
  follow_up.message = FollowUpMessage(*result, job.alert);
  const absl::Status raised = core_->RaiseServiceAlert(id, follow_up);
  LogEvent(raised.ok() ? "INFO" : "WARN", "auto_diagnosis_finished",
           absl::StrCat("automatic diagnosis #", result->id(), " of ", id, " finished in ",
                        absl::FormatDuration(absl::Seconds(seconds)), ": verdict ",
                        result->verdict(), "; it ", AnswersText(job.alert),
                        raised.ok() ? "" : absl::StrCat("; its alert cannot be raised: ",
                                                        raised.ToString())),
           {{"spacecraftId", id},
            {"alertSequence", job.alert.sequence},
            {"diagnosisId", static_cast<int64_t>(result->id())},
            {"verdict", result->verdict()},
            {"result", "ok"},
            {"durationSeconds", seconds}});
}

}  // namespace esg::server
