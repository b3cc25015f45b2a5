// Tests of storage/session_store.h: checkpoint round trip, replacement, NotFound, listing.
#include "storage/session_store.h"

#include <memory>
#include <string>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/storage.h"
#include "tests/storage/backend.h"
#include "tests/storage/storage_test_util.h"
#include "tests/testing/status_matchers.h"

namespace esg::storage {
namespace {

using ::esg::storage::testing::BackendTest;
using ::esg::storage::testing::IsOkAndHolds;
using ::esg::storage::testing::T;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::ElementsAre;
using ::testing::HasSubstr;

CheckpointRecord Checkpoint(const std::string& id, int64_t last_sequence) {
  CheckpointRecord c;
  c.spacecraft_id = id;
  c.last_sequence = last_sequence;
  c.measurement_time = T(60.0 * last_sequence);
  c.compute_time = T(60.0 * last_sequence + 0.5);
  c.state_blob = std::string("state\0", 6) + std::to_string(last_sequence);
  return c;
}

// The SessionStore tests run on both engines (tests/storage/backend.h).
class SessionStoreTest : public BackendTest {};
ESG_INSTANTIATE_BACKEND_TEST_SUITE(SessionStoreTest);

TEST_P(SessionStoreTest, CheckpointRoundTripsAndIsReplaced) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  SessionStore& sessions = (*storage)->sessions();
  EXPECT_THAT(sessions.GetCheckpoint("RDK-1"),
              StatusIs(absl::StatusCode::kNotFound, HasSubstr("RDK-1")));
  ASSERT_THAT(sessions.PutCheckpoint(Checkpoint("RDK-1", 10)), IsOk());
  ASSERT_THAT(sessions.PutCheckpoint(Checkpoint("RDK-1", 20)), IsOk());
  absl::StatusOr<CheckpointRecord> got = sessions.GetCheckpoint("RDK-1");
  ASSERT_THAT(got, IsOk());
  const CheckpointRecord expected = Checkpoint("RDK-1", 20);
  EXPECT_EQ(got->spacecraft_id, expected.spacecraft_id);
  EXPECT_EQ(got->last_sequence, 20);
  EXPECT_EQ(got->measurement_time, expected.measurement_time);
  EXPECT_EQ(got->compute_time, expected.compute_time);
  EXPECT_EQ(got->state_blob, expected.state_blob);
}

TEST_P(SessionStoreTest, ListsSpacecraftWithCheckpoints) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  SessionStore& sessions = (*storage)->sessions();
  ASSERT_THAT(sessions.PutCheckpoint(Checkpoint("SC-B", 1)), IsOk());
  ASSERT_THAT(sessions.PutCheckpoint(Checkpoint("SC-A", 1)), IsOk());
  ASSERT_THAT(sessions.PutCheckpoint(Checkpoint("SC-B", 2)), IsOk());
  EXPECT_THAT(sessions.ListSpacecraft(), IsOkAndHolds(ElementsAre("SC-A", "SC-B")));
}

TEST_P(SessionStoreTest, RejectsInvalidCheckpoints) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  EXPECT_THAT((*storage)->sessions().PutCheckpoint(Checkpoint("", 1)),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("checkpoint.spacecraft_id")));
  CheckpointRecord c = Checkpoint("RDK-1", 1);
  c.compute_time = absl::InfiniteFuture();
  EXPECT_THAT((*storage)->sessions().PutCheckpoint(c),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("checkpoint.compute_time")));
  EXPECT_THAT((*storage)->sessions().GetCheckpoint("RDK-1"),
              StatusIs(absl::StatusCode::kNotFound, ::testing::_));
}

}  // namespace
}  // namespace esg::storage
