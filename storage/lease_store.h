// Session leases (table session_leases, PostgreSQL only: postgres_schema.h): which server owns
// each spacecraft's estimation session when several servers share one database
// (docs/service.md "Several servers"). A lease is a row (spacecraft, owner, epoch, expiry);
// its owner renews it well before the expiry; a server that finds it expired takes it, which
// increments the epoch. Every transaction that writes a spacecraft's session state (frames,
// filter effects, configuration) checks inside itself that the writing server still holds the
// lease with its epoch (CheckHeld, a row lock taken against a concurrent takeover), so a server
// that lost its lease (paused, cut off) can never write after the new owner started.
//
// Expiry times are the servers' wall clocks (Unix nanoseconds): their clocks must agree to well
// within the lease duration (NTP).
#ifndef ESG_STORAGE_LEASE_STORE_H_
#define ESG_STORAGE_LEASE_STORE_H_

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "storage/database.h"

namespace esg::storage {

struct SessionLease {
  std::string spacecraft_id;
  std::string owner;   // the server's node id
  int64_t epoch = 0;   // 1 at the first take, +1 at each take (renewals keep it)
  absl::Time expires;  // wall clock
};

// A server's claim to a spacecraft's session, checked by the write transactions.
struct LeaseFence {
  std::string owner;
  int64_t epoch = 0;
};

// The spacecraft of a status CheckHeld returned for a lease lost (passed up through the commit
// that checked it); nullopt for any other status.
std::optional<std::string> LeaseLostSpacecraft(const absl::Status& status);

// The expiry of the other server's lease that an Acquire refused with (Unavailable "served by
// node N until T"), also when a caller passes the status up; nullopt for any other status.
std::optional<absl::Time> LeaseHeldUntil(const absl::Status& status);

// Thread-safe (through Database). FailedPrecondition on an SQLite database (one server owns
// an SQLite file: sqlite_db.h "Owner lock").
class LeaseStore {
 public:
  explicit LeaseStore(Database* db) : db_(db), renewal_db_(db) {}

  // RenewAll runs on `db` (not owned, outliving this store) instead of the main connection;
  // called once, before any other call (Storage::OpenPostgres).
  void SetRenewalDatabase(Database* db) { renewal_db_ = db; }

  // Takes the lease of `spacecraft_id` for `owner` until now + duration if it is free, expired
  // at `now`, or already `owner`'s (a restarted server with the same node id takes its own lease
  // back at once); the epoch increments. Returns the lease as stored. Unavailable
  // "spacecraft_id: 'X' is served by node N until T" (with the holder's lease) when another owner
  // holds it unexpired (LeaseHeldUntil reads T from it); InvalidArgument for an empty id or owner
  // or a non-positive duration.
  absl::StatusOr<SessionLease> Acquire(absl::string_view spacecraft_id, absl::string_view owner,
                                       absl::Time now, absl::Duration duration);

  // Extends `owner`'s lease with `epoch` to now + duration. NotFound when the lease is no longer
  // (owner, epoch)'s: another server took it over.
  absl::Status Renew(absl::string_view spacecraft_id, const LeaseFence& fence, absl::Time now,
                     absl::Duration duration);

  // Renews, in one transaction, every lease of `fences` (spacecraft id -> the fence this server
  // took it with: one server's leases) that is still its fence's (owner, epoch), to now +
  // duration, and returns the spacecraft whose lease was not (taken over by another server, or
  // gone), in id order: the caller drops those sessions. A lease expired at `now` but not taken
  // over is renewed, as by Renew. On an error nothing is renewed (the transaction rolls back;
  // Unavailable for a lost connection or a lock conflict: try again). An empty `fences` renews
  // nothing and returns no spacecraft. Same as calling Renew for each lease, with one commit
  // instead of one per lease (and a few statements instead of one per lease). Does not wait for
  // the write transactions holding these leases' fences (CheckHeld), nor they for it; runs on
  // the connection of SetRenewalDatabase (Storage::OpenPostgres: one of its own).
  absl::StatusOr<std::vector<std::string>> RenewAll(const std::map<std::string, LeaseFence>& fences,
                                                    absl::Time now, absl::Duration duration);

  // Ends `owner`'s lease with `epoch` at once (a clean shutdown), so another server may take the
  // session without waiting for the expiry. OK if it was no longer held.
  absl::Status Release(absl::string_view spacecraft_id, const LeaseFence& fence);

  // The lease of `spacecraft_id`; NotFound if it was never taken.
  absl::StatusOr<SessionLease> Get(absl::string_view spacecraft_id);

  // Inside a write transaction: OK if (owner, epoch) still holds the lease, locking the row
  // until the transaction ends (a takeover waits for it, and the transaction sees a takeover
  // committed before; a renewal or a release of the lease neither waits for it nor holds it
  // up: they change only the expiry); Aborted "spacecraft 'X': this server (node M) no longer holds its
  // session (taken over by node N, epoch E)" otherwise, which LeaseLostSpacecraft recognizes
  // (also when a commit passes it up). The expiry is not checked: a lease is taken over only
  // by writing a new owner or epoch.
  absl::Status CheckHeld(Transaction& txn, absl::string_view spacecraft_id,
                         const LeaseFence& fence);

 private:
  absl::Status CheckPostgres() const;
  // The renewal round's transaction on renewal_db_.
  absl::StatusOr<Transaction> BeginRenewal();
  // Sets the expiry of (owner, epoch)'s lease; false when the lease is no longer theirs.
  absl::StatusOr<bool> SetExpiry(absl::string_view spacecraft_id, const LeaseFence& fence,
                                 absl::Time expires);

  Database* db_;          // not owned
  Database* renewal_db_;  // not owned; db_ unless SetRenewalDatabase
};

}  // namespace esg::storage

#endif  // ESG_STORAGE_LEASE_STORE_H_
