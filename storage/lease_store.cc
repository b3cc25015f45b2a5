// Session leases; contract in lease_store.h.
#include "storage/lease_store.h"

#include <algorithm>
#include <set>
#include <utility>

#include "absl/strings/cord.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/time/time.h"
#include "estimator/status_macros.h"
#include "estimator/utc_time.h"
#include "storage/schema.h"

namespace esg::storage {
namespace {

using estimator::FormatUtc;

constexpr char kLeaseLostPayload[] = "type.esg/storage.LeaseLost";
// The holder's expiry in Unix nanoseconds, decimal.
constexpr char kLeaseHeldPayload[] = "type.esg/storage.LeaseHeldUntil";

absl::StatusOr<SessionLease> ReadLease(Transaction& txn, absl::string_view spacecraft_id) {
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT owner, epoch, expires_unix_ns FROM session_leases "
                               "WHERE spacecraft_id = ?1"));
  st->BindText(1, spacecraft_id);
  ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) {
    return absl::NotFoundError(
        absl::StrCat("spacecraft '", spacecraft_id, "': no session lease was ever taken"));
  }
  SessionLease lease;
  lease.spacecraft_id = std::string(spacecraft_id);
  lease.owner = st->ColumnText(0);
  lease.epoch = st->ColumnInt64(1);
  lease.expires = UnixNanosToTime(st->ColumnInt64(2));
  st->Reset();
  return lease;
}

}  // namespace

absl::Status LeaseStore::CheckPostgres() const {
  if (db_->dialect() == Dialect::kPostgres) return absl::OkStatus();
  return absl::FailedPreconditionError(
      "session leases need a PostgreSQL database: an SQLite file has one server");
}

absl::StatusOr<SessionLease> LeaseStore::Acquire(absl::string_view spacecraft_id,
                                                 absl::string_view owner, absl::Time now,
                                                 absl::Duration duration) {
  RETURN_IF_ERROR(CheckPostgres());
  RETURN_IF_ERROR(ValidateSpacecraftId(spacecraft_id, "lease.spacecraft_id"));
  if (owner.empty()) return absl::InvalidArgumentError("lease.owner: empty");
  if (duration <= absl::ZeroDuration()) {
    return absl::InvalidArgumentError("lease duration: must be positive");
  }
  RETURN_IF_ERROR(ValidateStorableTime(now + duration, "lease.expires"));
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  // One statement: the insert, or the update of a lease that is expired or the owner's own;
  // the row lock of ON CONFLICT makes two servers taking the same lease at once take it in turn
  // (the second sees the first's unexpired lease and gets no row).
  ASSIGN_OR_RETURN(
      Statement * take,
      txn.Prepare("INSERT INTO session_leases (spacecraft_id, owner, epoch, expires_unix_ns) "
                  "VALUES (?1, ?2, 1, ?3) ON CONFLICT (spacecraft_id) DO UPDATE SET "
                  "owner = excluded.owner, epoch = session_leases.epoch + 1, "
                  "expires_unix_ns = excluded.expires_unix_ns "
                  "WHERE session_leases.expires_unix_ns <= ?4 OR session_leases.owner = ?2 "
                  "RETURNING epoch"));
  take->BindText(1, spacecraft_id)
      .BindText(2, owner)
      .BindInt64(3, TimeToUnixNanos(now + duration))
      .BindInt64(4, TimeToUnixNanos(now));
  ASSIGN_OR_RETURN(bool taken, take->Step());
  take->Reset();
  ASSIGN_OR_RETURN(SessionLease lease, ReadLease(txn, spacecraft_id));
  RETURN_IF_ERROR(txn.Commit());
  if (!taken) {
    absl::Status held =
        absl::UnavailableError(absl::StrCat("spacecraft_id: '", spacecraft_id, "' is served by node ",
                                            lease.owner, " until ", FormatUtc(lease.expires)));
    held.SetPayload(kLeaseHeldPayload, absl::Cord(absl::StrCat(TimeToUnixNanos(lease.expires))));
    return held;
  }
  return lease;
}

absl::Status LeaseStore::Renew(absl::string_view spacecraft_id, const LeaseFence& fence,
                               absl::Time now, absl::Duration duration) {
  RETURN_IF_ERROR(ValidateStorableTime(now + duration, "lease.expires"));
  ASSIGN_OR_RETURN(const bool held, SetExpiry(spacecraft_id, fence, now + duration));
  if (!held) {
    return absl::NotFoundError(absl::StrCat("spacecraft '", spacecraft_id, "': the lease of node ",
                                            fence.owner, " (epoch ", fence.epoch,
                                            ") was taken over"));
  }
  return absl::OkStatus();
}

absl::StatusOr<std::vector<std::string>> LeaseStore::RenewAll(
    const std::map<std::string, LeaseFence>& fences, absl::Time now, absl::Duration duration) {
  RETURN_IF_ERROR(CheckPostgres());
  RETURN_IF_ERROR(ValidateStorableTime(now + duration, "lease.expires"));
  std::vector<std::string> lost;
  if (fences.empty()) return lost;
  // kBatch leases a statement, one SQL text each: a shorter last batch repeats its last lease
  // (the same row twice in the WHERE is locked and updated once), so the statement cache holds
  // one entry for the lock and one for the update.
  constexpr int kBatch = 64;
  std::string fenced;
  for (int i = 0; i < kBatch; ++i) {
    absl::StrAppend(&fenced, i == 0 ? "" : " OR ", "(spacecraft_id = ?", 2 + 3 * i,
                    " AND owner = ?", 3 + 3 * i, " AND epoch = ?", 4 + 3 * i, ")");
  }
  // A renewal changes only the expiry, which is not a key column (the unique index
  // session_leases_fence makes owner and epoch key columns: postgres_schema.cc), so its row
  // locks are FOR NO KEY UPDATE, which a fenced commit's FOR KEY SHARE (CheckHeld) does not
  // conflict with: the round never waits for a commit holding a fence (a filter group holds 64
  // of them for its whole transaction) and no commit waits for the round. The rows are still
  // locked in spacecraft-id order (bytewise: the "C" collation, as std::map orders the fences),
  // so two rounds, or a round and a release, take them in the same order.
  // Both statements take the same bindings (?1, the new expiry, is unused by the lock).
  const std::string lock_sql =
      absl::StrCat("SELECT spacecraft_id FROM session_leases WHERE ", fenced,
                   " ORDER BY spacecraft_id COLLATE \"C\" FOR NO KEY UPDATE");
  const std::string sql = absl::StrCat("UPDATE session_leases SET expires_unix_ns = ?1 WHERE ",
                                       fenced, " RETURNING spacecraft_id");
  std::vector<const std::pair<const std::string, LeaseFence>*> leases;
  leases.reserve(fences.size());
  for (const auto& lease : fences) leases.push_back(&lease);
  std::set<std::string> renewed;
  ASSIGN_OR_RETURN(Transaction txn, BeginRenewal());
  for (size_t first = 0; first < leases.size(); first += kBatch) {
    for (const std::string* text : {&lock_sql, &sql}) {
      ASSIGN_OR_RETURN(Statement * st, txn.Prepare(*text));
      st->BindInt64(1, TimeToUnixNanos(now + duration));
      for (int i = 0; i < kBatch; ++i) {
        const auto& [spacecraft_id, fence] = *leases[std::min(first + i, leases.size() - 1)];
        st->BindText(2 + 3 * i, spacecraft_id)
            .BindText(3 + 3 * i, fence.owner)
            .BindInt64(4 + 3 * i, fence.epoch);
      }
      for (;;) {
        ASSIGN_OR_RETURN(const bool row, st->Step());
        if (!row) break;
        if (text == &sql) renewed.insert(st->ColumnText(0));
      }
      st->Reset();
    }
  }
  RETURN_IF_ERROR(txn.Commit());
  for (const auto& [spacecraft_id, fence] : fences) {
    if (renewed.count(spacecraft_id) == 0) lost.push_back(spacecraft_id);
  }
  return lost;
}

absl::StatusOr<Transaction> LeaseStore::BeginRenewal() {
  // A connection of its own sits idle between rounds, possibly through a restart of the
  // database server: its first BEGIN then finds the connection lost (having done nothing) and
  // the next one reconnects.
  {
    absl::StatusOr<Transaction> txn = renewal_db_->Begin(TransactionMode::kImmediate);
    if (renewal_db_ == db_ || !absl::IsUnavailable(txn.status())) return txn;
  }
  return renewal_db_->Begin(TransactionMode::kImmediate);
}

absl::Status LeaseStore::Release(absl::string_view spacecraft_id, const LeaseFence& fence) {
  return SetExpiry(spacecraft_id, fence, absl::InfinitePast()).status();
}

absl::StatusOr<bool> LeaseStore::SetExpiry(absl::string_view spacecraft_id,
                                           const LeaseFence& fence, absl::Time expires) {
  RETURN_IF_ERROR(CheckPostgres());
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("UPDATE session_leases SET expires_unix_ns = ?4 "
                               "WHERE spacecraft_id = ?1 AND owner = ?2 AND epoch = ?3"));
  st->BindText(1, spacecraft_id)
      .BindText(2, fence.owner)
      .BindInt64(3, fence.epoch)
      .BindInt64(4, TimeToUnixNanos(expires));
  RETURN_IF_ERROR(st->Run());
  const bool held = txn.ChangedRows() > 0;
  RETURN_IF_ERROR(txn.Commit());
  return held;
}

absl::StatusOr<SessionLease> LeaseStore::Get(absl::string_view spacecraft_id) {
  RETURN_IF_ERROR(CheckPostgres());
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(SessionLease lease, ReadLease(txn, spacecraft_id));
  RETURN_IF_ERROR(txn.Commit());
  return lease;
}

absl::Status LeaseStore::CheckHeld(Transaction& txn, absl::string_view spacecraft_id,
                                   const LeaseFence& fence) {
  RETURN_IF_ERROR(CheckPostgres());
  // FOR KEY SHARE: a takeover (Acquire) writes a new epoch, a key column through the unique
  // index session_leases_fence (postgres_schema.cc), so its row lock is FOR UPDATE and waits
  // until this transaction ends, and this one waits for a takeover under way, then reads the
  // committed owner. A renewal or a release writes only the expiry (FOR NO KEY UPDATE): neither
  // waits for this lock nor this one for them.
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT owner, epoch FROM session_leases "
                               "WHERE spacecraft_id = ?1 FOR KEY SHARE"));
  st->BindText(1, spacecraft_id);
  ASSIGN_OR_RETURN(bool row, st->Step());
  const std::string owner = row ? st->ColumnText(0) : std::string();
  const int64_t epoch = row ? st->ColumnInt64(1) : 0;
  st->Reset();
  if (row && owner == fence.owner && epoch == fence.epoch) return absl::OkStatus();
  absl::Status lost = absl::AbortedError(absl::StrCat(
      "spacecraft '", spacecraft_id, "': this server (node ", fence.owner,
      ") no longer holds its session",
      row ? absl::StrCat(" (taken over by node ", owner, ", epoch ", epoch, ")") : ""));
  lost.SetPayload(kLeaseLostPayload, absl::Cord(spacecraft_id));
  return lost;
}

std::optional<std::string> LeaseLostSpacecraft(const absl::Status& status) {
  const auto payload = status.GetPayload(kLeaseLostPayload);
  if (!payload.has_value()) return std::nullopt;
  return std::string(*payload);
}

std::optional<absl::Time> LeaseHeldUntil(const absl::Status& status) {
  const auto payload = status.GetPayload(kLeaseHeldPayload);
  int64_t unix_ns = 0;
  if (!payload.has_value() || !absl::SimpleAtoi(std::string(*payload), &unix_ns)) {
    return std::nullopt;
  }
  return UnixNanosToTime(unix_ns);
}

}  // namespace esg::storage
