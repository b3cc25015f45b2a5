// Tests of storage/orbit_store.h on both engines (tests/storage/backend.h): round trip, listing
// without the text, the deliveries meeting a span in upload order, the bound per spacecraft,
// and the refusals naming the field.
#include "storage/orbit_store.h"

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

using ::esg::storage::testing::BackendTest;
using ::esg::storage::testing::T;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::HasSubstr;

OrbitRecord Delivery(const std::string& id, double from_s, double to_s) {
  OrbitRecord r;
  r.spacecraft_id = id;
  r.from_time = T(from_s);
  r.to_time = T(to_s);
  r.upload_time = T(to_s + 60);
  r.states = 1 + static_cast<int64_t>((to_s - from_s) / 60);
  r.uploaded_by = "flight-dynamics";
  r.oem_text = "CCSDS_OEM_VERS = 2.0\n(" + id + " " + std::to_string(from_s) + ")\n";
  return r;
}

std::vector<int64_t> Ids(const std::vector<OrbitRecord>& records) {
  std::vector<int64_t> ids;
  for (const OrbitRecord& r : records) ids.push_back(r.id);
  return ids;
}

class OrbitStoreTest : public BackendTest {};
ESG_INSTANTIATE_BACKEND_TEST_SUITE(OrbitStoreTest);

TEST_P(OrbitStoreTest, StoredDeliveriesComeBackByTheSpanTheyMeetInUploadOrder) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  OrbitStore& orbits = (*storage)->orbits();
  absl::StatusOr<int64_t> day1 = orbits.Put(Delivery("SC-1", 0, 86400));
  absl::StatusOr<int64_t> other = orbits.Put(Delivery("SC-2", 0, 86400));
  absl::StatusOr<int64_t> day2 = orbits.Put(Delivery("SC-1", 86400, 2 * 86400));
  absl::StatusOr<int64_t> redo1 = orbits.Put(Delivery("SC-1", 43200, 86400));
  ASSERT_THAT(day1, IsOk());
  ASSERT_THAT(other, IsOk());
  ASSERT_THAT(day2, IsOk());
  ASSERT_THAT(redo1, IsOk());
  EXPECT_LT(*day1, *other);
  EXPECT_LT(*day2, *redo1);

  absl::StatusOr<std::vector<OrbitRecord>> listed = orbits.ListSummaries("SC-1");
  ASSERT_THAT(listed, IsOk());
  EXPECT_EQ(Ids(*listed), (std::vector<int64_t>{*day1, *day2, *redo1}));
  for (const OrbitRecord& r : *listed) EXPECT_EQ(r.oem_text, "");  // summaries
  EXPECT_EQ((*listed)[1].from_time, T(86400));
  EXPECT_EQ((*listed)[1].to_time, T(2 * 86400));
  EXPECT_EQ((*listed)[1].upload_time, T(2 * 86400 + 60));
  EXPECT_EQ((*listed)[1].states, 1441);
  EXPECT_EQ((*listed)[1].uploaded_by, "flight-dynamics");

  // A span inside day 1's second half meets day 1 and its redo (and day 2 at its first
  // instant only when the span reaches it), with their text.
  absl::StatusOr<std::vector<OrbitRecord>> covering = orbits.Covering("SC-1", T(50000), T(60000));
  ASSERT_THAT(covering, IsOk());
  EXPECT_EQ(Ids(*covering), (std::vector<int64_t>{*day1, *redo1}));
  EXPECT_EQ((*covering)[0].oem_text, Delivery("SC-1", 0, 86400).oem_text);
  covering = orbits.Covering("SC-1", T(80000), T(86400));
  ASSERT_THAT(covering, IsOk());
  EXPECT_EQ(Ids(*covering), (std::vector<int64_t>{*day1, *day2, *redo1}));
  covering = orbits.Covering("SC-1", T(3 * 86400), T(4 * 86400));
  ASSERT_THAT(covering, IsOk());
  EXPECT_TRUE(covering->empty());
}

TEST_P(OrbitStoreTest, BeyondTheBoundTheOldestUploadsOfThatSpacecraftGo) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  OrbitStore& orbits = (*storage)->orbits();
  orbits.set_max_per_spacecraft(2);
  std::vector<int64_t> ids;
  for (int day = 0; day < 4; ++day) {
    absl::StatusOr<int64_t> id = orbits.Put(Delivery("SC-1", day * 86400.0, (day + 1) * 86400.0));
    ASSERT_THAT(id, IsOk());
    ids.push_back(*id);
    ASSERT_THAT(orbits.Put(Delivery("SC-2", day * 86400.0, (day + 1) * 86400.0)), IsOk());
  }
  absl::StatusOr<std::vector<OrbitRecord>> listed = orbits.ListSummaries("SC-1");
  ASSERT_THAT(listed, IsOk());
  EXPECT_EQ(Ids(*listed), (std::vector<int64_t>{ids[2], ids[3]}));
  listed = orbits.ListSummaries("SC-2");
  ASSERT_THAT(listed, IsOk());
  EXPECT_EQ(listed->size(), 2u);  // each spacecraft's own bound
}

TEST_P(OrbitStoreTest, BadRecordsAreRefusedNamingTheField) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  OrbitStore& orbits = (*storage)->orbits();
  OrbitRecord r = Delivery("SC-1", 0, 86400);
  r.spacecraft_id = "";
  EXPECT_THAT(orbits.Put(r).status(), StatusIs(absl::StatusCode::kInvalidArgument,
                                               HasSubstr("orbit.spacecraft_id")));
  r = Delivery("SC-1", 0, 86400);
  r.oem_text = "";
  EXPECT_THAT(orbits.Put(r).status(),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("orbit.oem_text")));
  r = Delivery("SC-1", 86400, 0);
  EXPECT_THAT(orbits.Put(r).status(),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("orbit.to_time")));
  r = Delivery("SC-1", 0, 86400);
  r.states = 1;
  EXPECT_THAT(orbits.Put(r).status(),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("orbit.states")));
  absl::StatusOr<std::vector<OrbitRecord>> listed = orbits.ListSummaries("SC-1");
  ASSERT_THAT(listed, IsOk());
  EXPECT_TRUE(listed->empty());
}

}  // namespace
}  // namespace esg::storage
