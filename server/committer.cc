// Group commit of accepted frames to the telemetry archive (see estimation_core.h "DATA FLOW AND
// DURABILITY" and docs/service.md "Storage faults"): one transaction for everything queued, acks
// only after it committed; a failed commit fails the senders' streams with UNAVAILABLE and holds
// ingest until a probe write succeeds.
#include <algorithm>
#include <map>
#include <set>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "estimator/status_macros.h"
#include "server/backoff.h"
#include "server/core_internal.h"
#include "server/estimation_core.h"
#include "server/log.h"
#include "server/memory_release.h"
#include "storage/service_queries.h"

namespace esg::server {

absl::Status EstimationCore::CommitFrames(const std::vector<CommitEntry>& batch) {
  std::vector<storage::ArchivedFrame> frames;
  frames.reserve(batch.size());
  std::map<std::string, std::vector<absl::Time>> late;
  std::map<std::string, storage::LeaseFence> fences;  // with leases
  for (const CommitEntry& e : batch) {
    if (e.barrier) continue;
    if (e.late) late[e.sc->id].push_back(e.time);
    if (std::optional<storage::LeaseFence> fence = FenceOf(*e.sc)) fences[e.sc->id] = *fence;
    storage::ArchivedFrame f;
    f.spacecraft_id = e.sc->id;
    f.station_id = e.station;
    f.sequence = e.sequence;
    f.measurement_time = e.time;
    f.payload = e.payload;
    frames.push_back(std::move(f));
  }
  // Ingest decided every frame new; one the archive already holds fails the whole commit
  // (AlreadyExists) rather than be acknowledged falsely. Late frames are recorded in the same
  // transaction: a restart still re-runs the filter over them.
  return storage_->ArchiveFrames(frames, late, fences);
}

// A filter job waiting for the group commit (CommitFilterJob).
struct EstimationCore::FilterCommit {
  EstimationCore* core = nullptr;
  const storage::FilterEffects* effects = nullptr;
  absl::StatusOr<std::vector<int64_t>> result;
  bool done = false;
};

// The filter's group commit on PostgreSQL, as ingest's (CommitterLoop) but without a thread of
// its own: the first waiting job's thread commits every job queued at that moment in one
// transaction, each job in its own savepoint (Storage::CommitFilterEffectsGroup), and hands each
// job its own result; jobs that arrive meanwhile wait and form the next group. The first job
// of a group waits up to filter_commit_window for others to join it (D109). A job's result is
// thus what committing it alone would give: OK only once its effects are durable, its lost lease
// or refused record its own failure, never the others'.
absl::StatusOr<std::vector<int64_t>> EstimationCore::CommitFilterJob(
    const storage::FilterEffects& effects) {
  if (!group_filter_commits_) {
    filter_transactions_.fetch_add(1, std::memory_order_relaxed);
    filter_jobs_committed_.fetch_add(1, std::memory_order_relaxed);
    return storage_->CommitFilterEffects(effects);
  }
  FilterCommit mine;
  mine.core = this;
  mine.effects = &effects;
  filter_commit_mu_.Lock();
  filter_commit_queue_.push_back(&mine);
  while (!mine.done) {
    if (filter_committing_) {
      filter_commit_mu_.Await(absl::Condition(
          +[](FilterCommit* c) ABSL_EXCLUSIVE_LOCKS_REQUIRED(c->core->filter_commit_mu_) {
            return c->done || !c->core->filter_committing_;
          },
          &mine));
      continue;
    }
    // The group's leader: the jobs that finish within filter_commit_window of this one join
    // its transaction (docs/decisions.md D109), up to every thread of the pool waiting; the
    // window only delays the estimates' publication, never an ack (acks follow ingest's commit).
    filter_committing_ = true;
    if (options_.filter_commit_window > absl::ZeroDuration()) {
      filter_commit_mu_.AwaitWithTimeout(
          absl::Condition(
              +[](EstimationCore* c) ABSL_EXCLUSIVE_LOCKS_REQUIRED(c->filter_commit_mu_) {
                return static_cast<int>(c->filter_commit_queue_.size()) >=
                       c->options_.filter_commit_group;
              },
              this),
          options_.filter_commit_window);
    }
    std::vector<FilterCommit*> group;
    group.swap(filter_commit_queue_);
    filter_commit_mu_.Unlock();
    std::vector<const storage::FilterEffects*> jobs;
    jobs.reserve(group.size());
    for (const FilterCommit* c : group) jobs.push_back(c->effects);
    std::vector<absl::StatusOr<std::vector<int64_t>>> results =
        storage_->CommitFilterEffectsGroup(jobs);
    filter_transactions_.fetch_add(1, std::memory_order_relaxed);
    filter_jobs_committed_.fetch_add(static_cast<int64_t>(group.size()),
                                     std::memory_order_relaxed);
    filter_commit_mu_.Lock();
    for (size_t j = 0; j < group.size(); ++j) {
      group[j]->result = std::move(results[j]);
      group[j]->done = true;
    }
    filter_committing_ = false;
  }
  filter_commit_mu_.Unlock();
  return std::move(mine.result);
}

void EstimationCore::AcquireApplySlot() {
  if (!group_filter_commits_) return;
  absl::MutexLock lock(&apply_slots_mu_);
  apply_slots_mu_.Await(absl::Condition(
      +[](int* free) { return *free > 0; }, &apply_slots_free_));
  --apply_slots_free_;
}

void EstimationCore::ReleaseApplySlot() {
  if (!group_filter_commits_) return;
  absl::MutexLock lock(&apply_slots_mu_);
  ++apply_slots_free_;
}

void EstimationCore::StorageCommitFailed(const std::string& reason) {
  bool log = false;
  int64_t failed_commits = 0;
  {
    absl::MutexLock lock(&commit_mu_);
    if (storage_fault_.empty()) {
      storage_fault_since_ = absl::Now();
      storage_failed_commits_ = 0;
      storage_failed_probes_ = 0;
    }
    log = storage_fault_ != reason;
    storage_fault_ = reason;
    storage_trial_ = false;
    failed_commits = ++storage_failed_commits_;
  }
  if (log) {
    LogEvent("ERROR", "storage_error",
             absl::StrCat("storage cannot commit: ", reason,
                          "; ingest refused with UNAVAILABLE until it can",
                          failed_commits > 1
                              ? absl::StrCat(" (", failed_commits, " commits failed so far)")
                              : std::string()),
             {{"reason", reason}, {"failedCommits", failed_commits}});
  }
  NotifyStorageHealth();
}

void EstimationCore::StorageCommitSucceeded() {
  std::string ended;
  int64_t failed_commits = 0;
  int64_t failed_probes = 0;
  absl::Duration lasted;
  {
    absl::MutexLock lock(&commit_mu_);
    if (storage_fault_.empty()) return;
    ended.swap(storage_fault_);
    storage_trial_ = false;
    failed_commits = storage_failed_commits_;
    failed_probes = storage_failed_probes_;
    lasted = absl::Trunc(absl::Now() - storage_fault_since_, absl::Milliseconds(1));
  }
  LogEvent("INFO", "storage_recovered",
           absl::StrCat("storage commits again: ingest resumed (", failed_commits,
                        " commits and ", failed_probes, " probe writes failed over ",
                        absl::FormatDuration(lasted), ")"),
           {{"failedCommits", failed_commits},
            {"failedProbes", failed_probes},
            {"durationSeconds", absl::ToDoubleSeconds(lasted)}});
  NotifyStorageHealth();
}

void EstimationCore::SetApplyFault(const std::string& spacecraft_id, const std::string& reason) {
  bool changed = false;
  {
    absl::MutexLock lock(&commit_mu_);
    auto it = apply_faults_.find(spacecraft_id);
    if (reason.empty()) {
      changed = it != apply_faults_.end();
      if (changed) apply_faults_.erase(it);
    } else {
      changed = it == apply_faults_.end();
      apply_faults_[spacecraft_id] = reason;
    }
  }
  if (!changed) return;
  if (reason.empty()) {
    LogEvent("INFO", "storage_recovered",
             absl::StrCat(spacecraft_id, ": the filter's commits succeed again"),
             {{"spacecraftId", spacecraft_id}});
  } else {
    LogEvent("ERROR", "storage_error",
             absl::StrCat(spacecraft_id, ": the filter cannot commit its results: ", reason,
                          "; it keeps its last checkpoint and retries"),
             {{"spacecraftId", spacecraft_id}, {"reason", reason}});
  }
  NotifyStorageHealth();
}

void EstimationCore::NotifyStorageHealth() {
  std::string fault;
  {
    absl::MutexLock lock(&commit_mu_);
    // On trial (a probe succeeded) ingest takes frames: health says so.
    fault = !storage_fault_.empty() && !storage_trial_ ? storage_fault_
            : !apply_faults_.empty()                   ? apply_faults_.begin()->second
                                                       : "";
  }
  absl::MutexLock lock(&listener_mu_);
  if (storage_listener_) storage_listener_(fault.empty(), fault);
}

// Fails every entry of `batch` (and of the queue behind it, which was accepted against the
// same high-water marks): their streams end with `error`, nothing of them is stored, and the
// marks of their spacecraft fall back to what is durable, so that the senders resume exactly
// from highest_durable_sequence + 1.
void EstimationCore::FailBatch(std::vector<CommitEntry>& batch, const absl::Status& error) {
  {
    absl::MutexLock lock(&commit_mu_);
    for (CommitEntry& e : commit_queue_) batch.push_back(std::move(e));
    commit_queue_.clear();
    commit_queue_bytes_ = 0;
  }
  std::set<Spacecraft*> rolled_back;
  for (const CommitEntry& e : batch) {
    if (!rolled_back.insert(e.sc.get()).second) continue;
    absl::MutexLock ingest(&e.sc->ingest_mu);
    absl::MutexLock state(&e.sc->state_mu);
    e.sc->highest_accepted = e.sc->highest_durable;
    e.sc->last_accepted_time = e.sc->last_durable_time;
    e.sc->pending.clear();
    e.sc->pending_ids.clear();
  }
  for (CommitEntry& e : batch) {
    if (e.done) e.done(error);
  }
}

bool EstimationCore::ProbeStorage() {
  const absl::Status probe = storage::ProbeWrite(storage_->database(), absl::Now());
  {
    absl::MutexLock lock(&commit_mu_);
    if (storage_fault_.empty()) return true;
    if (!probe.ok()) {
      ++storage_failed_probes_;
      return false;
    }
    // Not "ingest resumed" yet: a small probe write may fit where a commit of frames does not.
    storage_trial_ = true;
  }
  NotifyStorageHealth();
  return true;
}

void EstimationCore::CommitterLoop() {
  // The probe writes back off exponentially up to storage_probe_period (server/backoff.h).
  const absl::Duration probe_cap = options_.storage_probe_period;
  Backoff probes(std::min(absl::Milliseconds(50), probe_cap), probe_cap);
  absl::Duration wait = probe_cap;
  for (;;) {
    std::vector<CommitEntry> batch;
    bool faulted = false;
    bool probing = false;
    {
      absl::MutexLock lock(&commit_mu_);
      commit_mu_.AwaitWithTimeout(
          absl::Condition(
              +[](EstimationCore* c) ABSL_EXCLUSIVE_LOCKS_REQUIRED(c->commit_mu_) {
                return !c->commit_queue_.empty() || c->commit_stop_;
              },
              this),
          wait);
      faulted = !storage_fault_.empty();
      probing = faulted && !storage_trial_;
      if (commit_queue_.empty() && commit_stop_) return;
      batch.swap(commit_queue_);
      commit_queue_bytes_ = 0;
    }
    if (batch.empty()) {
      wait = probe_cap;
      if (!probing) continue;
      // The backoff goes on through a trial that fails (reset only by a commit that succeeds),
      // so a disk that takes a probe but not a commit is tried less and less often.
      if (!ProbeStorage()) wait = probes.Failed();
      continue;
    }
    const absl::Time commit_start = absl::Now();
    const absl::Status status = CommitFrames(batch);
    metrics_.storage_commit.With({"telemetry"}).Observe(
        absl::ToDoubleSeconds(absl::Now() - commit_start));
    if (const std::optional<std::string> lost = storage::LeaseLostSpacecraft(status)) {
      // Another server took a session over (a race with the lease renewal): not a storage
      // fault. Its record is marked lost; the batch's senders resume as after a fault.
      if (std::shared_ptr<Spacecraft> sc = Find(*lost)) MarkLeaseLost(*sc, status.message());
      FailBatch(batch, absl::UnavailableError(absl::StrCat(
                           status.message(), "; these frames are not stored: resume from "
                           "highest_durable_sequence + 1")));
      continue;
    }
    if (!status.ok()) {
      const std::string reason(status.ToString());
      StorageCommitFailed(reason);
      wait = std::min(absl::Milliseconds(50), probe_cap);
      FailBatch(batch, absl::UnavailableError(absl::StrCat(
                           "storage: the commit failed (", reason,
                           "); these frames are not stored: resume from "
                           "highest_durable_sequence + 1 when the service is SERVING again")));
      continue;
    }
    if (faulted) {
      StorageCommitSucceeded();
      probes.Reset();
    }
    metrics_.commit_batch_frames.Observe(static_cast<double>(std::count_if(
        batch.begin(), batch.end(), [](const CommitEntry& e) { return !e.barrier; })));
    // Per spacecraft, under both of its locks once: durable marks first, then out of the
    // pending set, so an ingest that finds a frame archived also finds it counted durable.
    std::map<Spacecraft*, std::vector<CommitEntry*>> by_spacecraft;
    std::vector<std::shared_ptr<Spacecraft>> touched;
    for (CommitEntry& e : batch) {
      if (e.barrier) continue;
      auto [it, inserted] = by_spacecraft.try_emplace(e.sc.get());
      if (inserted) touched.push_back(e.sc);
      it->second.push_back(&e);
    }
    for (auto& [sc, entries] : by_spacecraft) {
      absl::MutexLock ingest(&sc->ingest_mu);
      absl::MutexLock lock(&sc->state_mu);
      for (CommitEntry* e : entries) {
        sc->pending.erase(e->time);
        sc->pending_ids.erase({e->station, e->sequence});
        int64_t& durable = sc->highest_durable[e->station];
        durable = std::max(durable, e->sequence);
        sc->last_durable_time = std::max(sc->last_durable_time, e->time);
        ++sc->frames_accepted;
        if (e->late) sc->late_frames.insert(e->time);
        if (!sc->replay_from_archive) {
          sc->ready_bytes += static_cast<int64_t>(sizeof(ReadyFrame) + e->station.size());
          sc->ready.emplace(e->time, ReadyFrame{e->station, e->sequence, std::move(e->frame)});
          // A filter far behind ingest reads its backlog from the archive instead of memory.
          if (sc->ready_bytes > options_.max_ready_bytes) {
            sc->ready.clear();
            sc->ready_bytes = 0;
            sc->replay_from_archive = true;
          }
        }
      }
    }
    for (const auto& sc : touched) Schedule(sc);
    int64_t payload_bytes = 0;
    for (CommitEntry& e : batch) {
      payload_bytes += static_cast<int64_t>(sizeof(CommitEntry) + e.payload.size());
      if (e.done) e.done(absl::OkStatus());
    }
    // The batch's payloads are freed with it (memory_release.h, as the applied frames are).
    NoteFreedMemory(payload_bytes);
  }
}

}  // namespace esg::server
