// The filter workers (see estimation_core.h "DATA FLOW AND DURABILITY"): per spacecraft, one job
// at a time applies durable frames in measurement-time order to a copy of the session and
// commits the effects with the checkpoint in one transaction (on PostgreSQL together with the
// other jobs that finish at the same time: CommitFilterJob). A filter failure quarantines the
// spacecraft; a session rebuilt from the archive leaves quarantine when it has caught up.
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <set>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "estimator/rotation.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"
#include "proto/convert.h"
#include "server/alert_collapse.h"
#include "server/backoff.h"
#include "server/core_internal.h"
#include "server/estimation_core.h"
#include "server/grpc_status.h"
#include "server/log.h"
#include "server/memory_release.h"
#include "storage/coefficient_store.h"
#include "storage/service_queries.h"

namespace esg::server {

using estimator::EstimationSession;
using estimator::Event;
using estimator::TelemetryFrame;

namespace {

constexpr const char* kQuarantineReason = kQuarantineAlertReason;

// A frame of the job: its identity, and the decoded frame (absent when undecodable).
struct JobFrame {
  absl::Time time;
  std::string station;
  int64_t sequence = 0;
  std::optional<TelemetryFrame> frame;
  std::string undecodable;  // why `frame` is empty: the payload's parse or FrameFromProto status
};

// The per-step estimate of a measurement step (docs/service.md "Per-step estimates"). The
// star-tracker innovations come two per healthy gyro (a reading in this frame, not faulty) in
// the session's gyro order, as the discovery's model runs read them
// (estimator/discovery/model_run.cc).
storage::EstimateRecord EstimateFromStep(const std::string& spacecraft_id,
                                         const TelemetryFrame& frame,
                                         const estimator::StepReport& report,
                                         const std::vector<estimator::GyroEstimate>& gyros,
                                         absl::Time last_star_tracker_time, absl::Time now) {
  storage::EstimateRecord r;
  r.spacecraft_id = spacecraft_id;
  r.measurement_time = frame.time;
  r.compute_time = now;
  r.state = estimator::SessionStateName(report.state);
  const estimator::AttitudeEstimate& attitude = report.attitude;
  r.attitude_valid = attitude.valid;
  if (attitude.valid) {
    r.q_in_b = estimator::ToScalarFirst(attitude.q_in_b);
    for (int i = 0; i < 3; ++i) r.sigma_b[i] = attitude.sigma_b(i);
    r.output_pair = attitude.pair;
  } else {
    r.attitude_invalid_reason = attitude.invalid_reason;
  }
  r.star_tracker_used = report.star_tracker_used;
  const int m = static_cast<int>(report.star_tracker_innovation.size());
  int k = 0;
  for (const estimator::GyroEstimate& g : gyros) {
    if (m == 0) break;
    if (g.faulty || g.id < 1 || g.id > estimator::kMaxGyros ||
        !frame.gyros[g.id - 1].has_value()) {
      continue;
    }
    if (2 * k + 1 >= m) break;
    storage::GyroInnovationRecord gi;
    gi.gyro_id = g.id;
    for (int i = 0; i < 2; ++i) {
      gi.innovation[i] = report.star_tracker_innovation(2 * k + i);
      gi.sigma[i] = report.star_tracker_innovation_sigma(2 * k + i);
    }
    r.star_tracker_innovations.push_back(gi);
    ++k;
  }
  r.star_tracker_test_ratio = report.star_tracker_test_ratio;
  r.last_star_tracker_time = last_star_tracker_time;
  if (report.attitude_error_b_arcsec.has_value() &&
      report.attitude_error_sigma_b_arcsec.has_value()) {
    r.has_attitude_error = true;
    for (int k = 0; k < 3; ++k) {
      r.attitude_error_b[k] = estimator::ArcsecToRad((*report.attitude_error_b_arcsec)(k));
      r.attitude_error_sigma_b[k] =
          estimator::ArcsecToRad((*report.attitude_error_sigma_b_arcsec)(k));
    }
  }
  return r;
}

// A session state change of a job, logged once the job's effects are committed.
struct StateChange {
  estimator::SessionState from;
  estimator::SessionState to;
  absl::Time time;
  std::string station;
  int64_t sequence = 0;
};

// The coefficient history row of one gyro at a measurement step (docs/service.md).
storage::CoefficientRecord CoefficientsOfStep(const std::string& spacecraft_id,
                                              absl::Time measurement_time, absl::Time now,
                                              const std::string& model_name,
                                              const estimator::GyroEstimate& g) {
  storage::CoefficientRecord r;
  r.spacecraft_id = spacecraft_id;
  r.gyro_id = g.id;
  r.measurement_time = measurement_time;
  r.compute_time = now;
  r.values = storage::ToCoefficientValues(g.coefficients, g.misalignment_b);
  r.sigmas = storage::ToCoefficientValues(g.sigma, g.misalignment_sigma_b);
  r.model_name = absl::StrCat("model", model_name);
  r.basis_terms = g.basis_terms;
  for (size_t k = 0; k < r.basis_terms.size(); ++k) {
    r.basis_terms[k].sigma = k < g.basis_sigma.size() ? g.basis_sigma[k] : 0.0;
  }
  return r;
}

}  // namespace

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

// One filter job, passed from each step of RunJob to the next: what it took from the
// spacecraft, what it read from the store, what applying its frames produced, and what it
// committed.
struct EstimationCore::ApplyJob {
  // Applying takes one of the worker_threads slots, given back before the commit (and before any
  // pause), so the threads waiting for the group commit do not add to the filter's CPU share.
  class Slot {
   public:
    explicit Slot(EstimationCore* core) : core_(core) { core_->AcquireApplySlot(); }
    ~Slot() { Release(); }
    Slot(const Slot&) = delete;
    Slot& operator=(const Slot&) = delete;
    void Release() {
      if (core_ != nullptr) core_->ReleaseApplySlot();
      core_ = nullptr;
    }

   private:
    EstimationCore* core_;
  };

  explicit ApplyJob(EstimationCore* core) : slot(core) {}

  Slot slot;
  // Taken from the spacecraft (TakeJob).
  std::optional<EstimationSession> session;
  ServerCheckpoint apply;
  std::shared_ptr<const Setup> setup;
  int64_t generation = 0;
  bool from_archive = false;
  std::vector<AlertOccurrence> service_alerts;
  std::vector<storage::ReadmissionRecord> readmissions;
  std::vector<JobFrame> frames;
  // Late frames this job accounts for; a re-run starts before the first when it is behind the
  // cursor (the others are ahead of it and applied in time order like any frame).
  std::vector<absl::Time> late_done;
  std::optional<absl::Time> rerun_from;
  // Read from the store (ReadJobFrames).
  std::optional<Rerun> rerun;
  bool rebuild_done = false;
  // Applying the frames (ApplyJobFrames).
  absl::Time now;
  std::vector<storage::CoefficientRecord> coefficients;
  std::vector<storage::EstimateRecord> estimates;
  std::optional<AlertCollapser> alerts;
  std::vector<StateChange> state_changes;
  // Window checkpoints (D61): the state at the job's start is kept when its first frame opens a
  // new checkpoint period; a job stops before a later frame that would open one, so the next
  // job starts there.
  std::optional<storage::WindowCheckpoint> window_checkpoint;
  // Committed (CommitJob).
  storage::FilterEffects effects;
  std::vector<int64_t> new_sequences;
  std::optional<absl::Time> retained_at;
};

bool EstimationCore::RunJob(const std::shared_ptr<Spacecraft>& sc) {
  if (options_.before_apply_job) options_.before_apply_job(sc->id);
  absl::MutexLock job_lock(&sc->job_mu);
  // A session another server took over is that server's to apply (its record here is replaced
  // when this server takes the lease again).
  if (sc->lease_lost) return false;
  ApplyJob job(this);
  TakeJob(*sc, job);
  if (std::optional<bool> more = ReadJobFrames(*sc, job)) return *more;
  // Apply (no lock held: readers keep using the installed session meanwhile).
  ApplyJobFrames(*sc, job);
  if (std::optional<bool> more = CommitJob(*sc, job)) return *more;
  const std::optional<bool> more = InstallJob(*sc, job);
  // A reconfiguration replaced the session meanwhile: nothing of this job is published.
  if (!more.has_value()) return true;
  PublishJob(*sc, job);
  return *more;
}

void EstimationCore::TakeJob(Spacecraft& sc, ApplyJob& job) {
  absl::MutexLock lock(&sc.state_mu);
  job.session = sc.session;
  job.apply = sc.apply;
  job.setup = sc.setup;
  job.generation = sc.generation;
  job.from_archive = sc.replay_from_archive;
  job.service_alerts.swap(sc.service_alerts);
  job.readmissions = sc.readmissions;
  const bool stopped = job.apply.FilterStopped();
  if (job.setup != nullptr && job.session.has_value() && !stopped) {
    job.late_done.assign(sc.late_frames.begin(), sc.late_frames.end());
    if (!job.late_done.empty() && job.late_done.front() <= job.apply.applied_time) {
      job.rerun_from = job.late_done.front();
    }
  }
  sc.ready.erase(sc.ready.begin(), sc.ready.upper_bound(job.apply.applied_time));
  if (!job.from_archive && !stopped) {
    for (auto it = sc.ready.begin();
         it != sc.ready.end() && static_cast<int>(job.frames.size()) < options_.max_frames_per_job;
         ++it) {
      job.frames.push_back({it->first, it->second.station, it->second.sequence, it->second.frame});
    }
  }
  if (stopped || job.setup == nullptr || !job.session.has_value()) {
    job.frames.clear();
    job.from_archive = false;
  }
}

bool EstimationCore::RetryJobAfterReadError(Spacecraft& sc, ApplyJob& job,
                                            const std::string& message) {
  SetApplyFault(sc.id, message);
  {
    absl::MutexLock lock(&sc.state_mu);
    sc.service_alerts.insert(sc.service_alerts.begin(), job.service_alerts.begin(),
                             job.service_alerts.end());
  }
  ++sc.apply_retries;
  job.slot.Release();
  absl::SleepFor(BackoffDelay(sc.apply_retries, absl::Milliseconds(100), kMaxReconnectWait));
  return true;
}

void EstimationCore::EndApplyFault(Spacecraft& sc) {
  if (sc.apply_retries == 0) return;
  sc.apply_retries = 0;
  SetApplyFault(sc.id, "");
}

std::optional<bool> EstimationCore::ReadJobFrames(Spacecraft& sc, ApplyJob& job) {
  const bool filter_runs =
      job.setup != nullptr && job.session.has_value() && !job.apply.FilterStopped();
  if (filter_runs && job.rerun_from.has_value()) {
    absl::StatusOr<Rerun> started =
        StartRerun(sc.id, *job.setup, *job.rerun_from, &job.session, &job.apply);
    if (!started.ok()) {
      return RetryJobAfterReadError(
          sc, job,
          absl::StrCat(sc.id, ": cannot start the re-run over late frames: ",
                       started.status().ToString()));
    }
    job.rerun = std::move(*started);
    job.frames.clear();
    job.from_archive = true;
  }
  if (filter_runs && job.from_archive) {
    absl::StatusOr<std::vector<storage::ArchivedFrame>> archived =
        storage_->archive().ReadAfter(sc.id, job.apply.applied_time, options_.max_frames_per_job);
    if (!archived.ok()) {
      return RetryJobAfterReadError(
          sc, job, absl::StrCat(sc.id, ": archive read failed: ", archived.status().ToString()));
    }
    if (archived->empty()) {
      absl::MutexLock lock(&sc.state_mu);
      // Caught up only if nothing became durable meanwhile (the committer skips the in-memory
      // queue while this flag is set).
      if (sc.generation == job.generation && sc.last_durable_time <= job.apply.applied_time) {
        sc.replay_from_archive = false;
        job.rebuild_done = job.apply.rebuilding;
      }
      if (!job.rebuild_done && job.service_alerts.empty()) {
        EndApplyFault(sc);
        return true;
      }
    }
    for (const storage::ArchivedFrame& a : *archived) {
      absl::StatusOr<TelemetryFrame> frame = DecodeArchivedFrame(a.payload);
      JobFrame f{a.measurement_time, a.station_id, a.sequence, std::nullopt};
      if (frame.ok()) {
        f.frame = std::move(*frame);
      } else {
        f.undecodable = std::string(frame.status().message());
        LogEvent("ERROR", "frame_undecodable",
                 absl::StrCat(sc.id, ": archived frame (station ", a.station_id, ", sequence ",
                              a.sequence, ") cannot be decoded: ", frame.status().ToString()),
                 {{"spacecraftId", sc.id}, {"station", a.station_id}, {"sequence", a.sequence}});
      }
      job.frames.push_back(std::move(f));
    }
  }
  // A job with nothing to commit after its reads succeeded ends a fault the reads raised.
  if (job.frames.empty() && job.service_alerts.empty() && !job.rebuild_done &&
      !job.rerun.has_value() && job.late_done.empty()) {
    EndApplyFault(sc);
    return false;
  }
  return std::nullopt;
}

void EstimationCore::ApplyJobFrames(Spacecraft& sc, ApplyJob& job) {
  job.now = absl::Now();
  ServerCheckpoint& apply = job.apply;
  std::optional<EstimationSession>& session = job.session;
  job.alerts.emplace(sc.id, apply.alert_tracks, options_.alert_collapse_window, job.now);
  AlertCollapser& alerts = *job.alerts;
  // A rebuilt session does not store again what is already stored.
  const absl::Time written = apply.effects_written_until;
  for (const AlertOccurrence& o : job.service_alerts) alerts.Add(o);
  // The frame is behind the filter from here on, applied or skipped.
  auto advance_cursor = [&apply](const JobFrame& f) {
    apply.applied_time = f.time;
    apply.applied_station = f.station;
    apply.applied_sequence = f.sequence;
  };
  const absl::Duration period = options_.window_checkpoint_period;
  auto period_of = [period](absl::Time t) {
    absl::Duration rest;
    return absl::IDivDuration(t - absl::UnixEpoch(), period, &rest);
  };
  size_t processed = 0;
  for (JobFrame& f : job.frames) {
    if (period > absl::ZeroDuration() && options_.reorder_window > absl::ZeroDuration() &&
        apply.applied_time != absl::InfinitePast() && session.has_value() &&
        period_of(f.time) != period_of(apply.applied_time)) {
      if (processed > 0) break;
      job.window_checkpoint = storage::WindowCheckpoint{apply.applied_time, job.now,
                                                        EncodeWindowCheckpoint(apply, *session)};
    }
    ++processed;
    if (!f.frame.has_value()) {
      advance_cursor(f);
      ++apply.frames_apply_failed;
      // Raised on every run that skips it, also below `written`: the frame may have been
      // applied when it was first run (checks the service made stricter since, an archive of an
      // older version), so no alert of it was stored then; a repeat collapses into the stored
      // alert's track.
      alerts.Add({"ARCHIVED_FRAME_UNREADABLE", "WARNING", absl::StrCat("station ", f.station),
                  f.time, static_cast<double>(f.sequence), 0.0, "sequence",
                  absl::StrCat("an archived frame cannot be decoded (",
                               BoundedMessage(f.undecodable), "); the filter skipped it")});
      continue;
    }
    const TelemetryFrame& frame = *f.frame;
    // The operators' readmissions stored after the previous frame and before this one
    // (operator_actions.cc), in a re-run too; one that does not fit the session any more (the
    // gyro not excluded at this point of a re-run) changes nothing.
    ApplyReadmissions(sc.id, job.readmissions, frame.time, f.time > written, *session);
    const estimator::SessionState state_before = session->state();
    const absl::Time step_start = absl::Now();
    absl::StatusOr<estimator::StepReport> report = session->AddFrame(frame);
    metrics_.filter_step
        .With({!report.ok()                  ? "failed"
               : report->measurement_step ? "measurement"
                                            : "propagation"})
        .Observe(absl::ToDoubleSeconds(absl::Now() - step_start));
    if (!report.ok()) {
      LogEvent("WARN", "frame_not_applied",
               absl::StrCat(sc.id, ": frame (station ", f.station, ", sequence ", f.sequence,
                            ") not applied: ", report.status().ToString()),
               {{"spacecraftId", sc.id}, {"station", f.station}, {"sequence", f.sequence}});
      const absl::StatusCode code = report.status().code();
      if (code == absl::StatusCode::kInternal || code == absl::StatusCode::kDataLoss) {
        QuarantineJob(sc, job, f.time, f.station, f.sequence, report.status());
        break;
      }
      advance_cursor(f);
      ++apply.frames_apply_failed;
      continue;
    }
    advance_cursor(f);
    ++apply.frames_applied;
    if (session->state() != state_before && f.time > written) {
      job.state_changes.push_back({state_before, session->state(), f.time, f.station, f.sequence});
    }
    if (report->measurement_step && frame.star_tracker.has_value() && frame.star_tracker->valid &&
        !report->star_tracker_used) {
      ++apply.star_tracker_rejections;
    }
    if (report->measurement_step && report->star_tracker_used) {
      apply.last_star_tracker_time = frame.time;
    }
    if (report->measurement_step && frame.time > written) {
      const std::vector<estimator::GyroEstimate> gyros = session->Gyros();
      job.estimates.push_back(EstimateFromStep(sc.id, frame, *report, gyros,
                                               apply.last_star_tracker_time, job.now));
      for (const estimator::GyroEstimate& g : gyros) {
        job.coefficients.push_back(
            CoefficientsOfStep(sc.id, frame.time, job.now, job.setup->model_name, g));
      }
    }
    alerts.Advance(frame.time);
    if (report->measurement_step && report->star_tracker_used) {
      alerts.StarTrackerAccepted(frame.time);
    }
    for (const Event& event : report->events) {
      if (event.time <= written) continue;
      alerts.Add({estimator::EventKindName(event.kind), SeverityName(SeverityOf(event.kind)),
                  event.subsystem, event.time, event.value, event.threshold, event.unit,
                  event.message});
    }
  }
  if (job.rebuild_done) {
    LogEvent("INFO", "quarantine_over",
             absl::StrCat("spacecraft ", sc.id, " rebuilt from the archive; quarantine over"),
             {{"spacecraftId", sc.id}});
    apply.quarantine_reason.clear();
    apply.rebuilding = false;
    alerts.End(kQuarantineReason, "session", apply.applied_time);
  }
}

// The filter itself failed: the job stops before this frame (the checkpoint stays at the last
// good one) and the spacecraft is quarantined; the others and the server go on.
void EstimationCore::QuarantineJob(Spacecraft& sc, ApplyJob& job, absl::Time time,
                                   const std::string& station, int64_t sequence,
                                   const absl::Status& failure) {
  job.apply.quarantine_reason =
      absl::StrCat("the filter failed at the frame of ", FormatUtc(time), " (station ", station,
                   ", sequence ", sequence, "): ", failure.message(),
                   "; the filter is stopped until ConfigureSpacecraft with replace=true");
  job.apply.rebuilding = false;
  job.alerts->Add({kQuarantineReason, "DISTRESS", "session", time, 0.0, 0.0, "",
                   job.apply.quarantine_reason});
  LogEvent("ERROR", "session_quarantined",
           absl::StrCat("spacecraft ", sc.id, " quarantined: ", job.apply.quarantine_reason),
           {{"spacecraftId", sc.id}});
}

std::optional<bool> EstimationCore::CommitJob(Spacecraft& sc, ApplyJob& job) {
  // The effects and the checkpoint in one transaction.
  ServerCheckpoint to_store = job.apply;
  AlertCollapser& alerts = *job.alerts;
  storage::FilterEffects& effects = job.effects;
  effects.spacecraft_id = sc.id;
  effects.fence = FenceOf(sc);
  effects.coefficients = std::move(job.coefficients);
  // Retention of the per-step estimates, amortised: once the newest has advanced by the period.
  if (options_.estimate_retention > absl::ZeroDuration() && !job.estimates.empty()) {
    const absl::Time newest = job.estimates.back().measurement_time;
    if (sc.estimates_retained_at == absl::InfinitePast() ||
        newest - sc.estimates_retained_at >= options_.estimate_retention_period) {
      effects.estimates_before = newest - options_.estimate_retention;
      job.retained_at = newest;
    }
  }
  effects.estimates = std::move(job.estimates);
  if (job.rerun.has_value()) {
    effects.revision = storage::FilterEffects::Revision{job.rerun->after, job.now,
                                                        job.rerun->revised_alerts,
                                                        job.rerun->restores};
  }
  effects.late_frames_done = job.late_done;
  if (job.window_checkpoint.has_value()) {
    effects.window_checkpoint = std::move(job.window_checkpoint);
    // A late frame is accepted up to the window before the last accepted frame, which is at or
    // after this cursor: the latest checkpoint before (cursor - window) is the oldest needed.
    effects.prune_before = job.apply.applied_time - options_.reorder_window;
  }
  effects.new_alerts = alerts.new_alerts();
  for (const auto& [seq, rep] : alerts.repeats()) effects.repeats.push_back(rep);
  for (const AlertCollapser::Clear& c : alerts.clears()) {
    effects.clears.push_back({c.sequence, c.time});
  }
  // The checkpoint carries the live alert tracks with the sequences the store assigns.
  effects.checkpoint = [&](const std::vector<int64_t>& sequences) {
    to_store.alert_tracks = alerts.Tracks(sequences);
    storage::CheckpointRecord cp;
    cp.spacecraft_id = sc.id;
    cp.last_sequence = job.apply.applied_sequence;
    cp.measurement_time =
        job.session.has_value() && job.session->last_frame_time() != absl::InfinitePast()
            ? job.session->last_frame_time()
            : absl::UnixEpoch();
    cp.compute_time = job.now;
    if (job.session.has_value()) to_store.session = job.session->ExportCheckpoint();
    cp.state_blob = EncodeCheckpoint(to_store);
    return cp;
  };
  job.slot.Release();
  const absl::Time commit_start = absl::Now();
  absl::StatusOr<std::vector<int64_t>> committed = CommitFilterJob(effects);
  const absl::Status status = committed.status();
  if (committed.ok()) job.new_sequences = std::move(*committed);
  effects.checkpoint = nullptr;  // it refers to this function's to_store
  metrics_.storage_commit.With({"filter"}).Observe(
      absl::ToDoubleSeconds(absl::Now() - commit_start));
  if (storage::LeaseLostSpacecraft(status).has_value()) {
    MarkLeaseLost(sc, status.message());
    return false;
  }
  if (!status.ok()) {
    // Storage trouble (a full disk, an I/O error): health says so; this job is retried with a
    // growing pause (at most 2 s), the installed session and its checkpoint stay as they were.
    SetApplyFault(sc.id, status.ToString());
    ++sc.apply_retries;
    const absl::Duration pause =
        BackoffDelay(sc.apply_retries, absl::Milliseconds(100), kMaxReconnectWait);
    {
      absl::MutexLock lock(&sc.state_mu);
      sc.service_alerts.insert(sc.service_alerts.begin(), job.service_alerts.begin(),
                               job.service_alerts.end());
      if (job.rebuild_done && sc.generation == job.generation) sc.replay_from_archive = true;
    }
    absl::SleepFor(pause);
    return true;
  }
  EndApplyFault(sc);
  if (job.retained_at.has_value()) sc.estimates_retained_at = *job.retained_at;
  job.apply.alert_tracks = to_store.alert_tracks;
  return std::nullopt;
}

std::optional<bool> EstimationCore::InstallJob(Spacecraft& sc, ApplyJob& job) {
  bool more = false;
  int64_t freed_bytes = 0;  // of the applied frames dropped from memory
  {
    absl::MutexLock lock(&sc.state_mu);
    if (sc.generation != job.generation) return std::nullopt;
    sc.session = std::move(job.session);
    sc.apply = std::move(job.apply);
    sc.last_compute_time = job.now;
    for (absl::Time t : job.late_done) sc.late_frames.erase(t);
    if (job.rerun.has_value()) {
      // The re-run goes on from the archive until it has caught up.
      sc.ready.clear();
      sc.ready_bytes = 0;
      sc.replay_from_archive = true;
    }
    const bool stopped = sc.apply.FilterStopped();
    auto end = sc.ready.upper_bound(sc.apply.applied_time);
    for (auto it = sc.ready.begin(); it != end; ++it) {
      const int64_t bytes = static_cast<int64_t>(sizeof(ReadyFrame) + it->second.station.size());
      sc.ready_bytes -= bytes;
      freed_bytes += bytes;
    }
    sc.ready.erase(sc.ready.begin(), end);
    more = !stopped && (sc.replay_from_archive || !sc.ready.empty() ||
                        !sc.service_alerts.empty() || !sc.late_frames.empty());
  }
  // A backlog applied leaves its frames' memory free in malloc's arenas, interleaved with the
  // sessions' blocks: handed back to the system once enough is noted (memory_release.h), so a
  // burst of telemetry does not keep the resident set at its peak.
  NoteFreedMemory(freed_bytes);
  return more;
}

void EstimationCore::PublishJob(Spacecraft& sc, const ApplyJob& job) {
  const AlertCollapser& alerts = *job.alerts;
  std::vector<storage::AlertRecord> published = alerts.new_alerts();
  for (size_t k = 0; k < published.size(); ++k) published[k].sequence = job.new_sequences[k];
  absl::MutexLock publish(&sc.publish_mu);
  if (job.rerun.has_value()) {
    metrics_.revisions.Increment();
    LogEvent("INFO", "revision",
             absl::StrCat("spacecraft ", sc.id, ": late frame of ", FormatUtc(*job.rerun_from),
                          " re-runs the filter from ",
                          job.rerun->after == absl::InfinitePast()
                              ? std::string("the configuration")
                              : FormatUtc(job.rerun->after),
                          "; ", job.rerun->revised_alerts.size(), " alerts revised"),
             {{"spacecraftId", sc.id}, {"lateFrameTime", FormatUtc(*job.rerun_from)}});
    for (int64_t seq : job.rerun->revised_alerts) {
      absl::StatusOr<storage::AlertRecord> r = storage_->alerts().Get(sc.id, seq);
      if (r.ok()) hub_.Publish(*r);
    }
  }
  estimate_hub_.Publish(job.effects.estimates);
  for (const storage::AlertRecord& a : published) {
    metrics_.alerts_raised.With({a.reason, a.severity}).Increment();
    if (a.cleared) metrics_.alerts_cleared.With({a.reason, a.severity}).Increment();
    hub_.Publish(a);
  }
  NotifyModelAlerts(published);
  for (const StateChange& c : job.state_changes) {
    const char* from = estimator::SessionStateName(c.from);
    const char* to = estimator::SessionStateName(c.to);
    LogEvent("INFO", "session_state",
             absl::StrCat("spacecraft ", sc.id, ": session state ", from, " -> ", to, " at ",
                          FormatUtc(c.time), " (station ", c.station, ", sequence ", c.sequence,
                          ")"),
             {{"spacecraftId", sc.id},
              {"from", from},
              {"to", to},
              {"measurementTime", FormatUtc(c.time)},
              {"station", c.station},
              {"sequence", c.sequence}});
  }
  std::set<int64_t> changed;
  std::set<int64_t> cleared;
  for (const AlertCollapser::Clear& c : alerts.clears()) {
    changed.insert(c.sequence);
    cleared.insert(c.sequence);
  }
  for (const auto& [seq, rep] : alerts.repeats()) changed.insert(seq);
  // Alerts a re-run set back to their state at its checkpoint: their state now (set back, or
  // repeated or cleared again by the re-run) is news to subscribers even where it is lower.
  if (job.rerun.has_value()) {
    for (const storage::AlertRestore& r : job.rerun->restores) changed.insert(r.sequence);
  }
  for (int64_t seq : changed) {
    absl::StatusOr<storage::AlertRecord> r = storage_->alerts().Get(sc.id, seq);
    if (!r.ok()) continue;
    if (cleared.count(seq) != 0) metrics_.alerts_cleared.With({r->reason, r->severity}).Increment();
    hub_.Publish(*r);
  }
}

absl::StatusOr<TelemetryFrame> DecodeArchivedFrame(const std::string& payload) {
  esg::v1::TelemetryFrame proto;
  if (!proto.ParseFromString(payload)) return absl::DataLossError("the payload does not parse");
  return proto_convert::FrameFromProto(proto);
}

}  // namespace esg::server
