// Tests of storage/storage.h: the server's three transactions (ArchiveFrames refusing frames
// already archived, CommitFilterEffects and CommitConfiguration round trips, all-or-nothing on a
// failure inside each), persistence across reopen, acknowledged frames and committed effects
// surviving kill -9 of the writing process, concurrent writers (shared object and separate
// connections), and a corrupted file. The TEST_P tests run on SQLite and PostgreSQL
// (tests/storage/backend.h); kill -9 of the writer, several connections to one file and the
// corrupted file are about SQLite's file and stay TEST (SQLite only).
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
#include "absl/strings/str_join.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/schema.h"
#include "tests/storage/backend.h"
#include "tests/storage/storage_test_util.h"
#include "tests/testing/status_matchers.h"
#include "tests/testing/temp_dir.h"

namespace esg::storage {
namespace {

using ::esg::storage::testing::Alert;
using ::esg::storage::testing::BackendTest;
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

// Step number b of spacecraft `id` as the server writes it: the group commit of frames
// b*4 .. b*4+3, then the filter's effects: one coefficient estimate, one alert, and the
// checkpoint after the last frame (its blob lists the alert sequences it was built with).
struct Step {
  std::vector<ArchivedFrame> frames;
  FilterEffects effects;
};

Step MakeStep(const std::string& id, int64_t b) {
  Step step;
  for (int64_t s = b * kFramesPerBatch; s < (b + 1) * kFramesPerBatch; ++s) {
    step.frames.push_back(Frame(id, s));
  }
  const int64_t last = (b + 1) * kFramesPerBatch - 1;
  step.effects.spacecraft_id = id;
  step.effects.coefficients.push_back(Coefficients(id, 1, 60.0 * last));
  step.effects.new_alerts.push_back(Alert(id, 60.0 * last));
  step.effects.checkpoint = [id, last](const std::vector<int64_t>& alert_sequences) {
    CheckpointRecord checkpoint;
    checkpoint.spacecraft_id = id;
    checkpoint.last_sequence = last;
    checkpoint.measurement_time = T(60.0 * last);
    checkpoint.compute_time = T(60.0 * last + 1);
    checkpoint.state_blob = absl::StrCat("state after ", last, ", alerts ",
                                         absl::StrJoin(alert_sequences, ","));
    return checkpoint;
  };
  return step;
}

// Both transactions of a step, in the server's order; the first error.
absl::Status CommitStep(Storage& storage, const Step& step) {
  if (absl::Status archived = storage.ArchiveFrames(step.frames); !archived.ok()) return archived;
  return storage.CommitFilterEffects(step.effects).status();
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

// The Storage tests run on both engines (tests/storage/backend.h).
class StorageTest : public BackendTest {};
ESG_INSTANTIATE_BACKEND_TEST_SUITE(StorageTest);

TEST_P(StorageTest, FilterEffectsWriteEveryKindAndReturnAlertSequences) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  Step step = MakeStep("RDK-1", 0);
  step.effects.new_alerts.push_back(Alert("RDK-1", 30, "PAIR_MISMATCH"));
  ASSERT_THAT((*storage)->ArchiveFrames(step.frames), IsOk());
  EXPECT_THAT((*storage)->CommitFilterEffects(step.effects),
              IsOkAndHolds(ElementsAre(1, 2)));

  const Visible v = Count(**storage, "RDK-1");
  EXPECT_EQ(v.frames, 4);
  EXPECT_EQ(v.coefficients, 1);
  EXPECT_EQ(v.alerts, 2);
  EXPECT_EQ(v.checkpoint_sequence, std::optional<int64_t>(3));
  // The checkpoint was built with the sequences the store assigned.
  absl::StatusOr<CheckpointRecord> checkpoint = (*storage)->sessions().GetCheckpoint("RDK-1");
  ASSERT_THAT(checkpoint, IsOk());
  EXPECT_EQ(checkpoint->state_blob, "state after 3, alerts 1,2");
  absl::StatusOr<AlertRecord> second = (*storage)->alerts().Get("RDK-1", 2);
  ASSERT_THAT(second, IsOk());
  EXPECT_EQ(second->reason, "PAIR_MISMATCH");

  // The next job collapses a repeat into alert 1, clears alert 2, and numbering continues.
  Step next = MakeStep("RDK-1", 1);
  next.effects.repeats.push_back(AlertRepeat{"RDK-1", 1, 2, T(420)});
  next.effects.clears.push_back(AlertClear{2, T(430)});
  ASSERT_THAT((*storage)->ArchiveFrames(next.frames), IsOk());
  EXPECT_THAT((*storage)->CommitFilterEffects(next.effects), IsOkAndHolds(ElementsAre(3)));
  absl::StatusOr<AlertRecord> first = (*storage)->alerts().Get("RDK-1", 1);
  ASSERT_THAT(first, IsOk());
  EXPECT_EQ(first->repeat_count, 2);
  EXPECT_EQ(first->measurement_time, T(420));
  second = (*storage)->alerts().Get("RDK-1", 2);
  ASSERT_THAT(second, IsOk());
  EXPECT_TRUE(second->cleared);
  EXPECT_EQ(second->cleared_time, T(430));
}

TEST_P(StorageTest, ArchiveFramesRefusesFramesAlreadyArchivedAndStoresNoneOfTheCommit) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  ASSERT_THAT(CommitStep(**storage, MakeStep("RDK-1", 0)), IsOk());
  // Frames of two spacecraft in one commit, one of them already archived.
  std::vector<ArchivedFrame> frames = MakeStep("RDK-1", 1).frames;
  frames.push_back(Frame("RDK-2", 0));
  frames.push_back(Frame("RDK-1", 2));
  EXPECT_THAT((*storage)->ArchiveFrames(frames),
              StatusIs(absl::StatusCode::kAlreadyExists,
                       HasSubstr("RDK-1: 1 frames are already archived (first sequence 2)")));
  EXPECT_EQ(Count(**storage, "RDK-1").frames, 4);
  EXPECT_EQ(Count(**storage, "RDK-2").frames, 0);
  frames.pop_back();
  ASSERT_THAT((*storage)->ArchiveFrames(frames), IsOk());
  EXPECT_EQ(Count(**storage, "RDK-1").frames, 8);
  EXPECT_EQ(Count(**storage, "RDK-2").frames, 1);
  // A frame the archive rejects is named by its place.
  frames = {Frame("RDK-3", 0), Frame("RDK-3", 1)};
  frames[1].spacecraft_id.clear();
  EXPECT_THAT((*storage)->ArchiveFrames(frames),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("frames[1]")));
  EXPECT_EQ(Count(**storage, "RDK-3").frames, 0);
}

TEST_P(StorageTest, FailureLateInTheFilterEffectsLeavesNothingOfThem) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  ASSERT_THAT(CommitStep(**storage, MakeStep("RDK-1", 0)), IsOk());
  ASSERT_THAT((*storage)->ArchiveFrames(MakeStep("RDK-1", 1).frames), IsOk());
  const Visible before = Count(**storage, "RDK-1");

  // Coefficients and alerts are inserted before the repeat of a missing alert fails.
  Step missing_alert = MakeStep("RDK-1", 1);
  missing_alert.effects.repeats.push_back(AlertRepeat{"RDK-1", 99, 2, T(500)});
  EXPECT_THAT((*storage)->CommitFilterEffects(missing_alert.effects),
              StatusIs(absl::StatusCode::kNotFound, HasSubstr("repeats[0]")));

  // A record only its store rejects.
  Step bad_alert = MakeStep("RDK-1", 1);
  bad_alert.effects.new_alerts.push_back(Alert("RDK-1", 500));
  bad_alert.effects.new_alerts.back().severity.clear();
  EXPECT_THAT((*storage)->CommitFilterEffects(bad_alert.effects),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("new_alerts[1]")));

  // An invalid coefficient estimate after a valid one.
  Step bad_coefficient = MakeStep("RDK-1", 1);
  bad_coefficient.effects.coefficients.push_back(Coefficients("RDK-1", 0, 500));
  EXPECT_THAT((*storage)->CommitFilterEffects(bad_coefficient.effects),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("coefficients[1]")));

  const Visible after = Count(**storage, "RDK-1");
  EXPECT_EQ(after.frames, before.frames);
  EXPECT_EQ(after.coefficients, before.coefficients);
  EXPECT_EQ(after.alerts, before.alerts);
  EXPECT_EQ(after.checkpoint_sequence, before.checkpoint_sequence);
  // The failed transactions consumed no alert numbers.
  EXPECT_THAT((*storage)->CommitFilterEffects(MakeStep("RDK-1", 1).effects),
              IsOkAndHolds(ElementsAre(2)));
}

TEST_P(StorageTest, EngineConstraintFailureInsideTheTransactionRollsItBack) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  // Make the engine itself refuse the checkpoint, the last write of the filter's transaction,
  // with a constraint error (SQLite's RAISE(ABORT), PostgreSQL's check_violation, SQLSTATE
  // 23514): the trigger is the one piece of SQL written per engine.
  const char* trigger =
      GetParam() == testing::Backend::kSqlite
          ? "CREATE TRIGGER refuse_checkpoint BEFORE INSERT ON checkpoints "
            "BEGIN SELECT RAISE(ABORT, 'checkpoint refused'); END"
          : "CREATE FUNCTION refuse_checkpoint() RETURNS trigger LANGUAGE plpgsql AS $$ "
            "BEGIN RAISE EXCEPTION 'checkpoint refused' USING ERRCODE = 'check_violation'; "
            "END $$; "
            "CREATE TRIGGER refuse_checkpoint BEFORE INSERT ON checkpoints "
            "FOR EACH ROW EXECUTE FUNCTION refuse_checkpoint()";
  ASSERT_THAT((*storage)->database().Execute(trigger), IsOk());
  EXPECT_THAT((*storage)->CommitFilterEffects(MakeStep("RDK-1", 0).effects),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("checkpoint refused")));
  const Visible v = Count(**storage, "RDK-1");
  EXPECT_EQ(v.coefficients, 0);
  EXPECT_EQ(v.alerts, 0);
  EXPECT_EQ(v.checkpoint_sequence, std::nullopt);
}

// The filter's group commit (Storage::CommitFilterEffectsGroup): several spacecraft's jobs in
// one transaction, one of which the engine refuses half-way (coefficients and alert written,
// then the checkpoint refused by a trigger for that spacecraft only). Its writes are undone
// alone; the others' are committed, and each job gets its own result in the order given.
TEST_P(StorageTest, AGroupOfFilterJobsCommitsEachAndUndoesARefusedJobAlone) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  const char* trigger =
      GetParam() == testing::Backend::kSqlite
          ? "CREATE TRIGGER refuse_checkpoint BEFORE INSERT ON checkpoints "
            "WHEN NEW.spacecraft_id = 'G-B' BEGIN SELECT RAISE(ABORT, 'checkpoint refused'); END"
          : "CREATE FUNCTION refuse_checkpoint() RETURNS trigger LANGUAGE plpgsql AS $$ "
            "BEGIN IF NEW.spacecraft_id = 'G-B' THEN RAISE EXCEPTION 'checkpoint refused' "
            "USING ERRCODE = 'check_violation'; END IF; RETURN NEW; END $$; "
            "CREATE TRIGGER refuse_checkpoint BEFORE INSERT ON checkpoints "
            "FOR EACH ROW EXECUTE FUNCTION refuse_checkpoint()";
  ASSERT_THAT((*storage)->database().Execute(trigger), IsOk());
  std::vector<Step> steps = {MakeStep("G-C", 0), MakeStep("G-B", 0), MakeStep("G-A", 0)};
  steps[2].effects.new_alerts.push_back(Alert("G-A", 30, "PAIR_MISMATCH"));
  std::vector<const FilterEffects*> jobs;
  for (const Step& step : steps) {
    ASSERT_THAT((*storage)->ArchiveFrames(step.frames), IsOk());
    jobs.push_back(&step.effects);
  }
  const std::vector<absl::StatusOr<std::vector<int64_t>>> results =
      (*storage)->CommitFilterEffectsGroup(jobs);
  ASSERT_EQ(results.size(), 3u);
  EXPECT_THAT(results[0], IsOkAndHolds(ElementsAre(1)));
  EXPECT_THAT(results[1],
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("checkpoint refused")));
  EXPECT_THAT(results[2], IsOkAndHolds(ElementsAre(1, 2)));
  for (const char* id : {"G-A", "G-C"}) {
    const Visible v = Count(**storage, id);
    EXPECT_EQ(v.coefficients, 1) << id;
    EXPECT_EQ(v.alerts, id == std::string("G-A") ? 2 : 1) << id;
    EXPECT_EQ(v.checkpoint_sequence, std::optional<int64_t>(3)) << id;
  }
  const Visible refused = Count(**storage, "G-B");
  EXPECT_EQ(refused.frames, 4);
  EXPECT_EQ(refused.coefficients, 0);
  EXPECT_EQ(refused.alerts, 0);
  EXPECT_EQ(refused.checkpoint_sequence, std::nullopt);
  // A job refused before the transaction (no checkpoint function) is named alone too.
  Step next = MakeStep("G-A", 1);
  ASSERT_THAT((*storage)->ArchiveFrames(next.frames), IsOk());
  Step broken = MakeStep("G-C", 1);
  broken.effects.checkpoint = nullptr;
  const std::vector<absl::StatusOr<std::vector<int64_t>>> again =
      (*storage)->CommitFilterEffectsGroup({&broken.effects, &next.effects});
  ASSERT_EQ(again.size(), 2u);
  EXPECT_THAT(again[0], StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("checkpoint")));
  EXPECT_THAT(again[1], IsOkAndHolds(ElementsAre(3)));
  EXPECT_EQ(Count(**storage, "G-A").checkpoint_sequence, std::optional<int64_t>(7));
  EXPECT_EQ(Count(**storage, "G-C").checkpoint_sequence, std::optional<int64_t>(3));
}

TEST_P(StorageTest, RejectsRecordsOfAnotherSpacecraft) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  Step step = MakeStep("RDK-1", 0);
  step.effects.new_alerts.push_back(Alert("RDK-2", 0));
  EXPECT_THAT((*storage)->CommitFilterEffects(step.effects),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("new_alerts[1].spacecraft_id")));
  step = MakeStep("RDK-1", 0);
  step.effects.checkpoint = [](const std::vector<int64_t>&) {
    CheckpointRecord checkpoint;
    checkpoint.spacecraft_id = "RDK-2";
    return checkpoint;
  };
  EXPECT_THAT((*storage)->CommitFilterEffects(step.effects),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("checkpoint.spacecraft_id")));
  step.effects.checkpoint = nullptr;
  EXPECT_THAT((*storage)->CommitFilterEffects(step.effects),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("checkpoint: required")));
  EXPECT_EQ(Count(**storage, "RDK-1").alerts, 0);
}

TEST_P(StorageTest, ConfigurationIsStoredWithItsCheckpointAndAlertChanges) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  ASSERT_THAT((*storage)->alerts().Append(Alert("RDK-1", 60)), IsOkAndHolds(1));
  ConfigurationChange change;
  change.config.spacecraft_id = "RDK-1";
  change.config.config_json = "{}";
  change.config.updated_time = T(100);
  change.checkpoint.spacecraft_id = "RDK-1";
  change.checkpoint.state_blob = "fresh";
  change.new_alerts.push_back(Alert("RDK-1", 90, "SESSION_QUARANTINED"));
  change.clears.push_back(AlertClear{1, T(95)});
  EXPECT_THAT((*storage)->CommitConfiguration(change), IsOkAndHolds(ElementsAre(2)));
  EXPECT_THAT((*storage)->configs().Get("RDK-1"), IsOk());
  absl::StatusOr<CheckpointRecord> checkpoint = (*storage)->sessions().GetCheckpoint("RDK-1");
  ASSERT_THAT(checkpoint, IsOk());
  EXPECT_EQ(checkpoint->state_blob, "fresh");
  absl::StatusOr<AlertRecord> cleared = (*storage)->alerts().Get("RDK-1", 1);
  ASSERT_THAT(cleared, IsOk());
  EXPECT_TRUE(cleared->cleared);
  // A clear of a missing alert fails the whole configuration.
  change.checkpoint.state_blob = "second";
  change.new_alerts.clear();
  change.clears = {AlertClear{99, T(95)}};
  EXPECT_THAT((*storage)->CommitConfiguration(change),
              StatusIs(absl::StatusCode::kNotFound, HasSubstr("clears[0]")));
  checkpoint = (*storage)->sessions().GetCheckpoint("RDK-1");
  ASSERT_THAT(checkpoint, IsOk());
  EXPECT_EQ(checkpoint->state_blob, "fresh");
}

TEST_P(StorageTest, DataSurvivesCloseAndReopen) {
  const std::string path = NewDatabase();
  {
    absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
    ASSERT_THAT(storage, IsOk());
    for (int64_t b = 0; b < 3; ++b) ASSERT_THAT(CommitStep(**storage, MakeStep("RDK-1", b)), IsOk());
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

// The durability contract of sqlite_db.h: frames whose ArchiveFrames returned OK (the ack) and
// effects whose CommitFilterEffects returned OK are in the file after the writing process is
// killed with SIGKILL at an arbitrary point, and no transaction is ever half there.
// SQLite only: the writer is a forked process holding the file, killed with SIGKILL (the
// PostgreSQL server's own crash is in postgres_db_test.cc).
TEST(Storage, AcknowledgedBatchesSurviveKillNine) {
  TempDir dir;
  const std::string path = dir.File("esg.db");
  int acks[2];
  ASSERT_EQ(pipe(acks), 0);
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    // The "server": commit steps forever, acknowledging each one after both commits are OK.
    close(acks[0]);
    absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
    if (!storage.ok()) _exit(2);
    for (int64_t b = 0;; ++b) {
      if (!CommitStep(**storage, MakeStep("RDK-K", b)).ok()) _exit(3);
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
  // Every acknowledged step is there; one more may be (committed, killed before its ack).
  const int64_t batches = v.alerts;
  EXPECT_THAT(batches, AnyOf(last_acked + 1, last_acked + 2));
  // Each visible filter transaction is whole; the frames of one more step may be archived
  // (killed between the two transactions: the server's restart applies them from the archive).
  EXPECT_EQ(v.coefficients, batches);
  EXPECT_EQ(v.checkpoint_sequence, std::optional<int64_t>(batches * kFramesPerBatch - 1));
  EXPECT_THAT(v.frames, AnyOf(batches * kFramesPerBatch, (batches + 1) * kFramesPerBatch));
  EXPECT_THAT((*storage)->archive().HighestSequence("RDK-K"),
              IsOkAndHolds(std::optional<int64_t>(v.frames - 1)));
}

TEST_P(StorageTest, FourThreadsSharingOneStorageLoseNothing) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  constexpr int kThreads = 4;
  constexpr int kBatchesPerThread = 15;
  std::vector<absl::Status> failures(kThreads);
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      const std::string id = absl::StrCat("SC-", t);
      for (int64_t b = 0; b < kBatchesPerThread; ++b) {
        absl::Status r = CommitStep(**storage, MakeStep(id, b));
        if (!r.ok()) {
          failures[t] = r;
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

// SQLite only: several connections to one file (DatabaseOptions::exclusive = false). With
// PostgreSQL each spacecraft is written by the one server that owns it (docs/service.md
// "Storage backends"), so one spacecraft's alerts numbered from four connections is not a case.
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
        absl::Status s = CommitStep(**own, MakeStep(id, b));
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

// SQLite only: garbles the pages of the database file.
TEST(Storage, CorruptedPagesAreReportedAsDataLossWithoutACrash) {
  TempDir dir;
  const std::string path = dir.File("esg.db");
  {
    absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
    ASSERT_THAT(storage, IsOk());
    std::vector<ArchivedFrame> frames;
    for (int64_t s = 0; s < 200; ++s) {
      frames.push_back(Frame("RDK-1", s));
      frames.back().payload.append(1000, 'p');
    }
    ASSERT_THAT((*storage)->ArchiveFrames(frames), IsOk());
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
