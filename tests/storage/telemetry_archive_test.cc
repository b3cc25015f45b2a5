// Tests of storage/telemetry_archive.h: batch append with duplicates, ordering of reads,
// time ranges, highest sequence, argument errors.
#include "storage/telemetry_archive.h"

#include <cstdint>
#include <memory>
#include <optional>
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

using ::esg::storage::testing::BackendTest;
using ::esg::storage::testing::Frame;
using ::esg::storage::testing::IsOkAndHolds;
using ::esg::storage::testing::T;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::IsEmpty;

std::vector<int64_t> Sequences(const std::vector<ArchivedFrame>& frames) {
  std::vector<int64_t> out;
  for (const ArchivedFrame& f : frames) out.push_back(f.sequence);
  return out;
}

// The TelemetryArchive tests run on both engines (tests/storage/backend.h).
class TelemetryArchiveTest : public BackendTest {};
ESG_INSTANTIATE_BACKEND_TEST_SUITE(TelemetryArchiveTest);

TEST_P(TelemetryArchiveTest, AppendedFramesReadBackExactly) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  TelemetryArchive& archive = (*storage)->archive();
  const std::vector<ArchivedFrame> frames = {Frame("RDK-1", 3), Frame("RDK-1", 1),
                                             Frame("RDK-1", 2)};
  absl::StatusOr<AppendResult> result = archive.AppendBatch("RDK-1", frames);
  ASSERT_THAT(result, IsOk());
  EXPECT_THAT(result->new_sequences, ElementsAre(3, 1, 2));
  EXPECT_THAT(result->duplicate_sequences, IsEmpty());

  absl::StatusOr<std::vector<ArchivedFrame>> read = archive.Read("RDK-1", 0, 100);
  ASSERT_THAT(read, IsOk());
  ASSERT_THAT(Sequences(*read), ElementsAre(1, 2, 3));  // sequence order, not insertion order
  for (const ArchivedFrame& f : *read) {
    const ArchivedFrame expected = Frame("RDK-1", f.sequence);
    EXPECT_EQ(f.spacecraft_id, expected.spacecraft_id);
    EXPECT_EQ(f.measurement_time, expected.measurement_time);
    EXPECT_EQ(f.payload, expected.payload);  // binary, with an embedded NUL
  }
}

TEST_P(TelemetryArchiveTest, DuplicatesAreIgnoredCountedAndNeverOverwrite) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  TelemetryArchive& archive = (*storage)->archive();
  ASSERT_THAT(archive.AppendBatch("RDK-1", {Frame("RDK-1", 1), Frame("RDK-1", 2)}), IsOk());

  ArchivedFrame resent = Frame("RDK-1", 2);
  resent.payload = "different bytes";
  absl::StatusOr<AppendResult> result =
      archive.AppendBatch("RDK-1", {resent, Frame("RDK-1", 3), Frame("RDK-1", 3)});
  ASSERT_THAT(result, IsOk());
  EXPECT_THAT(result->new_sequences, ElementsAre(3));
  EXPECT_THAT(result->duplicate_sequences, ElementsAre(2, 3));

  absl::StatusOr<std::vector<ArchivedFrame>> read = archive.Read("RDK-1", 2, 1);
  ASSERT_THAT(read, IsOk());
  ASSERT_EQ(read->size(), 1u);
  EXPECT_EQ((*read)[0].payload, Frame("RDK-1", 2).payload);  // the first copy stays
  // The same sequence number of another spacecraft is not a duplicate.
  absl::StatusOr<AppendResult> other = archive.AppendBatch("RDK-2", {Frame("RDK-2", 2)});
  ASSERT_THAT(other, IsOk());
  EXPECT_THAT(other->new_sequences, ElementsAre(2));
}

TEST_P(TelemetryArchiveTest, HighestSequenceAndReadWindows) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  TelemetryArchive& archive = (*storage)->archive();
  EXPECT_THAT(archive.HighestSequence("RDK-1"), IsOkAndHolds(std::optional<int64_t>()));
  std::vector<ArchivedFrame> frames;
  for (int64_t s = 0; s < 10; ++s) frames.push_back(Frame("RDK-1", s));
  ASSERT_THAT(archive.AppendBatch("RDK-1", frames), IsOk());
  ASSERT_THAT(archive.AppendBatch("RDK-2", {Frame("RDK-2", 50)}), IsOk());
  EXPECT_THAT(archive.HighestSequence("RDK-1"), IsOkAndHolds(std::optional<int64_t>(9)));

  absl::StatusOr<std::vector<ArchivedFrame>> page = archive.Read("RDK-1", 4, 3);
  ASSERT_THAT(page, IsOk());
  EXPECT_THAT(Sequences(*page), ElementsAre(4, 5, 6));
  EXPECT_THAT(archive.Read("RDK-1", 10, 3), IsOkAndHolds(IsEmpty()));
  EXPECT_THAT(archive.Read("RDK-1", 0, 0),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("limit")));

  // Frame s is at T(60 s); [T(120), T(300)) holds sequences 2, 3, 4.
  absl::StatusOr<std::vector<ArchivedFrame>> range =
      archive.ReadTimeRange("RDK-1", T(120), T(300));
  ASSERT_THAT(range, IsOk());
  EXPECT_THAT(Sequences(*range), ElementsAre(2, 3, 4));
  absl::StatusOr<std::vector<ArchivedFrame>> all =
      archive.ReadTimeRange("RDK-1", absl::InfinitePast(), absl::InfiniteFuture());
  ASSERT_THAT(all, IsOk());
  EXPECT_EQ(all->size(), 10u);
}

TEST_P(TelemetryArchiveTest, InvalidBatchWritesNothing) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  TelemetryArchive& archive = (*storage)->archive();
  EXPECT_THAT(archive.AppendBatch("RDK-1", {Frame("RDK-1", 1), Frame("RDK-9", 2)}),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("frames[1].spacecraft_id")));
  ArchivedFrame bad_time = Frame("RDK-1", 3);
  bad_time.measurement_time = absl::InfinitePast();
  EXPECT_THAT(archive.AppendBatch("RDK-1", {Frame("RDK-1", 1), bad_time}),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("frames[1].measurement_time")));
  EXPECT_THAT(archive.AppendBatch("", {}),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("spacecraft_id")));
  EXPECT_THAT(archive.HighestSequence("RDK-1"), IsOkAndHolds(std::optional<int64_t>()));
}

}  // namespace
}  // namespace esg::storage
