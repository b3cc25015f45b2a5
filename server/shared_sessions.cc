// Several servers sharing one PostgreSQL database (docs/service.md "Several servers"): session
// leases (take on demand, renew, fence the writes), the fleet as other servers committed it, and
// the relay of other servers' alert changes and estimates. Part of EstimationCore
// (estimation_core.h); the lease rows are storage/lease_store.h.
#include <algorithm>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "estimator/status_macros.h"
#include "server/backoff.h"
#include "server/core_internal.h"
#include "server/estimation_core.h"
#include "server/grpc_status.h"
#include "server/log.h"
#include "storage/lease_store.h"
#include "storage/postgres_db.h"
#include "storage/postgres_schema.h"
#include "storage/schema.h"

namespace esg::server {

absl::Status EstimationCore::CheckConfigured(const std::string& spacecraft_id) {
  if (Find(spacecraft_id) != nullptr) return absl::OkStatus();
  if (!shared()) return NotConfigured(spacecraft_id);
  absl::StatusOr<storage::ConfigRecord> stored = storage_->configs().Get(spacecraft_id);
  if (absl::IsNotFound(stored.status())) return NotConfigured(spacecraft_id);
  return stored.status();
}

absl::StatusOr<std::shared_ptr<EstimationCore::Spacecraft>> EstimationCore::Lookup(
    const std::string& spacecraft_id) {
  std::shared_ptr<Spacecraft> sc = Find(spacecraft_id);
  if (!shared()) {
    if (sc == nullptr) return NotConfigured(spacecraft_id);
    return sc;
  }
  if (sc != nullptr && !sc->lease_lost) return sc;
  absl::MutexLock takeover(&takeover_mu_);
  sc = Find(spacecraft_id);
  if (sc != nullptr && !sc->lease_lost) return sc;
  absl::StatusOr<storage::ConfigRecord> record = storage_->configs().Get(spacecraft_id);
  if (absl::IsNotFound(record.status())) return NotConfigured(spacecraft_id);
  if (!record.ok()) return record.status();
  absl::StatusOr<storage::SessionLease> lease = storage_->leases().Acquire(
      spacecraft_id, options_.node_id, absl::Now(), options_.lease_duration);
  if (!lease.ok()) return LeaseRefused(lease.status());
  // The session as the last owner left it: its checkpoint, then the archive after it.
  RETURN_IF_ERROR(LoadSpacecraft(*record, lease->epoch));
  sc = Find(spacecraft_id);
  if (sc == nullptr) return absl::InternalError("a loaded session is not in the registry");
  metrics_.lease_events.With({"taken"}).Increment();
  LogEvent("INFO", "session_taken",
           absl::StrCat("took the session of ", spacecraft_id, " (lease epoch ", lease->epoch,
                        ")"),
           {{"spacecraftId", spacecraft_id}, {"leaseEpoch", lease->epoch}});
  Schedule(sc);
  return sc;
}

absl::Status EstimationCore::LeaseRefused(const absl::Status& status) {
  const std::optional<absl::Time> held_until = storage::LeaseHeldUntil(status);
  if (!held_until.has_value()) return status;
  metrics_.lease_events.With({"refused"}).Increment();
  // The holder's expiry by this server's clock (the clocks agree: docs/service.md), at most one
  // lease duration: a holder that renews refuses the retry again with a new delay.
  const absl::Duration delay =
      std::clamp(*held_until - absl::Now(), absl::ZeroDuration(), options_.lease_duration);
  // The store's message names the field first ("spacecraft_id: 'X' is served by node N until
  // T"), so a refused frame's Rejection names it (RejectionFromStatus).
  return WithRetryDelay(
      absl::UnavailableError(absl::StrCat(status.message(), "; retry after that (leases last ",
                                          absl::FormatDuration(options_.lease_duration),
                                          "): docs/service.md \"Several servers\"")),
      delay);
}

std::optional<storage::LeaseFence> EstimationCore::FenceOf(const Spacecraft& sc) const {
  if (!shared()) return std::nullopt;
  return storage::LeaseFence{options_.node_id, sc.lease_epoch.load()};
}

void EstimationCore::MarkLeaseLost(Spacecraft& sc, absl::string_view why) {
  if (sc.lease_lost.exchange(true)) return;
  metrics_.lease_events.With({"lost"}).Increment();
  LogEvent("WARN", "session_lost",
           absl::StrCat("the session of ", sc.id, " was taken over by another server: ", why),
           {{"spacecraftId", sc.id}});
}

// The notification connection is re-made with backoff (backoff.h): while the database is
// unreachable the loop makes at most two connection attempts a second and logs two lines in all,
// one when the connection is lost (or cannot be made at the start) and one with the count of
// attempts when it is made again (docs/service.md "Reconnects and retries").
void EstimationCore::RelayLoop() {
  std::unique_ptr<storage::PostgresListener> listener;
  Backoff reconnect(absl::Milliseconds(50), kMaxReconnectWait);
  bool lost = false;  // relay_interrupted or relay_failed logged, not yet relay_recovered
  absl::Time lost_at = absl::Now();
  for (;;) {
    {
      absl::MutexLock lock(&stop_mu_);
      if (stopped_) return;
    }
    if (listener == nullptr) {
      absl::StatusOr<std::unique_ptr<storage::PostgresListener>> opened =
          storage_->ListenForChanges();
      if (!opened.ok()) {
        if (!lost) {
          lost_at = absl::Now();
          LogEvent("ERROR", "relay_failed",
                   absl::StrCat("cannot follow the alerts and estimates of other servers: ",
                                opened.status().message(), " (retrying, at most ",
                                absl::FormatDuration(kMaxReconnectWait), " apart)"));
          lost = true;
        }
        const absl::Duration wait = reconnect.Failed();
        absl::MutexLock lock(&stop_mu_);
        stop_mu_.AwaitWithTimeout(absl::Condition(&stopped_), wait);
        continue;
      }
      listener = *std::move(opened);
      if (lost) {
        LogEvent("INFO", "relay_recovered",
                 absl::StrCat("following the alerts and estimates of other servers again after ",
                              reconnect.failures() + 1, " connection attempts over ",
                              absl::FormatDuration(
                                  absl::Trunc(absl::Now() - lost_at, absl::Milliseconds(1))),
                              " (what they stored meanwhile was not relayed: replay with since)"),
                 {{"attempts", reconnect.failures() + 1}});
      }
      lost = false;
      reconnect.Reset();
    }
    absl::StatusOr<std::vector<storage::PostgresListener::Notification>> notified =
        listener->Wait(absl::Milliseconds(250));
    if (!notified.ok()) {
      // Re-made by the branch above, with backoff: Wait's own reconnect would be tried again at
      // once, as fast as the refusals come (docs/decisions.md D95: 70,000 lines a second).
      LogEvent("WARN", "relay_interrupted",
               absl::StrCat("alerts and estimates of other servers may have been missed: ",
                            notified.status().message(), " (reconnecting, at most ",
                            absl::FormatDuration(kMaxReconnectWait), " apart)"));
      listener.reset();
      lost = true;
      lost_at = absl::Now();
      reconnect.Reset();
      continue;
    }
    if (notified->empty()) continue;
    const int own_pid = storage_->ConnectionPid();
    const int own_filter_pid = storage_->FilterConnectionPid();
    // Estimates are read only for subscribers, per spacecraft in one range read.
    const bool estimate_subscribers = estimate_hub_.size() > 0;
    std::map<std::string, std::set<absl::Time>> estimated;
    for (const storage::PostgresListener::Notification& n : *notified) {
      // This server's own commits are published by the code that made them.
      if (n.sender_pid == own_pid || n.sender_pid == own_filter_pid) continue;
      // "<number> <spacecraft id>": an alert's sequence, an estimate's measurement time.
      const size_t space = n.payload.find(' ');
      int64_t number = 0;
      if (space == std::string::npos || !absl::SimpleAtoi(n.payload.substr(0, space), &number)) {
        continue;
      }
      std::string spacecraft_id = n.payload.substr(space + 1);
      if (n.channel == storage::kAlertsChannel) {
        absl::StatusOr<storage::AlertRecord> record = storage_->alerts().Get(spacecraft_id, number);
        if (record.ok()) hub_.Publish(*record, /*log=*/false);
      } else if (n.channel == storage::kEstimatesChannel && estimate_subscribers) {
        estimated[std::move(spacecraft_id)].insert(storage::UnixNanosToTime(number));
      }
    }
    for (const auto& [spacecraft_id, times] : estimated) RelayEstimates(spacecraft_id, times);
  }
}

void EstimationCore::RelayEstimates(const std::string& spacecraft_id,
                                    const std::set<absl::Time>& times) {
  constexpr int64_t kPage = 500;
  std::vector<storage::EstimateRecord> relayed;
  std::optional<absl::Time> after;
  do {
    absl::StatusOr<storage::EstimatePage> page = storage_->estimates().Page(
        spacecraft_id, *times.begin(), *times.rbegin() + absl::Nanoseconds(1), after, kPage);
    if (!page.ok()) {
      LogEvent(
          "WARN", "relay_interrupted",
          absl::StrCat("estimates of ", spacecraft_id,
                       " stored by another server were not relayed: ", page.status().message()),
          {{"spacecraftId", spacecraft_id}});
      break;
    }
    // A step recomputed again since its notification is sent as stored now (its later
    // compute_time), and once more for its own notification; a deleted one is not sent.
    for (storage::EstimateRecord& r : page->records) {
      if (times.count(r.measurement_time) > 0) relayed.push_back(std::move(r));
    }
    after = page->next;
  } while (after.has_value());
  estimate_hub_.Publish(relayed);
}

// A failed renewal is retried with backoff, at most kMaxReconnectWait apart (and never later than
// the next period), so the leases are renewed within that time of the database's return; one
// line when renewals start failing, one with the count of attempts when one succeeds again.
void EstimationCore::LeaseLoop() {
  const absl::Duration period = options_.lease_duration / 3;
  Backoff retry(absl::Milliseconds(100), std::min(period, kMaxReconnectWait));
  absl::Duration wait = period;
  for (;;) {
    {
      absl::MutexLock lock(&stop_mu_);
      stop_mu_.AwaitWithTimeout(absl::Condition(&stopped_), wait);
      if (stopped_) return;
    }
    wait = period;
    // One transaction for all of this server's leases: one commit a period, however many
    // sessions it holds.
    std::map<std::string, std::shared_ptr<Spacecraft>> held;
    std::map<std::string, storage::LeaseFence> fences;
    for (const auto& sc : registry_.All()) {
      if (sc->lease_lost) continue;
      fences.emplace(sc->id, *FenceOf(*sc));
      held.emplace(sc->id, sc);
    }
    if (fences.empty()) continue;
    const absl::StatusOr<std::vector<std::string>> lost =
        storage_->leases().RenewAll(fences, absl::Now(), options_.lease_duration);
    if (!lost.ok()) {
      if (retry.failures() == 0) {
        LogEvent("ERROR", "lease_renewal_failed",
                 absl::StrCat("cannot renew the session leases of ", fences.size(),
                              " spacecraft: ", lost.status().message(), " (retrying, at most ",
                              absl::FormatDuration(std::min(period, kMaxReconnectWait)),
                              " apart; sessions are lost when their leases expire)"),
                 {{"leases", static_cast<int64_t>(fences.size())}});
      }
      wait = retry.Failed();
      continue;
    }
    if (retry.failures() > 0) {
      LogEvent("INFO", "lease_renewal_recovered",
               absl::StrCat("renewed the session leases of ", fences.size(),
                            " spacecraft again after ", retry.failures(),
                            " failed attempts over ",
                            absl::FormatDuration(absl::Trunc(absl::Now() - retry.since(),
                                                             absl::Milliseconds(1)))),
               {{"leases", static_cast<int64_t>(fences.size())}, {"attempts", retry.failures()}});
      retry.Reset();
    }
    for (const std::string& id : *lost) {
      const storage::LeaseFence& fence = fences.at(id);
      MarkLeaseLost(*held.at(id),
                    absl::StrCat("spacecraft '", id, "': the lease of node ", fence.owner,
                                 " (epoch ", fence.epoch, ") was taken over"));
    }
  }
}

absl::StatusOr<esg::v1::SessionInfo> EstimationCore::SummarizeFromDatabase(
    const storage::ConfigRecord& record) {
  ASSIGN_OR_RETURN(std::shared_ptr<Spacecraft> sc, RestoreSpacecraft(record, /*snapshot=*/true));
  SessionSummary summary = Summarize(*sc);
  summary.served_by.clear();
  absl::StatusOr<storage::SessionLease> lease = storage_->leases().Get(record.spacecraft_id);
  if (lease.ok() && lease->expires > absl::Now()) summary.served_by = lease->owner;
  if (!lease.ok() && !absl::IsNotFound(lease.status())) return lease.status();
  return SessionInfoToProto(summary);
}

}  // namespace esg::server
