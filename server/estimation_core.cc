// The service engine's life cycle: start, load (with quarantine of a spacecraft whose stored
// state cannot be used), configuration, stop (see estimation_core.h and docs/service.md).
#include "server/estimation_core.h"

#include <algorithm>
#include <string_view>
#include <utility>

#include "absl/strings/escaping.h"
#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "estimator/status_macros.h"
#include "proto/convert.h"
#include "server/alert_collapse.h"
#include "server/core_internal.h"
#include "server/log.h"
#include "storage/service_queries.h"

namespace esg::server {

using estimator::EstimationSession;

absl::Status NotConfigured(const std::string& id) {
  return absl::NotFoundError(absl::StrCat("spacecraft_id: '", absl::CHexEscape(id.substr(0, 64)),
                                          id.size() > 64 ? "...'" : "'", " is not configured"));
}

EstimationCore::EstimationCore(storage::Storage* storage, const CoreOptions& options)
    : storage_(storage),
      options_(options),
      group_filter_commits_(storage->database().dialect() == storage::Dialect::kPostgres &&
                            options.filter_commit_group > std::max(1, options.worker_threads)),
      apply_slots_free_(std::max(1, options.worker_threads)) {}

absl::StatusOr<std::unique_ptr<EstimationCore>> EstimationCore::Start(storage::Storage* storage,
                                                                      const CoreOptions& options) {
  std::unique_ptr<EstimationCore> core(new EstimationCore(storage, options));
  RETURN_IF_ERROR(core->Load());
  core->metrics_.registry.AddCollector([c = core.get()] { c->CollectGauges(); });
  core->committer_ = std::thread([c = core.get()] { c->CommitterLoop(); });
  // With the filter's group commit, threads beyond worker_threads wait for commits
  // (AcquireApplySlot keeps the applying ones to worker_threads).
  const int n = core->group_filter_commits_ ? options.filter_commit_group
                                            : std::max(1, options.worker_threads);
  for (int i = 0; i < n; ++i) core->workers_.emplace_back([c = core.get()] { c->WorkerLoop(); });
  if (core->shared()) {
    core->lease_renewer_ = std::thread([c = core.get()] { c->LeaseLoop(); });
    core->relay_ = std::thread([c = core.get()] { c->RelayLoop(); });
  }
  for (const auto& sc : core->registry_.All()) core->Schedule(sc);
  return core;
}

void EstimationCore::CollectGauges() {
  std::map<std::string, int> by_state;
  for (const char* state :
       {"NO_DATA", "CALIBRATING", "CONVERGED", "AUTONOMOUS", "FAULTED", "QUARANTINED"}) {
    by_state[state] = 0;
  }
  std::map<std::string, int> excluded;
  for (const char* reason : {"READING_JUMP", "READING_BEYOND_ANY_DRIFT", "READINGS_ERRATIC",
                             "DRIFT_CHANGE_BEYOND_LIMIT", "EXCLUDED_BEFORE_UPGRADE"}) {
    excluded[reason] = 0;
  }
  int degraded = 0;
  for (const auto& sc : registry_.All()) {
    if (sc->lease_lost) continue;  // another server's now
    absl::MutexLock state(&sc->state_mu);
    if (!sc->apply.quarantine_reason.empty() || sc->setup == nullptr || !sc->session.has_value()) {
      ++by_state["QUARANTINED"];
    } else {
      ++by_state[estimator::SessionStateName(sc->session->state())];
      degraded += sc->session->degraded() ? 1 : 0;
      for (const estimator::GyroEstimate& g : sc->session->Gyros()) {
        if (g.faulty) ++excluded[estimator::ExclusionReasonName(g.exclusion.reason)];
      }
    }
  }
  for (const auto& [state, n] : by_state) metrics_.sessions.With({state}).Set(n);
  metrics_.sessions_degraded.Set(degraded);
  for (const auto& [reason, n] : excluded) metrics_.gyros_excluded.With({reason}).Set(n);
  int64_t backlog = 0;
  {
    absl::MutexLock lock(&commit_mu_);
    backlog = commit_queue_bytes_;
  }
  metrics_.commit_backlog_bytes.Set(static_cast<double>(backlog));
  metrics_.storage_healthy.Set(StorageFault().empty() ? 1 : 0);
}

absl::Status EstimationCore::Load() {
  // With leases a session is loaded when a call for it arrives (Lookup), by one server.
  if (shared()) return absl::OkStatus();
  ASSIGN_OR_RETURN(std::vector<storage::ConfigRecord> configs, storage_->configs().List());
  for (const storage::ConfigRecord& record : configs) RETURN_IF_ERROR(LoadSpacecraft(record));
  return absl::OkStatus();
}

// A stored configuration or checkpoint that cannot be used quarantines its spacecraft only
// (docs/service.md "Session states"): the others and the server start as usual.
absl::Status EstimationCore::LoadSpacecraft(const storage::ConfigRecord& record,
                                            int64_t lease_epoch) {
  ASSIGN_OR_RETURN(std::shared_ptr<Spacecraft> sc, RestoreSpacecraft(record, /*snapshot=*/false));
  sc->lease_epoch = lease_epoch;
  registry_.Put(std::move(sc));
  return absl::OkStatus();
}

// What RestoreSpacecraft reads and decides before installing it: the archive's marks, the stored
// configuration's setup, the checkpoint and the session, and why they cannot be used.
struct EstimationCore::Restoration {
  std::map<std::string, int64_t> highest;  // per station
  absl::Time last_time = absl::InfinitePast();  // the latest archived frame's
  int64_t count = 0;  // archived frames
  std::vector<absl::Time> late_frames;
  std::vector<storage::ReadmissionRecord> readmissions;
  std::shared_ptr<Setup> setup;  // null: the stored configuration cannot be used
  ServerCheckpoint checkpoint;
  std::optional<EstimationSession> session;
  std::string config_problem;
  std::string checkpoint_problem;
};

absl::Status EstimationCore::ReadArchiveMarks(const std::string& spacecraft_id, Restoration& r) {
  using StationSequences = std::map<std::string, int64_t>;
  ASSIGN_OR_RETURN(StationSequences highest, storage_->archive().HighestSequences(spacecraft_id));
  ASSIGN_OR_RETURN(std::optional<storage::ArchivedFrame> latest,
                   storage_->archive().Latest(spacecraft_id));
  ASSIGN_OR_RETURN(int64_t count,
                   storage::CountArchivedFrames(storage_->database(), spacecraft_id));
  ASSIGN_OR_RETURN(std::vector<absl::Time> late_frames,
                   storage_->reorder().LateFrames(spacecraft_id));
  ASSIGN_OR_RETURN(std::vector<storage::ReadmissionRecord> readmissions,
                   storage_->sessions().ListReadmissions(spacecraft_id));
  r.highest = std::move(highest);
  r.last_time = latest.has_value() ? latest->measurement_time : absl::InfinitePast();
  r.count = count;
  r.late_frames = std::move(late_frames);
  r.readmissions = std::move(readmissions);
  return absl::OkStatus();
}

void EstimationCore::SetupFromStoredConfig(const storage::ConfigRecord& record, Restoration& r) {
  absl::StatusOr<estimator::SpacecraftConfig> config =
      proto_convert::ParseConfigJson(record.config_json);
  if (!config.ok()) {
    r.config_problem =
        absl::StrCat("the stored configuration cannot be used (", config.status().message(), ")");
    return;
  }
  r.setup = std::make_shared<Setup>();
  r.setup->config = *config;
  for (const auto& g : config->gyros) {
    if (g.id >= 1 && g.id <= estimator::kMaxGyros) r.setup->configured[g.id - 1] = true;
  }
}

absl::Status EstimationCore::ReadStoredCheckpoint(const std::string& spacecraft_id,
                                                  Restoration& r) {
  absl::StatusOr<storage::CheckpointRecord> stored =
      storage_->sessions().GetCheckpoint(spacecraft_id);
  if (absl::IsNotFound(stored.status())) {
    if (r.count > 0) r.checkpoint_problem = "its checkpoint is missing";
    return absl::OkStatus();
  }
  if (!stored.ok()) return stored.status();
  absl::StatusOr<ServerCheckpoint> decoded = DecodeCheckpoint(stored->state_blob);
  if (!decoded.ok()) {
    r.checkpoint_problem =
        absl::StrCat("its checkpoint cannot be decoded (", decoded.status().message(), ")");
    return absl::OkStatus();
  }
  ServerCheckpoint& checkpoint = r.checkpoint;
  checkpoint = std::move(*decoded);
  if (checkpoint.cursor_from_sequence && stored->last_sequence > 0) {
    // Format 1 kept the last applied sequence of the single station.
    ASSIGN_OR_RETURN(std::optional<storage::ArchivedFrame> at,
                     storage_->archive().Find(spacecraft_id, storage::kDefaultStation,
                                              stored->last_sequence));
    if (at.has_value()) {
      checkpoint.applied_time = at->measurement_time;
      checkpoint.applied_station = at->station_id;
      checkpoint.applied_sequence = at->sequence;
    } else {
      r.checkpoint_problem = absl::StrCat("its checkpoint is ahead of the archive (sequence ",
                                          stored->last_sequence, " is not archived)");
    }
  }
  if (r.checkpoint_problem.empty() && checkpoint.applied_time > r.last_time) {
    r.checkpoint_problem =
        absl::StrCat("its checkpoint is ahead of the archive (applied up to ",
                     FormatUtc(checkpoint.applied_time), ", archive up to ",
                     r.last_time == absl::InfinitePast() ? "nothing" : FormatUtc(r.last_time),
                     ")");
  }
  return absl::OkStatus();
}

void EstimationCore::RestoreSession(Restoration& r) {
  ServerCheckpoint& checkpoint = r.checkpoint;
  if (checkpoint.model.empty()) checkpoint.model = kDefaultModel;
  if (r.setup != nullptr) {
    absl::StatusOr<estimator::ModelSpec> model = estimator::ParseModel(checkpoint.model);
    if (!model.ok()) {
      r.checkpoint_problem =
          absl::StrCat("its checkpoint names an unknown model (", model.status().message(), ")");
      model = estimator::ParseModel(kDefaultModel);
      checkpoint.model = kDefaultModel;
    }
    r.setup->model = *model;
    r.setup->model_name = r.setup->model.Name();
    const estimator::SessionOptions session_options{r.setup->model};
    if (r.checkpoint_problem.empty() && checkpoint.session.has_value()) {
      absl::StatusOr<EstimationSession> restored =
          EstimationSession::FromCheckpoint(r.setup->config, session_options, *checkpoint.session);
      if (restored.ok()) {
        r.session = std::move(*restored);
      } else {
        r.checkpoint_problem =
            absl::StrCat("its checkpoint cannot be restored (", restored.status().message(), ")");
      }
    }
    if (!r.session.has_value()) {
      absl::StatusOr<EstimationSession> fresh =
          EstimationSession::Create(r.setup->config, session_options);
      if (fresh.ok()) {
        r.session = std::move(*fresh);
      } else {
        r.config_problem = absl::StrCat("the stored configuration cannot be used (",
                                        fresh.status().message(), ")");
        r.setup = nullptr;
      }
    }
  }
  checkpoint.session.reset();
}

absl::StatusOr<std::string> EstimationCore::QuarantineReason(const std::string& spacecraft_id,
                                                             Restoration& r) {
  std::string reason;
  if (!r.config_problem.empty()) {
    reason = absl::StrCat(r.config_problem,
                          "; frames are refused until ConfigureSpacecraft with replace=true");
    r.checkpoint.rebuilding = false;
  } else if (!r.checkpoint_problem.empty()) {
    // Rebuild from the archive: a fresh session replays every frame; what is already stored
    // (coefficient history, alerts) is not written again.
    const std::string model = r.checkpoint.model;
    ServerCheckpoint fresh;
    fresh.model = model;
    ASSIGN_OR_RETURN(fresh.effects_written_until,
                     storage::LatestEffectTime(storage_->database(), spacecraft_id));
    r.checkpoint = std::move(fresh);
    reason = absl::StrCat(r.checkpoint_problem, "; rebuilding the session from the archive");
    r.checkpoint.rebuilding = true;
  }
  if (!reason.empty()) r.checkpoint.quarantine_reason = reason;
  return reason;
}

void EstimationCore::InstallRestoration(Spacecraft& sc, Restoration& r, const std::string& reason) {
  {
    absl::MutexLock lock(&sc.ingest_mu);
    sc.ingest_setup = r.setup;
    sc.highest_accepted = r.highest;
    sc.last_accepted_time = r.last_time;
  }
  {
    absl::MutexLock lock(&sc.state_mu);
    sc.setup = r.setup;
    sc.highest_durable = r.highest;
    sc.last_durable_time = r.last_time;
    sc.frames_accepted = r.count;
    if (r.session.has_value()) sc.session = std::move(*r.session);
    if (!reason.empty()) {
      sc.service_alerts.push_back(
          {kQuarantineAlertReason, "DISTRESS", "session",
           r.last_time == absl::InfinitePast() ? absl::UnixEpoch() : r.last_time, 0.0, 0.0, "",
           reason});
    }
    sc.apply = std::move(r.checkpoint);
    sc.replay_from_archive = true;
    sc.late_frames.insert(r.late_frames.begin(), r.late_frames.end());
    sc.readmissions = std::move(r.readmissions);
  }
}

absl::StatusOr<std::shared_ptr<EstimationCore::Spacecraft>> EstimationCore::RestoreSpacecraft(
    const storage::ConfigRecord& record, bool snapshot) {
  auto sc = std::make_shared<Spacecraft>(record.spacecraft_id);
  Restoration r;
  RETURN_IF_ERROR(ReadArchiveMarks(record.spacecraft_id, r));
  // The configuration.
  SetupFromStoredConfig(record, r);
  // The checkpoint: decoded, restored, and consistent with the archive; else rebuilt.
  RETURN_IF_ERROR(ReadStoredCheckpoint(record.spacecraft_id, r));
  RestoreSession(r);
  ASSIGN_OR_RETURN(const std::string reason, QuarantineReason(record.spacecraft_id, r));
  if (!reason.empty() && !snapshot) {
    LogEvent("ERROR", "session_quarantined",
             absl::StrCat("spacecraft ", sc->id, " quarantined: ", reason),
             {{"spacecraftId", sc->id}});
  }
  InstallRestoration(*sc, r, reason);
  if (snapshot) return sc;
  const std::string model_name = r.setup != nullptr ? r.setup->model_name : "-";
  LogEvent("INFO", "spacecraft_loaded",
           absl::StrCat("loaded spacecraft ", sc->id, ": model ", model_name, ", ", r.count,
                        " archived frames, applied up to ",
                        sc->apply.applied_time == absl::InfinitePast()
                            ? "nothing"
                            : FormatUtc(sc->apply.applied_time)),
           {{"spacecraftId", sc->id}, {"archivedFrames", r.count}});
  return sc;
}

EstimationCore::~EstimationCore() { Stop(absl::ZeroDuration()); }

void EstimationCore::CloseIngest() {
  {
    absl::MutexLock lock(&commit_mu_);
    ingest_closed_ = true;
  }
  std::map<int64_t, std::function<void()>> streams;
  {
    absl::MutexLock lock(&streams_mu_);
    streams_closed_ = true;
    streams.swap(ingest_streams_);
  }
  for (auto& [id, close] : streams) close();
}

int64_t EstimationCore::AddIngestStream(std::function<void()> on_close) {
  bool closed = false;
  int64_t id = 0;
  {
    absl::MutexLock lock(&streams_mu_);
    id = ++next_stream_id_;
    closed = streams_closed_;
    if (!closed) ingest_streams_.emplace(id, std::move(on_close));
  }
  if (closed) on_close();
  return id;
}

void EstimationCore::RemoveIngestStream(int64_t id) {
  absl::MutexLock lock(&streams_mu_);
  ingest_streams_.erase(id);
}

void EstimationCore::Stop(absl::Duration drain_deadline) {
  {
    absl::MutexLock lock(&stop_mu_);
    if (stopped_) return;
    stopped_ = true;
  }
  hub_.CloseAll();
  estimate_hub_.CloseAll();
  CloseIngest();
  {
    absl::MutexLock lock(&commit_mu_);
    commit_stop_ = true;
  }
  if (committer_.joinable()) committer_.join();
  // Let the workers catch up with the durable backlog, within the deadline.
  const absl::Time deadline = absl::Now() + drain_deadline;
  while (absl::Now() < deadline) {
    bool busy = false;
    {
      absl::MutexLock lock(&pool_mu_);
      busy = !ready_.empty();
    }
    if (!busy) {
      for (const auto& sc : registry_.All()) {
        absl::MutexLock state(&sc->state_mu);
        if (sc->session.has_value() && sc->setup != nullptr && !sc->apply.FilterStopped() &&
            (sc->replay_from_archive || !sc->ready.empty() || !sc->late_frames.empty())) {
          busy = true;
        }
      }
    }
    if (!busy) break;
    absl::SleepFor(absl::Milliseconds(10));
  }
  {
    absl::MutexLock lock(&pool_mu_);
    pool_stop_ = true;
  }
  for (std::thread& t : workers_) t.join();
  workers_.clear();
  if (lease_renewer_.joinable()) lease_renewer_.join();
  if (relay_.joinable()) relay_.join();
  // Nothing of this server writes any more: another server may take each session at once
  // instead of waiting for the expiry.
  if (shared()) {
    for (const auto& sc : registry_.All()) {
      if (sc->lease_lost) continue;
      const absl::Status released = storage_->leases().Release(sc->id, *FenceOf(*sc));
      if (released.ok()) {
        metrics_.lease_events.With({"released"}).Increment();
      } else {
        LogEvent("WARN", "lease_release_failed",
                 absl::StrCat("cannot release the session lease of ", sc->id, ": ",
                              released.message(), " (it expires by itself)"),
                 {{"spacecraftId", sc->id}});
      }
    }
  }
}

std::shared_ptr<EstimationCore::Spacecraft> EstimationCore::Find(const std::string& id) {
  return registry_.Find(id);
}

std::vector<std::string> EstimationCore::SpacecraftIds() {
  std::vector<std::string> ids;
  for (const auto& sc : registry_.All()) ids.push_back(sc->id);
  if (shared()) {
    // Also those other servers hold (a read error leaves this server's own).
    absl::StatusOr<std::vector<storage::ConfigRecord>> configs = storage_->configs().List();
    if (configs.ok()) {
      for (const storage::ConfigRecord& c : *configs) ids.push_back(c.spacecraft_id);
    }
  }
  std::sort(ids.begin(), ids.end());
  ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
  return ids;
}

absl::Status EstimationCore::CheckSpacecraft(const std::string& spacecraft_id) {
  if (spacecraft_id.empty()) return absl::OkStatus();
  return CheckConfigured(spacecraft_id);
}

absl::Status EstimationCore::WaitApplied(const std::string& spacecraft_id, absl::Duration timeout) {
  std::shared_ptr<Spacecraft> sc = Find(spacecraft_id);
  if (sc == nullptr) return NotConfigured(spacecraft_id);
  const absl::Time deadline = absl::Now() + timeout;
  for (;;) {
    {
      absl::MutexLock lock(&sc->state_mu);
      if (!sc->replay_from_archive && sc->ready.empty() && !sc->apply.Rebuilding() &&
          sc->late_frames.empty() && sc->apply.applied_time >= sc->last_durable_time) {
        return absl::OkStatus();
      }
      if (sc->apply.FilterStopped()) {
        return absl::FailedPreconditionError(
            absl::StrCat(spacecraft_id, " is quarantined: ", sc->apply.quarantine_reason));
      }
    }
    if (absl::Now() > deadline) {
      return absl::DeadlineExceededError(
          absl::StrCat(spacecraft_id, ": frames still being applied"));
    }
    absl::SleepFor(absl::Milliseconds(2));
  }
}

void EstimationCore::SetStorageHealthListener(
    std::function<void(bool ok, const std::string& reason)> listener) {
  absl::MutexLock lock(&listener_mu_);
  storage_listener_ = std::move(listener);
}

std::string EstimationCore::StorageFault() {
  absl::MutexLock lock(&commit_mu_);
  if (!storage_fault_.empty()) return storage_fault_;
  return apply_faults_.empty() ? "" : apply_faults_.begin()->second;
}

// ---------------------------------------------------------------------------------------------
// Configuration.

// A configuration call's new setup, fresh session and what it stores, with what the store and the
// publication after it need.
struct EstimationCore::Configuration {
  std::shared_ptr<Setup> setup;
  std::optional<EstimationSession> fresh;
  ServerCheckpoint checkpoint;
  storage::CheckpointRecord cp;
  storage::ConfigRecord record;
  // A quarantine that the reconfiguration ends: its alert is cleared as the apply worker clears
  // one (AlertCollapser::End: cleared_time stored, then published and logged once committed).
  std::optional<AlertCollapser> quarantine_end;
  std::vector<int64_t> revised_alerts;  // the old session's, revised by the new one
  bool new_session = false;  // replaces a session: its window checkpoints and late frames go
  std::vector<int64_t> ended_sequences;  // stored by this transaction, to publish after it
  std::optional<storage::LeaseFence> fence;  // with leases: this server's lease of the session
};

absl::StatusOr<EstimationCore::Configuration> EstimationCore::PrepareConfiguration(
    const esg::v1::ConfigureRequest& request) {
  if (!request.has_config()) return absl::InvalidArgumentError("config: required");
  ASSIGN_OR_RETURN(estimator::SpacecraftConfig config,
                   proto_convert::ConfigFromProto(request.config()));
  const std::string model_text = request.model().empty() ? kDefaultModel : request.model();
  ASSIGN_OR_RETURN(estimator::ModelSpec model, estimator::ParseModel(model_text));
  const estimator::SessionOptions session_options{model};
  ASSIGN_OR_RETURN(EstimationSession fresh, EstimationSession::Create(config, session_options));

  Configuration c;
  c.fresh = std::move(fresh);
  auto setup = std::make_shared<Setup>();
  setup->config = config;
  setup->model = model;
  setup->model_name = model.Name();
  for (const auto& g : config.gyros) setup->configured[g.id - 1] = true;
  c.setup = setup;

  c.checkpoint.model = setup->model_name;
  c.cp.spacecraft_id = config.spacecraft_id;
  c.cp.last_sequence = 0;
  c.cp.compute_time = absl::Now();
  c.record.spacecraft_id = config.spacecraft_id;
  c.record.config_json = proto_convert::ConfigToJson(config);
  c.record.updated_time = c.cp.compute_time;
  return c;
}

namespace {

// Whether a stored configuration's JSON holds the same values as a new one: both parsed and
// written afresh (ConfigToJson), so the same values given another way (a coefficient by its field
// or keyed, keys in another order, other whitespace, the form an older esgd wrote) are the same
// configuration and store no new version. A stored text that no longer parses is not the same.
bool SameConfiguration(absl::string_view stored_json, absl::string_view new_json) {
  if (stored_json == new_json) return true;
  absl::StatusOr<estimator::SpacecraftConfig> stored =
      proto_convert::ParseConfigJson(std::string_view(stored_json.data(), stored_json.size()));
  absl::StatusOr<estimator::SpacecraftConfig> fresh =
      proto_convert::ParseConfigJson(std::string_view(new_json.data(), new_json.size()));
  return stored.ok() && fresh.ok() &&
         proto_convert::ConfigToJson(*stored) == proto_convert::ConfigToJson(*fresh);
}

}  // namespace

absl::Status EstimationCore::StoreConfiguration(Configuration& c) {
  const absl::Time commit_start = absl::Now();
  const absl::Status status = [&]() -> absl::Status {
    c.cp.state_blob = EncodeCheckpoint(c.checkpoint);
    storage::ConfigurationChange change;
    change.config = c.record;
    change.same_config = SameConfiguration;
    change.checkpoint = c.cp;
    change.new_session = c.new_session;
    change.revised_alerts = c.revised_alerts;
    change.fence = c.fence;
    if (c.quarantine_end.has_value()) {
      change.new_alerts = c.quarantine_end->new_alerts();
      for (const AlertCollapser::Clear& clear : c.quarantine_end->clears()) {
        change.clears.push_back({clear.sequence, clear.time});
      }
    }
    ASSIGN_OR_RETURN(c.ended_sequences, storage_->CommitConfiguration(change));
    for (const storage::AlertClear& clear : change.clears) {
      c.ended_sequences.push_back(clear.sequence);
    }
    return absl::OkStatus();
  }();
  metrics_.storage_commit.With({"configure"}).Observe(
      absl::ToDoubleSeconds(absl::Now() - commit_start));
  return status;
}

absl::StatusOr<std::shared_ptr<EstimationCore::Spacecraft>> EstimationCore::FindForConfigure(
    const std::string& spacecraft_id, Configuration& c, int64_t* new_lease_epoch) {
  if (absl::StatusOr<std::shared_ptr<Spacecraft>> found = Lookup(spacecraft_id); found.ok()) {
    std::shared_ptr<Spacecraft> sc = *std::move(found);
    c.fence = FenceOf(*sc);
    return sc;
  } else if (!absl::IsNotFound(found.status())) {
    return found.status();
  } else if (shared()) {
    absl::StatusOr<storage::SessionLease> lease = storage_->leases().Acquire(
        spacecraft_id, options_.node_id, absl::Now(), options_.lease_duration);
    if (!lease.ok()) return LeaseRefused(lease.status());
    *new_lease_epoch = lease->epoch;
    metrics_.lease_events.With({"taken"}).Increment();
    c.fence = storage::LeaseFence{options_.node_id, *new_lease_epoch};
  }
  return std::shared_ptr<Spacecraft>();
}

absl::StatusOr<esg::v1::ConfigureResponse> EstimationCore::ConfigureNewSpacecraft(
    Configuration& c, int64_t lease_epoch) {
  RETURN_IF_ERROR(StoreConfiguration(c));
  auto sc = std::make_shared<Spacecraft>(c.record.spacecraft_id);
  sc->lease_epoch = lease_epoch;
  {
    absl::MutexLock lock(&sc->ingest_mu);
    sc->ingest_setup = c.setup;
  }
  {
    absl::MutexLock lock(&sc->state_mu);
    sc->setup = c.setup;
    sc->session = std::move(*c.fresh);
    sc->apply = c.checkpoint;
    sc->replay_from_archive = false;
  }
  registry_.Put(sc);
  LogEvent("INFO", "spacecraft_configured",
           absl::StrCat("configured new spacecraft ", sc->id, ", model ", c.setup->model_name),
           {{"spacecraftId", sc->id}, {"model", c.setup->model_name}, {"created", true}});
  esg::v1::ConfigureResponse response;
  response.set_created(true);
  *response.mutable_session() = SessionInfoToProto(Summarize(*sc));
  return response;
}

void EstimationCore::EndQuarantineAtReconfiguration(Spacecraft& sc, Configuration& c) {
  // The quarantine ends at the reconfiguration: in telemetry time, at the latest archived
  // frame (every frame up to it was under the quarantine), or at the alert's own latest
  // occurrence when that is later (nothing archived). A quarantine raised at load whose
  // alert no job has stored yet is stored raised and cleared.
  absl::Time end = sc.last_durable_time;
  std::vector<AlertOccurrence> raised;
  for (const AlertOccurrence& o : sc.service_alerts) {
    if (o.reason == kQuarantineAlertReason) raised.push_back(o);
  }
  for (const AlertOccurrence& o : raised) end = std::max(end, o.time);
  for (const AlertTrack& t : sc.apply.alert_tracks) {
    if (t.reason == kQuarantineAlertReason) end = std::max(end, t.last_time);
  }
  if (end == absl::InfinitePast()) end = absl::UnixEpoch();
  c.quarantine_end.emplace(sc.id, sc.apply.alert_tracks, options_.alert_collapse_window,
                           c.cp.compute_time);
  for (const AlertOccurrence& o : raised) c.quarantine_end->Add(o);
  c.quarantine_end->End(kQuarantineAlertReason, "session", end);
}

absl::Status EstimationCore::ReplaceSessionIfChanged(Spacecraft& sc, Configuration& c,
                                                     bool replace) {
  absl::MutexLock ingest(&sc.ingest_mu);
  absl::MutexLock state(&sc.state_mu);
  const Setup& setup = *c.setup;
  const bool quarantined = !sc.apply.quarantine_reason.empty();
  // Both in the JSON this program writes (a stored configuration of an older one compares by
  // what it says, not by how it was written).
  const bool same = sc.setup != nullptr &&
                    proto_convert::ConfigToJson(sc.setup->config) == c.record.config_json &&
                    sc.setup->model_name == setup.model_name;
  if (same && !(quarantined && replace)) return absl::OkStatus();
  if (!sc.highest_accepted.empty() && !replace) {
    return absl::FailedPreconditionError(
        absl::StrCat("config: spacecraft '", sc.id, "' already has telemetry (up to ",
                     FormatUtc(sc.last_accepted_time),
                     "); set replace=true to recreate its session and reapply the archive"));
  }
  // The new session replays the whole archive and stores its own history and alerts (a
  // different model gives a different history); the earlier ones are kept, revised.
  if (quarantined) EndQuarantineAtReconfiguration(sc, c);
  // The old session's snapshots and filter alerts are superseded by the new session's
  // (revised, kept for audit); the job lock keeps the worker from adding any meanwhile.
  ASSIGN_OR_RETURN(c.revised_alerts, FilterAlertsAfter(sc.id, absl::InfinitePast()));
  c.new_session = true;
  RETURN_IF_ERROR(StoreConfiguration(c));
  sc.late_frames.clear();
  std::erase_if(sc.service_alerts,
                [](const AlertOccurrence& o) { return o.reason == kQuarantineAlertReason; });
  sc.ingest_setup = c.setup;
  sc.setup = c.setup;
  sc.session = std::move(*c.fresh);
  sc.apply = c.checkpoint;
  ++sc.generation;
  sc.ready.clear();
  sc.ready_bytes = 0;
  sc.replay_from_archive = true;
  LogEvent("INFO", "spacecraft_configured",
           absl::StrCat("reconfigured spacecraft ", sc.id, ", model ", setup.model_name,
                        "; reapplying the archive", quarantined ? "; quarantine over" : ""),
           {{"spacecraftId", sc.id}, {"model", setup.model_name}, {"created", false}});
  return absl::OkStatus();
}

void EstimationCore::PublishReconfiguration(Spacecraft& sc, const Configuration& c) {
  // Publish (and log) the cleared quarantine alerts once committed, in the worker's order:
  // under publish_mu, with the job lock held (not the state locks) so no job of the new session
  // publishes first.
  absl::MutexLock publish(&sc.publish_mu);
  // Subscribers receive the superseded alerts again with revised_time set.
  for (int64_t seq : c.revised_alerts) {
    absl::StatusOr<storage::AlertRecord> r = storage_->alerts().Get(sc.id, seq);
    if (r.ok()) hub_.Publish(*r);
  }
  // ended_sequences: the alerts stored new by this transaction first, then the cleared ones.
  const size_t raised = c.quarantine_end.has_value() ? c.quarantine_end->new_alerts().size() : 0;
  for (size_t k = 0; k < c.ended_sequences.size(); ++k) {
    const int64_t seq = c.ended_sequences[k];
    absl::StatusOr<storage::AlertRecord> r = storage_->alerts().Get(sc.id, seq);
    if (r.ok()) {
      if (k < raised) metrics_.alerts_raised.With({r->reason, r->severity}).Increment();
      if (r->cleared) metrics_.alerts_cleared.With({r->reason, r->severity}).Increment();
      hub_.Publish(*r);
    } else {
      LogEvent("ERROR", "storage_error",
               absl::StrCat(sc.id, ": the cleared quarantine alert #", seq,
                            " cannot be read back: ", r.status().ToString()),
               {{"spacecraftId", sc.id}, {"alertSequence", seq}});
    }
  }
}

absl::StatusOr<esg::v1::ConfigureResponse> EstimationCore::Configure(
    const esg::v1::ConfigureRequest& request, const std::function<absl::Status()>& precondition) {
  ASSIGN_OR_RETURN(Configuration c, PrepareConfiguration(request));
  absl::MutexLock configure(&configure_mu_);
  if (precondition) RETURN_IF_ERROR(precondition());
  int64_t new_lease_epoch = 0;  // a new spacecraft's lease, with leases
  ASSIGN_OR_RETURN(std::shared_ptr<Spacecraft> sc,
                   FindForConfigure(c.record.spacecraft_id, c, &new_lease_epoch));
  if (sc == nullptr) return ConfigureNewSpacecraft(c, new_lease_epoch);
  {
    absl::MutexLock job(&sc->job_mu);
    RETURN_IF_ERROR(ReplaceSessionIfChanged(*sc, c, request.replace()));
    PublishReconfiguration(*sc, c);
  }
  // The automatic diagnosis of the old configuration is stale (auto_diagnosis.h).
  if (c.new_session) NotifyConfigured(sc->id);
  Schedule(sc);
  esg::v1::ConfigureResponse response;
  response.set_created(false);
  *response.mutable_session() = SessionInfoToProto(Summarize(*sc));
  return response;
}

}  // namespace esg::server
