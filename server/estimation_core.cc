// The service engine: registry, group-commit ingest, per-spacecraft apply workers, alerts and
// queries (see estimation_core.h and docs/service.md).
#include "server/estimation_core.h"

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <set>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/time/clock.h"
#include "estimator/discovery/diagnose.h"
#include "proto/diagnosis_json.h"
#include "estimator/conventions.h"
#include "estimator/rotation.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"
#include "proto/convert.h"
#include "server/log.h"
#include "server/planned_profile.h"
#include "storage/aem.h"
#include "storage/coefficient_store.h"
#include "storage/service_queries.h"

namespace esg::server {

using estimator::Event;
using estimator::EstimationSession;
using estimator::TelemetryFrame;

namespace {

constexpr const char* kDefaultModel = "10+11";
// Durable frames kept in memory for the filter; beyond this it reads the archive.
constexpr size_t kMaxReadyFrames = 20000;

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

void QuaternionToProto(const Eigen::Quaterniond& q_in_b,
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

// "field: reason" -> Rejection (proto/convert.h error contract).
esg::v1::Rejection RejectionFromStatus(const absl::Status& status) {
  esg::v1::Rejection r;
  const absl::string_view m = status.message();
  const size_t colon = m.find(": ");
  if (colon == absl::string_view::npos) {
    r.set_field("frame");
    r.set_reason(std::string(m));
  } else {
    r.set_field(std::string(m.substr(0, colon)));
    r.set_reason(std::string(m.substr(colon + 2)));
  }
  return r;
}

std::string FormatUtc(absl::Time t) {
  return absl::FormatTime(absl::RFC3339_full, t, absl::UTCTimeZone());
}

absl::Status NotConfigured(const std::string& id) {
  return absl::NotFoundError(absl::StrCat("spacecraft_id: '", id, "' is not configured"));
}

}  // namespace

esg::v1::AlertSeverity SeverityOf(Event::Kind kind) {
  switch (kind) {
    case Event::Kind::kStarTrackerInnovation:
      return esg::v1::ALERT_SEVERITY_WARNING;
    case Event::Kind::kStarTrackerFault:
      return esg::v1::ALERT_SEVERITY_DISTRESS;
    case Event::Kind::kWorkingPairFault:
      return esg::v1::ALERT_SEVERITY_CRITICAL;
    case Event::Kind::kReservePairFault:
      return esg::v1::ALERT_SEVERITY_DISTRESS;
    case Event::Kind::kGyroDataRejected:
      return esg::v1::ALERT_SEVERITY_WARNING;
    case Event::Kind::kStarTrackerInvalid:
      return esg::v1::ALERT_SEVERITY_INFO;
    case Event::Kind::kFilterReset:
      return esg::v1::ALERT_SEVERITY_DISTRESS;
  }
  return esg::v1::ALERT_SEVERITY_UNSPECIFIED;
}

esg::v1::AlertReason ReasonOf(Event::Kind kind) {
  switch (kind) {
    case Event::Kind::kStarTrackerInnovation:
      return esg::v1::ALERT_REASON_STAR_TRACKER_INNOVATION;
    case Event::Kind::kStarTrackerFault:
      return esg::v1::ALERT_REASON_STAR_TRACKER_FAULT;
    case Event::Kind::kWorkingPairFault:
      return esg::v1::ALERT_REASON_WORKING_PAIR_FAULT;
    case Event::Kind::kReservePairFault:
      return esg::v1::ALERT_REASON_RESERVE_PAIR_FAULT;
    case Event::Kind::kGyroDataRejected:
      return esg::v1::ALERT_REASON_GYRO_DATA_REJECTED;
    case Event::Kind::kStarTrackerInvalid:
      return esg::v1::ALERT_REASON_STAR_TRACKER_INVALID;
    case Event::Kind::kFilterReset:
      return esg::v1::ALERT_REASON_FILTER_RESET;
  }
  return esg::v1::ALERT_REASON_UNSPECIFIED;
}

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
  a.set_message(r.message);
  return a;
}

esg::v1::CoefficientSnapshot SnapshotToProto(const storage::CoefficientRecord& r) {
  esg::v1::CoefficientSnapshot s;
  s.set_spacecraft_id(r.spacecraft_id);
  s.set_gyro_id(r.gyro_id);
  *s.mutable_measurement_time() = proto_convert::TimeToProto(r.measurement_time);
  *s.mutable_compute_time() = proto_convert::TimeToProto(r.compute_time);
  // The stored layout is already deg/h and arcsec (storage/records.h): copied as stored.
  auto fill = [](const std::vector<double>& v, esg::v1::GyroDriftModel* m,
                 google::protobuf::RepeatedField<double>* misalignment) {
    if (v.size() != static_cast<size_t>(storage::kNumCoefficientValues)) return;
    m->set_k0_deg_h(v[storage::kCoefficientK0]);
    for (int i = 0; i < 3; ++i) {
      m->add_c1_deg_h(v[storage::kCoefficientC1 + i]);
      m->add_c2_deg_h(v[storage::kCoefficientC2 + i]);
      m->add_mu_deg_h(v[storage::kCoefficientMu + i]);
      m->add_nu_deg_h(v[storage::kCoefficientNu + i]);
      misalignment->Add(v[storage::kCoefficientMisalignment + i]);
    }
  };
  fill(r.values, s.mutable_model(), s.mutable_misalignment_arcsec());
  fill(r.sigmas, s.mutable_sigma(), s.mutable_misalignment_sigma_arcsec());
  return s;
}

// ---------------------------------------------------------------------------------------------

struct EstimationCore::Setup {
  estimator::SpacecraftConfig config;
  esg::v1::SpacecraftConfig proto;
  estimator::ModelSpec model;
  std::string model_name;
  std::string config_json;
  std::array<bool, estimator::kMaxGyros> configured{};
};

struct EstimationCore::Spacecraft {
  explicit Spacecraft(std::string spacecraft_id) : id(std::move(spacecraft_id)) {}
  const std::string id;

  // Held for a whole worker job and by a reconfiguration.
  absl::Mutex job_mu;

  // Ingest side.
  absl::Mutex ingest_mu ABSL_ACQUIRED_AFTER(job_mu);
  std::shared_ptr<const Setup> ingest_setup ABSL_GUARDED_BY(ingest_mu);
  int64_t highest_accepted ABSL_GUARDED_BY(ingest_mu) = 0;
  absl::Time last_accepted_time ABSL_GUARDED_BY(ingest_mu) = absl::InfinitePast();
  int64_t frames_rejected ABSL_GUARDED_BY(ingest_mu) = 0;
  int64_t frames_duplicate ABSL_GUARDED_BY(ingest_mu) = 0;

  // Durable and applied state.
  absl::Mutex state_mu ABSL_ACQUIRED_AFTER(ingest_mu);
  std::shared_ptr<const Setup> setup ABSL_GUARDED_BY(state_mu);
  int64_t highest_durable ABSL_GUARDED_BY(state_mu) = 0;
  absl::Time last_durable_time ABSL_GUARDED_BY(state_mu) = absl::InfinitePast();
  int64_t frames_accepted ABSL_GUARDED_BY(state_mu) = 0;
  std::map<int64_t, TelemetryFrame> ready ABSL_GUARDED_BY(state_mu);  // durable, not applied
  std::optional<EstimationSession> session ABSL_GUARDED_BY(state_mu);
  ServerCheckpoint apply ABSL_GUARDED_BY(state_mu);  // counters, tracks (session unused)
  int64_t applied_sequence ABSL_GUARDED_BY(state_mu) = 0;
  int64_t generation ABSL_GUARDED_BY(state_mu) = 0;
  bool replay_from_archive ABSL_GUARDED_BY(state_mu) = true;
  absl::Time last_compute_time ABSL_GUARDED_BY(state_mu) = absl::InfinitePast();

  // Orders alert publication (worker) with acknowledgements (rpc threads).
  absl::Mutex publish_mu;

  // Worker scheduling, guarded by EstimationCore::pool_mu_.
  bool scheduled = false;
  bool wake = false;
};

struct EstimationCore::CommitEntry {
  std::shared_ptr<Spacecraft> sc;
  bool barrier = false;  // no frame: completes with the next commit (duplicate of a pending frame)
  int64_t sequence = 0;
  absl::Time time;
  std::string payload;
  TelemetryFrame frame;
  std::function<void()> done;
};

// ---------------------------------------------------------------------------------------------
// Start, load, stop.

EstimationCore::EstimationCore(storage::Storage* storage, const CoreOptions& options)
    : storage_(storage), options_(options) {}

absl::StatusOr<std::unique_ptr<EstimationCore>> EstimationCore::Start(
    storage::Storage* storage, const CoreOptions& options) {
  std::unique_ptr<EstimationCore> core(new EstimationCore(storage, options));
  RETURN_IF_ERROR(core->Load());
  core->committer_ = std::thread([c = core.get()] { c->CommitterLoop(); });
  const int n = std::max(1, options.worker_threads);
  for (int i = 0; i < n; ++i) core->workers_.emplace_back([c = core.get()] { c->WorkerLoop(); });
  {
    absl::MutexLock lock(&core->registry_mu_);
    for (auto& [id, sc] : core->registry_) core->Schedule(sc);
  }
  return core;
}

absl::Status EstimationCore::Load() {
  ASSIGN_OR_RETURN(std::vector<storage::ConfigRecord> configs, storage_->configs().List());
  for (const storage::ConfigRecord& record : configs) {
    auto sc = std::make_shared<Spacecraft>(record.spacecraft_id);
    auto setup = std::make_shared<Setup>();
    absl::StatusOr<estimator::SpacecraftConfig> config =
        proto_convert::ParseConfigJson(record.config_json);
    if (!config.ok()) {
      return absl::DataLossError(absl::StrCat("stored configuration of '", record.spacecraft_id,
                                              "': ", config.status().message()));
    }
    setup->config = *config;
    setup->proto = proto_convert::ConfigToProto(*config);
    setup->config_json = record.config_json;
    for (const auto& g : config->gyros) {
      if (g.id >= 1 && g.id <= estimator::kMaxGyros) setup->configured[g.id - 1] = true;
    }
    ServerCheckpoint checkpoint;
    int64_t last_sequence = 0;
    absl::StatusOr<storage::CheckpointRecord> record_cp =
        storage_->sessions().GetCheckpoint(record.spacecraft_id);
    if (record_cp.ok()) {
      ASSIGN_OR_RETURN(checkpoint, DecodeCheckpoint(record_cp->state_blob));
      last_sequence = record_cp->last_sequence;
    } else if (!absl::IsNotFound(record_cp.status())) {
      return record_cp.status();
    }
    if (checkpoint.model.empty()) checkpoint.model = kDefaultModel;
    ASSIGN_OR_RETURN(setup->model, estimator::ParseModel(checkpoint.model));
    setup->model_name = setup->model.Name();
    const estimator::SessionOptions session_options{setup->model};
    absl::StatusOr<EstimationSession> session =
        checkpoint.session.has_value()
            ? EstimationSession::FromCheckpoint(setup->config, session_options, *checkpoint.session)
            : EstimationSession::Create(setup->config, session_options);
    if (!session.ok()) {
      return absl::DataLossError(absl::StrCat("checkpoint of '", record.spacecraft_id,
                                              "': ", session.status().message()));
    }
    ASSIGN_OR_RETURN(std::optional<int64_t> highest,
                     storage_->archive().HighestSequence(record.spacecraft_id));
    ASSIGN_OR_RETURN(int64_t count,
                     storage::CountArchivedFrames(storage_->database(), record.spacecraft_id));
    absl::Time last_time = absl::InfinitePast();
    if (highest.has_value()) {
      ASSIGN_OR_RETURN(std::vector<storage::ArchivedFrame> last,
                       storage_->archive().Read(record.spacecraft_id, *highest, 1));
      if (!last.empty()) last_time = last.front().measurement_time;
    }
    {
      absl::MutexLock lock(&sc->ingest_mu);
      sc->ingest_setup = setup;
      sc->highest_accepted = highest.value_or(0);
      sc->last_accepted_time = last_time;
    }
    {
      absl::MutexLock lock(&sc->state_mu);
      sc->setup = setup;
      sc->highest_durable = highest.value_or(0);
      sc->last_durable_time = last_time;
      sc->frames_accepted = count;
      sc->session = std::move(*session);
      checkpoint.session.reset();
      sc->apply = std::move(checkpoint);
      sc->applied_sequence = last_sequence;
      sc->replay_from_archive = true;
    }
    Log("INFO", absl::StrCat("loaded spacecraft ", sc->id, ": model ", setup->model_name,
                             ", archive up to sequence ", highest.value_or(0),
                             ", checkpoint at sequence ", last_sequence));
    absl::MutexLock lock(&registry_mu_);
    registry_[sc->id] = std::move(sc);
  }
  return absl::OkStatus();
}

EstimationCore::~EstimationCore() { Stop(absl::ZeroDuration()); }

void EstimationCore::Stop(absl::Duration drain_deadline) {
  {
    absl::MutexLock lock(&stop_mu_);
    if (stopped_) return;
    stopped_ = true;
  }
  hub_.CloseAll();
  {
    absl::MutexLock lock(&commit_mu_);
    ingest_closed_ = true;
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
      absl::MutexLock lock(&registry_mu_);
      for (auto& [id, sc] : registry_) {
        absl::MutexLock state(&sc->state_mu);
        if (sc->replay_from_archive || !sc->ready.empty()) busy = true;
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
}

std::shared_ptr<EstimationCore::Spacecraft> EstimationCore::Find(const std::string& id) {
  absl::MutexLock lock(&registry_mu_);
  auto it = registry_.find(id);
  return it == registry_.end() ? nullptr : it->second;
}

absl::Status EstimationCore::CheckSpacecraft(const std::string& spacecraft_id) {
  if (spacecraft_id.empty() || Find(spacecraft_id) != nullptr) return absl::OkStatus();
  return NotConfigured(spacecraft_id);
}

// ---------------------------------------------------------------------------------------------
// Ingest and group commit.

bool EstimationCore::Ingest(const esg::v1::TelemetryFrame& proto, esg::v1::TelemetryAck* ack,
                            std::function<void()> on_durable) {
  ack->set_spacecraft_id(proto.spacecraft_id());
  ack->set_sequence(proto.sequence());
  auto reject = [&](std::string field, std::string reason) {
    ack->set_accepted(false);
    ack->mutable_rejection()->set_field(std::move(field));
    ack->mutable_rejection()->set_reason(std::move(reason));
    return false;
  };
  std::shared_ptr<Spacecraft> sc = Find(proto.spacecraft_id());
  if (sc == nullptr) {
    return reject("spacecraft_id", absl::StrCat("'", proto.spacecraft_id(), "' is not configured"));
  }
  absl::StatusOr<TelemetryFrame> frame = proto_convert::FrameFromProto(proto);
  absl::MutexLock lock(&sc->ingest_mu);
  auto reject_counted = [&](std::string field, std::string reason) {
    ++sc->frames_rejected;
    return reject(std::move(field), std::move(reason));
  };
  if (proto.sequence() < 1) {
    return reject_counted("sequence", absl::StrCat("must be >= 1, got ", proto.sequence()));
  }
  if (proto.sequence() <= sc->highest_accepted) {
    ++sc->frames_duplicate;
    ack->set_accepted(true);
    ack->set_duplicate(true);
    int64_t durable = 0;
    {
      absl::MutexLock state(&sc->state_mu);
      durable = sc->highest_durable;
    }
    if (proto.sequence() <= durable) return false;
    // The original is still being committed: this ack waits for the next commit.
    CommitEntry entry;
    entry.sc = sc;
    entry.barrier = true;
    entry.done = std::move(on_durable);
    absl::MutexLock commit(&commit_mu_);
    if (ingest_closed_) return reject("frame", "the server is shutting down");
    commit_queue_.push_back(std::move(entry));
    return true;
  }
  if (!frame.ok()) {
    const esg::v1::Rejection r = RejectionFromStatus(frame.status());
    return reject_counted(r.field(), r.reason());
  }
  for (int i = 0; i < proto.gyros_size(); ++i) {
    const int id = proto.gyros(i).gyro_id();
    if (!sc->ingest_setup->configured[id - 1]) {  // 1..4 checked by FrameFromProto
      return reject_counted(absl::StrCat("gyros[", i, "].gyro_id"),
                            absl::StrCat("gyro ", id, " is not configured for spacecraft '",
                                         sc->id, "'"));
    }
  }
  if (frame->time <= sc->last_accepted_time) {
    return reject_counted(
        "time", absl::StrCat(FormatUtc(frame->time),
                             " is not after the previous accepted frame of this spacecraft (",
                             FormatUtc(sc->last_accepted_time), ", sequence ",
                             sc->highest_accepted, ")"));
  }
  if (sc->last_accepted_time != absl::InfinitePast() &&
      frame->time - sc->last_accepted_time > options_.max_frame_gap) {
    // The filter integrates across a gap at the configured rate: an absurd gap (a wrong time
    // tag) would occupy a worker for hours.
    return reject_counted(
        "time", absl::StrCat(FormatUtc(frame->time), " is more than ",
                             absl::FormatDuration(options_.max_frame_gap),
                             " after the previous accepted frame (", FormatUtc(sc->last_accepted_time),
                             ")"));
  }
  const absl::Time frame_time = frame->time;
  CommitEntry entry;
  entry.sc = sc;
  entry.sequence = proto.sequence();
  entry.time = frame_time;
  entry.payload = proto.SerializeAsString();
  entry.frame = std::move(*frame);
  entry.done = std::move(on_durable);
  // The verdict goes into the ack before the entry is queued: the committer may commit and send
  // this ack before push_back returns here.
  ack->set_accepted(true);
  {
    absl::MutexLock commit(&commit_mu_);
    if (ingest_closed_) return reject("frame", "the server is shutting down");
    commit_queue_.push_back(std::move(entry));
  }
  sc->highest_accepted = proto.sequence();
  sc->last_accepted_time = frame_time;
  return true;
}

void EstimationCore::FillDurable(esg::v1::TelemetryAck* ack) {
  std::shared_ptr<Spacecraft> sc = Find(ack->spacecraft_id());
  if (sc == nullptr) return;
  absl::MutexLock lock(&sc->state_mu);
  ack->set_highest_durable_sequence(sc->highest_durable);
}

void EstimationCore::CommitterLoop() {
  for (;;) {
    std::vector<CommitEntry> batch;
    {
      absl::MutexLock lock(&commit_mu_);
      commit_mu_.Await(absl::Condition(
          +[](EstimationCore* c) ABSL_EXCLUSIVE_LOCKS_REQUIRED(c->commit_mu_) {
            return !c->commit_queue_.empty() || c->commit_stop_;
          },
          this));
      if (commit_queue_.empty() && commit_stop_) return;
      batch.swap(commit_queue_);
    }
    // Group by spacecraft, keeping the accept order (sequences increase within a spacecraft).
    std::map<Spacecraft*, std::vector<storage::ArchivedFrame>> frames;
    for (const CommitEntry& e : batch) {
      if (e.barrier) continue;
      storage::ArchivedFrame f;
      f.spacecraft_id = e.sc->id;
      f.sequence = e.sequence;
      f.measurement_time = e.time;
      f.payload = e.payload;
      frames[e.sc.get()].push_back(std::move(f));
    }
    absl::Duration backoff = absl::Milliseconds(20);
    for (int attempt = 1;; ++attempt) {
      absl::Status status = [&]() -> absl::Status {
        if (frames.empty()) return absl::OkStatus();
        ASSIGN_OR_RETURN(storage::Transaction txn, storage_->database().Begin());
        for (auto& [sc, list] : frames) {
          ASSIGN_OR_RETURN(storage::AppendResult r,
                           storage_->archive().AppendBatch(txn, sc->id, list));
          if (!r.duplicate_sequences.empty()) {
            Log("WARN", absl::StrCat(sc->id, ": ", r.duplicate_sequences.size(),
                                     " frames were already archived"));
          }
        }
        return txn.Commit();
      }();
      if (status.ok()) break;
      // Acks must not go out before the frames are durable: retry (storage busy or I/O).
      Log("ERROR", absl::StrCat("telemetry commit failed (attempt ", attempt,
                                "), retrying: ", status.ToString()));
      absl::SleepFor(backoff);
      backoff = std::min(backoff * 2, absl::Seconds(1));
    }
    std::vector<std::shared_ptr<Spacecraft>> touched;
    for (CommitEntry& e : batch) {
      if (e.barrier) continue;
      absl::MutexLock lock(&e.sc->state_mu);
      if (e.sequence > e.sc->highest_durable) {
        e.sc->highest_durable = e.sequence;
        e.sc->last_durable_time = e.time;
      }
      ++e.sc->frames_accepted;
      if (!e.sc->replay_from_archive) {
        e.sc->ready.emplace(e.sequence, std::move(e.frame));
        // A filter far behind ingest reads its backlog from the archive instead of memory.
        if (e.sc->ready.size() > kMaxReadyFrames) {
          e.sc->ready.clear();
          e.sc->replay_from_archive = true;
        }
      }
      if (touched.empty() || touched.back() != e.sc) touched.push_back(e.sc);
    }
    for (const auto& sc : touched) Schedule(sc);
    for (CommitEntry& e : batch) {
      if (e.done) e.done();
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Workers.

void EstimationCore::Schedule(const std::shared_ptr<Spacecraft>& sc) {
  absl::MutexLock lock(&pool_mu_);
  if (sc->scheduled) {
    sc->wake = true;
    return;
  }
  sc->scheduled = true;
  ready_.push_back(sc);
}

void EstimationCore::WorkerLoop() {
  // The filter runs behind ingest by design: its threads yield the CPU to the ingest path
  // (reactors, committer) so acknowledgements stay fast while a backlog is applied.
  if (options_.worker_nice > 0) {
    setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), options_.worker_nice);
  }
  for (;;) {
    std::shared_ptr<Spacecraft> sc;
    {
      absl::MutexLock lock(&pool_mu_);
      pool_mu_.Await(absl::Condition(
          +[](EstimationCore* c) ABSL_EXCLUSIVE_LOCKS_REQUIRED(c->pool_mu_) {
            return !c->ready_.empty() || c->pool_stop_;
          },
          this));
      if (pool_stop_) return;
      sc = ready_.front();
      ready_.pop_front();
      sc->wake = false;
    }
    const bool more = RunJob(sc);
    absl::MutexLock lock(&pool_mu_);
    if (more || sc->wake) {
      sc->wake = false;
      ready_.push_back(sc);
    } else {
      sc->scheduled = false;
    }
  }
}

bool EstimationCore::RunJob(const std::shared_ptr<Spacecraft>& sc) {
  absl::MutexLock job(&sc->job_mu);
  std::optional<EstimationSession> session;
  ServerCheckpoint apply;
  std::shared_ptr<const Setup> setup;
  int64_t applied = 0;
  int64_t generation = 0;
  bool from_archive = false;
  std::vector<std::pair<int64_t, TelemetryFrame>> frames;
  {
    absl::MutexLock lock(&sc->state_mu);
    session = sc->session;
    apply = sc->apply;
    setup = sc->setup;
    applied = sc->applied_sequence;
    generation = sc->generation;
    from_archive = sc->replay_from_archive;
    sc->ready.erase(sc->ready.begin(), sc->ready.upper_bound(applied));
    if (!from_archive) {
      for (auto it = sc->ready.begin();
           it != sc->ready.end() && static_cast<int>(frames.size()) < options_.max_frames_per_job;
           ++it) {
        frames.emplace_back(it->first, it->second);
      }
    }
  }
  if (!session.has_value()) return false;
  if (from_archive) {
    absl::StatusOr<std::vector<storage::ArchivedFrame>> archived =
        storage_->archive().Read(sc->id, applied + 1, options_.max_frames_per_job);
    if (!archived.ok()) {
      Log("ERROR", absl::StrCat(sc->id, ": archive read failed: ", archived.status().ToString()));
      absl::SleepFor(absl::Milliseconds(100));
      return true;
    }
    if (archived->empty()) {
      absl::MutexLock lock(&sc->state_mu);
      // Caught up only if nothing became durable meanwhile (the committer skips the in-memory
      // queue while this flag is set).
      if (sc->generation == generation && sc->highest_durable <= applied) {
        sc->replay_from_archive = false;
      }
      return true;  // continue from the in-memory queue (or the archive again)
    }
    for (const storage::ArchivedFrame& a : *archived) {
      esg::v1::TelemetryFrame proto;
      absl::StatusOr<TelemetryFrame> frame =
          proto.ParseFromString(a.payload) ? proto_convert::FrameFromProto(proto)
                                           : absl::DataLossError("payload does not parse");
      if (!frame.ok()) {
        Log("ERROR", absl::StrCat(sc->id, ": archived frame ", a.sequence,
                                  " cannot be decoded: ", frame.status().ToString()));
        frame = absl::DataLossError("undecodable");
        frames.emplace_back(a.sequence, TelemetryFrame{});
        frames.back().second.time = absl::InfinitePast();  // marks a frame to skip
        continue;
      }
      frames.emplace_back(a.sequence, std::move(*frame));
    }
  }
  if (frames.empty()) return false;

  // Apply (no lock held: readers keep using the installed session meanwhile).
  const absl::Time now = absl::Now();
  std::vector<storage::CoefficientRecord> coefficients;
  std::vector<storage::AlertRecord> new_alerts;
  // Alerts created in this job, not yet stored: (reason, subsystem) -> index into new_alerts.
  std::map<std::pair<std::string, std::string>, size_t> pending;
  std::map<int64_t, storage::AlertRepeat> repeats;
  std::vector<int64_t> clears;
  // Ends a track (the condition is over): a stored alert is cleared, a pending one is stored
  // cleared.
  auto end_track = [&](std::vector<AlertTrack>::iterator it) {
    auto p = pending.find({it->reason, it->subsystem});
    if (p != pending.end()) {
      new_alerts[p->second].cleared = true;
      pending.erase(p);
    } else {
      clears.push_back(it->sequence);
    }
    return apply.alert_tracks.erase(it);
  };
  for (auto& [sequence, frame] : frames) {
    applied = sequence;
    if (frame.time == absl::InfinitePast()) {
      ++apply.frames_apply_failed;
      continue;
    }
    absl::StatusOr<estimator::StepReport> report = session->AddFrame(frame);
    if (!report.ok()) {
      ++apply.frames_apply_failed;
      Log("WARN", absl::StrCat(sc->id, ": frame ", sequence,
                               " not applied: ", report.status().ToString()));
      continue;
    }
    ++apply.frames_applied;
    if (report->measurement_step && frame.star_tracker.has_value() &&
        frame.star_tracker->valid && !report->star_tracker_used) {
      ++apply.star_tracker_rejections;
    }
    if (report->measurement_step) {  // a coefficient snapshot at every measurement step
      for (const estimator::GyroEstimate& g : session->Gyros()) {
        storage::CoefficientRecord r;
        r.spacecraft_id = sc->id;
        r.gyro_id = g.id;
        r.measurement_time = frame.time;
        r.compute_time = now;
        r.values = storage::ToCoefficientValues(g.coefficients, g.misalignment_b);
        r.sigmas = storage::ToCoefficientValues(g.sigma, g.misalignment_sigma_b);
        r.model_name = absl::StrCat("model", setup->model_name);
        coefficients.push_back(std::move(r));
      }
    }
    // Tracks without an occurrence for a whole window are over.
    for (auto it = apply.alert_tracks.begin(); it != apply.alert_tracks.end();) {
      it = frame.time - it->last_time > options_.alert_collapse_window ? end_track(it) : it + 1;
    }
    // Events: a repeat of a live track, or a new alert.
    for (const Event& event : report->events) {
      const std::string reason = estimator::EventKindName(event.kind);
      auto it = std::find_if(apply.alert_tracks.begin(), apply.alert_tracks.end(),
                             [&](const AlertTrack& t) {
                               return t.reason == reason && t.subsystem == event.subsystem;
                             });
      if (it != apply.alert_tracks.end()) {
        ++it->repeat_count;
        it->last_time = event.time;
        auto p = pending.find({reason, event.subsystem});
        if (p != pending.end()) {
          storage::AlertRecord& a = new_alerts[p->second];
          a.repeat_count = it->repeat_count;
          a.measurement_time = event.time;
          a.value = event.value;
          a.threshold = event.threshold;
          a.message = event.message;
        } else {
          storage::AlertRepeat& rep = repeats[it->sequence];
          rep.spacecraft_id = sc->id;
          rep.sequence = it->sequence;
          rep.repeat_count = it->repeat_count;
          rep.last_time = event.time;
        }
        continue;
      }
      storage::AlertRecord a;
      a.spacecraft_id = sc->id;
      a.severity = SeverityName(SeverityOf(event.kind));
      a.reason = reason;
      a.subsystem = event.subsystem;
      a.value = event.value;
      a.threshold = event.threshold;
      a.unit = event.unit;
      a.repeat_count = 1;
      a.first_time = event.time;
      a.measurement_time = event.time;
      a.compute_time = now;
      a.message = event.message;
      pending[{reason, event.subsystem}] = new_alerts.size();
      new_alerts.push_back(std::move(a));
      apply.alert_tracks.push_back(AlertTrack{reason, event.subsystem, 0, 1, event.time});
    }
  }

  // Commit the effects and the checkpoint in one transaction.
  ServerCheckpoint to_store = apply;
  std::vector<int64_t> new_sequences;
  const absl::Status status = [&]() -> absl::Status {
    ASSIGN_OR_RETURN(storage::Transaction txn, storage_->database().Begin());
    for (const storage::CoefficientRecord& r : coefficients) {
      RETURN_IF_ERROR(storage_->coefficients().Append(txn, r));
    }
    for (const storage::AlertRecord& a : new_alerts) {
      ASSIGN_OR_RETURN(int64_t seq, storage_->alerts().Append(txn, a));
      new_sequences.push_back(seq);
    }
    for (const auto& [seq, rep] : repeats) {
      RETURN_IF_ERROR(storage_->alerts().UpdateRepeat(txn, rep));
    }
    for (int64_t seq : clears) RETURN_IF_ERROR(storage::ClearAlert(txn, sc->id, seq));
    // Sequences of alerts created in this job go into the stored tracks too.
    for (AlertTrack& t : to_store.alert_tracks) {
      auto p = pending.find({t.reason, t.subsystem});
      if (p != pending.end()) t.sequence = new_sequences[p->second];
    }
    storage::CheckpointRecord cp;
    cp.spacecraft_id = sc->id;
    cp.last_sequence = applied;
    cp.measurement_time = session->last_frame_time() == absl::InfinitePast()
                              ? absl::UnixEpoch()
                              : session->last_frame_time();
    cp.compute_time = now;
    to_store.session = session->ExportCheckpoint();
    cp.state_blob = EncodeCheckpoint(to_store);
    RETURN_IF_ERROR(storage_->sessions().PutCheckpoint(txn, cp));
    return txn.Commit();
  }();
  if (!status.ok()) {
    Log("ERROR", absl::StrCat(sc->id, ": apply commit failed, will retry: ", status.ToString()));
    absl::SleepFor(absl::Milliseconds(100));
    return true;
  }
  apply.alert_tracks = to_store.alert_tracks;
  for (size_t k = 0; k < new_alerts.size(); ++k) new_alerts[k].sequence = new_sequences[k];
  bool more = false;
  {
    absl::MutexLock lock(&sc->state_mu);
    if (sc->generation != generation) return true;
    sc->session = std::move(session);
    sc->apply = std::move(apply);
    sc->applied_sequence = applied;
    sc->last_compute_time = now;
    sc->ready.erase(sc->ready.begin(), sc->ready.upper_bound(applied));
    more = sc->replay_from_archive || !sc->ready.empty();
  }
  // Publish the committed changes.
  absl::MutexLock publish(&sc->publish_mu);
  for (const storage::AlertRecord& a : new_alerts) hub_.Publish(a);
  std::set<int64_t> changed(clears.begin(), clears.end());
  for (const auto& [seq, rep] : repeats) changed.insert(seq);
  for (int64_t seq : changed) {
    absl::StatusOr<storage::AlertRecord> r = storage_->alerts().Get(sc->id, seq);
    if (r.ok()) hub_.Publish(*r);
  }
  return more;
}

absl::Status EstimationCore::WaitApplied(const std::string& spacecraft_id,
                                         absl::Duration timeout) {
  std::shared_ptr<Spacecraft> sc = Find(spacecraft_id);
  if (sc == nullptr) return NotConfigured(spacecraft_id);
  const absl::Time deadline = absl::Now() + timeout;
  for (;;) {
    {
      absl::MutexLock lock(&sc->state_mu);
      if (!sc->replay_from_archive && sc->applied_sequence >= sc->highest_durable) {
        return absl::OkStatus();
      }
    }
    if (absl::Now() > deadline) {
      return absl::DeadlineExceededError(
          absl::StrCat(spacecraft_id, ": frames still being applied"));
    }
    absl::SleepFor(absl::Milliseconds(2));
  }
}

// ---------------------------------------------------------------------------------------------
// Configuration.

absl::StatusOr<esg::v1::ConfigureResponse> EstimationCore::Configure(
    const esg::v1::ConfigureRequest& request) {
  if (!request.has_config()) return absl::InvalidArgumentError("config: required");
  ASSIGN_OR_RETURN(estimator::SpacecraftConfig config,
                   proto_convert::ConfigFromProto(request.config()));
  const std::string model_text = request.model().empty() ? kDefaultModel : request.model();
  ASSIGN_OR_RETURN(estimator::ModelSpec model, estimator::ParseModel(model_text));
  const estimator::SessionOptions session_options{model};
  ASSIGN_OR_RETURN(EstimationSession fresh, EstimationSession::Create(config, session_options));

  auto setup = std::make_shared<Setup>();
  setup->config = config;
  setup->proto = proto_convert::ConfigToProto(config);
  setup->model = model;
  setup->model_name = model.Name();
  setup->config_json = proto_convert::ConfigToJson(config);
  for (const auto& g : config.gyros) setup->configured[g.id - 1] = true;

  ServerCheckpoint checkpoint;
  checkpoint.model = setup->model_name;
  storage::CheckpointRecord cp;
  cp.spacecraft_id = config.spacecraft_id;
  cp.last_sequence = 0;
  cp.compute_time = absl::Now();
  cp.state_blob = EncodeCheckpoint(checkpoint);
  storage::ConfigRecord record;
  record.spacecraft_id = config.spacecraft_id;
  record.config_json = setup->config_json;
  record.updated_time = cp.compute_time;
  auto store = [&]() -> absl::Status {
    ASSIGN_OR_RETURN(storage::Transaction txn, storage_->database().Begin());
    RETURN_IF_ERROR(storage_->configs().Put(txn, record).status());
    RETURN_IF_ERROR(storage_->sessions().PutCheckpoint(txn, cp));
    return txn.Commit();
  };

  absl::MutexLock configure(&configure_mu_);
  std::shared_ptr<Spacecraft> sc = Find(config.spacecraft_id);
  esg::v1::ConfigureResponse response;
  if (sc == nullptr) {
    RETURN_IF_ERROR(store());
    sc = std::make_shared<Spacecraft>(config.spacecraft_id);
    {
      absl::MutexLock lock(&sc->ingest_mu);
      sc->ingest_setup = setup;
    }
    {
      absl::MutexLock lock(&sc->state_mu);
      sc->setup = setup;
      sc->session = std::move(fresh);
      sc->apply = checkpoint;
      sc->replay_from_archive = false;
    }
    {
      absl::MutexLock lock(&registry_mu_);
      registry_[sc->id] = sc;
    }
    Log("INFO", absl::StrCat("configured new spacecraft ", sc->id, ", model ", setup->model_name));
    response.set_created(true);
    *response.mutable_session() = Summarize(*sc);
    return response;
  }
  {
    absl::MutexLock job(&sc->job_mu);
    absl::MutexLock ingest(&sc->ingest_mu);
    absl::MutexLock state(&sc->state_mu);
    const bool same = sc->setup->config_json == setup->config_json &&
                      sc->setup->model_name == setup->model_name;
    if (!same) {
      if (sc->highest_accepted > 0 && !request.replace()) {
        return absl::FailedPreconditionError(absl::StrCat(
            "config: spacecraft '", sc->id, "' already has telemetry (up to sequence ",
            sc->highest_accepted,
            "); set replace=true to recreate its session and reapply the archive"));
      }
      RETURN_IF_ERROR(store());
      sc->ingest_setup = setup;
      sc->setup = setup;
      sc->session = std::move(fresh);
      sc->apply = checkpoint;
      sc->applied_sequence = 0;
      ++sc->generation;
      sc->ready.clear();
      sc->replay_from_archive = true;
      Log("INFO", absl::StrCat("reconfigured spacecraft ", sc->id, ", model ",
                               setup->model_name, "; reapplying the archive"));
    }
  }
  Schedule(sc);
  response.set_created(false);
  *response.mutable_session() = Summarize(*sc);
  return response;
}

// ---------------------------------------------------------------------------------------------
// Queries.

esg::v1::SessionInfo EstimationCore::Summarize(Spacecraft& sc) {
  esg::v1::SessionInfo info;
  info.set_spacecraft_id(sc.id);
  {
    absl::MutexLock lock(&sc.ingest_mu);
    info.set_frames_rejected(sc.frames_rejected);
    info.set_frames_duplicate(sc.frames_duplicate);
    info.set_last_sequence(sc.highest_accepted);
    if (sc.last_accepted_time != absl::InfinitePast()) {
      *info.mutable_last_frame_time() = proto_convert::TimeToProto(sc.last_accepted_time);
    }
  }
  std::optional<EstimationSession> session;
  {
    absl::MutexLock lock(&sc.state_mu);
    info.set_highest_durable_sequence(sc.highest_durable);
    info.set_highest_applied_sequence(sc.applied_sequence);
    info.set_frames_accepted(sc.frames_accepted);
    info.set_frames_applied(sc.apply.frames_applied);
    info.set_frames_apply_failed(sc.apply.frames_apply_failed);
    info.set_star_tracker_rejections(sc.apply.star_tracker_rejections);
    info.set_model(sc.setup->model_name);
    *info.mutable_config() = sc.setup->proto;
    for (int id : sc.setup->config.reserve_pair) info.add_reserve_pair(id);
    if (sc.last_compute_time != absl::InfinitePast()) {
      *info.mutable_last_compute_time() = proto_convert::TimeToProto(sc.last_compute_time);
    }
    session = sc.session;
  }
  if (session.has_value()) {
    info.set_state(StateToProto(session->state()));
    for (int id : session->working_pair()) info.add_working_pair(id);
    const estimator::AttitudeEstimate attitude = session->CurrentAttitude();
    if (session->initialized() && attitude.valid) {
      std::vector<std::pair<int, Eigen::Vector3d>> h_in;
      for (const estimator::GyroEstimate& g : session->Gyros()) h_in.emplace_back(g.id, g.h_in);
      FillSample(attitude.time, attitude, h_in, info.mutable_latest_attitude());
    }
  }
  absl::StatusOr<storage::AlertCounts> counts = storage::CountAlerts(storage_->database(), sc.id);
  if (counts.ok()) {
    info.set_active_alerts(counts->active);
    info.set_unacknowledged_alerts(counts->unacknowledged);
  }
  return info;
}

absl::StatusOr<esg::v1::SessionInfo> EstimationCore::GetSession(const std::string& spacecraft_id) {
  if (spacecraft_id.empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  std::shared_ptr<Spacecraft> sc = Find(spacecraft_id);
  if (sc == nullptr) return NotConfigured(spacecraft_id);
  return Summarize(*sc);
}

absl::StatusOr<esg::v1::ListSessionsResponse> EstimationCore::ListSessions() {
  std::vector<std::shared_ptr<Spacecraft>> all;
  {
    absl::MutexLock lock(&registry_mu_);
    for (auto& [id, sc] : registry_) all.push_back(sc);
  }
  esg::v1::ListSessionsResponse response;
  for (auto& sc : all) *response.add_sessions() = Summarize(*sc);
  return response;
}

absl::StatusOr<esg::v1::PredictResponse> EstimationCore::Predict(
    const esg::v1::PredictRequest& request) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  std::shared_ptr<Spacecraft> sc = Find(request.spacecraft_id());
  if (sc == nullptr) return NotConfigured(request.spacecraft_id());

  // The requested epochs: the from/to grid plus the explicit times.
  std::vector<absl::Time> times;
  if (request.has_from() || request.has_to()) {
    if (!request.has_from()) return absl::InvalidArgumentError("from: required when to is given");
    if (!request.has_to()) return absl::InvalidArgumentError("to: required when from is given");
    ASSIGN_OR_RETURN(absl::Time from, proto_convert::TimeFromProto(request.from()));
    ASSIGN_OR_RETURN(absl::Time to, proto_convert::TimeFromProto(request.to()));
    if (!(request.step_s() > 0) || !std::isfinite(request.step_s())) {
      return absl::InvalidArgumentError(
          absl::StrCat("step_s: must be > 0 when from/to are given, got ", request.step_s()));
    }
    if (to < from) {
      return absl::InvalidArgumentError(absl::StrCat("to: ", FormatUtc(to),
                                                     " is before from ", FormatUtc(from)));
    }
    const double count = std::floor(absl::ToDoubleSeconds(to - from) / request.step_s()) + 1;
    if (count > options_.max_prediction_samples) {
      return absl::OutOfRangeError(absl::StrCat("step_s: ", count, " samples exceed the limit of ",
                                                options_.max_prediction_samples));
    }
    for (int64_t i = 0; i < static_cast<int64_t>(count); ++i) {
      times.push_back(from + absl::Seconds(request.step_s() * static_cast<double>(i)));
    }
  }
  absl::Time explicit_previous = absl::InfinitePast();
  for (int i = 0; i < request.times_size(); ++i) {
    absl::StatusOr<absl::Time> t = proto_convert::TimeFromProto(request.times(i));
    if (!t.ok()) {
      return absl::InvalidArgumentError(absl::StrCat("times[", i, "]: ", t.status().message()));
    }
    if (i > 0 && *t <= explicit_previous) {
      return absl::InvalidArgumentError(absl::StrCat("times[", i, "]: ", FormatUtc(*t),
                                                     " is not after times[", i - 1, "]"));
    }
    explicit_previous = *t;
    times.push_back(*t);
  }
  if (times.empty()) {
    return absl::InvalidArgumentError("times: no epoch requested (give from, to and step_s, or times)");
  }
  if (static_cast<int>(times.size()) > options_.max_prediction_samples) {
    return absl::OutOfRangeError(absl::StrCat("times: ", times.size(),
                                              " samples exceed the limit of ",
                                              options_.max_prediction_samples));
  }
  std::sort(times.begin(), times.end());
  times.erase(std::unique(times.begin(), times.end()), times.end());

  std::optional<SampledProfile> planned;
  if (request.planned_attitude_size() > 0) {
    std::vector<PlannedSample> samples;
    for (int i = 0; i < request.planned_attitude_size(); ++i) {
      const esg::v1::AttitudeSample& s = request.planned_attitude(i);
      if (!s.has_time()) {
        return absl::InvalidArgumentError(absl::StrCat("planned_attitude[", i, "].time: required"));
      }
      if (s.q_in_b_size() != 4) {
        return absl::InvalidArgumentError(absl::StrCat(
            "planned_attitude[", i, "].q_in_b: expected 4 values, got ", s.q_in_b_size()));
      }
      ASSIGN_OR_RETURN(absl::Time t, proto_convert::TimeFromProto(s.time()));
      samples.push_back({t, estimator::QuaternionFromScalarFirst(
                                {s.q_in_b(0), s.q_in_b(1), s.q_in_b(2), s.q_in_b(3)})});
    }
    ASSIGN_OR_RETURN(planned, SampledProfile::Create(std::move(samples)));
  }

  // Copy the session under the lock; predict on the copy.
  std::optional<EstimationSession> session;
  std::string model_name;
  {
    absl::MutexLock lock(&sc->state_mu);
    session = sc->session;
    model_name = sc->setup->model_name;
  }
  if (!session.has_value() || !session->initialized()) {
    return absl::FailedPreconditionError(absl::StrCat(
        "spacecraft '", sc->id, "' has no attitude yet (no frame with a valid star-tracker "
                                "quaternion and a readable pair has been applied)"));
  }
  const absl::Time last = session->last_frame_time();
  if (times.front() <= last) {
    return absl::OutOfRangeError(absl::StrCat(
        request.has_from() ? "from" : "times", ": ", FormatUtc(times.front()),
        " is not after the last applied frame ", FormatUtc(last)));
  }
  if (times.back() - last > options_.max_prediction_horizon) {
    return absl::OutOfRangeError(absl::StrCat(
        request.has_to() ? "to" : "times", ": ", FormatUtc(times.back()),
        " is beyond the prediction horizon of ",
        absl::FormatDuration(options_.max_prediction_horizon), " after the last applied frame ",
        FormatUtc(last)));
  }
  ASSIGN_OR_RETURN(std::vector<estimator::PredictedSample> predicted,
                   session->Predict(times, planned.has_value() ? &*planned : nullptr,
                                    planned.has_value() ? planned->start() : absl::UnixEpoch()));
  esg::v1::PredictResponse response;
  std::vector<storage::AemSample> aem_samples;
  for (const estimator::PredictedSample& p : predicted) {
    FillSample(p.time, p.attitude, p.h_in, response.add_samples());
    if (request.aem()) aem_samples.push_back({p.time, p.attitude.q_in_b.normalized()});
  }
  if (request.aem()) {
    storage::AemHeader header;
    header.object_name = sc->id;
    header.object_id = sc->id;
    header.originator = "ESG-ESGD";
    header.creation_date = absl::Now();
    header.comments.push_back(absl::StrCat("Predicted attitude q_in_b, calibration model ",
                                           model_name, ", from the state at ", FormatUtc(last)));
    ASSIGN_OR_RETURN(std::string text, storage::WriteAem(header, aem_samples));
    response.set_aem_text(std::move(text));
  }
  return response;
}

namespace {

esg::v1::DiagnosisResult DiagnosisResultFromRecord(const storage::DiagnosisRecord& r) {
  esg::v1::DiagnosisResult out;
  out.set_id(r.id);
  out.set_spacecraft_id(r.spacecraft_id);
  out.set_verdict(r.verdict);
  out.set_report_json(r.report_json);
  *out.mutable_first_frame_time() = proto_convert::TimeToProto(r.from_time);
  *out.mutable_last_frame_time() = proto_convert::TimeToProto(r.to_time);
  *out.mutable_compute_time() = proto_convert::TimeToProto(r.compute_time);
  return out;
}

}  // namespace

absl::StatusOr<esg::v1::DiagnosisResult> EstimationCore::Diagnose(
    const esg::v1::DiagnoseRequest& request,
    const std::function<void(double fraction, const std::string& stage)>& progress) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  std::shared_ptr<Spacecraft> sc = Find(request.spacecraft_id());
  if (sc == nullptr) return NotConfigured(request.spacecraft_id());
  absl::Time from = absl::InfinitePast();
  absl::Time to = absl::InfiniteFuture();
  if (request.has_from()) {
    ASSIGN_OR_RETURN(from, proto_convert::TimeFromProto(request.from()));
  }
  if (request.has_to()) {
    ASSIGN_OR_RETURN(to, proto_convert::TimeFromProto(request.to()));
    if (to <= from) {
      return absl::InvalidArgumentError(
          absl::StrCat("to: ", FormatUtc(to), " is not after from ", FormatUtc(from)));
    }
  }
  std::shared_ptr<const Setup> setup;
  {
    absl::MutexLock state(&sc->state_mu);
    setup = sc->setup;
  }
  if (setup == nullptr) return NotConfigured(request.spacecraft_id());
  estimator::discovery::DiagnoseOptions options;
  options.model = request.model().empty() ? setup->model_name : request.model();
  if (absl::StatusOr<estimator::ModelSpec> m = estimator::ParseModel(options.model); !m.ok()) {
    return absl::InvalidArgumentError(absl::StrCat("model: ", m.status().message()));
  }
  ASSIGN_OR_RETURN(std::vector<storage::ArchivedFrame> archived,
                   storage_->archive().ReadTimeRange(sc->id, from, to));
  if (archived.empty()) {
    return absl::FailedPreconditionError(absl::StrCat(
        "no archived telemetry of '", sc->id, "' in [", FormatUtc(from), ", ", FormatUtc(to), ")"));
  }
  std::vector<TelemetryFrame> frames;
  frames.reserve(archived.size());
  for (const storage::ArchivedFrame& a : archived) {
    esg::v1::TelemetryFrame proto;
    if (!proto.ParseFromString(a.payload)) {
      return absl::DataLossError(absl::StrCat("archived frame ", a.sequence, " of '", sc->id,
                                              "' does not parse"));
    }
    ASSIGN_OR_RETURN(TelemetryFrame frame, proto_convert::FrameFromProto(proto));
    frames.push_back(std::move(frame));
  }
  ASSIGN_OR_RETURN(estimator::discovery::DiagnosisReport report,
                   estimator::discovery::Diagnose(setup->config, frames, options, progress));
  storage::DiagnosisRecord record;
  record.spacecraft_id = sc->id;
  record.from_time = frames.front().time;
  record.to_time = frames.back().time;
  record.compute_time = absl::Now();
  record.verdict = report.verdict;
  record.report_json = proto_convert::DiagnosisToJson(report);
  ASSIGN_OR_RETURN(record.id, storage_->diagnoses().Put(record));
  esg::v1::DiagnosisResult result = DiagnosisResultFromRecord(record);
  result.set_frames(static_cast<int64_t>(frames.size()));
  return result;
}

absl::StatusOr<esg::v1::ListDiagnosesResponse> EstimationCore::ListDiagnoses(
    const esg::v1::ListDiagnosesRequest& request) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  if (Find(request.spacecraft_id()) == nullptr) return NotConfigured(request.spacecraft_id());
  ASSIGN_OR_RETURN(std::vector<storage::DiagnosisRecord> records,
                   storage_->diagnoses().List(request.spacecraft_id()));
  esg::v1::ListDiagnosesResponse response;
  for (const storage::DiagnosisRecord& r : records) *response.add_diagnoses() = DiagnosisResultFromRecord(r);
  return response;
}

absl::StatusOr<esg::v1::HistoryResponse> EstimationCore::History(
    const esg::v1::HistoryRequest& request) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  if (Find(request.spacecraft_id()) == nullptr) return NotConfigured(request.spacecraft_id());
  if (request.gyro_id() < 0 || request.gyro_id() > estimator::kMaxGyros) {
    return absl::InvalidArgumentError(
        absl::StrCat("gyro_id: must be 0 (all) or 1..4, got ", request.gyro_id()));
  }
  absl::Time from = absl::InfinitePast();
  absl::Time to = absl::InfiniteFuture();
  if (request.has_from()) {
    ASSIGN_OR_RETURN(from, proto_convert::TimeFromProto(request.from()));
  }
  if (request.has_to()) {
    ASSIGN_OR_RETURN(to, proto_convert::TimeFromProto(request.to()));
    if (to < from) {
      return absl::InvalidArgumentError(absl::StrCat("to: ", FormatUtc(to), " is before from ",
                                                     FormatUtc(from)));
    }
    to += absl::Nanoseconds(1);  // inclusive
  }
  ASSIGN_OR_RETURN(std::vector<storage::CoefficientRecord> records,
                   storage_->coefficients().History(request.spacecraft_id(), request.gyro_id(),
                                                    from, to));
  esg::v1::HistoryResponse response;
  for (const storage::CoefficientRecord& r : records) *response.add_snapshots() = SnapshotToProto(r);
  return response;
}

absl::StatusOr<esg::v1::Alert> EstimationCore::Acknowledge(
    const esg::v1::AcknowledgeRequest& request) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  std::shared_ptr<Spacecraft> sc = Find(request.spacecraft_id());
  if (sc == nullptr) return NotConfigured(request.spacecraft_id());
  if (request.sequence() < 1) {
    return absl::InvalidArgumentError(
        absl::StrCat("sequence: must be >= 1, got ", request.sequence()));
  }
  if (request.operator_name().empty()) {
    return absl::InvalidArgumentError("operator_name: must not be empty");
  }
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
