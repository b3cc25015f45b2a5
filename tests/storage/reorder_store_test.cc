// Tests of storage/reorder_store.h and the reorder window's parts of storage/storage.h: late
// frames recorded in the archive's transaction and forgotten in the filter's, window checkpoints
// found before a time and pruned to what the window needs, and revisions that mark (never
// delete) coefficient estimates and alerts, which the queries then leave out unless asked.
#include "storage/reorder_store.h"

#include <memory>
#include <string>
#include <vector>

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
using ::testing::ElementsAre;

// The ReorderStore tests run on both engines (tests/storage/backend.h).
class ReorderStoreTest : public BackendTest {
 protected:
  std::unique_ptr<Storage> OpenNew() {
    auto storage = Storage::Open(NewDatabase());
    EXPECT_TRUE(storage.ok()) << storage.status();
    return storage.ok() ? std::move(*storage) : nullptr;
  }
};
ESG_INSTANTIATE_BACKEND_TEST_SUITE(ReorderStoreTest);

CoefficientRecord Estimate(const std::string& id, double at_seconds) {
  CoefficientRecord r;
  r.spacecraft_id = id;
  r.gyro_id = 1;
  r.measurement_time = T(at_seconds);
  r.compute_time = T(at_seconds);
  r.values.assign(kNumCoefficientValues, 1e-7);
  r.model_name = "model10";
  return r;
}

FilterEffects Effects(const std::string& id) {
  FilterEffects e;
  e.spacecraft_id = id;
  e.checkpoint = [id](const std::vector<int64_t>&) {
    CheckpointRecord cp;
    cp.spacecraft_id = id;
    cp.state_blob = "state";
    return cp;
  };
  return e;
}

TEST_P(ReorderStoreTest, LateFramesAreRecordedWithTheirArchiveCommitAndForgottenByTheFilterCommit) {
  auto storage = OpenNew();
  ASSERT_NE(storage, nullptr);
  ASSERT_THAT(storage->ArchiveFrames({Frame("RDK-1", 3)}), IsOk());
  ASSERT_THAT(
      storage->ArchiveFrames({Frame("RDK-1", 1), Frame("RDK-1", 2)}, {{"RDK-1", {T(60), T(120)}}}),
      IsOk());
  EXPECT_THAT(storage->reorder().LateFrames("RDK-1"),
              testing::IsOkAndHolds(ElementsAre(T(60), T(120))));
  // A failed archive commit records nothing late either.
  EXPECT_FALSE(storage->ArchiveFrames({Frame("RDK-1", 2)}, {{"RDK-1", {T(600)}}}).ok());
  EXPECT_THAT(storage->reorder().LateFrames("RDK-1"),
              testing::IsOkAndHolds(ElementsAre(T(60), T(120))));
  FilterEffects e = Effects("RDK-1");
  e.late_frames_done = {T(60)};
  ASSERT_THAT(storage->CommitFilterEffects(e).status(), IsOk());
  EXPECT_THAT(storage->reorder().LateFrames("RDK-1"), testing::IsOkAndHolds(ElementsAre(T(120))));
}

TEST_P(ReorderStoreTest, CheckpointBeforeATimeAndPruningKeepTheOldestOneTheWindowNeeds) {
  auto storage = OpenNew();
  ASSERT_NE(storage, nullptr);
  for (int hour = 1; hour <= 5; ++hour) {
    FilterEffects e = Effects("RDK-1");
    e.window_checkpoint = WindowCheckpoint{T(3600.0 * hour - 60), T(0), absl::StrCat("cp", hour)};
    ASSERT_THAT(storage->CommitFilterEffects(e).status(), IsOk());
  }
  auto before = storage->reorder().CheckpointBefore("RDK-1", T(3 * 3600.0 + 10));
  ASSERT_TRUE(before.ok());
  ASSERT_TRUE(before->has_value());
  EXPECT_EQ((*before)->applied_time, T(3 * 3600.0 - 60));
  EXPECT_EQ((*before)->state_blob, "cp3");
  // Strictly before: a checkpoint at the late frame's own time does not include it.
  before = storage->reorder().CheckpointBefore("RDK-1", T(3 * 3600.0 - 60));
  ASSERT_TRUE(before.ok() && before->has_value());
  EXPECT_EQ((*before)->state_blob, "cp2");
  before = storage->reorder().CheckpointBefore("RDK-1", T(0));
  ASSERT_TRUE(before.ok());
  EXPECT_FALSE(before->has_value());
  // A late frame can come no earlier than 3:30: the checkpoint of 2:59 is the oldest needed.
  FilterEffects e = Effects("RDK-1");
  e.window_checkpoint = WindowCheckpoint{T(6 * 3600.0 - 60), T(0), "cp6"};
  e.prune_before = T(3.5 * 3600);
  ASSERT_THAT(storage->CommitFilterEffects(e).status(), IsOk());
  EXPECT_THAT(storage->reorder().CheckpointTimes("RDK-1"),
              testing::IsOkAndHolds(ElementsAre(T(3 * 3600.0 - 60), T(4 * 3600.0 - 60),
                                                T(5 * 3600.0 - 60), T(6 * 3600.0 - 60))));
}

TEST_P(ReorderStoreTest, RevisionMarksLaterEstimatesAndAlertsKeepsThemAndDropsLaterCheckpoints) {
  auto storage = OpenNew();
  ASSERT_NE(storage, nullptr);
  FilterEffects first = Effects("RDK-1");
  for (double t : {60.0, 120.0, 180.0, 240.0}) first.coefficients.push_back(Estimate("RDK-1", t));
  first.new_alerts = {Alert("RDK-1", 60), Alert("RDK-1", 200)};
  first.window_checkpoint = WindowCheckpoint{T(130), T(0), "cp"};
  ASSERT_THAT(storage->CommitFilterEffects(first).status(), IsOk());
  ASSERT_THAT(storage->alerts().UpdateRepeat("RDK-1", 1, 5, T(230)), IsOk());
  ASSERT_TRUE(storage->alerts().Clear("RDK-1", 1, T(235)).ok());
  auto after = storage->reorder().CurrentAlertsAfter("RDK-1", T(120));
  ASSERT_TRUE(after.ok());
  EXPECT_THAT(*after, ElementsAre(2));

  // A re-run from the state at 2:00: estimates after it and alert 2 revised, alert 1 set back
  // to its state then (2 occurrences, the latest at 1:50), the re-run's estimate stored.
  FilterEffects rerun = Effects("RDK-1");
  rerun.revision = FilterEffects::Revision{T(120), T(1000), {2}, {{1, 2, T(110)}}};
  rerun.coefficients.push_back(Estimate("RDK-1", 180));
  ASSERT_THAT(storage->CommitFilterEffects(rerun).status(), IsOk());
  auto current =
      storage->coefficients().History("RDK-1", 0, absl::InfinitePast(), absl::InfiniteFuture());
  ASSERT_TRUE(current.ok());
  ASSERT_EQ(current->size(), 3u);
  EXPECT_EQ((*current)[2].measurement_time, T(180));
  EXPECT_EQ((*current)[2].revised_time, absl::InfinitePast());
  auto all = storage->coefficients().History("RDK-1", 0, absl::InfinitePast(),
                                             absl::InfiniteFuture(), /*include_revised=*/true);
  ASSERT_TRUE(all.ok());
  ASSERT_EQ(all->size(), 5u);
  int revised = 0;
  for (const CoefficientRecord& r : *all) {
    if (r.revised_time == absl::InfinitePast()) continue;
    ++revised;
    EXPECT_EQ(r.revised_time, T(1000));
    EXPECT_GT(r.measurement_time, T(120));
  }
  EXPECT_EQ(revised, 2);
  auto alerts = storage->alerts().Since("RDK-1", absl::InfinitePast(), 10);
  ASSERT_TRUE(alerts.ok());
  ASSERT_EQ(alerts->size(), 1u);
  EXPECT_EQ((*alerts)[0].sequence, 1);
  EXPECT_EQ((*alerts)[0].repeat_count, 2);
  EXPECT_EQ((*alerts)[0].measurement_time, T(110));
  EXPECT_FALSE((*alerts)[0].cleared);
  auto with_revised = storage->alerts().Since("RDK-1", absl::InfinitePast(), 10, true);
  ASSERT_TRUE(with_revised.ok());
  ASSERT_EQ(with_revised->size(), 2u);
  EXPECT_EQ((*with_revised)[1].revised_time, T(1000));
  // The window checkpoint after 2:00 missed the late frame: dropped.
  EXPECT_THAT(storage->reorder().CheckpointTimes("RDK-1"), testing::IsOkAndHolds(ElementsAre()));
}

TEST_P(ReorderStoreTest, ANewSessionDropsTheWindowCheckpointsAndLateFrames) {
  auto storage = OpenNew();
  ASSERT_NE(storage, nullptr);
  ASSERT_THAT(storage->ArchiveFrames({Frame("RDK-1", 2), Frame("RDK-1", 1)}, {{"RDK-1", {T(60)}}}),
              IsOk());
  FilterEffects e = Effects("RDK-1");
  e.window_checkpoint = WindowCheckpoint{T(100), T(0), "cp"};
  ASSERT_THAT(storage->CommitFilterEffects(e).status(), IsOk());
  ConfigurationChange change;
  change.config.spacecraft_id = "RDK-1";
  change.config.config_json = "{}";
  change.checkpoint.spacecraft_id = "RDK-1";
  change.checkpoint.state_blob = "fresh";
  change.new_session = true;
  ASSERT_THAT(storage->CommitConfiguration(change).status(), IsOk());
  EXPECT_THAT(storage->reorder().LateFrames("RDK-1"), testing::IsOkAndHolds(ElementsAre()));
  EXPECT_THAT(storage->reorder().CheckpointTimes("RDK-1"), testing::IsOkAndHolds(ElementsAre()));
}

}  // namespace
}  // namespace esg::storage
