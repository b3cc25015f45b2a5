// Tests of storage/lease_store.h on both backends: on PostgreSQL the lease rules (take when
// free, expired or one's own, epochs, renewal and release by the holder only) and the fence that
// makes a write of a server that lost its lease store nothing; on SQLite every call is refused
// (one server owns an SQLite file).
#include "storage/lease_store.h"

#include <map>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_format.h"
#include "absl/synchronization/notification.h"
#include "absl/time/clock.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/storage.h"
#include "tests/storage/backend.h"
#include "tests/storage/storage_test_util.h"
#include "tests/testing/status_matchers.h"

namespace esg::storage {
namespace {

using ::esg::storage::testing::Alert;
using ::esg::storage::testing::BackendTest;
using ::esg::storage::testing::Frame;
using ::esg::storage::testing::T;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::HasSubstr;
using ::testing::Optional;

class LeaseStoreTest : public BackendTest {};
ESG_INSTANTIATE_BACKEND_TEST_SUITE(LeaseStoreTest);

constexpr absl::Duration kLease = absl::Seconds(15);

TEST_P(LeaseStoreTest, TakenWhenFreeExpiredOrOwnEachTakeANewEpochRenewedAndReleasedByTheHolder) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  LeaseStore& leases = (*storage)->leases();
  if (GetParam() == testing::Backend::kSqlite) {
    EXPECT_THAT(leases.Acquire("L-1", "a", T(0), kLease),
                StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("PostgreSQL")));
    return;
  }
  absl::StatusOr<SessionLease> a = leases.Acquire("L-1", "a", T(0), kLease);
  ASSERT_THAT(a, IsOk());
  EXPECT_EQ(a->owner, "a");
  EXPECT_EQ(a->epoch, 1);
  EXPECT_EQ(a->expires, T(15));
  // Another server before the expiry: refused, naming the holder.
  EXPECT_THAT(leases.Acquire("L-1", "b", T(14), kLease),
              StatusIs(absl::StatusCode::kUnavailable, HasSubstr("served by node a")));
  // The holder renews; a renewal does not change the epoch. The refusal carries the
  // holder's expiry (the server turns it into a retry delay).
  EXPECT_THAT(leases.Renew("L-1", {"a", 1}, T(10), kLease), IsOk());
  const absl::StatusOr<SessionLease> refused = leases.Acquire("L-1", "b", T(20), kLease);
  EXPECT_THAT(refused, StatusIs(absl::StatusCode::kUnavailable, HasSubstr("served by node a")));
  EXPECT_THAT(LeaseHeldUntil(refused.status()), Optional(T(25)));
  EXPECT_EQ(LeaseHeldUntil(absl::UnavailableError("served by node a")), std::nullopt);
  // Expired: b takes it with the next epoch; a's renewal is then refused.
  absl::StatusOr<SessionLease> b = leases.Acquire("L-1", "b", T(25), kLease);
  ASSERT_THAT(b, IsOk());
  EXPECT_EQ(b->owner, "b");
  EXPECT_EQ(b->epoch, 2);
  EXPECT_THAT(leases.Renew("L-1", {"a", 1}, T(26), kLease),
              StatusIs(absl::StatusCode::kNotFound, HasSubstr("taken over")));
  // b, restarted with the same node id, takes its own lease back at once (a new epoch).
  absl::StatusOr<SessionLease> again = leases.Acquire("L-1", "b", T(27), kLease);
  ASSERT_THAT(again, IsOk());
  EXPECT_EQ(again->epoch, 3);
  // A release by a stale epoch changes nothing; b's own release frees it at once.
  EXPECT_THAT(leases.Release("L-1", {"b", 2}), IsOk());
  EXPECT_THAT(leases.Acquire("L-1", "a", T(28), kLease),
              StatusIs(absl::StatusCode::kUnavailable, HasSubstr("served by node b")));
  EXPECT_THAT(leases.Release("L-1", {"b", 3}), IsOk());
  absl::StatusOr<SessionLease> back = leases.Acquire("L-1", "a", T(28), kLease);
  ASSERT_THAT(back, IsOk());
  EXPECT_EQ(back->epoch, 4);
  // The leases of two spacecraft are independent.
  absl::StatusOr<SessionLease> other = leases.Acquire("L-2", "b", T(28), kLease);
  ASSERT_THAT(other, IsOk());
  EXPECT_EQ(other->epoch, 1);
  EXPECT_THAT(leases.Get("L-3"), StatusIs(absl::StatusCode::kNotFound, HasSubstr("no session lease was ever taken")));
}

// RenewAll: one server's leases renewed in one transaction; the ones another server took over
// (or that never existed) are reported, in id order, and left as they are. 150 leases span
// three of its statements (64 leases each, the last one short).
TEST_P(LeaseStoreTest, RenewAllRenewsEveryHeldLeaseAndReportsTheOnesTakenOverWithoutRenewingThem) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  LeaseStore& leases = (*storage)->leases();
  if (GetParam() == testing::Backend::kSqlite) {
    EXPECT_THAT(leases.RenewAll({{"R-1", {"a", 1}}}, T(0), kLease),
                StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("PostgreSQL")));
    EXPECT_THAT(leases.RenewAll({}, T(0), kLease),
                StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("PostgreSQL")));
    return;
  }
  constexpr int kLeases = 150;
  auto id = [](int i) { return absl::StrFormat("R-%03d", i); };
  std::map<std::string, LeaseFence> fences;
  for (int i = 0; i < kLeases; ++i) {
    ASSERT_THAT(leases.Acquire(id(i), "a", T(0), kLease), IsOk());
    fences[id(i)] = {"a", 1};
  }
  absl::StatusOr<std::vector<std::string>> lost = leases.RenewAll({}, T(5), kLease);
  ASSERT_THAT(lost, IsOk());
  EXPECT_TRUE(lost->empty());

  // All held: all renewed to now + duration, epochs unchanged.
  lost = leases.RenewAll(fences, T(10), kLease);
  ASSERT_THAT(lost, IsOk());
  EXPECT_TRUE(lost->empty());
  for (int i = 0; i < kLeases; ++i) {
    absl::StatusOr<SessionLease> lease = leases.Get(id(i));
    ASSERT_THAT(lease, IsOk());
    EXPECT_EQ(lease->expires, T(25)) << id(i);
    EXPECT_EQ(lease->epoch, 1) << id(i);
  }

  // Expired at T(25): b takes over one lease in the first statement's batch and one in the
  // last; a lease never taken is in a's map too. The others, expired but not taken over, are
  // renewed (as Renew does).
  ASSERT_THAT(leases.Acquire(id(10), "b", T(26), kLease), IsOk());
  ASSERT_THAT(leases.Acquire(id(140), "b", T(26), kLease), IsOk());
  fences["R-999"] = {"a", 1};
  lost = leases.RenewAll(fences, T(27), kLease);
  ASSERT_THAT(lost, IsOk());
  EXPECT_THAT(*lost, ::testing::ElementsAre(id(10), id(140), "R-999"));
  for (int i = 0; i < kLeases; ++i) {
    absl::StatusOr<SessionLease> lease = leases.Get(id(i));
    ASSERT_THAT(lease, IsOk());
    if (i == 10 || i == 140) {
      // b's lease as b took it: not renewed by a.
      EXPECT_EQ(lease->owner, "b") << id(i);
      EXPECT_EQ(lease->epoch, 2) << id(i);
      EXPECT_EQ(lease->expires, T(41)) << id(i);
    } else {
      EXPECT_EQ(lease->owner, "a") << id(i);
      EXPECT_EQ(lease->expires, T(42)) << id(i);
    }
  }
  EXPECT_THAT(leases.Get("R-999"),
              StatusIs(absl::StatusCode::kNotFound, HasSubstr("no session lease was ever taken")));
  // The same lost leases through Renew, one by one.
  EXPECT_THAT(leases.Renew(id(10), {"a", 1}, T(28), kLease),
              StatusIs(absl::StatusCode::kNotFound, HasSubstr("taken over")));
}

TEST_P(LeaseStoreTest, AWriteFencedByALostLeaseStoresNothingAndNamesTheSpacecraft) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  LeaseStore& leases = (*storage)->leases();
  if (GetParam() == testing::Backend::kSqlite) {
    // A fenced write is refused outright: there is no lease to check it against.
    EXPECT_THAT((*storage)->ArchiveFrames({Frame("F-1", 1)}, {}, {{"F-1", {"a", 1}}}),
                StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("PostgreSQL")));
    return;
  }
  ASSERT_THAT(leases.Acquire("F-1", "a", T(0), kLease), IsOk());
  ASSERT_THAT((*storage)->ArchiveFrames({Frame("F-1", 1)}, {}, {{"F-1", {"a", 1}}}), IsOk());
  ASSERT_THAT(leases.Acquire("F-1", "b", T(30), kLease), IsOk());  // a's expired: epoch 2

  const absl::Status stale = (*storage)->ArchiveFrames({Frame("F-1", 2)}, {}, {{"F-1", {"a", 1}}});
  EXPECT_THAT(stale, StatusIs(absl::StatusCode::kAborted, HasSubstr("taken over by node b")));
  EXPECT_THAT(LeaseLostSpacecraft(stale), Optional(std::string("F-1")));
  EXPECT_EQ(LeaseLostSpacecraft(absl::UnavailableError("disk")), std::nullopt);
  absl::StatusOr<std::vector<ArchivedFrame>> stored =
      (*storage)->archive().ReadTimeRange("F-1", absl::InfinitePast(), absl::InfiniteFuture());
  ASSERT_THAT(stored, IsOk());
  ASSERT_EQ(stored->size(), 1u);
  EXPECT_EQ((*stored)[0].sequence, 1);

  // The new holder's fence writes.
  EXPECT_THAT((*storage)->ArchiveFrames({Frame("F-1", 2)}, {}, {{"F-1", {"b", 2}}}), IsOk());
}

// The filter's group commit of one server (Storage::CommitFilterEffectsGroup) holding three
// spacecraft, one of which another server has taken over meanwhile: that job is refused as lost
// (nothing of it stored) and the other two are committed in the same transaction.
TEST_P(LeaseStoreTest, AGroupCommitWithOneLeaseLostCommitsTheOthers) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  if (GetParam() == testing::Backend::kSqlite) return;  // no leases (above)
  LeaseStore& leases = (*storage)->leases();
  const std::vector<std::string> ids = {"F-A", "F-B", "F-C"};
  std::vector<FilterEffects> jobs(ids.size());
  for (size_t i = 0; i < ids.size(); ++i) {
    ASSERT_THAT(leases.Acquire(ids[i], "a", T(0), kLease), IsOk());
    ASSERT_THAT((*storage)->ArchiveFrames({Frame(ids[i], 1)}), IsOk());
    FilterEffects& e = jobs[i];
    e.spacecraft_id = ids[i];
    e.fence = LeaseFence{"a", 1};
    e.new_alerts.push_back(Alert(ids[i], 60));
    e.checkpoint = [id = ids[i]](const std::vector<int64_t>&) {
      CheckpointRecord cp;
      cp.spacecraft_id = id;
      cp.last_sequence = 1;
      cp.measurement_time = T(60);
      cp.compute_time = T(61);
      cp.state_blob = "state";
      return cp;
    };
  }
  // b takes F-B over after a's lease expired.
  ASSERT_THAT(leases.Acquire("F-B", "b", T(20), kLease), IsOk());
  const std::vector<absl::StatusOr<std::vector<int64_t>>> results =
      (*storage)->CommitFilterEffectsGroup({&jobs[0], &jobs[1], &jobs[2]});
  ASSERT_EQ(results.size(), 3u);
  EXPECT_THAT(results[0], IsOk());
  EXPECT_THAT(results[1], StatusIs(absl::StatusCode::kAborted, HasSubstr("taken over by node b")));
  EXPECT_EQ(LeaseLostSpacecraft(results[1].status()), std::optional<std::string>("F-B"));
  EXPECT_THAT(results[2], IsOk());
  for (const std::string& id : ids) {
    absl::StatusOr<CheckpointRecord> cp = (*storage)->sessions().GetCheckpoint(id);
    absl::StatusOr<std::vector<AlertRecord>> alerts =
        (*storage)->alerts().Since(id, absl::InfinitePast(), 100);
    ASSERT_THAT(alerts, IsOk());
    if (id == "F-B") {
      EXPECT_THAT(cp, StatusIs(absl::StatusCode::kNotFound, ::testing::_));
      EXPECT_TRUE(alerts->empty());
    } else {
      EXPECT_THAT(cp, IsOk()) << id;
      EXPECT_EQ(alerts->size(), 1u) << id;
    }
  }
}

// Whether the backend `pid` of the database `observer` is connected to waits for a lock now (a
// new transaction per call, so pg_stat_activity is read afresh).
bool WaitsForALock(Storage& observer, int pid) {
  absl::StatusOr<Transaction> look = observer.database().Begin(TransactionMode::kDeferred);
  EXPECT_THAT(look, IsOk());
  if (!look.ok()) return false;
  absl::StatusOr<Statement*> st = look->Prepare(
      "SELECT count(*) FROM pg_stat_activity WHERE pid = ?1 AND wait_event_type = 'Lock'");
  EXPECT_THAT(st, IsOk());
  if (!st.ok()) return false;
  (*st)->BindInt64(1, pid);
  EXPECT_THAT((*st)->Step(), IsOk());
  const bool waiting = (*st)->ColumnInt64(0) == 1;
  (*st)->Reset();
  EXPECT_THAT(look->Commit(), IsOk());
  return waiting;
}

// A renewal round and a commit fenced by several of the same server's leases (the filter's group
// commit, Storage::ArchiveFrames) need the same lease rows, the renewal to change their expiry,
// the commit to check their fences (FOR KEY SHARE). The renewal changes no key column, so it
// neither waits for the commit nor makes it wait: it finishes while the commit's transaction is
// open, and the commit goes on to the next lease and commits (before, the renewal locked the
// rows FOR UPDATE, waited for each row a commit held, and ingest's commits waited for the rows
// it held: issue 43). The leases are made in reverse id order, so a renewal locking in table
// order would take D-B before D-A.
TEST_P(LeaseStoreTest, ARenewalRoundNeitherWaitsForAFencedCommitOfTheSameLeasesNorHoldsItUp) {
  const std::string uri = NewDatabase();
  absl::StatusOr<std::unique_ptr<Storage>> committer = Storage::Open(uri);
  ASSERT_THAT(committer, IsOk());
  if (GetParam() == testing::Backend::kSqlite) return;  // no leases (above)
  absl::StatusOr<std::unique_ptr<Storage>> renewer = Storage::Open(uri);
  ASSERT_THAT(renewer, IsOk());
  absl::StatusOr<std::unique_ptr<Storage>> observer = Storage::Open(uri);
  ASSERT_THAT(observer, IsOk());
  const std::map<std::string, LeaseFence> fences = {{"D-A", {"a", 1}}, {"D-B", {"a", 1}}};
  ASSERT_THAT((*committer)->leases().Acquire("D-B", "a", T(0), kLease), IsOk());
  ASSERT_THAT((*committer)->leases().Acquire("D-A", "a", T(0), kLease), IsOk());

  // The commit checks D-A's fence and keeps its transaction open.
  Database& db = (*committer)->database();
  absl::StatusOr<Transaction> txn = db.Begin(TransactionMode::kImmediate);
  ASSERT_THAT(txn, IsOk());
  ASSERT_THAT((*committer)->leases().CheckHeld(*txn, "D-A", fences.at("D-A")), IsOk());

  // The renewal round runs to its end; had it waited for D-A's lock, it would stay waiting until
  // the commit below, and the observer would see it waiting.
  // (The pid is read before the round: it takes the connection's lock.)
  const int renewer_pid = (*renewer)->RenewalConnectionPid();
  absl::StatusOr<std::vector<std::string>> lost;
  absl::Notification renewed;
  std::thread renewal([&] {
    lost = (*renewer)->leases().RenewAll(fences, T(5), kLease);
    renewed.Notify();
  });
  bool waited = false;
  while (!renewed.WaitForNotificationWithTimeout(absl::Milliseconds(10))) {
    if (WaitsForALock(**observer, renewer_pid)) {
      waited = true;
      break;
    }
  }
  EXPECT_FALSE(waited) << "the renewal round waited for the commit's lock on D-A";

  // The commit goes on to D-B, renewed meanwhile, and commits.
  EXPECT_THAT((*committer)->leases().CheckHeld(*txn, "D-B", fences.at("D-B")), IsOk());
  EXPECT_THAT(txn->Commit(), IsOk());
  renewal.join();
  ASSERT_THAT(lost, IsOk());
  EXPECT_TRUE(lost->empty());
  for (const auto& [id, fence] : fences) {
    absl::StatusOr<SessionLease> lease = (*committer)->leases().Get(id);
    ASSERT_THAT(lease, IsOk());
    EXPECT_EQ(lease->expires, T(5) + kLease) << id;
    EXPECT_EQ(lease->epoch, 1) << id;
  }
}

// The renewal round runs on a connection of its own: while it waits (here for a row another
// server's takeover holds locked; in service for its own 2,000 rows), the same Storage's
// frames commit and their acknowledgements go out. On the main connection the commit would
// wait until the round ended.
TEST_P(LeaseStoreTest, FramesCommitWhileTheRenewalRoundWaitsForALock) {
  const std::string uri = NewDatabase();
  absl::StatusOr<std::unique_ptr<Storage>> server = Storage::Open(uri);
  ASSERT_THAT(server, IsOk());
  if (GetParam() == testing::Backend::kSqlite) return;  // no leases (above)
  absl::StatusOr<std::unique_ptr<Storage>> other = Storage::Open(uri);
  ASSERT_THAT(other, IsOk());
  absl::StatusOr<std::unique_ptr<Storage>> observer = Storage::Open(uri);
  ASSERT_THAT(observer, IsOk());
  const std::map<std::string, LeaseFence> fences = {{"N-A", {"a", 1}}, {"N-B", {"a", 1}}};
  for (const auto& [id, fence] : fences) {
    ASSERT_THAT((*server)->leases().Acquire(id, fence.owner, T(0), kLease), IsOk());
  }
  // (Read before the round: the pid takes the connection's lock.)
  const int renewal_pid = (*server)->RenewalConnectionPid();
  ASSERT_NE(renewal_pid, (*server)->ConnectionPid());

  // Another server's transaction holds N-A's row as a takeover does (FOR UPDATE).
  absl::StatusOr<Transaction> takeover = (*other)->database().Begin(TransactionMode::kImmediate);
  ASSERT_THAT(takeover, IsOk());
  absl::StatusOr<Statement*> lock = takeover->Prepare(
      "SELECT owner FROM session_leases WHERE spacecraft_id = 'N-A' FOR UPDATE");
  ASSERT_THAT(lock, IsOk());
  ASSERT_THAT((*lock)->Step(), IsOk());
  (*lock)->Reset();

  absl::StatusOr<std::vector<std::string>> lost;
  std::thread renewal([&] { lost = (*server)->leases().RenewAll(fences, T(5), kLease); });
  bool waiting = false;
  for (int i = 0; i < 500 && !waiting; ++i) {
    waiting = WaitsForALock(**observer, renewal_pid);
    if (!waiting) absl::SleepFor(absl::Milliseconds(10));
  }
  EXPECT_TRUE(waiting) << "the renewal round never waited for N-A";

  // A fenced frame of N-B commits meanwhile. Had it waited for the round, it would wait until
  // the takeover's transaction below ends: the 20 s bound only keeps the test from hanging.
  absl::Status archived = absl::UnknownError("not returned");
  absl::Notification done;
  std::thread frames([&] {
    archived = (*server)->ArchiveFrames({Frame("N-B", 1)}, {}, {{"N-B", fences.at("N-B")}});
    done.Notify();
  });
  const bool before_the_round_ended = done.WaitForNotificationWithTimeout(absl::Seconds(20));
  EXPECT_TRUE(before_the_round_ended) << "the frames' commit waited for the renewal round";
  EXPECT_TRUE(WaitsForALock(**observer, renewal_pid));
  EXPECT_THAT(takeover->Commit(), IsOk());
  frames.join();
  renewal.join();
  EXPECT_THAT(archived, IsOk());
  ASSERT_THAT(lost, IsOk());
  EXPECT_TRUE(lost->empty());
}

// The fence still holds against a takeover: another server taking an expired lease over waits
// for a commit that checked the lease's fence (so that commit's writes land before the new owner
// starts), and the old owner's next commit is refused.
TEST_P(LeaseStoreTest, ATakeoverWaitsForACommitHoldingTheFenceAndThenRefusesTheOldOwner) {
  const std::string uri = NewDatabase();
  absl::StatusOr<std::unique_ptr<Storage>> old_owner = Storage::Open(uri);
  ASSERT_THAT(old_owner, IsOk());
  if (GetParam() == testing::Backend::kSqlite) return;  // no leases (above)
  absl::StatusOr<std::unique_ptr<Storage>> new_owner = Storage::Open(uri);
  ASSERT_THAT(new_owner, IsOk());
  absl::StatusOr<std::unique_ptr<Storage>> observer = Storage::Open(uri);
  ASSERT_THAT(observer, IsOk());
  ASSERT_THAT((*old_owner)->leases().Acquire("W-1", "a", T(0), kLease), IsOk());

  // a's commit checks its fence and keeps its transaction open past the expiry.
  Database& db = (*old_owner)->database();
  absl::StatusOr<Transaction> txn = db.Begin(TransactionMode::kImmediate);
  ASSERT_THAT(txn, IsOk());
  ASSERT_THAT((*old_owner)->leases().CheckHeld(*txn, "W-1", {"a", 1}), IsOk());

  absl::StatusOr<SessionLease> taken;
  std::thread takeover([&] { taken = (*new_owner)->leases().Acquire("W-1", "b", T(30), kLease); });
  const int taker_pid = (*new_owner)->ConnectionPid();
  bool waiting = false;
  for (int i = 0; i < 500 && !waiting; ++i) {
    waiting = WaitsForALock(**observer, taker_pid);
    if (!waiting) absl::SleepFor(absl::Milliseconds(10));
  }
  EXPECT_TRUE(waiting) << "the takeover did not wait for the commit holding W-1's fence";
  EXPECT_THAT(txn->Commit(), IsOk());
  takeover.join();
  ASSERT_THAT(taken, IsOk());
  EXPECT_EQ(taken->owner, "b");
  EXPECT_EQ(taken->epoch, 2);
  // a's next commit is refused.
  EXPECT_THAT((*old_owner)->ArchiveFrames({Frame("W-1", 1)}, {}, {{"W-1", {"a", 1}}}),
              StatusIs(absl::StatusCode::kAborted, HasSubstr("taken over by node b")));
}

}  // namespace
}  // namespace esg::storage
