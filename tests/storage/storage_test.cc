// Tests of storage/storage.h: the atomic CommitBatch (round trip, duplicates, all-or-nothing on
// a failure inside the batch), persistence across reopen, acknowledged batches surviving
// kill -9 of the writing process, concurrent writers (shared object and separate
// connections), and a corrupted file.
#include "storage/storage.h"

#include <signal.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/schema.h"
#include "tests/storage/storage_test_util.h"
#include "tests/testing/status_matchers.h"
#include "tests/testing/temp_dir.h"

namespace esg::storage {
namespace {

using ::esg::storage::testing::Alert;
using ::esg::storage::testing::Frame;
using ::esg::storage::testing::IsOkAndHolds;
using ::esg::storage::testing::QueryInt;
using ::esg::storage::testing::T;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::esg::testing::TempDir;
using ::testing::AnyOf;
using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::IsEmpty;

constexpr int kFramesPerBatch = 4;

CoefficientRecord Coefficients(const std::string& id, int gyro, double at_seconds) {
  CoefficientRecord r;
  r.spacecraft_id = id;
  r.gyro_id = gyro;
  r.measurement_time = T(at_seconds);
  r.compute_time = T(at_seconds + 0.5);
  r.model_name = "model10";
  r.values.assign(kNumCoefficientValues, 0.1 * gyro);
  return r;
}

// Batch number b of spacecraft `id`: frames b*4 .. b*4+3, one coefficient estimate, one
// alert, and the checkpoint after the last frame.
Batch MakeBatch(const std::string& id, int64_t b) {
  Batch batch;
  batch.spacecraft_id = id;
  for (int64_t s = b * kFramesPerBatch; s < (b + 1) * kFramesPerBatch; ++s) {
    batch.frames.push_back(Frame(id, s));
  }
  const int64_t last = (b + 1) * kFramesPerBatch - 1;
  batch.coefficients.push_back(Coefficients(id, 1, 60.0 * last));
  batch.alerts.push_back(Alert(id, 60.0 * last));
  CheckpointRecord checkpoint;
  checkpoint.spacecraft_id = id;
  checkpoint.last_sequence = last;
  checkpoint.measurement_time = T(60.0 * last);
  checkpoint.compute_time = T(60.0 * last + 1);
  checkpoint.state_blob = absl::StrCat("state after ", last);
  batch.checkpoint = checkpoint;
  return batch;
}

// Everything of `id` that is visible, as counts.
struct Visible {
  int64_t frames = 0;
  int64_t coefficients = 0;
  int64_t alerts = 0;
  std::optional<int64_t> checkpoint_sequence;
};

Visible Count(Storage& storage, const std::string& id) {
  Visible v;
  absl::StatusOr<std::vector<ArchivedFrame>> frames =
      storage.archive().ReadTimeRange(id, absl::InfinitePast(), absl::InfiniteFuture());
  EXPECT_THAT(frames, IsOk());
  if (frames.ok()) v.frames = static_cast<int64_t>(frames->size());
  absl::StatusOr<std::vector<CoefficientRecord>> coefficients =
      storage.coefficients().History(id, 0, absl::InfinitePast(), absl::InfiniteFuture());
  EXPECT_THAT(coefficients, IsOk());
  if (coefficients.ok()) v.coefficients = static_cast<int64_t>(coefficients->size());
  absl::StatusOr<std::vector<AlertRecord>> alerts =
      storage.alerts().Since(id, absl::InfinitePast(), 1000000);
  EXPECT_THAT(alerts, IsOk());
  if (alerts.ok()) v.alerts = static_cast<int64_t>(alerts->size());
  absl::StatusOr<CheckpointRecord> checkpoint = storage.sessions().GetCheckpoint(id);
  if (checkpoint.ok()) {
    v.checkpoint_sequence = checkpoint->last_sequence;
  } else {
    EXPECT_THAT(checkpoint, StatusIs(absl::StatusCode::kNotFound, ::testing::_));
  }
  return v;
}

TEST(Storage, CommitBatchWritesEveryKindAndReturnsAlertSequences) {
  TempDir dir;
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(dir.File("esg.db"));
  ASSERT_THAT(storage, IsOk());
  Batch batch = MakeBatch("RDK-1", 0);
  batch.alerts.push_back(Alert("RDK-1", 30, "PAIR_MISMATCH"));
  absl::StatusOr<BatchResult> result = (*storage)->CommitBatch(batch);
  ASSERT_THAT(result, IsOk());
  EXPECT_THAT(result->new_frame_sequences, ElementsAre(0, 1, 2, 3));
  EXPECT_THAT(result->duplicate_frame_sequences, IsEmpty());
  EXPECT_THAT(result->alert_sequences, ElementsAre(1, 2));

  const Visible v = Count(**storage, "RDK-1");
  EXPECT_EQ(v.frames, 4);
  EXPECT_EQ(v.coefficients, 1);
  EXPECT_EQ(v.alerts, 2);
  EXPECT_EQ(v.checkpoint_sequence, std::optional<int64_t>(3));
  absl::StatusOr<AlertRecord> second = (*storage)->alerts().Get("RDK-1", 2);
  ASSERT_THAT(second, IsOk());
  EXPECT_EQ(second->reason, "PAIR_MISMATCH");

  // The next batch collapses a repeat into alert 1 and numbering continues.
  Batch next = MakeBatch("RDK-1", 1);
  next.alert_repeats.push_back(AlertRepeat{"RDK-1", 1, 2, T(420)});
  absl::StatusOr<BatchResult> next_result = (*storage)->CommitBatch(next);
  ASSERT_THAT(next_result, IsOk());
  EXPECT_THAT(next_result->alert_sequences, ElementsAre(3));
  absl::StatusOr<AlertRecord> first = (*storage)->alerts().Get("RDK-1", 1);
  ASSERT_THAT(first, IsOk());
  EXPECT_EQ(first->repeat_count, 2);
  EXPECT_EQ(first->measurement_time, T(420));
}

TEST(Storage, CommitBatchReportsDuplicateFramesAndStillWritesEffects) {
  TempDir dir;
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(dir.File("esg.db"));
  ASSERT_THAT(storage, IsOk());
  ASSERT_THAT((*storage)->CommitBatch(MakeBatch("RDK-1", 0)), IsOk());
  Batch overlapping = MakeBatch("RDK-1", 1);
  overlapping.frames.insert(overlapping.frames.begin(), Frame("RDK-1", 2));
  overlapping.frames.insert(overlapping.frames.begin(), Frame("RDK-1", 3));
  absl::StatusOr<BatchResult> result = (*storage)->CommitBatch(overlapping);
  ASSERT_THAT(result, IsOk());
  EXPECT_THAT(result->new_frame_sequences, ElementsAre(4, 5, 6, 7));
  EXPECT_THAT(result->duplicate_frame_sequences, ElementsAre(3, 2));
  const Visible v = Count(**storage, "RDK-1");
  EXPECT_EQ(v.frames, 8);
  EXPECT_EQ(v.alerts, 2);
  EXPECT_EQ(v.checkpoint_sequence, std::optional<int64_t>(7));
}

TEST(Storage, FailureLateInTheBatchLeavesNothingOfIt) {
  TempDir dir;
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(dir.File("esg.db"));
  ASSERT_THAT(storage, IsOk());
  ASSERT_THAT((*storage)->CommitBatch(MakeBatch("RDK-1", 0)), IsOk());
  const Visible before = Count(**storage, "RDK-1");

  // Frames, coefficients and alerts are inserted before the repeat of a missing alert fails.
  Batch missing_alert = MakeBatch("RDK-1", 1);
  missing_alert.alert_repeats.push_back(AlertRepeat{"RDK-1", 99, 2, T(500)});
  EXPECT_THAT((*storage)->CommitBatch(missing_alert),
              StatusIs(absl::StatusCode::kNotFound, HasSubstr("alert_repeats[0]")));

  // A record only its store rejects, after the frames went in.
  Batch bad_alert = MakeBatch("RDK-1", 1);
  bad_alert.alerts.push_back(Alert("RDK-1", 500));
  bad_alert.alerts.back().severity.clear();
  EXPECT_THAT((*storage)->CommitBatch(bad_alert),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("alerts[1]")));

  // An invalid coefficient estimate after a valid one.
  Batch bad_coefficient = MakeBatch("RDK-1", 1);
  bad_coefficient.coefficients.push_back(Coefficients("RDK-1", 0, 500));
  EXPECT_THAT((*storage)->CommitBatch(bad_coefficient),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("coefficients[1]")));

  const Visible after = Count(**storage, "RDK-1");
  EXPECT_EQ(after.frames, before.frames);
  EXPECT_EQ(after.coefficients, before.coefficients);
  EXPECT_EQ(after.alerts, before.alerts);
  EXPECT_EQ(after.checkpoint_sequence, before.checkpoint_sequence);
  EXPECT_THAT((*storage)->archive().HighestSequence("RDK-1"),
              IsOkAndHolds(std::optional<int64_t>(3)));
  // The failed batches consumed no alert numbers.
  absl::StatusOr<BatchResult> retry = (*storage)->CommitBatch(MakeBatch("RDK-1", 1));
  ASSERT_THAT(retry, IsOk());
  EXPECT_THAT(retry->alert_sequences, ElementsAre(2));
}

TEST(Storage, SqliteConstraintFailureInsideTheTransactionRollsBackTheBatch) {
  TempDir dir;
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(dir.File("esg.db"));
  ASSERT_THAT(storage, IsOk());
  // Make SQLite itself refuse the checkpoint, the last write of the batch.
  ASSERT_THAT((*storage)->database().Execute(
                  "CREATE TRIGGER refuse_checkpoint BEFORE INSERT ON checkpoints "
                  "BEGIN SELECT RAISE(ABORT, 'checkpoint refused'); END"),
              IsOk());
  EXPECT_THAT((*storage)->CommitBatch(MakeBatch("RDK-1", 0)),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("checkpoint refused")));
  const Visible v = Count(**storage, "RDK-1");
  EXPECT_EQ(v.frames, 0);
  EXPECT_EQ(v.coefficients, 0);
  EXPECT_EQ(v.alerts, 0);
  EXPECT_EQ(v.checkpoint_sequence, std::nullopt);
}

TEST(Storage, RejectsRecordsOfAnotherSpacecraft) {
  TempDir dir;
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(dir.File("esg.db"));
  ASSERT_THAT(storage, IsOk());
  Batch batch = MakeBatch("RDK-1", 0);
  batch.alerts.push_back(Alert("RDK-2", 0));
  EXPECT_THAT((*storage)->CommitBatch(batch),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("alerts[1].spacecraft_id")));
  batch = MakeBatch("RDK-1", 0);
  batch.frames[2].spacecraft_id = "RDK-2";
  EXPECT_THAT((*storage)->CommitBatch(batch),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("frames[2].spacecraft_id")));
  batch = MakeBatch("RDK-1", 0);
  batch.checkpoint->spacecraft_id = "RDK-2";
  EXPECT_THAT((*storage)->CommitBatch(batch),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("checkpoint.spacecraft_id")));
  EXPECT_EQ(Count(**storage, "RDK-1").frames, 0);
}

TEST(Storage, DataSurvivesCloseAndReopen) {
  TempDir dir;
  const std::string path = dir.File("esg.db");
  {
    absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
    ASSERT_THAT(storage, IsOk());
    for (int64_t b = 0; b < 3; ++b) ASSERT_THAT((*storage)->CommitBatch(MakeBatch("RDK-1", b)), IsOk());
    ConfigRecord config;
    config.spacecraft_id = "RDK-1";
    config.config_json = "{}";
    config.updated_time = T(0);
    ASSERT_THAT((*storage)->configs().Put(config), IsOk());
    DiagnosisRecord diagnosis;
    diagnosis.spacecraft_id = "RDK-1";
    diagnosis.from_time = T(0);
    diagnosis.to_time = T(60);
    diagnosis.compute_time = T(61);
    diagnosis.verdict = "none";
    ASSERT_THAT((*storage)->diagnoses().Put(diagnosis), IsOk());
    ASSERT_THAT((*storage)->alerts().Acknowledge("RDK-1", 2, "ops", T(1000)), IsOk());
  }
  absl::StatusOr<std::unique_ptr<Storage>> reopened = Storage::Open(path);
  ASSERT_THAT(reopened, IsOk());
  const Visible v = Count(**reopened, "RDK-1");
  EXPECT_EQ(v.frames, 3 * kFramesPerBatch);
  EXPECT_EQ(v.coefficients, 3);
  EXPECT_EQ(v.alerts, 3);
  EXPECT_EQ(v.checkpoint_sequence, std::optional<int64_t>(3 * kFramesPerBatch - 1));
  EXPECT_THAT((*reopened)->configs().Get("RDK-1"), IsOk());
  EXPECT_THAT((*reopened)->diagnoses().List("RDK-1"), IsOkAndHolds(::testing::SizeIs(1)));
  absl::StatusOr<AlertRecord> acked = (*reopened)->alerts().Get("RDK-1", 2);
  ASSERT_THAT(acked, IsOk());
  EXPECT_EQ(acked->acknowledged_by, "ops");
  absl::StatusOr<std::vector<ArchivedFrame>> frames = (*reopened)->archive().Read("RDK-1", 5, 1);
  ASSERT_THAT(frames, IsOk());
  ASSERT_EQ(frames->size(), 1u);
  EXPECT_EQ((*frames)[0].payload, Frame("RDK-1", 5).payload);
}

// The durability contract of sqlite_db.h: a batch whose CommitBatch returned OK (the ack) is
// in the file after the writing process is killed with SIGKILL at an arbitrary point, and no
// batch is ever half there.
TEST(Storage, AcknowledgedBatchesSurviveKillNine) {
  TempDir dir;
  const std::string path = dir.File("esg.db");
  int acks[2];
  ASSERT_EQ(pipe(acks), 0);
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    // The "server": commit batches forever, acknowledging each one after CommitBatch is OK.
    close(acks[0]);
    absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
    if (!storage.ok()) _exit(2);
    for (int64_t b = 0;; ++b) {
      if (!(*storage)->CommitBatch(MakeBatch("RDK-K", b)).ok()) _exit(3);
      if (write(acks[1], &b, sizeof(b)) != static_cast<ssize_t>(sizeof(b))) _exit(4);
    }
  }
  close(acks[1]);
  constexpr int64_t kAcksBeforeKill = 25;
  int64_t last_acked = -1;
  int64_t b = 0;
  while (last_acked + 1 < kAcksBeforeKill && read(acks[0], &b, sizeof(b)) == sizeof(b)) {
    last_acked = b;
  }
  ASSERT_EQ(kill(child, SIGKILL), 0);
  int wait_status = 0;
  ASSERT_EQ(waitpid(child, &wait_status, 0), child);
  EXPECT_TRUE(WIFSIGNALED(wait_status) && WTERMSIG(wait_status) == SIGKILL)
      << "the writer ended by itself with status " << wait_status;
  while (read(acks[0], &b, sizeof(b)) == sizeof(b)) last_acked = b;  // acks sent before death
  close(acks[0]);
  ASSERT_GE(last_acked, kAcksBeforeKill - 1);

  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
  ASSERT_THAT(storage, IsOk());
  EXPECT_THAT((*storage)->database().QuickCheck(), IsOk());
  const Visible v = Count(**storage, "RDK-K");
  // Every acknowledged batch is there; one more may be (committed, killed before its ack).
  const int64_t batches = v.alerts;
  EXPECT_THAT(batches, AnyOf(last_acked + 1, last_acked + 2));
  // And each visible batch is whole.
  EXPECT_EQ(v.frames, batches * kFramesPerBatch);
  EXPECT_EQ(v.coefficients, batches);
  EXPECT_EQ(v.checkpoint_sequence, std::optional<int64_t>(batches * kFramesPerBatch - 1));
  EXPECT_THAT((*storage)->archive().HighestSequence("RDK-K"),
              IsOkAndHolds(std::optional<int64_t>(batches * kFramesPerBatch - 1)));
}

TEST(Storage, FourThreadsSharingOneStorageLoseNothing) {
  TempDir dir;
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(dir.File("esg.db"));
  ASSERT_THAT(storage, IsOk());
  constexpr int kThreads = 4;
  constexpr int kBatchesPerThread = 15;
  std::vector<absl::Status> failures(kThreads);
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      const std::string id = absl::StrCat("SC-", t);
      for (int64_t b = 0; b < kBatchesPerThread; ++b) {
        absl::StatusOr<BatchResult> r = (*storage)->CommitBatch(MakeBatch(id, b));
        if (!r.ok()) {
          failures[t] = r.status();
          return;
        }
      }
    });
  }
  for (std::thread& th : threads) th.join();
  for (const absl::Status& s : failures) EXPECT_THAT(s, IsOk());
  for (int t = 0; t < kThreads; ++t) {
    const Visible v = Count(**storage, absl::StrCat("SC-", t));
    EXPECT_EQ(v.frames, kBatchesPerThread * kFramesPerBatch) << t;
    EXPECT_EQ(v.alerts, kBatchesPerThread) << t;
    EXPECT_EQ(v.coefficients, kBatchesPerThread) << t;
  }
}

TEST(Storage, FourConnectionsWritingOneFileLoseNothingAndNumberAlertsUniquely) {
  TempDir dir;
  const std::string path = dir.File("esg.db");
  ASSERT_THAT(Storage::Open(path), IsOk());  // create and migrate once
  constexpr int kThreads = 4;
  constexpr int kBatchesPerThread = 15;
  std::vector<absl::Status> failures(kThreads);
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      DatabaseOptions shared;
      shared.exclusive = false;  // the default locks out every other connection
      absl::StatusOr<std::unique_ptr<Storage>> own = Storage::Open(path, shared);
      if (!own.ok()) {
        failures[t] = own.status();
        return;
      }
      const std::string id = absl::StrCat("SC-", t);
      for (int64_t b = 0; b < kBatchesPerThread; ++b) {
        absl::Status s = (*own)->CommitBatch(MakeBatch(id, b)).status();
        // Every connection also raises alerts on one shared spacecraft: numbering contention.
        if (s.ok()) s = (*own)->alerts().Append(Alert("SC-SHARED", 60.0 * b)).status();
        if (!s.ok()) {
          failures[t] = s;
          return;
        }
      }
    });
  }
  for (std::thread& th : threads) th.join();
  for (const absl::Status& s : failures) EXPECT_THAT(s, IsOk());

  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
  ASSERT_THAT(storage, IsOk());
  for (int t = 0; t < kThreads; ++t) {
    EXPECT_EQ(Count(**storage, absl::StrCat("SC-", t)).frames,
              kBatchesPerThread * kFramesPerBatch)
        << t;
  }
  absl::StatusOr<std::vector<AlertRecord>> shared =
      (*storage)->alerts().Since("SC-SHARED", absl::InfinitePast(), 1000);
  ASSERT_THAT(shared, IsOk());
  std::set<int64_t> sequences;
  for (const AlertRecord& a : *shared) sequences.insert(a.sequence);
  EXPECT_EQ(shared->size(), static_cast<size_t>(kThreads * kBatchesPerThread));
  ASSERT_EQ(sequences.size(), shared->size());  // unique
  EXPECT_EQ(*sequences.begin(), 1);
  EXPECT_EQ(*sequences.rbegin(), kThreads * kBatchesPerThread);  // and gap-free
}

TEST(Storage, CorruptedPagesAreReportedAsDataLossWithoutACrash) {
  TempDir dir;
  const std::string path = dir.File("esg.db");
  {
    absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
    ASSERT_THAT(storage, IsOk());
    Batch batch;
    batch.spacecraft_id = "RDK-1";
    for (int64_t s = 0; s < 200; ++s) {
      batch.frames.push_back(Frame("RDK-1", s));
      batch.frames.back().payload.append(1000, 'p');
    }
    ASSERT_THAT((*storage)->CommitBatch(batch), IsOk());
  }  // closing the last connection checkpoints the WAL into the main file
  ASSERT_FALSE(std::filesystem::exists(path + "-wal"));
  const auto size = std::filesystem::file_size(path);
  ASSERT_GT(size, 40000u);
  {
    // Garble everything after the first page (header and schema root stay readable).
    std::FILE* f = std::fopen(path.c_str(), "r+b");
    ASSERT_NE(f, nullptr);
    ASSERT_EQ(std::fseek(f, 4096, SEEK_SET), 0);
    uint32_t x = 12345;
    for (uintmax_t i = 4096; i < size; ++i) {
      x = x * 1103515245u + 12345u;
      std::fputc(static_cast<int>((x >> 16) & 0xff), f);
    }
    std::fclose(f);
  }
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
  if (!storage.ok()) {
    EXPECT_THAT(storage, StatusIs(absl::StatusCode::kDataLoss, HasSubstr("malformed")));
    return;
  }
  EXPECT_THAT((*storage)->database().QuickCheck(), StatusIs(absl::StatusCode::kDataLoss, ::testing::_));
  EXPECT_THAT((*storage)->archive().Read("RDK-1", 0, 1000),
              StatusIs(absl::StatusCode::kDataLoss, ::testing::_));
}

}  // namespace
}  // namespace esg::storage
